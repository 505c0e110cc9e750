"""Unit tests of the service's parts: upload guards, ranges, scopes, content addresses, limits, the atomic claim,
progress, and the layering rule (the API process imports no Mitsuba, Dr.Jit or torch)."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import threading
import time
import zipfile

import pytest

from holocore.display.optics import OpticsConfig
from service.api.files import Unsatisfiable, parse_range
from service.auth import allows, create_token, revoke_token, verify_token
from service.db import Database
from service.cost import estimate_cost
from service.job_rules import job_limit_errors
from service.models import JobRequest, cache_key
from service.settings import JobLimits, UploadLimits
from service.uploads import (
    UploadError,
    _copy_with_budget,
    bundle_root,
    safe_member_path,
    unpack_zip,
)
from service.workers.driver import preview_focus_mm
from service.workers.runfiles import read_progress
from tests.service.helpers import REPO


@pytest.mark.parametrize("name, ok", [
    ("scene.xml", "scene.xml"), ("./a//b/./c.obj", "a/b/c.obj"), ("a\\b.obj", "a/b.obj"),
    ("../x", None), ("a/../../x", None), ("/etc/passwd", None), ("C:/x", None), ("c:x", None), ("", None),
    ("a\x00b", None), ("a\nb", None), (".", None), ("x" * 2000, None),
])
def test_safe_member_path(name, ok):
    if ok is None:
        with pytest.raises(UploadError):
            safe_member_path(name)
    else:
        assert safe_member_path(name).as_posix() == ok

def test_stream_budget_stops_lying_members_and_totals(tmp_path):
    with pytest.raises(UploadError, match="more bytes than its header declares"):
        _copy_with_budget(io.BytesIO(b"x" * 5000), tmp_path / "a", declared=100, budget=[10**9], what="a")
    with pytest.raises(UploadError, match="more bytes than allowed"):
        _copy_with_budget(io.BytesIO(b"x" * 5000), tmp_path / "b", declared=None, budget=[4000], what="b")
    _copy_with_budget(io.BytesIO(b"x" * 10), tmp_path / "c", declared=10, budget=[10], what="c")
    with pytest.raises(FileExistsError):  # never overwrites
        _copy_with_budget(io.BytesIO(b"y"), tmp_path / "c", declared=None, budget=[10], what="c")
    assert (tmp_path / "c").read_bytes() == b"x" * 10

def test_unpack_zip_and_single_top_folder(tmp_path):
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("wrap/scene.xml", "<scene/>")
        zf.writestr("wrap/meshes/a.obj", "v 0 0 0\n")
        zf.writestr("__MACOSX/wrap/._scene.xml", "junk")
    staging = tmp_path / "s"
    staging.mkdir()
    files = unpack_zip(io.BytesIO(buf.getvalue()), staging, limits=UploadLimits())
    assert sorted(files) == ["__MACOSX/wrap/._scene.xml", "wrap/meshes/a.obj", "wrap/scene.xml"]
    root = bundle_root(staging)
    assert root == staging / "wrap" and (root / "meshes/a.obj").read_text() == "v 0 0 0\n"
    dup = io.BytesIO()
    with zipfile.ZipFile(dup, "w") as zf:
        zf.writestr("a.xml", "1")
        zf.writestr("./a.xml", "2")
    other = tmp_path / "o"
    other.mkdir()
    with pytest.raises(UploadError, match="appears twice"):
        unpack_zip(io.BytesIO(dup.getvalue()), other, limits=UploadLimits())

@pytest.mark.parametrize("header, size, expect", [
    ("bytes=0-9", 100, (0, 9)), ("bytes=90-", 100, (90, 99)), ("bytes=-10", 100, (90, 99)),
    ("bytes=50-1000", 100, (50, 99)), ("bytes=-1000", 100, (0, 99)), ("bytes=9-1", 100, None),
    ("bytes=0-1,5-6", 100, None), ("items=0-1", 100, None), ("bytes=-", 100, None),
    ("bytes=100-", 100, "416"), ("bytes=-0", 100, "416"), ("bytes=0-", 0, "416"),
])
def test_parse_range(header, size, expect):
    if expect == "416":
        with pytest.raises(Unsatisfiable):
            parse_range(header, size)
    else:
        assert parse_range(header, size) == expect

def test_scopes_and_tokens(tmp_path):
    assert allows({"admin"}, "submit") and allows({"admin"}, "agent")
    assert allows({"submit"}, "read") and not allows({"submit"}, "agent") and not allows({"submit"}, "admin")
    assert allows({"agent"}, "read") and allows({"agent"}, "agent") and not allows({"agent"}, "submit")
    assert not allows({"read"}, "submit") and not allows(set(), "read")
    db = Database(tmp_path / "db.sqlite")
    tid, tok = create_token(db, scopes=["agent", "read"], name="lab")
    p = verify_token(db, tok)
    assert p is not None and p.scopes == {"agent", "read"} and p.token_id == tid
    stored = db.one("SELECT hash FROM tokens WHERE id = ?", (tid,))["hash"]
    assert tok not in stored and len(stored) == 64  # only the sha256 is kept
    assert verify_token(db, tok + "x") is None and verify_token(db, None) is None
    assert revoke_token(db, tid) and verify_token(db, tok) is None
    with pytest.raises(ValueError, match="unknown"):
        create_token(db, scopes=["root"])
    with pytest.raises(ValueError, match="at least one"):
        create_token(db, scopes=[])

def test_cache_key_names_what_changes_the_result():
    base = JobRequest(scene_id="s1", optics=OpticsConfig(resolution_hw=(64, 64)), preset="fast", spp=4)
    k = cache_key(base, scene_sha256="a" * 64, entry="s.xml", code_version="1")
    assert cache_key(base.model_copy(update={"display": "other"}), scene_sha256="a" * 64, entry="s.xml",
                     code_version="1") == k
    frames_in_optics = base.model_copy(update={"optics": base.optics.model_copy(update={"frames": 3})})
    assert cache_key(base.model_copy(update={"frames": 3}), scene_sha256="a" * 64, entry="s.xml",
                     code_version="1") == cache_key(frames_in_optics, scene_sha256="a" * 64, entry="s.xml",
                                                    code_version="1")
    changed = [
        cache_key(base, scene_sha256="b" * 64, entry="s.xml", code_version="1"),
        cache_key(base, scene_sha256="a" * 64, entry="t.xml", code_version="1"),
        cache_key(base, scene_sha256="a" * 64, entry="s.xml", code_version="2"),
        cache_key(base.model_copy(update={"spp": 5}), scene_sha256="a" * 64, entry="s.xml", code_version="1"),
        cache_key(base.model_copy(update={"encoder": "dpac"}), scene_sha256="a" * 64, entry="s.xml", code_version="1"),
        cache_key(base.model_copy(update={"render_time_limit_s": 30.0}), scene_sha256="a" * 64, entry="s.xml",
                  code_version="1"),
        cache_key(base.model_copy(update={"optics": base.optics.model_copy(update={"seed": 1})}),
                  scene_sha256="a" * 64, entry="s.xml", code_version="1"),
    ]
    assert len(set(changed)) == len(changed) and k not in changed

def test_limits_and_estimate():
    lim = JobLimits(max_side_px=512, max_frames=4, max_spp=64, max_ray_budget=1e7)
    ok = JobRequest(scene_id="s", optics=OpticsConfig(resolution_hw=(256, 256)), spp=16, frames=4)
    assert job_limit_errors(ok, lim) == []
    big = ok.model_copy(update={"optics": OpticsConfig(resolution_hw=(1024, 256)), "frames": 5, "spp": 128})
    errs = " ".join(job_limit_errors(big, lim))
    assert "at most 512 px" in errs and "frames" in errs and "spp" in errs and "rays" in errs
    e1, e2 = estimate_cost(ok), estimate_cost(ok.model_copy(update={"spp": 64}))
    assert e2["rays"] == 4 * e1["rays"] == 256 * 256 * 3 * 64 and e2["seconds"] > e1["seconds"] > 0
    sgd = estimate_cost(ok.model_copy(update={"encoder": "sgd", "iterations": 1000}))
    dpac = estimate_cost(ok.model_copy(update={"encoder": "dpac"}))
    assert sgd["seconds"] > dpac["seconds"]


def test_a_time_limited_job():
    # The render takes its limit, rays up to the cap (the job's spp, else the service's max_spp); the cap counts
    # against the ray budget; the driver hands both to `holo render` in the job's options document.
    from service.jobfiles import JobFile
    from service.api.submission import job_spec

    lim = JobLimits(max_spp=64, max_ray_budget=1e7, max_render_time_s=600)
    timed = JobRequest(scene_id="s", optics=OpticsConfig(resolution_hw=(128, 128)), frames=4, encoder="dpac",
                       render_time_limit_s=30.0)
    assert job_limit_errors(timed, lim) == []  # 128 * 128 * 3 * 64 rays at most
    spec = job_spec(timed, lim)
    assert spec.spp == 64 and spec.render_time_limit_s == 30.0
    assert job_spec(timed.model_copy(update={"spp": 8}), lim).spp == 8
    doc = JobFile(**spec.model_dump(), job_id="j1", scene_path="scene.xml").hologram_options()
    assert doc.render_time_limit_s == 30.0 and doc.spp == 64
    assert JobFile(job_id="j", scene_path="s.xml", optics={}).hologram_options().render_time_limit_s is None
    e = estimate_cost(timed)
    assert e["spp_assumed"] is None and e["rays"] is None
    assert 30.0 < e["seconds"] < estimate_cost(timed.model_copy(update={"render_time_limit_s": 90.0}))["seconds"]
    wide = timed.model_copy(update={"optics": OpticsConfig(resolution_hw=(512, 512))})
    assert "give a smaller spp" in " ".join(job_limit_errors(wide, lim))
    assert "render_time_limit_s" in " ".join(job_limit_errors(timed.model_copy(update={"render_time_limit_s": 700.0}),
                                                              lim))
    for bad in (0, -1, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            JobRequest(scene_id="s", render_time_limit_s=bad)

def test_claim_is_atomic_across_threads(tmp_path):
    db = Database(tmp_path / "db.sqlite")
    now = time.time()
    for i in range(60):
        db.insert_job({"id": f"j{i:03d}", "state": "queued", "scene_id": "s", "spec": {}, "cache_key": "k",
                       "created_at": now + i})
    claimed: list[str] = []
    lock = threading.Lock()

    def worker():
        while (row := db.claim_next_job()) is not None:
            with lock:
                claimed.append(row["id"])

    threads = [threading.Thread(target=worker) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(claimed) == [f"j{i:03d}" for i in range(60)]  # each exactly once
    assert db.count_jobs()["running"] == 60 and db.claim_next_job() is None
    assert all(r["attempts"] == 1 for r in db.query("SELECT attempts FROM jobs"))
    assert db.update_job("j000", where_state=("queued",), state="cancelled") is False  # not queued any more
    assert db.update_job("j000", where_state=("running",), state="cancelled") is True

def test_progress_from_run_files(tmp_path):
    assert read_progress(tmp_path) is None
    (tmp_path / "step.json").write_text(json.dumps({"step": "render"}))
    assert read_progress(tmp_path)["fraction"] == 0.0
    (tmp_path / "progress-render.jsonl").write_text(
        '{"stage": "analysis", "done": 1, "total": 1}\n{"stage": "trace", "done": 1, "total": 2}\nnot json\n')
    p = read_progress(tmp_path)
    assert p["stage"] == "trace" and 0.75 * 0.1 < p["fraction"] < 0.75 * 0.9
    (tmp_path / "step.json").write_text(json.dumps({"step": "encode"}))
    (tmp_path / "progress-encode.jsonl").write_text('{"stage": "encode", "done": 50, "total": 100}\n')
    assert read_progress(tmp_path)["fraction"] == pytest.approx(0.75 + 0.15 * 0.5)
    # with the estimate's seconds per step (an encode at 80 mm takes as long as the render), those weigh the run,
    # so that its fraction grows with the time spent and the page's pace gives the time left
    (tmp_path / "job.json").write_text(json.dumps(
        {"step_seconds": {"render": 40.0, "encode": 40.0, "package": 0.0, "preview": 20.0}}))
    assert read_progress(tmp_path)["fraction"] == pytest.approx(0.4 + 0.4 * 0.5)
    for bad in ({"render": 40.0}, {"render": float("inf"), "encode": 1, "package": 0, "preview": 1}, [1, 2]):
        (tmp_path / "job.json").write_text(json.dumps({"step_seconds": bad}))  # not every step: the fixed shares
        assert read_progress(tmp_path)["fraction"] == pytest.approx(0.75 + 0.15 * 0.5)


def test_the_estimate_gives_each_step_its_seconds():
    req = JobRequest(scene_id="s" * 12, optics={"resolution_hw": [135, 240]}, frames=8, spp=16)
    e = estimate_cost(req)
    assert set(e["steps_s"]) == {"render", "encode", "package", "preview"}
    assert sum(e["steps_s"].values()) == pytest.approx(e["seconds"], abs=0.1)
    assert e["steps_s"]["encode"] > e["encode_s"] > 0  # the encode step starts a process first
    # virtual infinity at 4 mm: a 135 x 240 SLM lights the evaluation's views (at the default 80 mm it has none)
    near = req.model_copy(update={"evaluate": True, "optics": req.optics.model_copy(update={"z_inf_mm": 4})})
    evaluated = estimate_cost(near)
    assert evaluated["steps_s"]["evaluate"] == pytest.approx(evaluated["evaluate_s"], abs=0.05) and evaluated["evaluate_s"] > 0

def test_preview_focus_is_mid_volume():
    meta = {"z_inf_m": 0.08, "analysis": {"z_near_holo_m": 0.084, "z_far_holo_m": 0.080}}
    assert preview_focus_mm(meta) == pytest.approx(82.0)
    assert preview_focus_mm({"z_inf_m": 0.08}) == pytest.approx(80.0)

def test_api_process_imports_no_heavy_modules(tmp_path):
    code = ("import sys, pathlib; from service.settings import ServiceSettings; from service.api.app import create_app; "
            f"app = create_app(ServiceSettings(data_dir=pathlib.Path({str(tmp_path)!r})), start_workers=False); "
            "import holo.app; "
            "print([m for m in ('torch', 'mitsuba', 'drjit', 'numpy', 'scipy') if m in sys.modules])")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"

@pytest.mark.slow
def test_serve_and_token_cli_errors(tmp_path):
    r = subprocess.run([sys.executable, "-m", "holo", "token", "create", "--data-dir", str(tmp_path),
                        "--scope", "root"], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert r.returncode == 2 and "unknown ['root']" in r.stderr
    r = subprocess.run([sys.executable, "-m", "holo", "serve", "--data-dir", str(tmp_path), "--workers", "0"],
                       capture_output=True, text=True, cwd=REPO, timeout=60)
    assert r.returncode == 2 and "workers" in r.stderr
    env = {k: v for k, v in os.environ.items() if k != "HOLO_DATA_DIR"}
    r = subprocess.run([sys.executable, "-m", "holo", "serve"], capture_output=True, text=True, cwd=REPO, timeout=60,
                       env=env)
    assert r.returncode == 2 and "--data-dir DIR or HOLO_DATA_DIR" in r.stderr
    r = subprocess.run([sys.executable, "-m", "holo", "serve", "--workers", "0"], capture_output=True, text=True,
                       cwd=REPO, timeout=60, env={**env, "HOLO_DATA_DIR": str(tmp_path)})
    assert r.returncode == 2 and "workers" in r.stderr  # got past the data dir: HOLO_DATA_DIR was read
    ok = subprocess.run([sys.executable, "-m", "holo", "token", "create", "--data-dir", str(tmp_path), "--scope",
                         "agent", "--scope", "read", "--name", "lab"], capture_output=True, text=True, cwd=REPO,
                        timeout=60)
    assert ok.returncode == 0 and ok.stdout.startswith("hpt_")
    listed = subprocess.run([sys.executable, "-m", "holo", "token", "list", "--data-dir", str(tmp_path)],
                            capture_output=True, text=True, cwd=REPO, timeout=60).stdout
    assert "agent,read" in listed and "lab" in listed and ok.stdout.strip() not in listed

@pytest.mark.slow
def test_second_server_on_the_same_data_dir_is_refused(server_factory):
    first = server_factory("busy").start()
    r = subprocess.run([sys.executable, "-m", "holo", "serve", "--data-dir", str(first.data_dir), "--port", "0"],
                       capture_output=True, text=True, cwd=REPO, timeout=60)
    assert r.returncode != 0 and "another holo serve uses" in r.stderr



def test_jobs_run_together_only_while_their_memory_estimates_fit(tmp_path):
    from service.settings import ServiceSettings
    from service.workers.engine import Handle
    from service.workers.scheduler import Scheduler

    settings = ServiceSettings(data_dir=tmp_path, workers=3, worker_memory_mb=1000, sandbox="off")
    db = Database(settings.db_path)
    now = time.time()
    for i, mb in enumerate((600, 300, 500, 900)):
        db.insert_job({"id": f"j{i}", "state": "queued", "scene_id": "s", "spec": {}, "cache_key": "k",
                       "created_at": now + i, "estimate": {"memory": {"peak_bytes": int(mb * 1e6)}}})
    sched = Scheduler(settings, db, engine=None)
    launched: list[str] = []

    def fake_launch(row):
        launched.append(row["id"])
        sched.running[row["id"]] = Handle(job_id=row["id"], attempt=1, job_dir=tmp_path)

    sched._launch = fake_launch  # noqa: SLF001 - the claim order is what this test watches
    sched._watch = lambda job_id, h: None  # noqa: SLF001
    sched.tick()
    assert launched == ["j0", "j1"]  # 600 + 300 MB fit in 1000; + 500 would not: j2 waits (in order)
    del sched.running["j0"]
    sched.tick()
    assert launched == ["j0", "j1", "j2"]  # 300 + 500
    del sched.running["j1"], sched.running["j2"]
    sched.tick()
    assert launched[-1] == "j3"  # alone, 900 MB

def test_render_stages_are_the_ones_holo_render_reports():
    """The scheduler splits the render step by the stages `holo render` emits (it once expected "bank" and
    "cache", which nothing emits)."""
    import re
    from typing import get_args

    from service.jobfiles import RenderStage
    from service.workers.runfiles import RENDER_STAGE_END

    assert tuple(RENDER_STAGE_END) == get_args(RenderStage)
    emitters = ("pipeline.py", "render_setup.py", "render_passes.py", "trace/hologram_rays.py")
    src = "".join((REPO / "holocore" / f).read_text() for f in emitters)
    emitted = set(re.findall(r'progress\("([a-z-]+)"', src))
    assert emitted == set(get_args(RenderStage)), emitted

def test_job_files_of_earlier_versions_still_read(tmp_path):
    from service.jobfiles import JobSpec, read_job_file, read_run_status

    old_spec = {"optics": {"frames": 2}, "preset": "fast", "frames": None, "spp": None, "encoder": "sgd",
                "iterations": None, "method": "wrp"}  # before wrp_planes
    assert JobSpec.model_validate(old_spec).wrp_planes == 1
    (tmp_path / "job.json").write_text(json.dumps({**{k: v for k, v in old_spec.items() if k != "optics"},
                                                   "job_id": "j1", "scene_path": "/s/scene.xml",
                                                   "keep_result": True}))  # before attempts were recorded
    job = read_job_file(tmp_path)
    assert (job.job_id, job.attempt, job.wrp_planes, job.preset) == ("j1", None, 1, "fast")
    (tmp_path / "status.json").write_text(json.dumps({"ok": True, "stack_sha256": "a" * 64, "stack_bytes": 10,
                                                      "timings": {"render_s": 1.5, "peak_rss_bytes": 7},
                                                      "plan": {"summary": []}, "total_s": 2.0, "attempt": 1}))
    st = read_run_status(tmp_path, 1)
    assert st.ok and st.warnings == [] and st.timings["peak_rss_bytes"] == 7
    assert read_run_status(tmp_path, 2) is None  # a stale run's status
    (tmp_path / "status.json").write_text("[1, 2]")
    assert read_run_status(tmp_path, 1) is None
