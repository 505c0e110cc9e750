"""The scene scale on the page, in headless Chromium against a real `holo serve`: a scene modelled metres from its
camera says under its upload that an eye sees no focus change and suggests a scale; the form's Scene scale box
takes it, the estimate's plan then spans depths of field, the job stores it, and a re-run keeps it."""

from __future__ import annotations

import re
import zipfile

import pytest

from tests.service.test_web_page import Page, browser, files, page, scene  # noqa: F401 (fixtures)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def far_scene_zip(tmp_path_factory):
    """A Cornell box 4 m from its camera (0.7 depths of field for a 4 mm pupil), as a bundle to upload."""
    from holocore.scene.demo import write_cbox_scene

    tmp = tmp_path_factory.mktemp("far")
    write_cbox_scene(tmp / "box", res_px=64)
    out = tmp / "far-box.zip"
    with zipfile.ZipFile(out, "w") as zf:
        for p in sorted((tmp / "box").rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(tmp / "box").as_posix())
    return out


def _depths_of_field(text: str) -> float:
    m = re.search(r"spans ([0-9.e+-]+) depths of field", text)
    assert m, text
    return float(m.group(1))


def test_a_far_scene_is_offered_a_scale_which_the_job_and_its_rerun_keep(page, server, far_scene_zip):  # noqa: F811
    from selenium.webdriver.common.by import By

    page.upload(far_scene_zip)
    page.until(lambda: page.visible("scene-focus"), what="the scene's focus line", timeout=240)
    line = page.text("scene-focus")
    assert "no focus change" in line and _depths_of_field(line) < 1, line
    hint = page.js("return document.getElementById('scene-scale').placeholder")
    suggested = re.search(r"suggested ([0-9.e+-]+)", hint).group(1)
    assert 0 < float(suggested) < 0.5
    for field, value in (("frames", "1"), ("res-h", "48"), ("res-w", "64"), ("spp", "4"), ("iterations", "20")):
        page.set(field, value)
    page.set("scene-scale", suggested)
    def focus_line() -> str:
        return next((ln for ln in page.text("form-plan").splitlines() if ln.startswith("focus:")), "")

    # the plan shown until the estimate comes back is the unscaled one: wait for the scaled plan's focus line
    page.until(lambda: page.enabled("submit-button") and focus_line()
               and "no focus change" not in focus_line(), what="the scaled scene's estimate")
    assert _depths_of_field(focus_line()) >= 1, focus_line()
    page.d.find_element(By.ID, "submit-button").click()
    page.until(lambda: re.search(r"#/jobs/j\w+$", page.d.current_url), what="the job's page")
    jid = page.d.current_url.rsplit("/", 1)[1]
    with server.client("submit") as c:
        job = c.get(f"/v1/jobs/{jid}").json()
    assert job["options"]["optics"]["scene_scale"] == pytest.approx(float(suggested))
    page.until(lambda: page.enabled("job-rerun"), what="re-run")
    page.d.find_element(By.ID, "job-rerun").click()
    page.until(lambda: page.visible("home") and page.visible("job-form"), what="the form with the job's options")
    assert float(page.js("return document.getElementById('scene-scale').value")) == pytest.approx(float(suggested))
    with server.client("submit") as c:
        c.delete(f"/v1/jobs/{jid}")
