"""What ``GET /v1/jobs/{id}/live`` (and the stream's ``live`` event) says of a job, read from a job folder as the
driver leaves it: the render's plan once the render has listed it (also for a job cancelled during encode), each
step's estimated against its actual seconds, the time left at the measured pace, the running step's log tail and
the worker's CPU and memory."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from service.api.job_live import group_usage, live_doc, render_log_plan, time_left_s
from service.workers.driver import write_render_plan

RENDER_LOG = """rendered scene.xml for display paper: 1 frame(s) x 3 color(s) x 48x64, f = 50
mm, 12,288 rays (100% with an image point), z_wrp = 82.790 mm, in 1.4 s on cpu
->
/data/jobs/j1/result.npz
  - time limit 30 s: 7 rays per pixel in 2 pass(es) of 4, 3
  - mirror reflection: 1 surface(s) (mirror_sphere)
  - one wave recording plane (auto: more planes would not lower the noise much
at this depth)
  - ignored: the scene's <integrator type='path'> (the hologram renderer brings
its own)
"""
STEPS_S = {"render": 10.0, "encode": 5.0, "package": 0.0, "preview": 5.0}


def _ctx(scene=None):
    return SimpleNamespace(db=SimpleNamespace(get_scene=lambda _id: scene))


def _row(folder: Path, state: str, **kw) -> dict:
    now = time.time()
    return {"id": "j1", "state": state, "scene_id": "s1", "artifact_dir": str(folder), "created_at": now - 70,
            "started_at": now - 60, "finished_at": None if state == "running" else now, "worker_pid": None,
            "spec": {"optics": {}}, "estimate": {"seconds": 20.0, "steps_s": STEPS_S}, "timings": None,
            "progress": None, "plan": {"summary": ["default optics"], "source": "scene plan at default optics"},
            **kw}


def _encoding(folder: Path, *, render_end_after_s: float, encode_for_s: float) -> None:
    """A run 60 s old whose render ended ``render_end_after_s`` in and whose encode runs since."""
    now = time.time()
    folder.mkdir(exist_ok=True)
    (folder / "render.log").write_text(RENDER_LOG)
    (folder / "progress-render.jsonl").write_text(json.dumps({"stage": "propagate", "done": 1, "total": 1,
                                                              "t": now - 60 + render_end_after_s}) + "\n")
    (folder / "step.json").write_text(json.dumps({"step": "encode", "index": 1, "t": now - encode_for_s}))
    (folder / "encode.log").write_text("".join(f"iteration {i}: loss 0.{i:03d}\n" for i in range(100)))
    (folder / "progress-encode.jsonl").write_text(json.dumps({"stage": "load", "done": 1, "total": 1,
                                                              "t": now}) + "\n")


def test_render_log_plan_joins_the_wrapped_lines_and_leaves_the_run_notes_out():
    assert render_log_plan(RENDER_LOG) == [
        "mirror reflection: 1 surface(s) (mirror_sphere)",
        "one wave recording plane (auto: more planes would not lower the noise much at this depth)",
        "ignored: the scene's <integrator type='path'> (the hologram renderer brings its own)"]
    assert render_log_plan("loading scene...\n") == []


def test_a_job_cancelled_during_encode_has_its_renders_plan(tmp_path):
    _encoding(tmp_path / "j1", render_end_after_s=50, encode_for_s=10)
    doc = live_doc(_ctx(), _row(tmp_path / "j1", "cancelled"))
    assert doc["plan"]["source"] == "render"
    assert doc["plan"]["summary"][0] == "mirror reflection: 1 surface(s) (mirror_sphere)"
    assert doc["elapsed_s"] >= 59


def test_the_plan_file_the_driver_writes_comes_first(tmp_path):
    _encoding(tmp_path / "j1", render_end_after_s=50, encode_for_s=10)
    (tmp_path / "j1" / "plan.json").write_text(json.dumps({"summary": ["from the result"], "warnings": ["w"]}))
    doc = live_doc(_ctx(), _row(tmp_path / "j1", "running"))
    assert doc["plan"] == {"summary": ["from the result"], "warnings": ["w"], "source": "render"}


def test_a_running_job_has_its_steps_times_its_log_tail_and_the_time_left_at_its_pace(tmp_path):
    _encoding(tmp_path / "j1", render_end_after_s=50, encode_for_s=10)
    doc = live_doc(_ctx(), _row(tmp_path / "j1", "running"))
    steps = {s["step"]: s for s in doc["steps"]}
    assert list(steps) == ["render", "encode", "package", "preview"]
    assert steps["render"]["state"] == "done" and 49 <= steps["render"]["actual_s"] <= 51
    assert steps["encode"]["state"] == "running" and 9 <= steps["encode"]["actual_s"] <= 12
    assert steps["encode"]["estimated_s"] == 5.0 and steps["preview"]["state"] == "waiting"
    assert doc["step"] == "encode"
    # the render took 5x its estimate: encode's 5 s are 25 (15 left), the preview's 5 another 25
    assert 37 <= doc["left_s"] <= 42
    assert doc["log"]["step"] == "encode" and len(doc["log"]["lines"]) == 40
    assert doc["log"]["lines"][-1] == "iteration 99: loss 0.099"


def test_the_time_left_follows_the_running_steps_own_pace_once_it_has_one():
    steps = [{"step": "render", "estimated_s": 10.0, "actual_s": 12.0, "state": "done"},
             {"step": "encode", "estimated_s": 5.0, "actual_s": 30.0, "state": "running"},
             {"step": "preview", "estimated_s": 5.0, "actual_s": None, "state": "waiting"}]
    assert time_left_s(steps, 0.5) == 36.0  # 30 s more of encode, 5 s x 1.2 of preview
    assert time_left_s(steps, None) == 6.6  # past its estimate, no pace: a tenth of it, and the preview


def test_the_workers_cpu_and_memory_are_its_process_groups():
    busy = time.process_time()
    while time.process_time() - busy < 0.05:
        pass
    use = group_usage(os.getpgrp())
    assert use is not None and use["processes"] >= 1 and use["cpu_s"] > 0 and use["rss_bytes"] > 10 * 2**20
    assert group_usage(2**22 + 12345) is None


def test_the_driver_writes_the_renders_plan_when_the_render_ends(tmp_path):
    meta = {"plan": {"summary": ["refraction: glass_sphere"], "warnings": []}, "timings": {}}
    np.savez(tmp_path / "result.npz", wrp_field=np.zeros((1, 1, 2, 2), np.complex64), meta=np.array(json.dumps(meta)))
    write_render_plan(tmp_path)
    assert json.loads((tmp_path / "plan.json").read_text()) == {"summary": ["refraction: glass_sphere"],
                                                                "warnings": []}
    doc = live_doc(_ctx(), _row(tmp_path, "running"))
    assert doc["plan"]["summary"] == ["refraction: glass_sphere"] and doc["plan"]["source"] == "render"
    (tmp_path / "result.npz").write_bytes(b"not a zip")
    write_render_plan(tmp_path)  # a broken result leaves the plan file as it was, and fails nothing


def test_a_reused_result_has_no_steps_of_its_own(tmp_path):
    doc = live_doc(_ctx(), _row(tmp_path, "succeeded", timings={"reused": True}))
    assert doc["steps"] == [] and doc["step"] is None and doc["left_s"] is None


def test_a_step_whose_log_is_still_empty_shows_its_progress_lines(tmp_path):
    _encoding(tmp_path / "j1", render_end_after_s=50, encode_for_s=10)
    (tmp_path / "j1" / "encode.log").write_text("")  # `holo encode` prints its summary at its end
    with open(tmp_path / "j1" / "progress-encode.jsonl", "a") as fh:
        for i in (10, 20):
            fh.write(json.dumps({"stage": "iterate", "done": i, "total": 300, "t": time.time()}) + "\n")
    log = live_doc(_ctx(), _row(tmp_path / "j1", "running"))["log"]
    assert log == {"step": "encode", "source": "progress", "lines": ["load 1/1", "iterate 10/300", "iterate 20/300"]}
