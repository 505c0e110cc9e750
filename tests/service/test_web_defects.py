"""The page's wrong states, each as a user meets it, in headless Chromium against a real `holo serve`: re-run with
changes gives back every option of the job; a missing job's page shows nothing of the job seen before; signing
out leaves nothing of one owner's form to the next, and a read-only token sends no estimate.

One server, one browser and the jobs made through the API are shared by the module's tests.
"""

from __future__ import annotations

import json
import time

import pytest

from tests.service.test_web_page import Page, browser, files, page, scene  # noqa: F401 (fixtures)

pytestmark = pytest.mark.slow

# every job option the form has, away from its default (a direct job, and a wrp one at 6 planes)
DIRECT_JOB = {"optics": {"resolution_hw": [72, 104], "seed": 5}, "method": "direct", "wrp_planes": "auto",
              "preset": "fast", "frames": 3, "spp": 7, "encoder": "dpac", "evaluate": True, "display": "bench-a",
              "name": "direct demo"}
WRP6_JOB = {"optics": {"resolution_hw": [80, 120], "seed": 9}, "method": "wrp", "wrp_planes": 6,
            "preset": "reference", "frames": 5, "spp": 9, "render_time_limit_s": 30.0, "encoder": "sgd",
            "iterations": 33, "evaluate": False, "name": "six planes"}
OPTION_KEYS = ("method", "wrp_planes", "preset", "frames", "spp", "render_time_limit_s", "encoder", "iterations",
               "evaluate", "quality_db", "max_spp")


@pytest.fixture(scope="module")
def made_jobs(server, scene) -> dict[str, dict]:
    """The two jobs, made through the API and cancelled at once (their options are all a re-run needs)."""
    out = {}
    with server.client("submit") as c:
        for key, body in (("direct", DIRECT_JOB), ("wrp6", WRP6_JOB)):
            r = c.post("/v1/jobs", json={"scene_id": scene["id"], **body})
            assert r.status_code == 202, r.text
            c.delete(f"/v1/jobs/{r.json()['id']}")
            out[key] = c.get(f"/v1/jobs/{r.json()['id']}").json()
    return out


def _console_errors(p: Page) -> list[str]:
    return [e["message"] for e in p.d.get_log("browser") if e.get("level") == "SEVERE"]


@pytest.mark.parametrize("which", ["direct", "wrp6"])
def test_rerun_with_changes_submits_every_option_of_the_job(page, server, made_jobs, which):
    from selenium.webdriver.common.by import By

    job = made_jobs[which]
    page.go(f"#/jobs/{job['id']}")
    page.until(lambda: page.visible("job-rerun"), what="the Re-run button")
    page.d.find_element(By.ID, "job-rerun").click()
    page.until(lambda: page.visible("rerun-note") and page.enabled("submit-button"), what="the re-run's estimate")
    page.js("""window.posted = []; const f = window.fetch;
               window.fetch = (u, o) => { if (String(u) === '/v1/jobs' && o && o.method === 'POST')
                                            window.posted.push(o.body); return f(u, o); };""")
    page.d.find_element(By.ID, "submit-button").click()
    shown = {}  # the new job's id as its page shows it (the view redraws: read it once, in the wait)

    def on_new_page() -> bool:
        shown["id"] = page.text("job-id")
        return page.js("return window.posted.length") == 1 and shown["id"] not in ("", job["id"])

    page.until(on_new_page, what="the re-run job's page")
    sent = json.loads(page.js("return window.posted[0]"))
    asked = DIRECT_JOB if which == "direct" else WRP6_JOB
    for key, value in asked.items():
        if key == "name":
            continue
        got = sent.get(key) if key != "optics" else {k: sent["optics"][k] for k in value}
        assert got == value, f"{key}: sent {got!r}, the job had {value!r}"
    new_id = shown["id"]
    with server.client("submit") as c:
        again = c.get(f"/v1/jobs/{new_id}").json()
        c.delete(f"/v1/jobs/{new_id}")
    for key in OPTION_KEYS:
        assert again["options"].get(key) == job["options"].get(key), key
    assert again["options"]["optics"] == job["options"]["optics"]
    assert again["display"] == job["display"]


def test_a_missing_jobs_page_shows_nothing_of_the_job_before(page, made_jobs):
    job = made_jobs["direct"]
    page.go(f"#/jobs/{job['id']}")
    page.until(lambda: page.visible("job-fov-box") and page.text("job-fov-caption"), what="the job's scene picture")
    page.go("#/jobs/nosuchjob0000")
    page.until(lambda: "not found" in page.text("job-error").lower(), what="the missing job's message")
    assert page.text("job-id") == "nosuchjob0000"
    for id_ in ("job-scene-picture", "job-fov-box", "job-fov-caption", "plan-card", "look", "timings-card"):
        assert not page.visible(id_), f"{id_} is still shown"
    assert not page.js("return document.getElementById('job-scene-img')"), "the first job's picture is kept"
    assert page.text("job-facts") == "" and page.text("plan") == ""


def _switch_user(p: Page, token: str) -> None:
    """Sign out with the page's button and sign in with ``token`` in the same document (no reload)."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    p.d.find_element(By.ID, "signout").click()
    p.until(lambda: p.visible("signin"), what="the sign-in form")
    p.d.find_element(By.ID, "token").send_keys(token + Keys.ENTER)
    p.until(lambda: p.visible("home"), what="the home page")


def test_signing_out_leaves_nothing_of_the_form_to_the_next_owner(page, server, files):  # noqa: F811
    from service.auth import create_token
    from service.db import Database

    other = create_token(Database(server.data_dir / "service.db"), scopes=["submit"], owner="someone-else")[1]
    defaults = page.js("return ['frames', 'res-h', 'res-w', 'preset'].map((id) => document.getElementById(id).value)")
    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button") and page.visible("form-fov-box"), what="the demo's estimate")
    page.set("frames", "3")
    page.set("job-name", "first owner's job")
    page.choose("preset", "reference")
    page.until(lambda: "3 frame(s)" in page.text("form-plan"), what="the plan at 3 frames")
    page.d.get_log("browser")  # what the console said so far
    _switch_user(page, other)
    time.sleep(1.0)  # past the estimate's debounce
    assert page.text("scene-info") == "", page.text("scene-info")
    for id_ in ("job-form", "form-scene-picture", "rerun-note"):
        assert not page.visible(id_), f"{id_} is still shown"
    assert page.js("return document.getElementById('bundle').files.length") == 0
    assert page.js("return document.getElementById('job-name').value") == ""
    assert page.js("return ['frames', 'res-h', 'res-w', 'preset'].map((id) => document.getElementById(id).value)") \
        == defaults
    assert "error" not in page.js("return document.getElementById('status').className"), page.text("status")
    assert not _console_errors(page), _console_errors(page)
    # a read-only token after a submitter with a scene in the form: no estimate goes out (it would be refused)
    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button"), what="the second owner's estimate")
    page.d.get_log("browser")
    _switch_user(page, server.reader)
    time.sleep(1.0)
    assert not page.visible("submit")
    assert not _console_errors(page), _console_errors(page)


NO_EVAL_JOB = {"optics": {"resolution_hw": [96, 128], "seed": 3}, "preset": "fast", "frames": 1, "spp": 4,
               "encoder": "dpac", "evaluate": True, "name": "too small to evaluate"}


def test_a_job_too_small_to_evaluate_is_not_counted_or_called_evaluated(page, server, scene, files):  # noqa: F811
    """96 x 128 at virtual infinity 80 mm lights none of the evaluation's views: the form's estimate has no
    evaluation in it, the list does not call the job evaluated, its page says why there is none once and does
    not ask the service for it."""
    from selenium.webdriver.common.by import By

    from tests.service.helpers import finished_job

    job = finished_job(server, {"scene_id": scene["id"], **NO_EVAL_JOB})
    assert "evaluate_s" not in job["estimate"] and "evaluation" not in job["estimate"]["model"], job["estimate"]
    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button"), what="the demo scene's estimate")
    page.set("res-h", "96")
    page.set("res-w", "128")
    page.d.find_element(By.ID, "evaluate").click()
    page.until(lambda: "no evaluation at 96x128" in page.text("estimate") and page.enabled("submit-button"),
               what="the estimate's warning")
    assert "the evaluation" not in page.text("estimate") and "+ evaluation" not in page.text("estimate")
    row = f"tr[data-job-id='{job['id']}']"
    page.until(lambda: page.js(f"return !!document.querySelector(\"{row}\")"), what="the job's row")
    words = page.js(f"return document.querySelector(\"{row}\").innerText")
    assert "evaluated" not in words and "no evaluation" in words, words
    page.d.get_log("browser")
    page.go(f"#/jobs/{job['id']}")
    page.until(lambda: page.visible("evaluation") and page.text("eval-note"), what="the evaluation's note")
    time.sleep(0.5)
    note = page.text("eval-note")
    assert note.startswith("No evaluation") and "96x128" in note and note.lower().count("no evaluation") == 1, note
    shown = page.text("job")
    assert shown.count(note) == 1 and "evaluation: no evaluation" not in shown.lower(), shown
    assert "evaluated against ground truth" not in page.text("job-facts")
    assert not [m for m in _console_errors(page) if "/evaluation" in m], _console_errors(page)


def test_the_forms_small_wrong_states(page, files):  # noqa: F811
    """An untouched file box is not red; a box the page shows red is not estimated (and the field-of-view box
    goes with a refusal); the planner's "to plan" goes when the plan is done."""
    from selenium.webdriver.common.by import By

    red = page.js("return getComputedStyle(document.body).getPropertyValue('--bad').trim()")
    border = page.js("return getComputedStyle(document.getElementById('bundle')).borderTopColor")
    assert border != page.js("const e = document.createElement('i'); e.style.color = arguments[0]; "
                             "document.body.append(e); const c = getComputedStyle(e).color; e.remove(); return c;", red)
    page.d.find_element(By.ID, "bundle").send_keys(str(files["demo"]))
    page.d.find_element(By.ID, "upload-button").click()
    page.until(lambda: page.visible("job-form"), what="the uploaded scene")
    page.d.find_element(By.ID, "refresh").click()  # the queue's line while the scene's plan is pending
    page.until(lambda: page.enabled("submit-button") and page.visible("form-fov-box"), what="the estimate")
    page.until(lambda: "to plan" not in page.text("queue-line"), timeout=4, what="the planner's line to follow")
    page.set("res-h", "5000")  # beyond the service's largest side: its limit bounds the box (GET /v1/job-options)
    page.until(lambda: "Cannot submit" in page.text("estimate"), what="the refusal of 5000 rows")
    assert "1 to 4096" in page.text("estimate") and not page.enabled("submit-button"), page.text("estimate")
    assert page.js("return document.getElementById('res-h').matches(':invalid')")  # red once the box is left
    assert not page.visible("form-fov-box") and "refused" in page.text("form-fov-caption")
    page.set("res-h", "64")
    page.until(lambda: page.enabled("submit-button") and page.visible("form-fov-box"), what="the estimate again")


def test_a_queued_jobs_page_and_the_list_at_390_px(page, browser, made_jobs):
    """The queued line says it waits once; Cancel is not the page's primary button; at 390 px the job list shows
    a job's state and progress without scrolling sideways."""
    job = made_jobs["direct"]
    # the job as it was while queued: the page's GET answers it so, its event stream stays open
    page.js("""const real = window.fetch, id = arguments[0];
        window.fetch = async (u, o) => {
          if (String(u) === `/v1/jobs/${id}/events`) return new Response(new ReadableStream({ start() {} }), {
            headers: { 'Content-Type': 'text/event-stream' } });
          const r = await real(u, o);
          if (String(u) !== `/v1/jobs/${id}`) return r;
          const j = await r.json();
          return new Response(JSON.stringify({ ...j, state: 'queued', progress: null, finished_at: null,
                                               started_at: null, error: null }));
        };""", job["id"])
    page.go(f"#/jobs/{job['id']}")
    page.until(lambda: page.text("job-stage") and page.visible("job-cancel"), what="the queued job's line")
    line = page.text("job-stage")
    assert line.count("waiting for a worker") == 1, line
    accent = page.js("return getComputedStyle(document.getElementById('job-rerun')).borderTopColor")
    cancel = page.js("const s = getComputedStyle(document.getElementById('job-cancel')); "
                     "return [s.backgroundColor, s.borderTopColor]")
    assert cancel[0] in ("rgba(0, 0, 0, 0)", "transparent") and cancel[1] != accent, cancel
    browser.set_window_size(390, 900)
    page.go("#/")
    row = f"tr[data-job-id='{job['id']}']"
    page.until(lambda: page.js(f"return !!document.querySelector(\"{row}\")"), what="the job's row")
    edges = page.js(f"""const r = document.querySelector("{row}"), w = r.closest('.table-wrap');
        return [w.getBoundingClientRect().right, w.scrollLeft,
                r.querySelector('td.state').getBoundingClientRect().right,
                r.querySelector('td.progress-cell').getBoundingClientRect().right]""")
    assert edges[1] == 0 and edges[2] <= edges[0] + 1 and edges[3] <= edges[0] + 1, edges


def test_compare_lists_frames_once_and_merges_near_depths(page, made_jobs):
    a, b = made_jobs["direct"]["id"], made_jobs["wrp6"]["id"]
    page.go(f"#/compare/{a}/{b}")
    page.until(lambda: page.js("return document.querySelectorAll('#cmp-diff tbody tr').length") > 0,
               what="the options' differences")
    keys = page.js("return [...document.querySelectorAll('#cmp-diff tbody tr')].map(r => r.dataset.option)")
    assert "optics.frames" in keys and "frames" not in keys, keys
    # two sweeps of 9 depths over 8 mm whose depths differ by 2-15 µm: 9 slider stops, not 17
    stops = page.d.execute_async_script("""const done = arguments[arguments.length - 1];
        import('/web/compare.js').then((m) => {
          const one = [...Array(9).keys()].map((i) => ({ z_mm: 88 - i }));
          const two = one.map((p, i) => ({ z_mm: p.z_mm + 0.002 + 0.0015 * i }));
          done(m.sliderDepths([one, two]).length);
        }).catch((e) => done(String(e)));""")
    assert stops == 9, stops


def test_the_forms_default_is_a_preview_with_the_full_display_one_click_away(page, files):  # noqa: F811
    from selenium.webdriver.common.by import By

    def values():
        return page.js("return ['res-h', 'res-w', 'frames', 'preset', 'size'].map((id) => "
                       "document.getElementById(id).value)")

    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button") and page.visible("full-size"), what="the preview's estimate")
    assert values() == ["540", "960", "4", "fast", "preview"], values()
    full = page.text("full-estimate")
    assert "full display (1080x1920, 24 frames, balanced) would take" in full, full
    page.d.find_element(By.ID, "full-size").click()
    page.until(lambda: page.enabled("submit-button") and "24 frame(s)" in page.text("form-plan"),
               what="the full display's estimate")
    assert values() == ["1080", "1920", "24", "balanced", "full"], values()
    assert not page.visible("full-estimate")


def test_the_forms_boxes_carry_the_services_option_limits(page, server):
    """The page writes no limit of its own: every bounded box and the recording planes' choices come from the
    service's option limits (the options model's, tightened by the service's job limits)."""
    from holocore.options import MAX_WRP_PLANES

    with server.client("reader") as c:
        limits = c.get("/v1/job-options").json()["options"]
    boxes = {"frames": "frames", "iterations": "iterations", "spp": "spp", "quality_db": "quality-db",
             "resolution_px": "res-h"}
    got = page.js("return arguments[0].map((id) => [document.getElementById(id).min, document.getElementById(id).max])",
                  list(boxes.values()))
    assert [[float(a), float(b)] for a, b in got] == [[limits[n]["min"], limits[n]["max"]] for n in boxes]
    assert float(page.js("return document.getElementById('time-limit').max")) == limits["render_time_limit_s"]["max"]
    planes = page.js("return [...document.getElementById('wrp-planes').options].map((o) => o.value)")
    assert planes == ["auto", *map(str, range(1, MAX_WRP_PLANES + 1))]
