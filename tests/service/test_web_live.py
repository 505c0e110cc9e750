"""A job's page shows what the job is doing, live, in headless Chromium against a real `holo serve`: a queued
job's plan at its own options, a running job's step timeline, worker CPU and memory and the running step's log
tail, its render's plan through the later steps; and a job stopped during encode keeps its render's plan, its
run time and the step it stopped at.

One server (one worker: a second job waits behind the first), one browser.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from service.db import Database
from tests.service.helpers import wait_state
from tests.service.test_live_api import RENDER_LOG
from tests.service.test_web_page import Page, browser, files, page, scene  # noqa: F401 (fixtures)

pytestmark = pytest.mark.slow

# long enough to watch it run on 2 busy cores (the render alone takes several seconds)
LONG_JOB = {"optics": {"resolution_hw": [192, 256]}, "frames": 2, "preset": "fast", "encoder": "sgd",
            "iterations": 300, "name": "long one"}


def _steps(page: Page) -> dict:
    return page.js("const o = {}; for (const li of document.querySelectorAll('#steps li')) "
                   "o[li.dataset.step] = {cls: li.className, text: li.innerText}; return o;")


def test_a_job_cancelled_during_encode_keeps_its_plan_its_run_time_and_its_step(page, server, scene):
    with server.client("submit") as c:
        job = c.post("/v1/jobs", json={"scene_id": scene["id"], "name": "stopped in encode"}).json()
        c.delete(f"/v1/jobs/{job['id']}")
        job = c.get(f"/v1/jobs/{job['id']}").json()
    assert job["state"] == "cancelled"
    # as a run stopped during its encode leaves its folder and record: 39 s run, the render's plan in its log
    db = Database(server.data_dir / "service.db")
    row = db.get_job(job["id"])
    db.update_job(job["id"], started_at=row["finished_at"] - 39.0)
    folder = Path(row["artifact_dir"])
    folder.mkdir(parents=True, exist_ok=True)
    t0 = row["finished_at"] - 39.0
    (folder / "render.log").write_text(RENDER_LOG)
    (folder / "progress-render.jsonl").write_text(json.dumps({"stage": "propagate", "done": 1, "total": 1,
                                                              "t": t0 + 30}) + "\n")
    (folder / "step.json").write_text(json.dumps({"step": "encode", "index": 1, "t": t0 + 30.5}))
    (folder / "encode.log").write_text("encoding 1 frame(s)\n")
    page.go(f"#/jobs/{job['id']}")
    page.until(lambda: page.text("job-state") == "cancelled" and page.visible("steps"), what="the cancelled job")
    plan = page.text("plan")
    assert "mirror reflection: 1 surface(s) (mirror_sphere)" in plan
    assert "before its render made one" not in plan
    assert "actual 39 s" in page.text("job-facts")
    steps = _steps(page)
    assert "done" in steps["render"]["cls"] and "actual 30 s" in steps["render"]["text"]
    assert "current" in steps["encode"]["cls"] and "stopped here" in steps["encode"]["text"]
    page.until(lambda: page.js("return document.getElementById('log-text').dataset.step") == "encode",
               what="the encode log opened first")


def test_a_running_job_shows_its_steps_worker_log_and_plan_live_and_a_queued_one_its_plan(page, server, scene):
    with server.client("submit") as c:
        long = c.post("/v1/jobs", json={"scene_id": scene["id"], **LONG_JOB}).json()
        queued = c.post("/v1/jobs", json={"scene_id": scene["id"], "name": "behind it"}).json()
        try:
            page.go(f"#/jobs/{queued['id']}")
            page.until(lambda: page.text("job-name-title") == "behind it", what="the queued job")
            assert page.text("job-state") == "queued"  # behind the long one on the only worker
            page.until(lambda: "from its scene's plan" in page.text("plan"), what="the queued job's plan")
            assert page.js("return document.getElementById('plan').dataset.source") == "options"
            assert "frame(s)" in page.text("plan")
            page.go(f"#/jobs/{long['id']}")
            page.until(lambda: page.text("job-state") == "running" and "current" in _steps(page)
                       .get("render", {}).get("cls", ""), what="the render running")
            page.until(lambda: "of CPU time" in page.text("job-worker"), what="the worker's CPU and memory")
            assert "resident memory" in page.text("job-worker")
            page.until(lambda: page.js("return document.getElementById('log-text').dataset.live") == "1",
                       what="the running step's log tail")
            assert "left" in page.text("job-stage")
            page.until(lambda: "current" in _steps(page).get("encode", {}).get("cls", ""), timeout=120,
                       what="the encode running")
            assert page.text("job-state") == "running"
            assert page.js("return document.getElementById('plan').dataset.source") == "render"
            assert "comes when it renders" not in page.text("plan")
            render = _steps(page)["render"]
            assert "done" in render["cls"] and "actual –" not in render["text"]
            assert page.js("return document.getElementById('log-text').dataset.step") == "encode"
        finally:
            for j in (long, queued):
                c.delete(f"/v1/jobs/{j['id']}")
            wait_state(c, queued["id"], ("cancelled", "succeeded", "failed"))
            time.sleep(0.2)


def test_the_time_left_is_the_live_views_and_the_actual_time_never_a_dash_once_it_ran(page):
    """A run far slower than its estimate of 40 s: the blend of estimate and overall pace said "about 28 s left"
    where the steps still to come at the measured pace take two minutes."""
    out = page.d.execute_async_script("""const done = arguments[arguments.length - 1];
        import('/web/job_facts.js').then((m) => {
          const start = new Date(Date.now() - 85000).toISOString();
          const job = { id: 'jslow', state: 'running', started_at: start, estimate: { seconds: 40 },
                        progress: { step: 'encode', stage: 'iterate', fraction: 0.75 } };
          const live = { id: 'jslow', state: 'running', left_s: 120, elapsed_s: 85 };
          const stopped = { id: 'jstop', state: 'cancelled', started_at: new Date(Date.now() - 39000).toISOString(),
                            finished_at: new Date().toISOString(), timings: null };
          done([m.eta(job, live), m.eta(job), m.actualSeconds(stopped),
                m.actualSeconds({ ...job, started_at: null }, live)]);
        }, (err) => done(String(err)));""")
    assert out[0] == "about 2 min 0 s left (the estimate was 40 s; this run goes slower)", out
    assert "28 s" in out[1]  # without the live view: the old blend, kept for a job no stream follows
    assert 38.5 <= out[2] <= 40 and out[3] == 85, out
