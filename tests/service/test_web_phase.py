"""The job page's phase frames and "Send to display", in headless Chromium against a real `holo serve` and the
real display agent (its simulated SLM): the grey image is, pixel for pixel, the 8-bit frame the API serves for
the chosen frame and colour, at the SLM's aspect ratio, and changes with the slider and the colour buttons;
sending the job to a display that shows another job makes the page say that display shows this one.

``HOLO_WEB_SCREENSHOTS=DIR`` saves the page with its phase frames and displays there (as test_web.py does).
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest

from tests.service.helpers import finished_job, start_agent, wait_for
from tests.service.test_web_page import Page, browser, files, scene  # noqa: F401 (module fixtures)

# Three frames, three colours, wider than tall (24x40): a swapped axis or a frame index ignored shows.
JOB = {"optics": {"resolution_hw": [24, 40], "seed": 9, "wavelengths_nm": [638.0, 520.0, 450.0]},
       "preset": "fast", "frames": 3, "spp": 2, "encoder": "dpac", "name": "phase frames"}


@pytest.fixture(scope="module")
def jobs(server, scene) -> dict:  # noqa: F811
    """The job whose page is shown, and a newer one for display lab-1 (the same options: its result reused)."""
    with server.client("admin") as c:
        assert c.put("/v1/displays/lab-1", json={"owner": "default"}).status_code == 204
    return {key: finished_job(server, {"scene_id": scene["id"], **JOB, **extra})
            for key, extra in (("shown", {}), ("other", {"display": "lab-1", "name": "the other job"}))}


@pytest.fixture(scope="module")
def agent(server, jobs, tmp_path_factory):
    """The display agent of lab-1 with a simulated SLM, running while the module's tests do."""
    a, stop, th = start_agent(server, tmp_path_factory.mktemp("agent"), "lab-1", rate_hz=100, poll_interval_s=0.2,
                              heartbeat_interval_s=0.3, max_seconds=600)
    yield a
    stop.set()
    th.join(timeout=15)


@pytest.fixture
def page(browser, server) -> Page:  # noqa: F811
    browser.set_window_size(1280, 1500)
    return Page(browser, server).sign_in()


def _api_frame(server, job_id: str, f: int, c: int) -> np.ndarray:
    from PIL import Image

    with server.client("reader") as cl:
        r = cl.get(f"/v1/jobs/{job_id}/phase/{f}/{c}.png")
    assert r.status_code == 200, r.text
    return np.asarray(Image.open(io.BytesIO(r.content)))


def _shown(p: Page) -> tuple[str, str, np.ndarray, float]:
    """The frame and colour the image says it shows, its pixels' grey levels (red channel of the canvas; the
    PNG is grey, so red = green = blue) and its width / height on the page."""
    f, c, w, h, data, aspect = p.js("""const img = document.getElementById('phase-img');
        const cv = document.createElement('canvas'); cv.width = img.naturalWidth; cv.height = img.naturalHeight;
        const g = cv.getContext('2d'); g.drawImage(img, 0, 0);
        const d = g.getImageData(0, 0, cv.width, cv.height).data; const out = [];
        for (let i = 0; i < d.length; i += 4) { if (d[i] !== d[i + 1] || d[i] !== d[i + 2]) return null; out.push(d[i]); }
        const r = img.getBoundingClientRect();
        return [img.dataset.frame, img.dataset.colour, cv.width, cv.height, out, r.width / r.height];""")
    return f, c, np.array(data, dtype=np.uint8).reshape(h, w), aspect


def _wait_shown(p: Page, f: int, c: int, label: str):
    p.until(lambda: p.js("const i = document.getElementById('phase-img'); return !!i && i.complete && "
                         "i.naturalWidth > 0 && i.dataset.frame === arguments[0] && i.dataset.colour === arguments[1]",
                         str(f), str(c)) and p.text("phase-label") == label, what=f"frame {f} colour {c}: {label}")
    return _shown(p)


def test_the_frames_browse_per_frame_and_colour(page, server, jobs):
    from selenium.webdriver.common.by import By

    jid = jobs["shown"]["id"]
    page.go(f"#/jobs/{jid}")
    page.until(lambda: page.visible("phase-card"), what="the phase frames section")
    assert page.js("return document.querySelector('#phase-card h2').innerText") == "Phase frames"
    buttons = page.js("return [...document.querySelectorAll('#phase-colours button')].map(b => b.innerText)")
    assert buttons == ["red 638 nm", "green 520 nm", "blue 450 nm"], buttons
    assert "3 frames × 3 colours, 24x40 px" in page.text("phase-note")

    f, c, first, aspect = _wait_shown(page, 0, 0, "frame 1 of 3, 638 nm")
    assert np.array_equal(first, _api_frame(server, jid, 0, 0))
    assert abs(aspect - 40 / 24) < 0.02, aspect  # the SLM's aspect, not a square

    page.d.find_element(By.CSS_SELECTOR, '#phase-colours button[data-colour="1"]').click()
    _, _, green, _ = _wait_shown(page, 0, 1, "frame 1 of 3, 520 nm")
    assert np.array_equal(green, _api_frame(server, jid, 0, 1)) and not np.array_equal(green, first)
    assert page.js("return document.querySelector('#phase-colours button.active').dataset.colour") == "1"

    page.set("phase-frame-num", "3")
    page.js("document.getElementById('phase-frame-num').dispatchEvent(new Event('change'))")
    _, _, third, _ = _wait_shown(page, 2, 1, "frame 3 of 3, 520 nm")
    assert np.array_equal(third, _api_frame(server, jid, 2, 1)) and not np.array_equal(third, green)
    assert page.js("return document.getElementById('phase-frame').value") == "2"

    page.js("const s = document.getElementById('phase-frame'); s.value = '1'; s.dispatchEvent(new Event('input'))")
    _, _, second, _ = _wait_shown(page, 1, 1, "frame 2 of 3, 520 nm")
    assert np.array_equal(second, _api_frame(server, jid, 1, 1))
    assert page.js("return document.getElementById('phase-frame-num').value") == "2"

    page.set("phase-frame-num", "99")  # past the last frame: the last one, not an error
    page.js("document.getElementById('phase-frame-num').dispatchEvent(new Event('change'))")
    _wait_shown(page, 2, 1, "frame 3 of 3, 520 nm")

    page.d.set_window_size(390, 900)  # a phone: the section fits, the image keeps its aspect
    try:
        wide = page.js("""return [...document.querySelectorAll('#phase-card *, #job-send *')].filter(e =>
            e.getBoundingClientRect().right > window.innerWidth + 1).map(e => e.tagName + '#' + e.id)""")
        assert wide == [] and page.js("return document.documentElement.scrollWidth <= window.innerWidth + 1"), wide
        assert abs(_shown(page)[3] - 40 / 24) < 0.02
    finally:
        page.d.set_window_size(1280, 1500)


def test_sending_the_job_to_a_display_shows_on_the_page(page, server, jobs, agent):
    from selenium.webdriver.common.by import By

    jid, other = jobs["shown"]["id"], jobs["other"]["id"]

    def line() -> str:
        return page.js("const li = document.querySelector('#display-showing li[data-display=\"lab-1\"]');"
                       "return li ? li.innerText : ''")

    page.go(f"#/jobs/{jid}")
    page.until(lambda: line().startswith(f"lab-1 shows job {other}"), what="lab-1 showing the other job")
    assert page.enabled("send-go")
    assert page.js("return [...document.getElementById('send-display').options].map(o => o.value)") == ["lab-1"]
    page.choose("send-display", "lab-1")
    page.d.find_element(By.ID, "send-go").click()
    page.until(lambda: page.text("send-note").startswith("Sent to lab-1"), what="the send's note")
    page.until(lambda: line().startswith("lab-1 shows this job, frame "), timeout=60, what="lab-1 showing this job")
    frame = int(line().split("frame ")[1].split()[0])
    assert 1 <= frame <= 3, line()
    with server.client("reader") as c:
        d = [x for x in c.get("/v1/displays").json()["displays"] if x["name"] == "lab-1"][0]
    assert d["showing"]["job_id"] == jid
    if os.environ.get("HOLO_WEB_SCREENSHOTS"):
        out = Path(os.environ["HOLO_WEB_SCREENSHOTS"])
        out.mkdir(parents=True, exist_ok=True)
        page.js("window.scrollTo(0, 0)")
        page.d.save_screenshot(str(out / "job-send-to-display.png"))
        page.js("document.getElementById('phase-card').scrollIntoView()")
        page.d.save_screenshot(str(out / "job-phase-frames.png"))

    page.go(f"#/jobs/{other}")  # the other job's page names the display's job by its id, with a link
    page.until(lambda: line().startswith(f"lab-1 shows job {jid}"), what="the other job's page")
    assert page.js("return document.querySelector('#display-showing li[data-display=\"lab-1\"] a')"
                   ".getAttribute('href')") == f"#/jobs/{jid}"


def test_a_read_only_token_sees_the_displays_but_cannot_send(browser, server, jobs, agent):  # noqa: F811
    browser.set_window_size(1280, 1500)
    p = Page(browser, server).sign_in("reader")
    p.go(f"#/jobs/{jobs['shown']['id']}")
    p.until(lambda: p.js("return !!document.querySelector('#display-showing li[data-display=\"lab-1\"]')"),
            what="the displays' lines")
    assert not p.visible("send-go") and p.visible("phase-card")
    wait_for(lambda: p.text("phase-label") == "frame 1 of 3, 638 nm", timeout=30, what="the first frame")
