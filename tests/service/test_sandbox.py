"""Privilege separation against a real `holo serve --sandbox on`, as root: scene planning runs
as the planner uid, a job's driver as its slot uid, neither can read the database, the lock or another job's
files, and what the service records and serves comes from its own hashing (status.json is the worker's word:
a job that lies about its stack's hash fails; a job that swaps an artifact for a symlink to the database gets
it dropped).

The sandbox users must reach the interpreter, the code and the data dir. The data dir is not under pytest's
tmp root: pytest resets /tmp/pytest-of-<user> to 0700 whenever a session starts (any other pytest run on the
machine would lock the sandbox users out mid-job), so the module's files live in a mkdtemp folder of /tmp. The
fixture grants others o+x on the folders in the way (the interpreter's home may be 0700) and restores them after.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import stat
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

from tests.service import helpers
from tests.service.helpers import SMALL_JOB, Server, upload, wait_for, wait_state

pytestmark = [pytest.mark.scenes,
              pytest.mark.skipif(os.geteuid() != 0, reason="privilege separation needs root (the service switches "
                                                            "to unprivileged uids only when it runs as root)")]

BASE = 61000
PLANNER, SLOT0, SLOT1 = BASE, BASE + 1, BASE + 2

# Code "inside the job": imported by every Python process of the server's tree; in the job driver, at exit
# (after it wrote status.json, before the scheduler reads it), it tampers with the job's outputs by seed.
_HOOK = r'''
import atexit, json, os, sys

def _tamper():
    if not sys.argv or not sys.argv[0].endswith(os.path.join("service", "workers", "driver.py")):
        return
    try:
        seed = json.load(open("optics.json")).get("seed")
        if seed == 99:  # lie about the stack's hash
            doc = json.load(open("status.json"))
            doc["stack_sha256"] = "0" * 64
            doc.setdefault("artifacts", {}).setdefault("stack.npz", {})["sha256"] = "0" * 64
            with open("status.json", "w") as fh:
                json.dump(doc, fh)
        elif seed == 98:  # make the preview a link to the database
            os.unlink("preview.png")
            os.symlink(os.path.join(os.path.dirname(os.path.dirname(os.getcwd())), "service.db"), "preview.png")
    except Exception as exc:  # noqa: BLE001
        print("tamper hook:", type(exc).__name__, exc, file=sys.stderr)

atexit.register(_tamper)


def _swap_while_running():
    # in the job driver of seed 97, while it runs: step.json a FIFO for 3 s (a plain open() by the root-side
    # scheduler would block for good), then for 3 s step.json naming the encode step and its progress file a
    # link to a root-only file beside the data dir (read through the link, its text would reach the API)
    import time
    time.sleep(0.3)  # sys.argv names the module only once runpy has found it
    if not sys.argv or not sys.argv[0].endswith(os.path.join("service", "workers", "driver.py")):
        return
    try:
        if json.load(open("optics.json")).get("seed") != 97:
            return
        secret = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.getcwd()))), "secret.jsonl")
        t0 = time.monotonic()
        while time.monotonic() - t0 < 6.0:
            fifo = time.monotonic() - t0 < 3.0
            try:
                if fifo:
                    if os.path.lexists("step.json") and not stat.S_ISFIFO(os.lstat("step.json").st_mode):
                        os.unlink("step.json")
                    if not os.path.lexists("step.json"):
                        os.mkfifo("step.json")
                else:
                    with open("step.json.tmp", "w") as fh:
                        json.dump({"step": "encode", "index": 1}, fh)
                    os.replace("step.json.tmp", "step.json")
                    if not os.path.islink("progress-encode.jsonl"):
                        if os.path.lexists("progress-encode.jsonl"):
                            os.unlink("progress-encode.jsonl")
                        os.symlink(secret, "progress-encode.jsonl")
            except OSError:
                pass
            time.sleep(0.02)
        if os.path.islink("progress-encode.jsonl"):
            os.unlink("progress-encode.jsonl")
    except Exception as exc:  # noqa: BLE001
        print("swap hook:", type(exc).__name__, exc, file=sys.stderr)


import stat, threading
threading.Thread(target=_swap_while_running, daemon=True).start()
'''


def _open_for_others(paths) -> list[tuple[Path, int]]:
    """chmod o+x every folder from / down to each path (folders included) that lacks it; returns what to undo."""
    changed: list[tuple[Path, int]] = []
    for p in paths:
        p = Path(os.path.realpath(p))
        chain = [*reversed(p.parents), p] if p.is_dir() else list(reversed(p.parents))
        for d in chain:
            mode = stat.S_IMODE(os.stat(d).st_mode)
            if not mode & stat.S_IXOTH:
                os.chmod(d, mode | stat.S_IXOTH)
                changed.append((d, mode))
    return changed


def _as(uid: int, code: str) -> subprocess.CompletedProcess:
    """``python -c CODE`` as a sandbox user, with the service's own Popen settings."""
    from service.workers.engine import RunAs

    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/", timeout=60,
                          **RunAs(uid, uid).popen_kwargs())


def _uids_of(pattern: tuple[bytes, ...]) -> set[int]:
    """Real uids of the live processes whose command line holds every byte string of ``pattern``."""
    out = set()
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            cmd = Path(f"/proc/{entry.name}/cmdline").read_bytes()
            status = Path(f"/proc/{entry.name}/status").read_text()
        except OSError:
            continue
        # the job starter runs as root for the moment it takes to make the run's private folders, then drops
        # to the slot uid and executes the driver in place (same pid): it is not the driver
        if all(b in cmd for b in pattern) and b"service.workers.private_tmp" not in cmd:
            out.add(int(next(ln for ln in status.splitlines() if ln.startswith("Uid:")).split()[1]))
    return out


class _Watch:
    """Samples the uids of processes matching ``pattern`` every 20 ms until stopped."""

    def __init__(self, *pattern: bytes) -> None:
        self.pattern, self.seen, self._stop = pattern, set(), threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.seen |= _uids_of(self.pattern)
            time.sleep(0.02)

    def stop(self) -> set[int]:
        self._stop.set()
        self._t.join()
        return self.seen


@pytest.fixture(scope="module")
def sbx():
    root = Path(tempfile.mkdtemp(prefix="holo-sandbox-test-"))
    os.chmod(root, 0o711)
    hook = root / "hookrepo"  # the repository's packages plus the tamper hook, as the server's PYTHONPATH
    hook.mkdir()
    for pkg in ("holo", "holocore", "service", "display_agent"):
        if (helpers.REPO / pkg).exists():
            (hook / pkg).symlink_to(helpers.REPO / pkg)
    (hook / "sitecustomize.py").write_text(_HOOK)
    os.chmod(hook, 0o755)
    undo = _open_for_others([root, sys.executable, sys.prefix, sys.base_prefix, helpers.REPO])
    mp = pytest.MonkeyPatch()
    mp.setattr(helpers, "REPO", hook)
    server = Server(root / "data", workers=2, extra=("--sandbox", str(BASE)))
    plan_watch = _Watch(b"holo", b"plan", str(root / "data").encode())
    try:
        server.start()
        scene_dir = root / "scene"
        from holocore.scene.demo import write_demo_scene

        write_demo_scene(scene_dir)
        with server.client("submit") as c:
            up = upload(c, scene_dir)
            assert up.status_code == 201, up.text
            scene = wait_for(lambda: (lambda s: s if s["plan_state"] in ("ready", "failed") else None)(
                c.get(f"/v1/scenes/{up.json()['id']}").json()), timeout=120, what="the plan")
        yield {"server": server, "scene": scene, "plan_uids": plan_watch.stop(), "root": root}
    finally:
        plan_watch.stop()
        server.stop()
        mp.undo()
        for d, mode in reversed(undo):
            os.chmod(d, mode)
        shutil.rmtree(root, ignore_errors=True)


def _submit(sbx, seed: int) -> dict:
    body = {"scene_id": sbx["scene"]["id"], **SMALL_JOB, "optics": {**SMALL_JOB["optics"], "seed": seed}}
    with sbx["server"].client("submit") as c:
        r = c.post("/v1/jobs", json=body)
        assert r.status_code == 202, r.text
        return r.json()


@pytest.mark.slow
def test_sandbox_on_refuses_to_start_when_not_possible(tmp_path):
    """`--sandbox on` is mandatory: where sandbox users cannot reach the data dir it says what to chmod."""
    data = tmp_path / "closed" / "data"  # tmp_path's ancestors are 0700 (pytest), so not traversable
    data.mkdir(parents=True)
    os.chmod(data.parent, 0o700)
    r = subprocess.run([sys.executable, "-m", "holo", "serve", "--data-dir", str(data), "--port", "0",
                        "--sandbox", "on"], capture_output=True, text=True, timeout=60, cwd=helpers.REPO,
                       env=dict(os.environ, PYTHONPATH=str(helpers.REPO)))
    assert r.returncode != 0
    assert "chmod o+x" in r.stderr and "--sandbox off" in r.stderr, r.stderr


@pytest.mark.slow
def test_plan_runs_as_the_planner_uid(sbx):
    assert sbx["scene"]["plan_state"] == "ready", sbx["scene"]["plan_error"]
    assert sbx["plan_uids"] == {PLANNER}, sbx["plan_uids"]
    assert f"planning as uid {PLANNER}" in sbx["server"].log()
    # the plan's copy is gone (removed just after the plan is stored, once the planner uid's processes are)
    wait_for(lambda: not list((sbx["server"].data_dir / "sandbox").iterdir()), timeout=30, what="the plan's copy removed")


@pytest.mark.slow
def test_job_runs_as_its_slot_uid_and_its_dir_is_taken_back(sbx):
    data = sbx["server"].data_dir
    job = _submit(sbx, 7)
    job_dir = data / "jobs" / job["id"]
    watch = _Watch(b"service.workers.driver", str(job_dir).encode())
    # the later tests' jobs, queued now so that the second worker runs them beside this one
    sbx["queued"] = {seed: _submit(sbx, seed) for seed in (99, 98)}
    seen_dir = wait_for(lambda: (lambda st: st if st and st.st_uid != 0 else None)(
        job_dir.stat() if job_dir.is_dir() else None), timeout=60, interval=0.02, what="the job dir handed over")
    assert (seen_dir.st_uid, seen_dir.st_gid) in ((SLOT0, SLOT0), (SLOT1, SLOT1))
    assert stat.S_IMODE(seen_dir.st_mode) == 0o700
    with sbx["server"].client("reader") as c:
        final = wait_state(c, job["id"], ("succeeded", "failed"), timeout=300)
        assert final["state"] == "succeeded", final["error"]
        stack = c.get(f"/v1/jobs/{job['id']}/stack")
    uids = watch.stop()
    status = json.loads((job_dir / "status.json").read_text())
    assert uids == {seen_dir.st_uid} and status["uid"] == seen_dir.st_uid
    # its own /var/tmp and /dev/shm where the platform allows (this data dir is under /tmp, which stays shared)
    from service.workers.private_tmp import can_make_private

    import httpx

    assert httpx.get(f"{sbx['server'].url}/readyz").json()["sandbox"]["private_tmp"] is can_make_private()
    said = "sandbox: private /var/tmp, /dev/shm and System V IPC" if can_make_private() else \
        "sandbox: shared temporary folders"
    assert said in (job_dir / "driver.log").read_text()
    # taken back: ours, 0700, no scene copy, HOME or TMPDIR left
    st = job_dir.stat()
    assert (st.st_uid, stat.S_IMODE(st.st_mode)) == (0, 0o700)
    assert not any((job_dir / n).exists() for n in ("scene", "home", "tmp"))
    assert all(p.stat().st_uid == 0 for p in job_dir.rglob("*"))
    # the data dir's layout
    modes = {n: stat.S_IMODE((data / n).stat().st_mode) for n in ("", "jobs", "scenes", "sandbox", "service.db",
                                                                  "server.lock")}
    assert modes == {"": 0o711, "jobs": 0o711, "scenes": 0o700, "sandbox": 0o711, "service.db": 0o600,
                     "server.lock": 0o600}
    for side in ("service.db-wal", "service.db-shm"):
        if (data / side).exists():
            assert stat.S_IMODE((data / side).stat().st_mode) == 0o600
    # what is served is what the scheduler hashed
    true_sha = hashlib.sha256((job_dir / "stack.npz").read_bytes()).hexdigest()
    assert stack.status_code == 200 and hashlib.sha256(stack.content).hexdigest() == true_sha
    assert final["stack_sha256"] == true_sha == stack.headers["x-content-sha256"]
    sbx["done_job_dir"] = job_dir


@pytest.mark.slow
def test_sandbox_users_cannot_read_the_database_the_lock_or_jobs(sbx):
    data = sbx["server"].data_dir
    # a finished job taken back by the service (the queued jobs of other tests may still be running as a slot)
    done = sbx.get("done_job_dir") or next(p for p in (data / "jobs").iterdir() if (p / "stack.npz").exists())
    probes = {"db": f"open({str(data / 'service.db')!r}, 'rb').read(16)",
              "lock": f"open({str(data / 'server.lock')!r}, 'rb')",
              "data_dir": f"import os; os.listdir({str(data)!r})",
              "scenes": f"import os; os.listdir({str(data / 'scenes')!r})",
              "jobs": f"import os; os.listdir({str(data / 'jobs')!r})",
              "job": f"open({str(done / 'stack.npz')!r}, 'rb')",
              "job_dir": f"import os; os.listdir({str(done)!r})"}
    for side in ("service.db-wal", "service.db-shm"):
        if (data / side).exists():
            probes[side] = f"open({str(data / side)!r}, 'rb')"
    # the probes run as the slot uids: a run ending meanwhile kills every process of its uid, probes included
    with sbx["server"].client("reader") as c:
        for job in sbx.get("queued", {}).values():
            wait_state(c, job["id"], ("succeeded", "failed"), timeout=300)
    for uid in (PLANNER, SLOT0, SLOT1):
        ok = _as(uid, "import os; print(os.getuid(), os.getgid(), os.getgroups())")
        assert ok.returncode == 0 and ok.stdout.split() == [str(uid), str(uid), "[]"], ok.stderr
        for what, code in probes.items():
            r = _as(uid, code)
            assert r.returncode != 0 and "PermissionError" in r.stderr, (uid, what, r.stdout, r.stderr)


def _job_of_seed(sbx, seed: int) -> dict:
    """The job of ``seed`` queued by the slot-uid test, or a new one when that test did not run."""
    return sbx.get("queued", {}).get(seed) or _submit(sbx, seed)


@pytest.mark.slow
def test_a_job_that_lies_about_its_stack_hash_fails(sbx):
    job = _job_of_seed(sbx, 99)
    with sbx["server"].client("reader") as c:
        final = wait_state(c, job["id"], ("succeeded", "failed"), timeout=300)
        assert final["state"] == "failed" and "integrity check failed" in final["error"], final
        assert final["stack_sha256"] != "0" * 64
        assert c.get(f"/v1/jobs/{job['id']}/stack").status_code == 409


@pytest.mark.slow
def test_an_artifact_swapped_for_a_link_to_the_database_is_dropped(sbx):
    data = sbx["server"].data_dir
    job = _job_of_seed(sbx, 98)
    job_dir = data / "jobs" / job["id"]
    with sbx["server"].client("reader") as c:
        final = wait_state(c, job["id"], ("succeeded", "failed"), timeout=300)
        assert final["state"] == "succeeded", final["error"]
        assert not (job_dir / "preview.png").is_symlink() and not (job_dir / "preview.png").exists()
        prev = c.get(f"/v1/jobs/{job['id']}/preview.png")
        assert prev.status_code == 404 and b"SQLite format 3" not in prev.content, prev.status_code
        for kind in ("stack", "frames.zip"):
            r = c.get(f"/v1/jobs/{job['id']}/{kind}")
            assert r.status_code == 200 and b"SQLite format 3" not in r.content[:64]
    assert "removed from its dir" in sbx["server"].log()


@pytest.mark.slow
def test_a_job_that_swaps_its_files_for_fifos_and_links_leaves_the_scheduler_running(sbx):
    """The scheduler (root) reads a running job's step.json and progress file on every tick: a FIFO there must
    not block it, and a link to a root-only file must not put that file's text into the job's progress."""
    from service.auth import create_token
    from service.db import Database

    server = sbx["server"]
    secret = sbx["root"] / "secret.jsonl"
    secret.write_text(json.dumps({"stage": "ROOT-ONLY-SECRET", "done": 1, "total": 2}) + "\n")
    os.chmod(secret, 0o600)
    hostile = _submit(sbx, 97)
    other = create_token(Database(server.data_dir / "service.db"), scopes=("submit",), owner="bystander")[1]
    stages = set()
    with server.client(other) as b, server.client("reader") as c:
        up = upload(b, sbx["root"] / "scene")  # the same bundle: the scene is the bystander's too
        assert up.status_code in (200, 201), up.text
        body = {"scene_id": up.json()["id"], **SMALL_JOB, "optics": {**SMALL_JOB["optics"], "seed": 96}}
        r = b.post("/v1/jobs", json=body)
        assert r.status_code == 202, r.text
        bystander = r.json()["id"]
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline:
            job = c.get(f"/v1/jobs/{hostile['id']}").json()
            stages.add(str((job.get("progress") or {}).get("stage")))
            if job["state"] in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.05)
        done = wait_state(b, bystander, ("succeeded", "failed", "cancelled"), timeout=240)
        assert done["state"] == "succeeded", done["error"]
        assert c.get("/v1/queue").json()["workers"]["alive"] is True
    assert not any("SECRET" in s for s in stages), stages
    final = wait_state(server.client("reader"), hostile["id"], ("succeeded", "failed", "cancelled"), timeout=240)
    assert final["state"] in ("succeeded", "failed")  # its own run is its business; it ended, the service went on
