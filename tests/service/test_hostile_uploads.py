"""Hostile uploads and jobs, the backstop: kernel resource limits (service/workers/limits.py) on the scene planner
and on every process of a job, for whatever the bundle check and admission miss, and the steps of a job run in
an empty working folder. Each test runs a stand-in for `holo plan` or a job step that does what a scene the
checks let through could make Mitsuba do (fill memory, spin, write a huge file) and checks that it is stopped
and fails for good in one line naming the limit. The bundle-side attacks are in test_hostile_bundles.py."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import pytest

from service.workers.limits import ProcessLimits, job_limits, plan_limits
from tests.service.helpers import REPO

MB = 1 << 20


class FakeDb:
    def __init__(self) -> None:
        self.stored: dict = {}

    def update_scene(self, *a, **kw):
        self.stored.update(kw)

    def list_jobs(self, **kw):
        return []


def planner(tmp_path: Path, code: str, limits: ProcessLimits | None = None, **settings):
    """A Planner whose `holo plan` is ``python -c CODE`` (its limits and the watch as the service sets them)."""
    from service.settings import ServiceSettings
    from service.workers import planner as planner_mod

    s = ServiceSettings(data_dir=tmp_path / "data", **settings)
    (s.scenes_dir / "s1" / "bundle").mkdir(parents=True)
    db = FakeDb()
    p = planner_mod.Planner(s, db)
    p.limits = limits
    p._command = lambda entry: [sys.executable, "-c", code]
    return p, db


_REPORT_LIMITS = """
import json, resource
names = {"memory_bytes": resource.RLIMIT_DATA, "cpu_s": resource.RLIMIT_CPU, "open_files": resource.RLIMIT_NOFILE,
         "file_size_bytes": resource.RLIMIT_FSIZE, "core": resource.RLIMIT_CORE}
print(json.dumps({"summary": [], "rlimits": {k: resource.getrlimit(v)[0] for k, v in names.items()}}))
"""


def test_the_plan_runs_under_the_settings_limits(tmp_path):
    """The planner ran `holo plan` with the server's own (unlimited) rlimits: only a watch of its resident
    memory and wall clock stood behind the bundle check."""
    p, db = planner(tmp_path, _REPORT_LIMITS, worker_memory_mb=16000, plan_timeout_s=120)
    p._plan({"id": "s1", "entry": "scene.xml"})
    assert db.stored["plan_state"] == "ready", db.stored
    want = plan_limits(p.settings, sandboxed=False)
    assert want.memory_bytes == 8000 * 10**6 and want.cpu_s >= 120 and want.file_size_bytes == 1 << 30
    got = db.stored["plan"]["rlimits"]
    soft = {k: resource.getrlimit(v)[0] for k, v in (("open_files", resource.RLIMIT_NOFILE),)}
    assert got == {"memory_bytes": want.memory_bytes, "cpu_s": want.cpu_s, "file_size_bytes": want.file_size_bytes,
                   "open_files": min(want.open_files, soft["open_files"]), "core": 0}, got


@pytest.mark.parametrize("code, limits, words", [
    # memory the resident-memory watch would only see 0.25 s later (or never: allocated, not touched)
    ("x = bytearray(1 << 30); import json; print(json.dumps({'summary': []}))", ProcessLimits(memory_bytes=256 * MB),
     "holo plan needed more than the 268 MB of memory a process may use and was stopped"),
    ("while True: pass", ProcessLimits(cpu_s=1), "holo plan used its 1 s of CPU time"),
    ("f = open('big', 'wb'); f.write(b'x' * (3 << 20)); f.flush()",
     ProcessLimits(file_size_bytes=MB), "holo plan tried to write a file over 1 MB"),
])
def test_a_plan_past_a_kernel_limit_fails_saying_which(tmp_path, code, limits, words):
    p, db = planner(tmp_path, code, limits, plan_timeout_s=30)
    p.max_plan_rss_bytes = 64 << 30  # the watch alone would let each of these through
    p._plan({"id": "s1", "entry": "scene.xml"})  # the limit's words below, not the 30 s timeout's, say who stopped it
    assert db.stored["plan_state"] == "failed", db.stored
    error = db.stored["plan_error"]
    assert words in error and "\n" not in error and "Traceback" not in error, error


def test_the_limits_never_raise_what_an_operator_set_lower(tmp_path):
    code = ("import resource, sys; from service.workers.limits import ProcessLimits; "
            "resource.setrlimit(resource.RLIMIT_CPU, (30, 60)); ProcessLimits(cpu_s=1000).apply(); "
            "print(resource.getrlimit(resource.RLIMIT_CPU))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert out.stdout.strip() == "(30, 60)", out.stderr[-800:]


# ---- jobs -------------------------------------------------------------------------------------------------------
def _driver(tmp_path: Path, step_code: str, limits: dict | None) -> tuple[int, dict, Path]:
    """Run the job driver's ``main`` in a process of its own with a job.json holding ``limits`` and one step,
    ``python -m step`` running ``step_code`` (a stand-in for `holo render`)."""
    mods = tmp_path / "mods"
    mods.mkdir()
    (mods / "step.py").write_text(step_code)
    job = tmp_path / "job"
    job.mkdir()
    (job / "job.json").write_text(json.dumps({"job_id": "j1", "scene_path": "/nonexistent/scene.xml",
                                              "optics": {}, **({"limits": limits} if limits else {})}))
    code = ("import sys; from service.workers import driver\n"
            "def run_job(job_dir):\n"
            "    driver._run('render', [], job_dir, module='step')\n"
            "    raise SystemExit('the step should have been stopped')\n"
            "driver.run_job = run_job\n"
            "sys.exit(driver.main([sys.argv[1]]))\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), str(mods)]))
    proc = subprocess.run([sys.executable, "-c", code, str(job)], capture_output=True, text=True, timeout=120,
                          env=env, cwd=tmp_path)
    status = json.loads((job / "status.json").read_text()) if (job / "status.json").exists() else {}
    return proc.returncode, status, job


@pytest.mark.parametrize("step_code, limits, words", [
    ("x = bytearray(1 << 30)\n", {"memory_bytes": 512 * MB},
     "holo render needed more than the 537 MB of memory a process may use and was stopped"),
    ("while True:\n    pass\n", {"cpu_s": 2}, "holo render used its 2 s of CPU time"),
    ("import sys\nwith open(sys.argv[0] + '.out', 'wb') as f:\n    f.write(b'x' * (8 << 20))\n",
     {"file_size_bytes": 4 * MB}, "holo render tried to write a file over 4 MB"),
])
def test_a_job_step_past_its_limits_fails_for_good_saying_which(tmp_path, step_code, limits, words):
    """The scheduler's limits reach every step through job.json; without them the step fills memory, spins
    until the job's 6 h wall clock, or fills the disk, and a SIGXCPU or SIGKILL was retried."""
    from service.workers.driver import EXIT_FAILED

    rc, status, _ = _driver(tmp_path, step_code, limits)  # the limit's words below say it was the limit
    assert rc == EXIT_FAILED and status.get("ok") is False and status.get("retryable") is False, (rc, status)
    assert words in status["error"] and "\n" not in status["error"], status["error"]
    for key, value in limits.items():
        assert status["limits"][key] == value, status["limits"]


def test_the_scheduler_hands_every_job_the_settings_limits(tmp_path):
    from service.db import Database
    from service.settings import ServiceSettings
    from service.workers.engine import Handle
    from service.workers.scheduler import Scheduler

    launched = {}

    class FakeEngine:
        name = "fake"

        def launch(self, job_id, attempt, job_dir, **kw):
            launched[job_id] = json.loads((job_dir / "job.json").read_text())["limits"]
            return Handle(job_id=job_id, attempt=attempt, job_dir=job_dir, pid=None)

    settings = ServiceSettings(data_dir=tmp_path / "data", worker_memory_mb=6000, job_timeout_s=100)
    settings.data_dir.mkdir(parents=True)
    db = Database(settings.db_path)
    db.insert_scene({"id": "s1", "sha256": "0" * 64, "entry": "scene.xml", "report": {}, "plan_state": "ready",
                     "created_at": time.time()})
    small = {"resolution_hw": [64, 64], "wavelengths_nm": [520.0], "frames": 1}
    big = {"resolution_hw": [2304, 4096], "wavelengths_nm": [640.0, 520.0, 450.0], "frames": 64}
    for jid, optics, extra, border in (("small", small, {}, 0), ("big", big, {}, 0),
                                       ("planes", small, {"wrp_planes": 2}, None)):
        db.insert_job({"id": jid, "state": "running", "scene_id": "s1", "spec": {"optics": optics, **extra},
                       "cache_key": jid, "attempts": 1, "artifact_dir": str(settings.jobs_dir / jid),
                       "created_at": time.time(), "estimate": {"memory": {"plane_border_px": border}}})
        Scheduler(settings, db, FakeEngine())._launch(db.get_job(jid))
    want = job_limits(settings, sandboxed=False).model_dump(exclude_none=True)
    assert want["memory_bytes"] == 6000 * 10**6 and want["cpu_s"] >= 100 and "file_size_bytes" not in want
    assert launched["small"] == {**want, "file_size_bytes": 1 << 30}, launched
    # a render streams its result to the disk: the largest file is the job's folder, not its memory
    assert launched["big"]["file_size_bytes"] > 40e9 > launched["big"]["memory_bytes"], launched
    assert launched["planes"] == want  # deeper planes of a border not known: no size limit of ours
    assert "processes" not in want  # only for a sandbox uid (it would count the server's own processes)
    assert job_limits(settings, sandboxed=True).processes >= 1024
    # a small worker_memory_mb never holds a process below what the interpreter, torch and CUDA need to start
    tiny = ServiceSettings(data_dir=tmp_path / "tiny", worker_memory_mb=500)
    assert job_limits(tiny, sandboxed=False).memory_bytes == 4 << 30
    assert plan_limits(tiny, sandboxed=False).memory_bytes == 4 << 30


def test_job_steps_run_in_an_empty_folder(tmp_path):
    """The steps ran in the job folder; now in an empty one, naming the job's files by absolute path (no
    working directory ever holds anything Mitsuba's resolver could find)."""
    from service.workers import driver

    (tmp_path / "where.py").write_text("import json, os\nprint(json.dumps([os.getcwd(), os.listdir('.')]))\n")
    job = tmp_path / "job"
    job.mkdir()
    (job / "plugins").mkdir()
    (job / "plugins" / "sphere.so").write_text("not a plugin")
    env_before = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = str(tmp_path)
    try:
        driver._run("render", [], job, module="where")
    finally:
        if env_before is None:
            os.environ.pop("PYTHONPATH")
        else:
            os.environ["PYTHONPATH"] = env_before
    cwd, listing = json.loads((job / "render.log").read_text())
    assert listing == [] and Path(cwd) != job and not Path(cwd).exists()
    from service.jobfiles import JobFile

    args = driver.render_args(JobFile(job_id="j", scene_path=str(job / "s.xml"), optics={}), "p", job)
    assert args[args.index("--out") + 1] == str(job / "result.npz")
    assert args[args.index("--optics-json") + 1] == str(job / "optics.json")
    assert args[args.index("--options-json") + 1] == str(job / "options.json")


def test_no_job_starts_before_its_scene_is_planned(tmp_path):
    """A job queued while its scene was being planned started at once: a scene that crashes Mitsuba (or fills
    its memory) did so in the plan and in the job side by side, and the job ran on after the plan failed."""
    from service.db import Database
    from service.settings import ServiceSettings
    from service.workers.engine import Handle
    from service.workers.scheduler import Scheduler

    launched = []

    class FakeEngine:
        name = "fake"

        def launch(self, job_id, attempt, job_dir, **kw):
            launched.append(job_id)
            return Handle(job_id=job_id, attempt=attempt, job_dir=job_dir, pid=None)

        def poll(self, handle):
            return None

    settings = ServiceSettings(data_dir=tmp_path / "data", workers=4)
    settings.data_dir.mkdir(parents=True)
    db = Database(settings.db_path)
    for sid, state in (("splanning", "running"), ("sfailed", "failed"), ("sready", "ready")):
        db.insert_scene({"id": sid, "sha256": sid.ljust(64, "0"), "entry": "scene.xml", "report": {},
                         "plan_state": state, "created_at": time.time(),
                         "plan_error": "holo plan failed (exit -11)" if state == "failed" else None})
    for jid, sid in (("j1", "splanning"), ("j2", "sfailed"), ("j3", "sready")):
        db.insert_job({"id": jid, "state": "queued", "scene_id": sid, "spec": {"optics": {}}, "cache_key": jid,
                       "attempts": 0, "artifact_dir": str(settings.jobs_dir / jid), "created_at": time.time(),
                       "estimate": {"memory": {"peak_bytes": 1000}}})
    sched = Scheduler(settings, db, FakeEngine())
    sched.tick()
    assert launched == ["j3"], launched
    assert db.get_job("j1")["state"] == "queued"  # waits for its plan
    failed = db.get_job("j2")
    assert failed["state"] == "failed" and "the scene's plan failed: holo plan failed (exit -11)" in failed["error"]
    db.update_scene("splanning", plan_state="ready")
    sched.tick()
    assert launched == ["j3", "j1"], launched


# ---- OpenEXR: the data window as OpenEXR reads it ---------------------------------------------------------------
def _exr_with_decoy(n: int) -> bytes:
    """An n x n half-float EXR written by Mitsuba with a 1-pixel ``dataWindow`` put before the real one, its
    line offsets moved to match: OpenEXR reads every attribute and keeps the last of a name."""
    import struct

    import numpy as np

    from holocore.runtime.mitsuba_env import mitsuba

    mi = mitsuba()
    tmp = Path(os.environ.get("TMPDIR", "/tmp")) / f"holo-exr-{os.getpid()}.exr"
    try:
        mi.Bitmap(np.zeros((n, n, 3), dtype=np.float16)).write(str(tmp))
        raw = tmp.read_bytes()
    finally:
        tmp.unlink(missing_ok=True)
    pos = 8
    while raw[pos] != 0:
        end = raw.index(b"\0", pos)
        tend = raw.index(b"\0", end + 1)
        pos = tend + 5 + struct.unpack_from("<i", raw, tend + 1)[0]
    table = pos + 1
    chunks = (struct.unpack_from("<Q", raw, table)[0] - table) // 8
    decoy = b"dataWindow\0box2i\0" + struct.pack("<i", 16) + struct.pack("<4i", 0, 0, 0, 0)
    offsets = b"".join(struct.pack("<Q", struct.unpack_from("<Q", raw, table + 8 * k)[0] + len(decoy))
                       for k in range(chunks))
    return raw[:8] + decoy + raw[8:table] + offsets + raw[table + 8 * chunks:]


def test_exr_decoy_data_window_no_longer_hides_the_real_one(tmp_path):
    """The check took the first ``dataWindow``: a 1-pixel one before the real one counted 1 pixel while Mitsuba
    (OpenEXR) loaded the whole image (here 64 x 64 under a 1000-pixel cap; 9000 x 9000 fits in about a MB)."""
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.scene.bundle import BundleError, BundleLimits, validate_bundle

    root = tmp_path / "b"
    root.mkdir()
    (root / "sky.exr").write_bytes(_exr_with_decoy(64))
    (root / "scene.xml").write_text('<scene version="3.0.0"><emitter type="envmap"><string name="filename" '
                                    'value="sky.exr"/></emitter></scene>')
    assert list(mitsuba().Bitmap(str(root / "sky.exr")).size()) == [64, 64]  # what the attack gets loaded
    with pytest.raises(BundleError, match="defines 'dataWindow' twice") as info:
        validate_bundle(root, limits=BundleLimits(max_image_pixels=1000))
    assert "\n" not in str(info.value)


def test_exr_headers_read_otherwise_are_refused(tmp_path):
    import struct

    from holocore.scene.filekinds import FileKindError, image_pixels

    def pixels(data: bytes) -> int:
        p = tmp_path / "t.exr"
        p.write_bytes(data)
        return image_pixels(p, "t.exr", "exr", max_pixels=1 << 26)

    def attr(name: bytes, kind: bytes, value: bytes) -> bytes:
        return name + b"\0" + kind + b"\0" + struct.pack("<i", len(value)) + value

    magic = b"v/1\x01" + struct.pack("<I", 2)
    window = attr(b"dataWindow", b"box2i", struct.pack("<4i", 0, 0, 99, 49))
    assert pixels(magic + window + b"\0") == 5000
    for data, words in (
        (magic + attr(b"comment", b"string", b"x" * 70000) + window + b"\0", "does not end within its first"),
        (magic + window, "does not end within its first"),
        (magic + attr(b"dataWindow", b"box2f", struct.pack("<4f", 0, 0, 9, 9)) + b"\0", "is not a box2i"),
        (b"v/1\x01" + struct.pack("<I", 2 | 0x1000) + window + b"\0", "multi-part and deep"),
        (b"v/1\x01" + struct.pack("<I", 2 | 0x800) + window + b"\0", "multi-part and deep"),
        (magic + b"x\0int\0" + struct.pack("<i", -5) + window + b"\0", "bad size"),
    ):
        with pytest.raises(FileKindError, match=words):
            pixels(data)


# ---- plugins that crash or hang Mitsuba on load -------------------------------------------------------------------
_LOAD = ("import sys; sys.path.insert(0, sys.argv[1]); from holocore.runtime.mitsuba_env import mitsuba; "
         "mitsuba().load_string(sys.argv[2])")


@pytest.mark.parametrize("body, signal_name, words", [
    ('<shape type="sphere"><bsdf type="blendbsdf"/></shape>', "SIGSEGV", "needs its 'weight' property"),
    ('<sensor type="perspective"><sampler type="multijitter"><integer name="sample_count" value="0"/></sampler>'
     "</sensor>", "SIGFPE", "sample_count '0' must be an integer from 1 to 65536"),
])
def test_plugins_that_crash_mitsuba_are_refused(tmp_path, body, signal_name, words):
    """Both made the plan (and any job on the scene) die on a signal while Mitsuba loaded the scene."""
    import signal

    from holocore.scene.bundle import BundleError, validate_bundle

    xml = f'<scene version="3.0.0">{body}</scene>'
    env = dict(os.environ, HOLO_MI_VARIANT="scalar_rgb")
    proc = subprocess.run([sys.executable, "-c", _LOAD, str(REPO), xml], capture_output=True, timeout=300, env=env)
    assert proc.returncode == -getattr(signal, signal_name), (proc.returncode, proc.stderr[-800:])
    root = tmp_path / "b"
    root.mkdir()
    (root / "scene.xml").write_text(xml)
    with pytest.raises(BundleError, match=words) as info:
        validate_bundle(root)
    assert "\n" not in str(info.value)


def test_sample_counts_that_never_finish_loading_are_refused(tmp_path):
    """stratified, orthogonal and ldsampler with a sample_count near 2**32 spun in their constructor (a plan
    held the one planner until its timeout, every tenant's uploads waiting)."""
    from holocore.scene.bundle import BundleError, validate_bundle

    for i, (sampler, value) in enumerate((("stratified", "4294967295"), ("orthogonal", "4294967295"),
                                          ("ldsampler", "$n"), ("independent", "65537"), ("stratified", "1e3"))):
        root = tmp_path / f"b{i}"
        root.mkdir()
        (root / "scene.xml").write_text(
            f'<scene version="3.0.0"><default name="n" value="4294967295"/><sensor type="perspective">'
            f'<sampler type="{sampler}"><integer name="sample_count" value="{value}"/></sampler></sensor></scene>')
        with pytest.raises(BundleError, match="must be an integer from 1 to 65536"):
            validate_bundle(root)
    ok = tmp_path / "ok"
    ok.mkdir()
    (ok / "scene.xml").write_text('<scene version="3.0.0"><default name="spp" value="64"/><sensor type="perspective">'
                                  '<sampler type="stratified"><integer name="sample_count" value="$spp"/></sampler>'
                                  '</sensor><shape type="sphere"><bsdf type="blendbsdf"><float name="weight" '
                                  'value="0.5"/><bsdf type="diffuse"/><bsdf type="conductor"/></bsdf></shape></scene>')
    validate_bundle(ok)


def test_an_encoding_declared_past_the_first_kilobyte_is_still_seen(tmp_path):
    """The declaration was looked for in the first 1024 bytes: padded past them, ``encoding="koi8-r"`` made
    the check (expat) read a UTF-8 file name as other characters, naming a 4 x 4 image, while Mitsuba read it
    as UTF-8 and loaded a 64 x 64 one past the pixel cap."""
    from PIL import Image

    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.scene.bundle import BundleError, BundleLimits, validate_bundle

    root = tmp_path / "b"
    root.mkdir()
    Image.new("RGB", (4, 4)).save(root / ("\u00e9".encode().decode("koi8_r") + ".png"))  # what expat saw
    Image.new("RGB", (64, 64)).save(root / "\u00e9.png")  # what Mitsuba loads
    decl = b'<?xml version="1.0"' + b" " * 2000 + b' encoding="koi8-r"?>'
    (root / "scene.xml").write_bytes(decl + (
        '<scene version="3.0.0"><shape type="sphere"><bsdf type="diffuse"><texture type="bitmap" '
        'name="reflectance"><string name="filename" value="\u00e9.png"/></texture></bsdf></shape></scene>').encode())
    from holocore.scene.load import _resolver_holding, preload_plugins

    mi = mitsuba()
    preload_plugins()  # as every load does: plugins are never looked up through the scene's folder
    with _resolver_holding(root):
        params = mi.traverse(mi.load_file(str(root / "scene.xml")))
    assert [params[k].shape for k in params.keys() if k.endswith("reflectance.data")] == [(64, 64, 3)]
    with pytest.raises(BundleError, match="declares encoding 'koi8-r'; scene files must be UTF-8"):
        validate_bundle(root, limits=BundleLimits(max_image_pixels=1000))


def test_a_gpu_out_of_memory_is_not_blamed_on_the_memory_limit():
    from service.workers.limits import explain_limit

    limits = ProcessLimits(memory_bytes=8 << 30)
    for tail in ("torch.OutOfMemoryError: CUDA out of memory. Tried to allocate 2.00 GiB",
                 "RuntimeError: jit_malloc(): out of memory on device 0 (cuMemAlloc)"):
        assert explain_limit("holo render", 1, tail, 0.0, limits) is None, tail
    said = explain_limit("holo render", 1, "x\nMemoryError\n", 0.0, limits)
    assert said == "holo render needed more than the 8.6 GB of memory a process may use and was stopped"


# ---- a plan killed from outside; a plan that prints without end ----------------------------------------------------
_KILL_ITSELF = "import os, signal; os.kill(os.getpid(), signal.SIGKILL)"


def test_a_plan_killed_from_outside_goes_back_to_pending(tmp_path):
    """A SIGKILL that no limit of the plan's own explains (the out-of-memory killer choosing it for what others
    hold) stored the scene's plan as failed for good. It goes back to pending, a few times, then fails saying
    it may be planned again."""
    from service.workers import planner as planner_mod

    retries = getattr(planner_mod, "KILLED_RETRIES", 2)
    p, db = planner(tmp_path, _KILL_ITSELF, plan_timeout_s=60)
    for _ in range(retries):
        p._plan({"id": "s1", "entry": "scene.xml"})
        assert db.stored["plan_state"] == "pending" and "plan_error" not in db.stored, db.stored
    p._plan({"id": "s1", "entry": "scene.xml"})
    assert db.stored["plan_state"] == "failed" and planner_mod.killed_from_outside(db.stored["plan_error"]), \
        db.stored
    assert "SIGKILL" in db.stored["plan_error"] and "upload the scene again" in db.stored["plan_error"]


def test_a_scene_whose_plan_was_killed_is_planned_again_on_upload(tmp_path):
    """Re-uploading the bundle answered 200 with the failed plan: content blocked for good by someone else's
    memory. Now it goes back to pending; a plan that failed on its own merits stays failed."""
    from fastapi.testclient import TestClient

    from service.api.app import create_app
    from service.settings import ServiceSettings
    from service.workers import planner as planner_mod
    from tests.service.helpers import make_token, zip_dir

    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "scene.xml").write_text('<scene version="3.0.0"><shape type="sphere"/></scene>')
    app = create_app(ServiceSettings(data_dir=tmp_path / "data"), start_workers=False)
    db = app.state.ctx.db
    tok = make_token(tmp_path / "data", "submit")
    with TestClient(app, headers={"Authorization": f"Bearer {tok}"}) as c:
        def post():
            r = c.post("/v1/scenes", files={"bundle": ("b.zip", zip_dir(tmp_path / "s"), "application/zip")})
            assert r.status_code in (200, 201), r.text
            return r.json()

        sid = post()["id"]
        killed = getattr(planner_mod, "KILLED_ERROR", "holo plan was killed by a signal from outside")
        for error, again in ((f"{killed} (SIGKILL) 3 times", "pending"),
                             ("holo plan failed (exit -11): crashed", "failed")):
            db.update_scene(sid, plan_state="failed", plan_error=error)
            doc = post()
            assert doc["plan_state"] == again and db.get_scene(sid)["plan_state"] == again, (error, doc)
            assert (doc["plan_error"] is None) == (again == "pending")


def test_a_plan_that_prints_without_end_is_stopped(tmp_path):
    """The plan's stdout was read whole into the server's memory: past a few MiB it is refused, and the plan
    stopped, in one line."""
    from service.workers import planner as planner_mod

    cap = getattr(planner_mod, "MAX_PLAN_OUTPUT_BYTES", 4 << 20)
    ended = tmp_path / "plan_reached_its_end"  # written only by a plan left to run its course
    code = f"import sys, time; sys.stdout.write('x' * {cap + (1 << 20)}); sys.stdout.flush(); " \
           f"time.sleep(30); open({str(ended)!r}, 'w').write('end')"
    p, db = planner(tmp_path, code, plan_timeout_s=60)
    p._plan({"id": "s1", "entry": "scene.xml"})
    assert db.stored["plan_state"] == "failed" and "printed more than 4 MiB on its stdout" in db.stored["plan_error"]
    assert not ended.exists(), "stopped at once, not at its end"
