"""Two jobs side by side on the results page, in headless Chromium against a real `holo serve`: one focus slider
moves both focal sweeps to the same depth, the options they differ in are listed (and only those), the job page
offers the comparison, a missing job says so, and the layout holds at 390 px and at 1920 px.

The two jobs are one demo scene at two settings (the SGD encoder with one frame, the double-phase encoder with
two), so their sweeps span the same image volume.
"""

from __future__ import annotations

import pytest

from tests.service.helpers import finished_job
from tests.service.test_web_page import DONE_JOB, Page, browser, done_job, files, scene  # noqa: F401 (fixtures)

# headless Chromium on two jobs; tests/service/test_web_page.py drives the page
pytestmark = pytest.mark.slow

OTHER_JOB = {**DONE_JOB, "encoder": "dpac", "frames": 2, "name": "lab demo (dpac)"}
OTHER_JOB.pop("iterations")


@pytest.fixture(scope="module")
def other_job(server, scene) -> dict:  # noqa: F811
    return finished_job(server, {"scene_id": scene["id"], **OTHER_JOB})


@pytest.fixture
def page(browser, server, scene) -> Page:  # noqa: F811
    browser.set_window_size(1280, 1500)
    return Page(browser, server).sign_in()


def _loaded(page: Page) -> bool:
    return page.js("""return ['a', 'b'].every(s => { const i = document.getElementById('cmp-img-' + s);
        return i.src && i.complete && i.naturalWidth > 0; })""")


def _side(page: Page, s: str) -> dict:
    return page.js("""const s = arguments[0]; const i = document.getElementById('cmp-img-' + s);
        return {index: Number(i.dataset.index), src: i.src, z: document.getElementById('cmp-z-' + s).innerText};""", s)


def _slide(page: Page, value: int) -> None:
    page.js("const r = document.getElementById('cmp-focus'); r.value = String(arguments[0]);"
            "r.dispatchEvent(new Event('input'));", value)


def test_one_focus_slider_moves_both_sweeps_and_only_differing_options_are_listed(page, done_job, other_job):  # noqa: F811
    a, b = done_job["id"], other_job["id"]
    page.go(f"#/compare/{a}/{b}")
    page.until(lambda: _loaded(page), what="both jobs' views")
    assert page.text("cmp-name-a") == "lab demo (api)" and page.text("cmp-name-b") == "lab demo (dpac)"
    n = int(page.js("return Number(document.getElementById('cmp-focus').max)")) + 1
    # the same scene at the same optics: one sweep of depths, so every position is a depth both sweeps hold
    with server_client(page) as c:
        za = [p["z_mm"] for p in c.get(f"/v1/jobs/{a}/pictures").json()["sweep"]["pictures"]]
    assert n == len(za) >= 3
    seen = []
    for k in (0, n // 2, n - 1):
        _slide(page, k)
        left, right = _side(page, "a"), _side(page, "b")
        assert left["index"] == right["index"] == k, (k, left, right)
        assert left["z"] == right["z"] and f"{za[k]:.3f} mm" in left["z"]
        assert f"{za[k]:.3f} mm" in page.text("cmp-focus-label")
        seen.append((left["src"], right["src"]))
    assert len({s for s, _ in seen}) == 3 and len({s for _, s in seen}) == 3, "each depth shows its own picture"
    rows = page.js("return [...document.querySelectorAll('#cmp-diff tbody tr')].map(r => "
                   "[...r.cells].map(c => c.innerText.trim()))")
    diff = {k: (x, y) for k, x, y in rows}
    assert diff["encoder"] == ("sgd", "dpac")
    assert diff["optics.frames"] == ("1", "2")
    assert diff["iterations"] == ("40", "–")
    for same in ("preset", "spp", "optics.resolution_hw", "optics.wavelengths_nm", "scene"):
        assert same not in diff, (same, diff)
    assert "other options are the same" in page.text("cmp-same")


def server_client(page: Page):
    return page.server.client("reader")


def test_the_job_page_offers_the_comparison_and_a_missing_job_says_so(page, done_job, other_job):  # noqa: F811
    a, b = done_job["id"], other_job["id"]
    page.go(f"#/jobs/{a}")
    page.until(lambda: page.visible("job-compare"), what="the job page's compare box")
    options = page.js("return [...document.getElementById('job-compare-pick').options].map(o => o.value)")
    assert b in options and a not in options
    page.choose("job-compare-pick", b)
    page.js("document.getElementById('job-compare-go').click()")
    page.until(lambda: page.js("return location.hash") == f"#/compare/{a}/{b}" and _loaded(page))
    # the right side picker swaps a job in place
    page.choose("cmp-pick-b", a)
    page.until(lambda: page.js("return location.hash") == f"#/compare/{a}/{a}" and _loaded(page))
    assert page.text("cmp-same").startswith("The two jobs have the same options")
    assert not page.visible("cmp-diff")
    page.go(f"#/compare/{a}/nosuchjob00")
    page.until(lambda: "No such job" in page.text("cmp-error-b"), what="the missing job's message")
    assert page.text("cmp-name-b") == "" and not page.js("return document.getElementById('cmp-img-b').src")
    page.go("#/compare")  # no ids: the two newest succeeded jobs
    page.until(lambda: page.js("return location.hash").startswith("#/compare/") and _loaded(page))


def test_compare_layout_at_390_and_1920_px(page, browser, done_job, other_job):  # noqa: F811
    page.go(f"#/compare/{done_job['id']}/{other_job['id']}")
    page.until(lambda: _loaded(page))
    browser.set_window_size(1920, 1200)
    tops = page.js("return ['a', 'b'].map(s => document.getElementById('cmp-side-' + s).getBoundingClientRect().top)")
    assert abs(tops[0] - tops[1]) < 2, tops  # side by side
    browser.set_window_size(390, 900)
    assert page.js("return document.documentElement.scrollWidth <= window.innerWidth + 1"), \
        page.js("return document.documentElement.scrollWidth")
    tops = page.js("return ['a', 'b'].map(s => document.getElementById('cmp-side-' + s).getBoundingClientRect().top)")
    assert tops[1] > tops[0] + 50, tops  # one above the other
    # each view keeps the hologram's aspect (64x96)
    ratio = page.js("const r = document.getElementById('cmp-img-a').getBoundingClientRect(); return r.width / r.height")
    assert abs(ratio - 96 / 64) < 0.05, ratio
