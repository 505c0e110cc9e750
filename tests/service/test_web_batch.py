"""Working on several jobs at once on the results page, in headless Chromium against a real `holo serve`: tick
jobs in the list (or every shown one) to cancel, delete or compare them, the compare page over three and four jobs
under one focus slider, a sweep's job linking back to its sweep, and the flag on a result whose quality is too low
to be useful.

One server, one browser and three finished jobs of the demo scene (at three settings) are shared by the module.
"""

from __future__ import annotations

import pytest

from tests.service.helpers import finished_job
from tests.service.test_web_page import DONE_JOB, Page, browser, done_job, files, page, scene  # noqa: F401 (fixtures)

# headless Chromium on three rendered jobs; tests/service/test_web_page.py drives the page
pytestmark = pytest.mark.slow

# a job that keeps a worker busy long enough to be cancelled from the page
LIVE = {"optics": {"resolution_hw": [192, 256], "seed": 5}, "preset": "fast", "spp": 64, "encoder": "dpac",
        "frames": 8}


@pytest.fixture(scope="module")
def more_jobs(server, scene) -> list[dict]:  # noqa: F811
    """Two more finished jobs: the double-phase encoder at two frames, and SGD at two frames."""
    dpac = {**DONE_JOB, "encoder": "dpac", "frames": 2, "name": "lab demo (dpac)"}
    dpac.pop("iterations")
    two = {**DONE_JOB, "frames": 2, "name": "lab demo (two frames)"}
    return [finished_job(server, {"scene_id": scene["id"], **body}) for body in (dpac, two)]


def _submit(server, scene, body: dict) -> str:  # noqa: F811
    with server.client("submit") as c:
        r = c.post("/v1/jobs", json={"scene_id": scene["id"], **body})
        assert r.status_code == 202, r.text
        return r.json()["id"]


def _state(server, jid: str) -> str:
    with server.client("submit") as c:
        r = c.get(f"/v1/jobs/{jid}")
        return "gone" if r.status_code == 404 else r.json()["state"]


def _tick(page: Page, jid: str) -> None:
    page.js("document.querySelector(`#jobs tr[data-job-id=\"${arguments[0]}\"] input.pick`).click()", jid)


def _click(page: Page, id_: str) -> None:
    page.js("document.getElementById(arguments[0]).click()", id_)


def _rows(page: Page) -> list[str]:
    return page.js("return [...document.querySelectorAll('#jobs tbody tr')].map((r) => r.dataset.jobId)")


def _loaded(page: Page, n: int) -> bool:
    return page.js("""const n = arguments[0];
        const imgs = [...document.querySelectorAll('#cmp-sides img[id^=cmp-img-]')];
        return imgs.length === n && imgs.every((i) => i.src && i.complete && i.naturalWidth > 0);""", n)


def test_cancel_delete_and_compare_the_ticked_jobs_of_the_list(page, server, scene, done_job, more_jobs):  # noqa: F811
    live = [_submit(server, scene, {**LIVE, "frames": f}) for f in (6, 8)]
    page.go("#/")
    page.until(lambda: set(live + [done_job["id"]]) <= set(_rows(page)), what="the jobs in the list")
    for jid in (*live, done_job["id"]):
        _tick(page, jid)
    page.until(lambda: page.text("jobs-selected") == "3 jobs selected", what="the count")
    assert page.enabled("jobs-cancel-selected") and page.enabled("jobs-delete-selected")
    assert not page.enabled("jobs-compare-selected")  # two of the three have no result
    _click(page, "jobs-cancel-selected")
    page.until(lambda: page.text("status").startswith("Cancelled 2 jobs"), what="the cancel's line")
    assert f"skipped 1 job ({done_job['id']}): already finished" in page.text("status"), page.text("status")
    assert [_state(server, j) for j in live] == ["cancelled", "cancelled"]
    assert _state(server, done_job["id"]) == "succeeded"
    # delete: the two cancelled ones and a third still queued or running, which is skipped and said so
    third = _submit(server, scene, LIVE)
    _tick(page, done_job["id"])  # untick the finished job: it stays
    _click(page, "refresh")
    page.until(lambda: third in _rows(page), what="the third job's row")
    _tick(page, third)
    page.until(lambda: page.text("jobs-selected") == "3 jobs selected", what="the ticks kept over the reload")
    _click(page, "jobs-delete-selected")
    assert page.text("jobs-delete-selected").startswith("Click again to delete 2 finished jobs")
    assert all(_state(server, j) == "cancelled" for j in live), "the first click deletes nothing"
    _click(page, "jobs-delete-selected")
    page.until(lambda: page.text("status").startswith("Deleted 2 jobs"), what="the delete's line")
    assert f"skipped 1 job ({third}): not finished" in page.text("status"), page.text("status")
    assert [_state(server, j) for j in live] == ["gone", "gone"] and _state(server, third) != "gone"
    with server.client("submit") as c:
        c.delete(f"/v1/jobs/{third}")
    # select all shown: with the list filtered to succeeded jobs, the three results, then compare them
    page.choose("filter-state", "succeeded")
    page.until(lambda: page.text("filter-count").startswith("3 of"), what="the filter")
    _click(page, "jobs-select-all")
    page.until(lambda: page.text("jobs-selected") == "3 jobs selected" and page.enabled("jobs-compare-selected"),
               what="the three results ticked")
    assert not page.enabled("jobs-cancel-selected")  # a hidden ticked job (the third, cancelled) is not counted
    shown = page.js("return [...document.querySelectorAll('#jobs tbody tr:not([hidden])')].map((r) => r.dataset.jobId)")
    _click(page, "jobs-compare-selected")

    def on_compare() -> bool:  # the three jobs' compare page, in whatever order a refresh of the list left them
        h = page.js("return location.hash")
        return h.startswith("#/compare/") and sorted(h[len("#/compare/"):].split("/")) == sorted(shown)

    page.until(on_compare, what=f"the compare page of {shown}")
    # three simulated views from the server: on a loaded machine this takes longer than a page's wait
    page.until(lambda: _loaded(page, 3), what="the three jobs' views", timeout=240)
    page.go("#/")
    page.until(lambda: page.visible("home"))
    page.choose("filter-state", "")  # the filter is kept in the tab: leave none for the next test


def _slide(page: Page, value: int) -> None:
    page.js("const r = document.getElementById('cmp-focus'); r.value = String(arguments[0]);"
            "r.dispatchEvent(new Event('input'));", value)


def test_three_and_four_jobs_under_one_focus_slider(page, done_job, more_jobs):  # noqa: F811
    ids = [done_job["id"]] + [j["id"] for j in more_jobs]
    page.go("#/compare/" + "/".join(ids))
    page.until(lambda: _loaded(page, 3), what="three jobs' views")
    names = [page.text(f"cmp-name-{s}") for s in "abc"]
    assert names == ["lab demo (api)", "lab demo (dpac)", "lab demo (two frames)"], names
    n = int(page.js("return Number(document.getElementById('cmp-focus').max)")) + 1
    assert n >= 3
    for k in (0, n - 1):
        _slide(page, k)
        zs = [page.text(f"cmp-z-{s}") for s in "abc"]
        assert len(set(zs)) == 1, zs  # one scene at one optics: every column at the same depth
        assert "all 3 focused at" in page.text("cmp-focus-label")
    rows = page.js("return [...document.querySelectorAll('#cmp-diff tbody tr')].map(r => "
                   "[...r.cells].map(c => c.innerText.trim()))")
    diff = {r[0]: tuple(r[1:]) for r in rows}
    assert diff["encoder"] == ("sgd", "dpac", "sgd") and diff["optics.frames"] == ("1", "2", "2"), diff
    assert "preset" not in diff
    heads = page.js("return [...document.querySelectorAll('#cmp-diff thead th')].map((h) => h.innerText)")
    assert len(heads) == 4 and heads[1].startswith("Job 1"), heads
    # a fourth job from "Add a job", then one left out
    assert page.visible("cmp-more")
    page.choose("cmp-add", ids[0])
    page.until(lambda: _loaded(page, 4), what="four jobs' views")
    assert page.js("return location.hash") == "#/compare/" + "/".join(ids + [ids[0]])
    assert not page.visible("cmp-more")  # four is the most
    _click(page, "cmp-drop-b")
    page.until(lambda: page.js("return location.hash") == f"#/compare/{ids[0]}/{ids[2]}/{ids[0]}"
               and _loaded(page, 3), what="the column left out")
    page.go(f"#/compare/{'/'.join(ids + ids[:2])}")  # five: not a compare address
    page.until(lambda: "2 to 4 jobs" in page.text("status"), what="the refusal")


def test_a_sweeps_job_links_to_its_sweep(page, server, scene, done_job):  # noqa: F811
    from selenium.webdriver.common.by import By

    with server.client("submit") as c:
        r = c.post("/v1/sweeps", json={"job": {**LIVE, "scene_id": scene["id"]}, "option": "frames",
                                       "values": [5, 7]})
        assert r.status_code == 202, r.text
        sweep = r.json()
        c.delete(f"/v1/sweeps/{sweep['id']}")
    page.go(f"#/jobs/{sweep['jobs'][1]}")
    page.until(lambda: page.js("return !!document.getElementById('job-sweep-link')"), what="the sweep's link")
    assert page.js("return document.getElementById('job-sweep-link').getAttribute('href')") == f"#/sweeps/{sweep['id']}"
    page.d.find_element(By.ID, "job-sweep-link").click()
    page.until(lambda: page.visible("sweep") and page.text("sweep-title") == "frames = 5, 7", what="the sweep's page")
    page.go(f"#/jobs/{done_job['id']}")  # a job of its own names no sweep
    page.until(lambda: page.text("job-id") == done_job["id"] and page.text("job-name-title") == "lab demo (api)")
    assert not page.js("return !!document.getElementById('job-sweep-link')")


def test_a_result_too_poor_to_be_useful_is_flagged(page, server, scene, done_job, more_jobs):  # noqa: F811
    """The flag follows the API's quality (the prediction here: these jobs are not evaluated) against its one
    level; a job whose predicted quality is above it carries none."""
    high = _submit(server, scene, {**DONE_JOB, "frames": 24, "preset": "reference", "spp": 512, "iterations": 200,
                                   "name": "lab demo (24 frames)"})
    with server.client("submit") as c:
        jobs = {j["id"]: c.get(f"/v1/jobs/{j['id']}").json() for j in (done_job, *more_jobs)}
        jobs[high] = c.get(f"/v1/jobs/{high}").json()
    try:
        low = [j for j in jobs.values() if j["quality"]["too_low"]]
        fine = [j for j in jobs.values() if not j["quality"]["too_low"]]
        assert low and fine, {j["name"]: j["quality"] for j in jobs.values()}
        page.go("#/")
        page.until(lambda: set(jobs) <= set(_rows(page)), what="the jobs in the list")
        flagged = page.js("return [...document.querySelectorAll('#jobs tbody tr')].filter((r) => "
                          "r.querySelector('.low-quality')).map((r) => r.dataset.jobId)")
        assert set(flagged) & set(jobs) == {j["id"] for j in low}, (flagged, jobs)
        floor = low[0]["quality"]["floor_db"]
        title = page.js("return document.querySelector(`#jobs tr[data-job-id=\"${arguments[0]}\"] .low-quality`)"
                        ".title", low[0]["id"])
        assert f"below the {floor:g} dB" in title and title.startswith("predicted"), title
        page.go(f"#/jobs/{low[0]['id']}")
        page.until(lambda: page.text("job-id") == low[0]["id"] and page.visible("job-quality-flag"),
                   what="the job page's flag")
        assert page.text("job-quality-flag").startswith("Quality too low to be useful: predicted")
        page.go(f"#/jobs/{fine[0]['id']}")
        page.until(lambda: page.text("job-id") == fine[0]["id"] and page.text("job-name-title"))
        assert not page.js("return !!document.getElementById('job-quality-flag')")
    finally:
        with server.client("submit") as c:
            c.delete(f"/v1/jobs/{high}")
