"""The results page as a lab uses it every day, in headless Chromium against a real `holo serve` (test_web.py
has the sign-in, XSS and pictures tests): the form never submits a scene it does not show, shows the server's
refusals and the effect plan at the chosen options; a job's page shows only its own facts and plan, progress
that only moves forward with what is left, cancel, delete and re-run with changes, the steps' logs and why a job
failed; the layout at 390 px and at 1280 px. The API routes the page needs for that are tested beside.

One server, one browser and one finished job are shared by the module's tests.
"""

from __future__ import annotations

import io
import json
import time
import zipfile
from pathlib import Path

import pytest

from tests.service.helpers import finished_job, planned_scene, wait_state
from tests.service.test_web import _browser

BAD_RADIUS = ('<scene version="3.0.0">\n<sensor type="perspective"/>\n'
              '<shape type="sphere"><float name="radius" value="{}"/></shape>\n</scene>')
DONE_JOB = {"optics": {"resolution_hw": [64, 96], "seed": 3}, "preset": "fast", "frames": 1, "spp": 4,
            "encoder": "sgd", "iterations": 40, "name": "lab demo (api)"}


def _zip(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in files.items():
            zf.writestr(name, data)
    return buf.getvalue()


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """Bundles to upload from the browser: the demo scene (``lab-demo.zip``), a zip with no scene in it, and a
    scene Mitsuba cannot load (its plan fails)."""
    from holocore.scene.demo import write_demo_scene

    tmp = tmp_path_factory.mktemp("page")
    write_demo_scene(tmp / "demo")
    out = {"demo": tmp / "lab-demo.zip", "empty": tmp / "no-scene.zip", "broken": tmp / "broken.zip"}
    out["demo"].write_bytes(_zip({p.relative_to(tmp / "demo").as_posix(): p.read_bytes()
                                  for p in sorted((tmp / "demo").rglob("*")) if p.is_file()}))
    out["empty"].write_bytes(_zip({"notes.txt": b"no scene here\n"}))
    out["broken"].write_bytes(_zip({"scene.xml": BAD_RADIUS.format("abc").encode()}))
    return out


@pytest.fixture(scope="module")
def scene(server, files) -> dict:
    return planned_scene(server, files["demo"].read_bytes())


@pytest.fixture(scope="module")
def done_job(server, scene) -> dict:
    """A finished job on a non-square SLM (64x96), one frame, the SGD encoder."""
    return finished_job(server, {"scene_id": scene["id"], **DONE_JOB})


@pytest.fixture(scope="module")
def browser():
    driver = _browser()
    yield driver
    driver.quit()


class Page:
    """The browser on the page, with the reads every test needs (one script call each: the page re-renders
    live, so an element found first may be replaced before it is read)."""

    def __init__(self, driver, server) -> None:
        from selenium.webdriver.support.ui import WebDriverWait

        self.d, self.server = driver, server
        self.wait = WebDriverWait(driver, 30, poll_frequency=0.1)

    def js(self, script: str, *args):
        return self.d.execute_script(script, *args)

    def text(self, id_: str) -> str:
        return self.js("const e = document.getElementById(arguments[0]); return e ? e.innerText.trim() : '';", id_)

    def visible(self, id_: str) -> bool:
        return bool(self.js("const e = document.getElementById(arguments[0]); "
                            "return !!e && e.getClientRects().length > 0 && !e.closest('[hidden]');", id_))

    def enabled(self, id_: str) -> bool:
        return self.visible(id_) and not self.js("return document.getElementById(arguments[0]).disabled", id_)

    def until(self, pred, timeout: float = 60, what: str = ""):
        from selenium.webdriver.support.ui import WebDriverWait

        from selenium.common.exceptions import TimeoutException

        try:
            return WebDriverWait(self.d, timeout, poll_frequency=0.1).until(lambda d: pred())
        except TimeoutException:
            console = [e["message"] for e in self.d.get_log("browser")][-10:]
            raise AssertionError(f"timed out after {timeout} s waiting for {what or 'the page'}; status: "
                                 f"{self.text('status')!r}; estimate: {self.text('estimate')!r}; console: {console}") from None

    def sign_in(self, token: str = "submit") -> "Page":
        from selenium.webdriver.common.by import By
        from selenium.webdriver.common.keys import Keys

        tok = getattr(self.server, token)
        self.d.get("about:blank")  # a fresh document: no form state from the test before
        self.d.get(self.server.url + "/#/")
        if self.js("return sessionStorage.getItem('holo.token')") != tok:
            self.until(lambda: self.visible("signin") or self.visible("signout"))
            if self.visible("signout"):
                self.d.find_element(By.ID, "signout").click()
            self.until(lambda: self.visible("signin"))
            self.d.find_element(By.ID, "token").send_keys(tok + Keys.ENTER)
        self.until(lambda: self.visible("home"), what="the home page")
        return self

    def go(self, hash_: str) -> None:
        self.js("location.hash = arguments[0]", hash_)

    def set(self, id_: str, value: str) -> None:
        """Type ``value`` into a box (an input event per key, as a person's typing)."""
        from selenium.webdriver.common.by import By

        from selenium.webdriver.common.keys import Keys

        box = self.d.find_element(By.ID, id_)
        box.send_keys(Keys.CONTROL, "a")
        box.send_keys(Keys.DELETE)  # an input event, as clear() does not send
        if value:
            box.send_keys(value)

    def choose(self, id_: str, value: str) -> None:
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support.ui import Select

        Select(self.d.find_element(By.ID, id_)).select_by_value(value)

    def upload(self, path: Path) -> None:
        from selenium.webdriver.common.by import By

        self.d.find_element(By.ID, "bundle").send_keys(str(path))
        self.d.find_element(By.ID, "upload-button").click()


@pytest.fixture
def page(browser, server, scene) -> Page:  # the demo scene planned: the form's Submit waits for its plan
    browser.set_window_size(1280, 1500)
    return Page(browser, server).sign_in()


def _small_options(p: Page, *, frames: str = "1", encoder: str = "sgd") -> None:
    p.choose("preset", "fast")
    p.choose("encoder", encoder)
    for field, value in (("frames", frames), ("res-h", "64"), ("res-w", "96"), ("spp", "4"), ("iterations", "40")):
        p.set(field, value)


# ---- the form ---------------------------------------------------------------------------------------------
def test_a_refused_upload_leaves_nothing_to_submit(page, files):
    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button"), what="the demo scene's estimate")
    page.upload(files["empty"])
    page.until(lambda: "Scene refused" in page.text("scene-info"), what="the refusal")
    time.sleep(0.6)  # past the estimate's debounce: nothing turns Submit back on
    assert not page.enabled("submit-button"), "Submit would send the previous scene"
    assert not page.visible("job-form")
    refusal = page.text("scene-info")
    assert "refused: scene refused" not in refusal.lower(), refusal


def test_a_scene_whose_plan_failed_cannot_be_submitted(page, files):
    """Not even in the seconds before its plan fails: Submit waits for the plan."""
    page.upload(files["broken"])
    live = []
    deadline = time.monotonic() + 120
    while "failed" not in page.text("scene-info") and time.monotonic() < deadline:
        live.append(page.enabled("submit-button"))
        time.sleep(0.05)
    assert "failed" in page.text("scene-info"), page.text("scene-info")
    assert not any(live), f"Submit was live for {sum(live)} of {len(live)} looks while the plan was pending"
    page.until(lambda: "Cannot submit" in page.text("estimate") and not page.enabled("submit-button"),
               what="the estimate to refuse")
    time.sleep(1.5)  # the plan poll and the estimate have both had their turn
    assert not page.enabled("submit-button") and "plan failed" in page.text("estimate"), page.text("estimate")


def test_the_forms_plan_follows_the_options(page, files, scene):
    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button"))
    _small_options(page, frames="1")
    page.until(lambda: "1 frame(s): one frame" in page.text("form-plan"), what="the plan at 1 frame")
    page.set("frames", "3")
    page.until(lambda: "3 frame(s)" in page.text("form-plan"), what="the plan at 3 frames")
    assert "24 frame(s)" not in page.text("scene-info") + page.text("form-plan")
    page.choose("wrp-planes", "2")
    page.until(lambda: "2 wave recording planes" in page.text("form-plan"))
    page.choose("preset", "reference")
    page.until(lambda: "global illumination: up to" in page.text("form-plan")
               and "ambient radiance cache" not in page.text("form-plan"))


def test_the_forms_predicted_quality_follows_frames_and_rays_and_warns(page, files):
    """The quality the options buy is shown beside the time (service/quality.py): more frames and more rays
    predict more dB; one frame at 16 rays per pixel predicts an unrecognisable hologram and says so before
    submit; a quality target has the service choose the options and shows them."""
    import re

    def predicted() -> float:
        m = re.search(r"expected about (\d+) dB", page.text("quality"))
        return float(m.group(1)) if m else float("nan")

    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button"))
    page.choose("preset", "balanced")
    for field, value in (("frames", "1"), ("res-h", "135"), ("res-w", "240"), ("spp", "16"), ("iterations", "")):
        page.set(field, value)
    page.until(lambda: "1 frame(s)" in page.text("form-plan") and predicted() == predicted(),
               what="the prediction at 1 frame")
    one = predicted()
    page.until(lambda: "below 12 dB" in page.text("quality"), what="the warning of a 1-frame, 16-ray job")
    page.set("frames", "24")
    page.set("spp", "")  # the preset's rays
    page.until(lambda: "24 frame(s)" in page.text("form-plan") and predicted() > one + 3,
               what="a higher prediction at 24 frames and the preset's rays")
    at24 = predicted()
    assert "below 12 dB" not in page.text("quality")
    page.set("spp", "1024")
    page.until(lambda: predicted() >= at24 and "1024 rays" in page.text("estimate"), what="more rays")
    page.set("quality-db", "14")
    page.until(lambda: "for 14 dB:" in page.text("quality"), what="the options chosen for a 14 dB target")
    assert predicted() >= 14 - 0.5


def test_the_servers_refusals_are_shown(page, files):
    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button"))
    page.set("res-w", "5000")
    page.until(lambda: "4096" in page.text("estimate"), what="the resolution refusal")
    assert not page.enabled("submit-button") and "Fill in" not in page.text("estimate")
    page.set("res-w", "96")
    page.until(lambda: page.enabled("submit-button"))
    page.set("frames", "100")
    page.until(lambda: "64" in page.text("estimate") and "Cannot submit" in page.text("estimate"),
               what="the frames refusal")
    page.set("frames", "")
    page.until(lambda: "Fill in Frames" in page.text("estimate"))


# ---- a job from the browser -------------------------------------------------------------------------------
@pytest.mark.slow  # a job submitted from the page's form and watched to its end (25 s)
def test_a_job_named_after_its_file_whose_progress_only_moves_forward(page, files, server):
    from selenium.webdriver.common.by import By

    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button"))
    named = page.js("return (document.getElementById('job-name') || {}).value")
    _small_options(page)
    page.until(lambda: page.enabled("submit-button") and "4 rays per pixel" in page.text("estimate"))
    page.d.find_element(By.ID, "submit-button").click()
    page.until(lambda: "#/jobs/j" in page.d.current_url)
    job_id = page.d.current_url.rsplit("/", 1)[1]
    seen, stages = [], []
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:
        f, stage, st = page.js("return [parseFloat(document.getElementById('job-bar').style.width) / 100, "
                               "document.getElementById('job-stage').innerText, "
                               "(document.getElementById('job-state') || {}).innerText]")
        if f is not None:
            seen.append(float(f))
        stages.append(stage)
        if st in ("succeeded", "failed", "cancelled"):
            break
        time.sleep(0.05)
    assert page.text("job-state") == "succeeded", page.text("job-error")
    assert seen and all(b >= a for a, b in zip(seen, seen[1:])), f"the bar went back: {seen}"
    assert any(" left" in s for s in stages), set(stages)
    assert named == "lab-demo" and page.text("job-name-title") == "lab-demo"
    lines = (server.data_dir / "jobs" / job_id / "progress-preview.jsonl").read_text().splitlines()
    assert [json.loads(ln)["stage"] for ln in lines][-1] == "grid", lines  # the last step reports its views
    with server.client("reader") as c:
        job = c.get(f"/v1/jobs/{job_id}").json()
    assert job["name"] == "lab-demo" and job["options"]["optics"]["resolution_hw"] == [64, 96]

    page.go("#/")
    page.until(lambda: page.js("return !!document.querySelector(`tr[data-job-id=\"${arguments[0]}\"] img.thumb`)",
                               job_id), what="the list's thumbnail")
    row = page.js("return document.querySelector(`tr[data-job-id=\"${arguments[0]}\"]`).innerText", job_id)
    assert "lab-demo" in row and "64x96 px · 1 frame · fast · sgd" in row and "1 frames" not in row, row


def _fresh_failed_job(server) -> dict:
    """A job queued on a scene before its plan fails (a submit after that is refused): it fails with the plan."""
    with server.client("submit") as c:
        for i in range(4):
            data = _zip({"scene.xml": BAD_RADIUS.format(f"x{time.time_ns()}{i}").encode()})
            sid = c.post("/v1/scenes", files={"bundle": ("b.zip", data)}).json()["id"]
            r = c.post("/v1/jobs", json={"scene_id": sid, **DONE_JOB, "name": "doomed"})
            if r.status_code == 202:
                return wait_state(c, r.json()["id"], ("failed", "succeeded", "cancelled"), timeout=120)
    pytest.fail("every plan failed before its job could be queued")


def test_why_a_job_failed_shows_in_the_list_and_on_its_page(page, server):
    job = _fresh_failed_job(server)
    assert job["state"] == "failed" and job["error"], job
    page.go("#/")
    page.js("document.getElementById('refresh').click()")
    page.until(lambda: page.js("const r = document.querySelector(`tr[data-job-id=\"${arguments[0]}\"] .reason`); "
                               "return r ? r.innerText : ''", job["id"]), what="the reason in the list")
    page.go(f"#/jobs/{job['id']}")
    page.until(lambda: page.text("job-state") == "failed")
    assert page.text("job-error").startswith("Failed: ") and "plan failed" in page.text("job-error")
    assert "No effect plan" in page.text("plan")
    assert "before it finished" in page.text("timings-note") and not page.visible("timings")


def test_a_queued_or_running_job_shows_no_other_plan_and_can_be_cancelled_and_deleted(page, server, scene):
    from selenium.webdriver.common.by import By

    with server.client("submit") as c:
        r = c.post("/v1/jobs", json={"scene_id": scene["id"], "optics": {"resolution_hw": [64, 64]}, "frames": 2,
                                     "preset": "fast", "encoder": "dpac", "render_time_limit_s": 300})
        assert r.status_code == 202, r.text
        jid = r.json()["id"]
    page.go(f"#/jobs/{jid}")
    page.until(lambda: page.text("job-state") in ("queued", "running"))
    # never the scene's default-optics plan (24 frames): the plan at the job's own options, said to be that
    page.until(lambda: "from its scene's plan" in page.text("plan"), what="the plan at the job's options")
    assert "24 frame(s)" not in page.text("plan") and "2 frame(s)" in page.text("plan"), page.text("plan")
    assert page.enabled("job-cancel") and not page.visible("job-delete")
    page.d.find_element(By.ID, "job-cancel").click()
    page.until(lambda: page.text("job-state") == "cancelled", what="the cancel")
    assert "was cancelled" in page.text("plan") and "was cancelled before it finished" in page.text("timings-note")
    colours = page.js("""const b = document.createElement('span'); b.className = 'badge failed';
        document.body.append(b); const f = getComputedStyle(b).color; b.remove();
        return [getComputedStyle(document.getElementById('job-state')).color, f];""")
    assert colours[0] != colours[1], "cancelled is not shown as failed"
    assert page.enabled("job-delete") and not page.visible("job-cancel")
    page.d.find_element(By.ID, "job-delete").click()
    assert "Click again" in page.text("job-delete") and page.text("job-state") == "cancelled"
    page.d.find_element(By.ID, "job-delete").click()
    page.until(lambda: page.visible("home") and "Deleted job" in page.text("status"), what="the deletion")
    with server.client("submit") as c:
        assert c.get(f"/v1/jobs/{jid}").status_code == 404
    assert not (server.data_dir / "jobs" / jid).exists()


def test_a_missing_job_after_a_real_one_shows_nothing_of_it(page, done_job):
    page.go(f"#/jobs/{done_job['id']}")
    page.until(lambda: page.js("return document.querySelectorAll('#job-downloads button').length") == 3
               and page.js("return document.querySelectorAll('#grid img').length") == 9)
    page.go("#/jobs/jnosuchjob0000")
    page.until(lambda: "No such job" in page.text("job-error"))
    assert page.text("job-facts") == "" and page.text("plan") == ""
    assert page.js("return document.querySelectorAll('#job-downloads button, #grid img, #timings tbody tr').length") == 0
    assert not page.visible("look") and not page.visible("logs-card") and not page.visible("job-rerun")


def test_the_steps_logs(page, server, done_job):
    from selenium.webdriver.common.by import By

    page.go(f"#/jobs/{done_job['id']}")
    page.until(lambda: page.visible("logs-card") and page.text("log-text"), what="the logs")
    steps = page.js("return [...document.querySelectorAll('#log-tabs button')].map(b => b.dataset.step)")
    assert {"render", "encode", "preview"} <= set(steps), steps
    page.d.find_element(By.CSS_SELECTOR, '#log-tabs button[data-step="encode"]').click()
    page.until(lambda: "encoded" in page.text("log-text"), what="the encode log")
    assert str(server.data_dir) not in page.text("log-text")


def test_re_run_with_changes(page, server, done_job):
    from selenium.webdriver.common.by import By

    page.go(f"#/jobs/{done_job['id']}")
    page.until(lambda: page.enabled("job-rerun"))
    page.d.find_element(By.ID, "job-rerun").click()
    page.until(lambda: page.visible("home") and page.enabled("submit-button"), what="the form with the job's options")
    val = lambda i: page.js("return document.getElementById(arguments[0]).value", i)  # noqa: E731
    assert val("profile") == f"job:{done_job['id']}" and (val("res-h"), val("res-w"), val("frames")) == ("64", "96", "1")
    assert val("encoder") == "sgd" and val("preset") == "fast" and val("job-name") == "lab demo (api) (re-run)"
    assert val("iterations") == "40"
    assert "Re-run of job" in page.text("rerun-note")
    page.set("frames", "2")
    page.until(lambda: page.enabled("submit-button") and "2 frame(s)" in page.text("form-plan"))
    page.d.find_element(By.ID, "submit-button").click()
    page.until(lambda: "#/jobs/j" in page.d.current_url and done_job["id"] not in page.d.current_url)
    jid = page.d.current_url.rsplit("/", 1)[1]
    with server.client("submit") as c:
        job = c.get(f"/v1/jobs/{jid}").json()
        c.delete(f"/v1/jobs/{jid}")
    o = job["options"]
    assert o["optics"]["frames"] == 2 and o["optics"]["resolution_hw"] == [64, 96] and o["encoder"] == "sgd"
    assert o["optics"]["seed"] == 3 and o["spp"] == 4 and o["iterations"] == 40, o
    assert job["scene_id"] == done_job["scene_id"]
    assert job["name"] == "lab demo (api) (re-run)"


# ---- layout -----------------------------------------------------------------------------------------------
def test_layout_at_390_1280_and_1920_px(page, browser, done_job):
    def fits() -> bool:
        return page.js("return document.documentElement.scrollWidth <= window.innerWidth + 1")

    browser.get_log("browser")  # what came before
    jid = done_job["id"]
    page.go(f"#/jobs/{jid}")
    page.until(lambda: page.js("return document.querySelectorAll('#grid img').length") == 9
               and page.js("return [...document.querySelectorAll('#grid img')].every(i => i.complete)"))
    # the view grid keeps the hologram's aspect (64x96: wider than tall), the three figures stand in one row
    ratios = page.js("""return [...document.querySelectorAll('#grid img')].map(i =>
        [i.getBoundingClientRect().width / i.getBoundingClientRect().height, i.naturalWidth / i.naturalHeight]);""")
    assert all(abs(a - b) < 0.05 for a, b in ratios), ratios
    tops = page.js("return ['.sweep', '.viewgrid', '.preview'].map(s => document.querySelector(s)"
                   ".getBoundingClientRect().top)")
    assert max(tops) - min(tops) < 2, tops
    assert "engine" not in page.text("timings") and "local" not in page.text("timings")
    assert "1 frame," in page.text("job-facts") and "1 frames" not in page.text("job-facts")
    # an element the page hides stays hidden whatever display its class gives it (a flex row of actions)
    shown = page.js("return [...document.querySelectorAll('[hidden]')].filter(e => getComputedStyle(e).display "
                    "!== 'none').map(e => e.id || e.className)")
    assert shown == [], shown
    browser.set_window_size(390, 900)
    assert fits(), page.js("""return [...document.querySelectorAll('body *')].filter(e => e.getBoundingClientRect().right
        > window.innerWidth + 1 && !e.closest('.table-wrap')).map(e => e.tagName + '#' + e.id + '.' + e.className).slice(0, 8)""")
    page.go("#/")
    page.until(lambda: page.js("return !!document.querySelector(`tr[data-job-id=\"${arguments[0]}\"]`)", jid))
    assert fits(), page.js("return document.documentElement.scrollWidth")
    for width in (1280, 1920):  # a laptop and a wide screen: the job list needs no scrolling of its own
        browser.set_window_size(width, 1200)
        assert fits(), page.js("return document.documentElement.scrollWidth")
        inner = page.js("const w = document.querySelector('#jobs').closest('.table-wrap'); "
                        "return [w.scrollWidth, w.clientWidth]")
        assert inner[0] <= inner[1] + 1, (width, inner)
    browser.set_window_size(1280, 1500)
    # a short name never breaks inside a word
    lines = page.js("""const td = document.querySelector(`tr[data-job-id="${arguments[0]}"] td.scene-name`);
        const r = document.createRange(); r.selectNodeContents(td); return r.getClientRects().length;""", jid)
    assert lines == 1, lines
    # moving between pages while pictures load leaves nothing in the console
    for _ in range(3):
        page.go(f"#/jobs/{jid}")
        time.sleep(0.15)
        page.go("#/")
        time.sleep(0.15)
    page.go(f"#/jobs/{jid}")
    page.until(lambda: page.js("return document.querySelectorAll('#grid img').length") == 9)
    errors = [e["message"] for e in browser.get_log("browser") if e.get("level") == "SEVERE"
              or "DOMException" in e.get("message", "")]
    assert not errors, errors


# ---- the API the page uses --------------------------------------------------------------------------------
def test_read_progress_counts_a_steps_first_line_as_its_start(tmp_path):
    from service.workers.runfiles import read_progress

    (tmp_path / "step.json").write_text(json.dumps({"step": "encode"}))
    (tmp_path / "progress-encode.jsonl").write_text(json.dumps({"stage": "load", "done": 1, "total": 1}) + "\n")
    assert read_progress(tmp_path)["fraction"] == 0.75
    with open(tmp_path / "progress-encode.jsonl", "a") as fh:
        fh.write(json.dumps({"stage": "encode", "done": 10, "total": 100}) + "\n")
    assert read_progress(tmp_path)["fraction"] == 0.765


def test_names_logs_delete_and_the_estimates_plan_over_http(server, scene, done_job):
    from service.auth import create_token
    from service.db import Database

    jid = done_job["id"]
    assert done_job["name"] == "lab demo (api)"
    with server.client("submit") as c:
        est = c.post("/v1/jobs/estimate", json={"scene_id": scene["id"], **DONE_JOB}).json()
        assert est["plan"]["summary"] and any("1 frame(s)" in ln for ln in est["plan"]["summary"]), est["plan"]
        assert c.post("/v1/jobs/estimate", json={"scene_id": scene["id"], **DONE_JOB, "name": "a\nb"}).status_code == 422
        logs = c.get(f"/v1/jobs/{jid}/logs").json()["logs"]
        assert {"render", "encode", "preview"} <= {x["step"] for x in logs}, logs
        text = c.get(f"/v1/jobs/{jid}/logs/encode")
        assert text.status_code == 200 and text.headers["content-type"].startswith("text/plain")
        assert "encoded" in text.text and str(server.data_dir) not in text.text
        assert c.get(f"/v1/jobs/{jid}/logs/secrets").status_code == 422
        running = c.post("/v1/jobs", json={"scene_id": scene["id"], "optics": {"resolution_hw": [64, 64]},
                                           "frames": 1, "preset": "fast", "encoder": "dpac",
                                           "render_time_limit_s": 300}).json()
        assert c.post(f"/v1/jobs/{running['id']}/delete").status_code == 409
        assert c.delete(f"/v1/jobs/{running['id']}").status_code == 202
    with server.client("reader") as c:
        assert c.get(f"/v1/jobs/{jid}/logs/render").status_code == 200
        assert c.post(f"/v1/jobs/{jid}/delete").status_code == 403
    other = create_token(Database(server.data_dir / "service.db"), scopes=["submit"], name="t", owner="lab2")[1]
    with server.client(other) as c:
        assert c.get(f"/v1/jobs/{jid}/logs").status_code == 404
        assert c.post(f"/v1/jobs/{jid}/delete").status_code == 404
    with server.client("submit") as c:
        assert c.post(f"/v1/jobs/{jid}/delete").status_code == 204
        assert c.get(f"/v1/jobs/{jid}").status_code == 404
        assert c.post(f"/v1/jobs/{jid}/delete").status_code == 404
    assert not (server.data_dir / "jobs" / jid).exists()
