"""The home page's job list with filters and sort, the queue's line, and the scene's picture with the hologram's
field of view drawn over it (the form's, following the options, and a job's), in headless Chromium against a
real `holo serve`. The fixtures are test_web_page.py's: one server, the demo scene, one finished job."""

from __future__ import annotations

import math
import time

import pytest

from tests.service.helpers import wait_state
from tests.service.test_web_page import DONE_JOB, Page, browser, done_job, files, page, scene  # noqa: F401

# headless Chromium on four jobs; test_scene_picture.py and test_queue_status.py hold its API
pytestmark = pytest.mark.slow

TINY = {"optics": {"resolution_hw": [32, 48], "seed": 1}, "preset": "fast", "frames": 1, "spp": 1,
        "encoder": "dpac"}
DEMO_FOV_X_DEG, DEMO_FILM_HW = 10.0, (192, 256)  # holocore.scene.demo's camera


@pytest.fixture(scope="module")
def jobs(server, scene, done_job) -> list[dict]:  # noqa: F811
    """Three more jobs beside the finished one: two finished on different displays, one cancelled."""
    made = []
    with server.client("submit") as c:
        for seed, name, display in ((11, "zeta one", "lab-a"), (12, "alpha two", None)):
            # seeds of their own: the same options would reuse one result, and a reused job never ran
            body = {"scene_id": scene["id"], **TINY, "optics": {**TINY["optics"], "seed": seed}, "name": name,
                    **({"display": display} if display else {})}
            r = c.post("/v1/jobs", json=body)
            assert r.status_code == 202, r.text
            made.append(r.json()["id"])
        r = c.post("/v1/jobs", json={"scene_id": scene["id"], **TINY, "spp": 64, "name": "mid three",
                                     "display": "lab-b"})
        assert r.status_code == 202, r.text
        c.delete(f"/v1/jobs/{r.json()['id']}")
        made.append(r.json()["id"])
        out = [wait_state(c, j, ("succeeded", "failed", "cancelled"), timeout=240) for j in made]
        out.append(c.get(f"/v1/jobs/{done_job['id']}").json())
    assert [j["state"] for j in out] == ["succeeded", "succeeded", "cancelled", "succeeded"], [j["error"] for j in out]
    return out


def _rows(p: Page) -> list[str]:
    """The ids of the list's visible rows, top to bottom."""
    return p.js("return [...document.querySelectorAll('#jobs tbody tr')].filter(r => !r.hidden && "
                "r.getClientRects().length).map(r => r.dataset.jobId)")


def _marked_rows_left(p: Page) -> int:
    return p.js("return [...document.querySelectorAll('#jobs tbody tr')].filter(r => r.__old).length")


def test_filters_and_sort_change_the_rows_and_survive_a_refresh(page, jobs):  # noqa: F811
    ids = {j["id"] for j in jobs}
    page.until(lambda: set(_rows(page)) == ids, what="the four jobs in the list")
    by_id = {j["id"]: j for j in jobs}
    name = {j["id"]: j["name"] for j in jobs}

    page.choose("filter-state", "succeeded")
    page.until(lambda: set(_rows(page)) == {j["id"] for j in jobs if j["state"] == "succeeded"})
    assert "3 of 4 shown" in page.text("filter-count")
    page.choose("filter-state", "cancelled")
    page.until(lambda: _rows(page) == [j["id"] for j in jobs if j["state"] == "cancelled"])
    page.choose("filter-state", "")
    page.set("filter-text", "ALPHA")  # any case, over the name
    page.until(lambda: [name[i] for i in _rows(page)] == ["alpha two"])
    page.set("filter-text", jobs[0]["id"][:10])  # over the id
    page.until(lambda: _rows(page) == [jobs[0]["id"]])
    page.set("filter-text", "scene.xml")  # over the scene's file: every job is on the demo scene
    page.until(lambda: set(_rows(page)) == ids)
    page.set("filter-text", "no such job")
    page.until(lambda: _rows(page) == [] and page.visible("jobs-none-match"))
    page.set("filter-text", "")
    page.choose("filter-display", "lab-a")
    page.until(lambda: [name[i] for i in _rows(page)] == ["zeta one"])
    page.choose("filter-display", "")

    page.choose("sort-jobs", "name")
    page.until(lambda: [name[i] for i in _rows(page)] == sorted(name.values(), key=str.lower))
    page.choose("sort-jobs", "runtime")  # longest run first; the cancelled job never ran: last
    ran = sorted((j for j in jobs if (j["timings"] or {}).get("run_s") is not None),
                 key=lambda j: -j["timings"]["run_s"])
    page.until(lambda: _rows(page)[:len(ran)] == [j["id"] for j in ran] and _rows(page)[-1] == jobs[2]["id"],
               what=f"the run-time order {[(name[j['id']], j['timings']['run_s']) for j in ran]}")
    page.choose("sort-jobs", "state")
    page.until(lambda: [by_id[i]["state"] for i in _rows(page)] == ["succeeded"] * 3 + ["cancelled"])

    # The list reloads (the Refresh button; the timer does the same every 10 s): new rows, the same choice.
    page.choose("sort-jobs", "name")
    page.choose("filter-state", "succeeded")
    want = [i for i in sorted(ids, key=lambda i: name[i].lower()) if by_id[i]["state"] == "succeeded"]
    page.until(lambda: _rows(page) == want)
    page.js("for (const r of document.querySelectorAll('#jobs tbody tr')) r.__old = true;")
    page.js("document.getElementById('refresh').click()")
    page.until(lambda: _marked_rows_left(page) == 0 and len(page.js(
        "return document.querySelectorAll('#jobs tbody tr')")) == 4, what="the list to be rebuilt")
    assert _rows(page) == want
    assert page.js("return document.getElementById('filter-state').value") == "succeeded"
    # ...and a visit to a job's page and back
    page.go(f"#/jobs/{want[0]}")
    page.until(lambda: page.visible("job"))
    page.go("#/")
    page.until(lambda: page.visible("home") and _rows(page) == want, what="the filtered list again")
    page.choose("filter-state", "")
    page.choose("sort-jobs", "created")
    page.until(lambda: len(_rows(page)) == 4)


def test_the_queue_line_says_what_waits(page, server, jobs):  # noqa: F811
    page.until(lambda: page.text("queue-line").startswith("Queue:"), what="the queue line")
    line = page.text("queue-line")
    assert "Queue: 0 waiting (0 yours)" in line and "0 of 1 slot busy" in line and "planner: idle" in line, line
    # a scene being planned and a job waiting for it, written into the database: the line follows on refresh
    from service.db import Database

    db = Database(server.data_dir / "service.db")
    now = time.time()
    db.execute("INSERT INTO scenes (id, sha256, entry, report, plan_state, created_at) VALUES "
               "('sqline', 'ab', 'scene.xml', '{}', 'running', ?)", (now,))
    db.execute("INSERT INTO scene_owners (scene_id, owner, created_at) VALUES ('sqline', 'default', ?)", (now,))
    db.execute("INSERT INTO jobs (id, owner, scene_id, state, spec, cache_key, created_at, updated_at, attempts) "
               "VALUES ('jqline', 'default', 'sqline', 'queued', '{}', 'k-jqline', ?, ?, 0)", (now, now))
    try:
        page.js("document.getElementById('refresh').click()")
        page.until(lambda: "Queue: 1 waiting (1 yours)" in page.text("queue-line")
                   and "planner: 1 scene to plan (1 yours)" in page.text("queue-line"),
                   what=f"the line to count them: {page.text('queue-line')!r}")
    finally:
        db.execute("DELETE FROM jobs WHERE id = 'jqline'")
        db.execute("DELETE FROM scene_owners WHERE scene_id = 'sqline'")
        db.execute("DELETE FROM scenes WHERE id = 'sqline'")
    page.js("document.getElementById('refresh').click()")
    page.until(lambda: "Queue: 0 waiting" in page.text("queue-line"))


def _box(p: Page, prefix: str) -> dict:
    """The box's fractions (its data) and its drawn size against the picture's frame (px)."""
    return p.js("""const b = document.getElementById(arguments[0] + '-fov-box');
        const f = b && b.parentElement; if (!b || b.hidden) return null;
        const rb = b.getBoundingClientRect(), rf = f.getBoundingClientRect();
        return {x0: +b.dataset.x0, y0: +b.dataset.y0, x1: +b.dataset.x1, y1: +b.dataset.y1,
                w: rb.width / rf.width, h: rb.height / rf.height, beyond: b.classList.contains('beyond'),
                caption: document.getElementById(arguments[0] + '-fov-caption').innerText};""", prefix)


def _expected_width(res_w: int, pitch_um: float = 8.0, f_mm: float = 50.0) -> float:
    """The hologram's width as a fraction of the camera's: tan of half its view, 2 atan(W p / 2f), over the
    camera's tan(fov_x / 2)."""
    return (res_w * pitch_um * 1e-3 / (2 * f_mm)) / math.tan(math.radians(DEMO_FOV_X_DEG) / 2)


def _picture_loaded(p: Page, prefix: str) -> bool:
    return bool(p.js("const i = document.getElementById(arguments[0] + '-scene-img'); "
                     "return !!i && i.complete && i.naturalWidth > 0", prefix))


def test_the_scene_picture_and_its_fov_box_follow_the_form(page, files):  # noqa: F811
    page.upload(files["demo"])
    page.until(lambda: _picture_loaded(page, "form"), what="the scene's picture under the form")
    # the whole display (the form starts at a preview of half its rows and columns)
    page.js("const s = document.getElementById('size'); s.value = 'full'; "
            "s.dispatchEvent(new Event('change', { bubbles: true }));")
    nat = page.js("const i = document.getElementById('form-scene-img'); return [i.naturalWidth, i.naturalHeight]")
    assert nat == [DEMO_FILM_HW[1], DEMO_FILM_HW[0]]  # the camera's own 256 x 192 (under 320 px wide)
    # the paper display (1920 px of 8 µm at 50 mm: 17.5 deg) sees more than the demo's 10 deg camera
    page.until(lambda: (_box(page, "form") or {}).get("x1", 0) > 1, what="the box at the default display")
    wide = _box(page, "form")
    assert wide["x1"] - wide["x0"] == pytest.approx(_expected_width(1920), rel=1e-6)
    assert wide["beyond"] and "wider and taller than the camera's view" in wide["caption"], wide
    page.set("res-w", "480")  # a quarter of the columns: a quarter of the tangent
    page.until(lambda: (_box(page, "form") or {}).get("x1", 9) < 1, what="the box at 480 columns")
    narrow = _box(page, "form")
    assert narrow["x1"] - narrow["x0"] == pytest.approx(_expected_width(480), rel=1e-6)
    assert narrow["w"] == pytest.approx(narrow["x1"] - narrow["x0"], abs=0.02)  # drawn at that size on the picture
    assert narrow["w"] < wide["w"] and narrow["h"] == pytest.approx(wide["h"], abs=0.02)  # rows unchanged
    assert narrow["x0"] == pytest.approx(1 - narrow["x1"], abs=1e-9)  # around the camera's axis
    # 1080 rows of 8 µm still see 9.9 deg, more than the camera's 7.5 deg high
    assert narrow["beyond"] and "taller than the camera's view" in narrow["caption"], narrow
    page.set("res-h", "270")
    page.until(lambda: (_box(page, "form") or {}).get("y1", 9) < 1, what="the box at 270 rows")
    small = _box(page, "form")
    assert small["h"] < narrow["h"] and small["w"] == pytest.approx(narrow["w"], abs=0.02)
    assert not small["beyond"] and "The hologram shows 4.4° x 2.47° of the camera's 10° x 7.51°" == small["caption"]


def test_a_jobs_page_shows_the_scene_with_the_jobs_fov(page, done_job):  # noqa: F811
    page.go(f"#/jobs/{done_job['id']}")
    page.until(lambda: _picture_loaded(page, "job") and _box(page, "job") is not None,
               what="the scene's picture on the job page")
    box = _box(page, "job")
    h, w = DONE_JOB["optics"]["resolution_hw"]
    assert box["x1"] - box["x0"] == pytest.approx(_expected_width(w), rel=1e-6)
    assert box["w"] == pytest.approx(box["x1"] - box["x0"], abs=0.02)
    cam_tan_y = math.tan(math.radians(DEMO_FOV_X_DEG) / 2) * DEMO_FILM_HW[0] / DEMO_FILM_HW[1]
    assert box["y1"] - box["y0"] == pytest.approx((h * 8e-3 / 100.0) / cam_tan_y, rel=1e-6)
