"""What a person does with the results page, in one go, on one of the project's paper scenes (the mirror room,
holocore.scene.paper), in headless Chromium against a real `holo serve`, with nothing but clicks and typing:
upload, submit with an evaluation, watch it finish, see the ground truth beside the hologram, re-run it with
changes and cancel that, re-run it again, and compare the two finished jobs side by side.
"""

from __future__ import annotations

import time

import pytest

from tests.service.helpers import zip_dir
from tests.service.test_web_page import Page, browser  # noqa: F401 (fixture)

# headless Chromium through three jobs of the mirror room; test_web_page.py drives each part
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def mirror_zip(tmp_path_factory):
    from holocore.scene.paper import write_paper_scene

    tmp = tmp_path_factory.mktemp("journey")
    write_paper_scene("mirror", tmp / "scene")
    out = tmp / "mirror-room.zip"
    out.write_bytes(zip_dir(tmp / "scene"))
    return out


def _click(page: Page, id_: str) -> None:
    page.js("document.getElementById(arguments[0]).click()", id_)


def _job_id(page: Page) -> str:
    return page.js("return location.hash").rsplit("/", 1)[1]


def _submit(page: Page, what: str) -> str:
    before = page.js("return location.hash")
    page.until(lambda: page.enabled("submit-button"), what=f"Submit for {what}")
    _click(page, "submit-button")
    page.until(lambda: page.js("return location.hash") != before
               and page.js("return location.hash").startswith("#/jobs/"), what=f"{what}'s page")
    return _job_id(page)


def _watch(page: Page, timeout: float = 300) -> list[float]:
    """The bar's fractions from now until the job's state is final."""
    seen = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        f, st = page.js("return [parseFloat(document.getElementById('job-bar').style.width) / 100, "
                        "(document.getElementById('job-state') || {}).innerText]")
        if f is not None and f == f:
            seen.append(float(f))
        if st in ("succeeded", "failed", "cancelled"):
            return seen
        time.sleep(0.1)
    raise AssertionError(f"the job did not finish in {timeout} s: {page.text('job-stage')!r}")


def _small(page: Page, frames: str) -> None:
    page.choose("preset", "fast")
    # 360 rows: the evaluation scores a view only where the SLM lights all of a 1.6 mm pupil's bundle, a border
    # of about 165 px at this scene's depths on the paper display
    for field, value in (("frames", frames), ("res-h", "360"), ("res-w", "640"), ("spp", "4"), ("iterations", "40")):
        page.set(field, value)


def test_upload_submit_watch_ground_truth_rerun_cancel_and_compare(browser, server, mirror_zip):  # noqa: F811
    browser.set_window_size(1280, 1500)
    page = Page(browser, server).sign_in()
    page.upload(mirror_zip)
    page.until(lambda: page.enabled("submit-button"), timeout=180, what="the mirror room's plan")
    assert page.js("return document.getElementById('job-name').value") == "mirror-room"
    _small(page, "2")
    _click(page, "evaluate")
    page.until(lambda: "evaluation" in page.text("estimate"), what="the estimate counting the evaluation")
    page.set("res-h", "270")  # too few rows to score the ground truth on this display: said before the submit
    page.until(lambda: "no evaluation at 270x640 px" in page.text("estimate"), what="the evaluation's warning")
    page.set("res-h", "360")
    page.until(lambda: "evaluation" in page.text("estimate") and "no evaluation" not in page.text("estimate"),
               what="the warning gone")
    first = _submit(page, "the first job")

    seen = _watch(page)
    assert page.text("job-state") == "succeeded", page.text("job-error")
    assert seen and all(b >= a for a, b in zip(seen, seen[1:])), f"the bar went back: {seen}"
    # the ground truth beside the hologram, at the focus the slider picks, with its scores
    page.until(lambda: page.visible("evaluation") and page.js(
        "return ['eval-holo', 'eval-truth'].every(i => { const e = document.getElementById(i); "
        "return !!e.src && e.complete && e.naturalWidth > 0; })"), timeout=60, what="the ground truth")
    assert "dB" in page.text("eval-score")
    truth = page.js("return document.getElementById('eval-truth').src")
    page.js("const r = document.getElementById('focus'); r.value = '0'; r.dispatchEvent(new Event('input'));")
    page.until(lambda: page.js("return document.getElementById('eval-truth').src") != truth,
               what="the ground truth following the focus")

    # re-run with changes, then change one's mind: cancel it
    _click(page, "job-rerun")
    page.until(lambda: page.visible("rerun-note") and page.enabled("submit-button"), what="the re-run form")
    assert page.js("return document.getElementById('res-w').value") == "640"
    page.set("frames", "1")
    second = _submit(page, "the re-run")
    page.until(lambda: page.enabled("job-cancel"), what="Cancel")
    _click(page, "job-cancel")
    page.until(lambda: page.text("job-state") == "cancelled", timeout=120, what="the cancelled state")

    # re-run the first job again, one frame and no evaluation, and let it finish
    page.go(f"#/jobs/{first}")
    page.until(lambda: page.visible("job-rerun"))
    _click(page, "job-rerun")
    page.until(lambda: page.visible("rerun-note") and page.enabled("submit-button"), what="the re-run form")
    page.set("frames", "1")
    if page.js("return document.getElementById('evaluate').checked"):
        _click(page, "evaluate")
    third = _submit(page, "the second re-run")
    assert len({first, second, third}) == 3
    _watch(page)
    assert page.text("job-state") == "succeeded", page.text("job-error")

    # compare it with the first: both sweeps under one slider, their differences listed
    page.until(lambda: page.visible("job-compare"), what="Compare with")
    page.choose("job-compare-pick", first)
    _click(page, "job-compare-go")
    page.until(lambda: page.js("return ['a', 'b'].every(s => { const i = document.getElementById('cmp-img-' + s);"
                               "return !!i.src && i.complete && i.naturalWidth > 0; })"), what="both jobs' views")
    diff = {r[0]: r[1:] for r in page.js("return [...document.querySelectorAll('#cmp-diff tbody tr')].map(r => "
                                         "[...r.cells].map(c => c.innerText.trim()))")}
    assert diff["optics.frames"] == ["1", "2"], diff
    assert "scene" not in diff and "preset" not in diff, diff
    # the list shows all three with their states
    page.go("#/")
    for jid, state in ((first, "succeeded"), (second, "cancelled"), (third, "succeeded")):
        page.until(lambda: page.js("const r = document.querySelector(`tr[data-job-id=\"${arguments[0]}\"] .badge`);"
                                   "return r ? r.innerText : ''", jid) == state, what=f"{jid} {state} in the list")
