"""A sweep on the results page, in headless Chromium against a real `holo serve`: a person sweeps frames 1, 2, 4
of a small job from the submit form, lands on the sweep's page, sees its three jobs and a chart whose predicted
quality points lie left to right with the frames, watches the jobs finish until the time panel holds their
actual run times, and Cancel all on a second sweep leaves its jobs cancelled (then one is deleted from the
list, and a read-only token sees the sweep without those buttons)."""

from __future__ import annotations

import pytest

from tests.service.test_web_page import Page, browser, files, page, scene  # noqa: F401 (fixtures)

# headless Chromium and three renders; tests/service/test_web_page.py drives the page
pytestmark = pytest.mark.slow

SMALL = {"optics": {"resolution_hw": [48, 64], "seed": 3}, "preset": "fast", "spp": 4, "encoder": "dpac"}


def _circles(page: Page, panel: str, series: str) -> list[tuple[float, str]]:
    return [(float(x), v) for x, v in page.js(
        "return [...document.querySelectorAll(`#${arguments[0]} circle[data-series=${arguments[1]}]`)]"
        ".map((c) => [c.getAttribute('cx'), c.dataset.value])", panel, series)]


def test_a_frames_sweep_from_the_form_and_its_chart(page, files):  # noqa: F811
    from selenium.webdriver.common.by import By

    page.upload(files["demo"])
    page.until(lambda: page.enabled("submit-button"), what="the form")
    page.choose("preset", "fast")
    page.choose("encoder", "dpac")
    for field, value in (("frames", "1"), ("res-h", "48"), ("res-w", "64"), ("spp", "4")):
        page.set(field, value)
    page.choose("sweep-option", "frames")
    page.set("sweep-values", "1, 2, 4")
    page.until(lambda: page.enabled("submit-button") and page.text("submit-button") == "Submit sweep (3 jobs)",
               what="the sweep's Submit")
    assert "frames = 1, 2, 4" in page.text("sweep-note")
    page.d.find_element(By.ID, "submit-button").click()
    page.until(lambda: "#/sweeps/w" in page.d.current_url, what="the sweep's page")
    sweep_hash = "#" + page.d.current_url.split("#", 1)[1]
    page.until(lambda: len(_circles(page, "sweep-quality", "predicted")) == 3, what="three predicted points")
    rows = page.js("return [...document.querySelectorAll('#sweep-jobs tbody tr')].map((r) => r.innerText)")
    assert len(rows) == 3 and all("lab-demo · frames=" in r for r in rows), rows
    points = _circles(page, "sweep-quality", "predicted")
    assert [v for _, v in points] == ["1", "2", "4"]
    assert points[0][0] < points[1][0] < points[2][0], points
    labels = page.text("sweep-chart")
    assert "quality, dB" in labels and "time, s" in labels and "frames, count" in labels
    assert len(_circles(page, "sweep-time", "estimated")) == 3
    page.until(lambda: len(page.js("return document.querySelectorAll('#sweep-jobs tr[data-state=succeeded]')")) == 3,
               timeout=120, what="the three jobs to finish")
    page.until(lambda: len(_circles(page, "sweep-time", "actual")) == 3, what="the actual times")
    assert page.js("return document.getElementById('sweep-cancel').disabled")
    page.go("#/")  # the home page links the sweep
    page.until(lambda: "frames = 1, 2, 4" in page.text("sweeps-line"), what="the home page's sweeps line")
    assert page.js("return document.querySelector('#sweeps-line a').getAttribute('href')") == sweep_hash


def test_cancel_all_on_a_sweep(page, server, scene):  # noqa: F811
    from selenium.webdriver.common.by import By

    job = {**SMALL, "scene_id": scene["id"], "optics": {"resolution_hw": [192, 256], "seed": 5}, "spp": 64}
    with server.client("submit") as c:
        r = c.post("/v1/sweeps", json={"job": job, "option": "frames", "values": [6, 8]})
        assert r.status_code == 202, r.text
        sweep = r.json()
    page.go(f"#/sweeps/{sweep['id']}")
    page.until(lambda: page.enabled("sweep-cancel"), what="Cancel all")
    page.d.find_element(By.ID, "sweep-cancel").click()
    page.until(lambda: page.js("return [...document.querySelectorAll('#sweep-jobs tbody tr')]"
                               ".map((r) => r.dataset.state).join()") == "cancelled,cancelled",
               what="both jobs cancelled")
    with server.client("submit") as c:
        assert [j["state"] for j in c.get(f"/v1/sweeps/{sweep['id']}").json()["jobs"]] == ["cancelled"] * 2
    # tick the first job and delete it (two clicks): the sweep keeps the other
    page.d.find_element(By.CSS_SELECTOR, f"#sweep-jobs input[value={sweep['jobs'][0]}]").click()
    page.until(lambda: page.enabled("sweep-delete-selected"), what="Delete selected")
    page.d.find_element(By.ID, "sweep-delete-selected").click()
    page.d.find_element(By.ID, "sweep-delete-selected").click()
    page.until(lambda: page.js("return document.querySelectorAll('#sweep-jobs tbody tr').length") == 1,
               what="the deleted job gone from the list")
    assert "(1 deleted)" in page.text("sweep-summary")
    # a read-only token watches the sweep; it has nothing to cancel or delete with
    page.sign_in("reader")
    page.go(f"#/sweeps/{sweep['id']}")
    page.until(lambda: page.js("return document.querySelectorAll('#sweep-jobs tbody tr').length") == 1)
    assert not page.visible("sweep-cancel") and not page.visible("sweep-delete-selected")
