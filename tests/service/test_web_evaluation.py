"""The evaluation on the results page, in headless Chromium against a real `holo serve`: the submit form's
"Evaluate against ground truth" box goes into the job it estimates (the estimate grows by the evaluation and
says so), and an evaluated job's page shows, at the focus the sweep's slider selects, the hologram's scored view
beside the ground truth with that depth's PSNR and SSIM: moving the slider moves the sweep, both images and the
numbers to the same depth; the tables list every depth and view, and the viewer-faithful score is there.

The evaluated job is the session's (tests/service/conftest.py), submitted over the API with
tests/service/test_evaluation_job.py's options: the form's display profiles put virtual infinity at 80 mm, where
a 96 x 128 SLM lights none of the evaluation's views.
"""

from __future__ import annotations

import pytest

from tests.service.helpers import wait_state
from tests.service.test_web import _pixels
from tests.service.test_web_page import Page, browser, files, scene  # noqa: F401 (fixtures)

# headless Chromium on an evaluated job; test_evaluation_job.py holds the API it shows
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def server(evaluation_server):
    """The session's evaluation server (tests/service/conftest.py): its evaluated job is shared with
    tests/service/test_evaluation_job.py, and these tests leave it as they found it."""
    return evaluation_server


@pytest.fixture(scope="module")
def evaluated(evaluated_job, evaluation_server) -> dict:
    with evaluation_server.client("reader") as c:
        index = c.get(f"/v1/jobs/{evaluated_job['job']['id']}/evaluation").json()
    return {"job": evaluated_job["job"], "index": index}


@pytest.fixture
def page(browser, server, scene) -> Page:  # noqa: F811
    browser.set_window_size(1280, 1500)
    return Page(browser, server).sign_in()


def test_the_forms_evaluate_box_goes_into_the_estimate(page, files):  # noqa: F811
    from selenium.webdriver.common.by import By

    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button"), what="the demo scene's estimate")
    assert not page.js("return document.getElementById('evaluate').checked")
    plain = page.text("estimate")
    assert "evaluation" not in plain
    page.d.find_element(By.ID, "evaluate").click()
    page.until(lambda: "the evaluation" in page.text("estimate") and page.enabled("submit-button"),
               what="the estimate with the evaluation")
    with_ev = page.text("estimate")
    assert "+ evaluation" in with_ev and with_ev != plain
    page.d.find_element(By.ID, "evaluate").click()
    page.until(lambda: "evaluation" not in page.text("estimate") and page.enabled("submit-button"),
               what="the estimate without it")


def _shown(page: Page) -> dict:
    return page.js("""const $ = (id) => document.getElementById(id);
        return {slider: Number($('focus').value), max: Number($('focus').max), sweep: Number($('sweep-img').dataset.index),
                truth: Number($('eval-truth').dataset.index), holo: Number($('eval-holo').dataset.index),
                score: $('eval-score').innerText, label: $('eval-focus-label').innerText,
                current: [...document.querySelectorAll('#eval-focus tr.current')].map(r => Number(r.dataset.index)),
                loaded: ['eval-truth', 'eval-holo', 'sweep-img'].every(i => $(i).complete && $(i).naturalWidth > 0)};""")


def test_the_ground_truth_follows_the_focus_slider(page, evaluated):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    job, idx = evaluated["job"], evaluated["index"]
    page.go(f"#/jobs/{job['id']}")
    page.until(lambda: page.visible("evaluation") and _shown(page)["loaded"] and page.text("eval-score"),
               what="the evaluation's pictures")
    assert page.text("job-state") == "succeeded" and "evaluated against ground truth" in page.text("job-facts")
    n = len(idx["focus"])
    first = _shown(page)
    assert first["max"] == n - 1 and first["slider"] == (n - 1) // 2
    seen = {}
    slider = page.d.find_element(By.ID, "focus")
    for key in (Keys.HOME, Keys.END, Keys.ARROW_LEFT):  # a person's keys on the range: far end, near end, one back
        slider.send_keys(key)
        want = {Keys.HOME: 0, Keys.END: n - 1, Keys.ARROW_LEFT: n - 2}[key]
        page.until(lambda: _shown(page)["truth"] == want and _shown(page)["loaded"], what=f"the depth {want}")
        s = _shown(page)
        f = idx["focus"][want]
        # the sweep, both images, the numbers and the table's mark are all at the slider's depth
        assert s["slider"] == s["sweep"] == s["truth"] == s["holo"] == want and s["current"] == [want], s
        assert f"PSNR {f['psnr_db']:.2f} dB" in s["score"] and f"SSIM {f['ssim']:.3f}" in s["score"], (s, f)
        assert f"{f['z_mm']:.3f} mm" in s["label"] and f["words"] in s["label"]
        seen[want] = (_pixels(page.d, "eval-truth"), _pixels(page.d, "eval-holo"), s["score"])
    assert seen[0][0] != seen[n - 1][0] and seen[0][1] != seen[n - 1][1], "the images did not change"
    assert seen[0][2] != seen[n - 1][2] and seen[n - 1][0] != seen[n - 2][0]
    # a row of the table moves the slider there
    page.d.find_element(By.CSS_SELECTOR, "#eval-focus tr[data-index='1']").click()
    page.until(lambda: _shown(page)["slider"] == 1 == _shown(page)["truth"] == _shown(page)["sweep"])
    rows = page.js("return document.querySelectorAll('#eval-focus tbody tr').length")
    views = page.js("return document.querySelectorAll('#eval-views tbody tr').length")
    assert rows == n and views == len(idx["view_grid"]) == 9 and page.visible("eval-views")
    assert "Viewer-faithful score:" in page.text("eval-viewer") and "2.0 mm" in page.text("eval-viewer")
    assert f"{idx['pupil_mm']:.2f} mm pupil" in page.text("eval-note")
    errors = [e for e in page.d.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors


def test_a_job_without_an_evaluation_shows_no_ground_truth(page, evaluated, server, scene):  # noqa: F811
    from tests.service.test_web_page import DONE_JOB

    with server.client("submit") as c:
        r = c.post("/v1/jobs", json={"scene_id": scene["id"], **DONE_JOB})
        job = wait_state(c, r.json()["id"], ("succeeded", "failed", "cancelled"), timeout=240)
    page.go(f"#/jobs/{job['id']}")
    page.until(lambda: page.visible("look") and page.js("return document.getElementById('sweep-img').complete "
                                                        "&& document.getElementById('sweep-img').naturalWidth > 0"))
    assert not page.visible("evaluation")
    page.go(f"#/jobs/{evaluated['job']['id']}")  # and the next job's page has its own
    page.until(lambda: page.visible("evaluation") and _shown(page)["loaded"])
