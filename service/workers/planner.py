"""Effect plans of uploaded scenes: a thread that runs ``holo plan SCENE --json`` in a subprocess (its own
process group, with a timeout) for each scene whose plan is pending, and stores the JSON or the error.

With the sandbox on (service/workers/engine.py) the plan runs as the planner uid (``sandbox_uid_base``) on a
copy of the bundle in ``data_dir/sandbox/plan-<scene>/`` that it owns (its HOME and TMPDIR too); the copy is
deleted afterwards, and so is anything the planner uid left running. Either way the plan runs in an empty
working directory of its own, never the bundle's folder: Mitsuba's default file resolver starts with the working
directory, and plugins are looked up through it as ``plugins/<name>.so``.

The plan runs under kernel resource limits (service/workers/limits.py: memory, CPU time, open files, file
size, and processes for the planner uid) and, besides, under a watch of its resident memory, its wall clock and
how much it prints (``MAX_PLAN_OUTPUT_BYTES`` on each of stdout and stderr: the plan's JSON is small, and the
whole output was read into the server's memory); a plan stopped by any of them fails saying which.

A plan killed by SIGKILL or SIGTERM that no limit of its own explains was most likely stopped from outside (the
kernel's out-of-memory killer choosing it for what others hold, an operator): it goes back to pending and is
planned again, up to ``KILLED_RETRIES`` times in a server's life; after that it fails saying so
(``KILLED_ERROR``), and uploading the same bundle again plans it afresh (service/api/scenes.py), so content is
never blocked for good by someone else's memory."""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Optional

from holocore.scene.errors import scrub_message
from service.db import Database
from service.settings import ServiceSettings
from service.workers.engine import (
    RunAs,
    driver_env,
    give_tree,
    kill_group,
    kill_uids,
    resolve_sandbox,
    sandbox_env,
)
from service.workers.limits import ProcessLimits, explain_limit, plan_limits, wrap_command

__all__ = ["Planner", "keep_picture", "PICTURE_NAME", "MAX_PLAN_OUTPUT_BYTES", "KILLED_ERROR", "KILLED_RETRIES",
           "killed_from_outside"]

log = logging.getLogger("holo.service.planner")

_WATCH_S = 0.25  # how often a running plan's resident memory is looked at
# The scene's picture through its camera (`holo plan --picture`): small and cheap, a second or two of CPU.
PICTURE_NAME = "picture.png"
PICTURE_WIDTH_PX = 320
PICTURE_SPP = 32
_PICTURE_MAX_BYTES = 4 << 20
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
MAX_PLAN_OUTPUT_BYTES = 4 << 20  # of each of stdout and stderr; a plan's JSON is tens of kB
_EXTERNAL_SIGNALS = (signal.SIGKILL, signal.SIGTERM)  # what another process or the kernel sends; a crash is not
KILLED_RETRIES = 2
KILLED_ERROR = "holo plan was killed by a signal from outside"  # how a stored failure says it may be re-planned


def killed_from_outside(plan_error: object) -> bool:
    """Whether a failed plan's stored error says its process was killed from outside (worth planning again)."""
    return isinstance(plan_error, str) and plan_error.startswith(KILLED_ERROR)


class _Capped:
    """Reads a pipe to its end on a thread of its own, keeping at most ``cap`` bytes; ``over`` is set (and the
    reading stops) once the process has printed more."""

    def __init__(self, pipe, cap: int) -> None:
        self.pipe, self.cap, self.data = pipe, cap, bytearray()
        self.over = threading.Event()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        read = getattr(self.pipe, "read1", self.pipe.read)
        try:
            while True:
                chunk = read(1 << 16)
                if not chunk:
                    return
                if len(self.data) + len(chunk) > self.cap:
                    self.over.set()
                    return
                self.data += chunk
        except (OSError, ValueError):  # closed under it
            return

    def result(self) -> bytes:
        self.thread.join(timeout=5)
        return bytes(self.data)


def keep_picture(made: Path, scene_dir: Path, said: object) -> dict:
    """Move the picture the plan made (``made``, in the plan's working folder) to ``scene_dir/picture.png``;
    what the stored plan says of it: its size and SHA-256, or ``error``. The plan's folder is the planner
    uid's, so the file is opened without following links and must be a plain PNG of bounded size whose
    header gives the size the plan said."""
    import hashlib
    import stat as st_mod

    said = said if isinstance(said, dict) else {}
    if isinstance(said.get("error"), str):
        return {"error": said["error"][:400]}
    try:
        fd = os.open(made, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return {"error": "no picture: holo plan wrote none"}
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        data = fh.read(_PICTURE_MAX_BYTES + 1) if st_mod.S_ISREG(st.st_mode) else b""
    if not data.startswith(_PNG_MAGIC) or len(data) > _PICTURE_MAX_BYTES or data[12:16] != b"IHDR":
        return {"error": "no picture: holo plan's picture is not a PNG of at most 4 MiB"}
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if (w, h) != (said.get("width_px"), said.get("height_px")):
        return {"error": "no picture: holo plan's picture is not the size it said"}
    tmp = scene_dir / f".{PICTURE_NAME}.tmp"
    tmp.write_bytes(data)
    os.replace(tmp, scene_dir / PICTURE_NAME)
    q = said.get("image_q")  # the picture's image statistic, for the quality estimate: a number in [0, 1] or none
    q = float(q) if isinstance(q, (int, float)) and not isinstance(q, bool) and 0.0 <= q <= 1.0 else None
    return {"width_px": w, "height_px": h, "spp": said.get("spp"), "bytes": len(data),
            "sha256": hashlib.sha256(data).hexdigest(), "image_q": q}


def _cpu_seconds(pid: int) -> float:
    """CPU time (user + system) process ``pid`` has used so far (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            rest = fh.read().rsplit(b")", 1)[1].split()
        return (int(rest[11]) + int(rest[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return 0.0


def _rss_bytes(pid: int) -> int:
    """Resident memory of process ``pid`` (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/status", "rb") as fh:
            for line in fh:
                if line.startswith(b"VmRSS:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


class Planner:
    def __init__(self, settings: ServiceSettings, db: Database) -> None:
        self.settings = settings
        self.db = db
        # The backstop for what the bundle check misses: a plan holding more than half of what the workers may
        # hold is killed (resident memory, watched; an address-space rlimit would also break CUDA, which
        # reserves far more than it uses).
        self.max_plan_rss_bytes = settings.worker_memory_bytes // 2
        # the kernel's limits on the plan process (None: plan_limits of the settings, for the sandbox or not)
        self.limits: Optional[ProcessLimits] = None
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._proc: Optional[subprocess.Popen] = None
        self._thread: Optional[threading.Thread] = None
        self.run_as: Optional[RunAs] = None
        self._killed: dict[str, int] = {}  # scene id -> plans of it killed from outside in this server's life

    def start(self) -> None:
        base = resolve_sandbox(self.settings)
        if base is not None:
            self.run_as = RunAs(base, base)
            kill_uids({base})  # what a previous server's plan left running
            self.settings.sandbox_dir.mkdir(parents=True, exist_ok=True)
            os.chmod(self.settings.sandbox_dir, 0o711)
            for old in self.settings.sandbox_dir.glob("plan-*"):
                shutil.rmtree(old, ignore_errors=True)
        self._thread = threading.Thread(target=self._loop, name="holo-planner", daemon=True)
        self._thread.start()

    def wake(self) -> None:
        self._wake.set()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        proc = self._proc
        if proc is not None and proc.poll() is None:
            kill_group(proc.pid, grace_s=0.5, proc=proc)
        if self.run_as is not None:
            kill_uids({self.run_as.uid})
        if self._thread is not None:
            self._thread.join(timeout=10)

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                scene = self.db.claim_next_plan()
                if scene is not None:
                    self._plan(scene)
                    continue
            except Exception:  # noqa: BLE001
                log.exception("planner failed")
            self._wake.wait(1.0)
            self._wake.clear()

    def _plan(self, scene: dict) -> None:
        if self.run_as is None:
            with tempfile.TemporaryDirectory(prefix="holo-plan-") as cwd:
                self._run_plan(scene, self.settings.scenes_dir / scene["id"] / "bundle", None, Path(cwd))
            return
        work = self.settings.sandbox_dir / f"plan-{scene['id']}"
        try:
            shutil.rmtree(work, ignore_errors=True)
            work.mkdir(mode=0o700)
            shutil.copytree(self.settings.scenes_dir / scene["id"] / "bundle", work / "bundle", symlinks=True)
            for sub in ("home", "tmp", "cwd"):
                (work / sub).mkdir()
            give_tree(work, self.run_as)
            self._run_plan(scene, work / "bundle", work, work / "cwd")
        finally:
            kill_uids({self.run_as.uid})
            shutil.rmtree(work, ignore_errors=True)

    def _command(self, entry: Path) -> list[str]:
        # the picture goes into the plan's own empty working folder (relative: the one place it may write)
        # --probe: a short render timing what a ray of this scene costs, for the jobs' estimates
        return [sys.executable, "-m", "holo", "plan", str(entry), "--json", "--probe", "--picture", PICTURE_NAME,
                "--picture-width", str(PICTURE_WIDTH_PX), "--picture-spp", str(PICTURE_SPP)]

    def _run_plan(self, scene: dict, bundle, work, cwd: Path) -> None:
        """``holo plan`` on ``bundle``, run in the empty folder ``cwd``; sandboxed (as ``self.run_as``, in
        ``work``) when ``work`` is given. Killed past ``plan_timeout_s`` or ``max_plan_rss_bytes``."""
        import time

        limits = self.limits or plan_limits(self.settings, sandboxed=work is not None)
        cmd = wrap_command(limits, self._command(bundle / scene["entry"]))
        cpu_used = 0.0
        extra = {} if work is None else self.run_as.popen_kwargs()
        if work is not None:
            log.info("scene %s: planning as uid %d", scene["id"], self.run_as.uid)
        try:
            self._proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                          stdin=subprocess.DEVNULL, cwd=cwd,
                                          env=driver_env() if work is None else sandbox_env(work),
                                          start_new_session=True, **extra)
            deadline = time.monotonic() + self.settings.plan_timeout_s
            pipes = {"stdout": _Capped(self._proc.stdout, MAX_PLAN_OUTPUT_BYTES),
                     "stderr": _Capped(self._proc.stderr, MAX_PLAN_OUTPUT_BYTES)}
            while True:
                try:
                    self._proc.wait(timeout=_WATCH_S)
                except subprocess.TimeoutExpired:
                    pass
                over = next((name for name, p in pipes.items() if p.over.is_set()), None)
                if over is not None:
                    kill_group(self._proc.pid, grace_s=0.5, proc=self._proc)
                    self._store(scene["id"], None, f"holo plan printed more than {MAX_PLAN_OUTPUT_BYTES >> 20} MiB "
                                                   f"on its {over} and was stopped")
                    return
                if self._proc.returncode is not None:
                    out, err = pipes["stdout"].result(), pipes["stderr"].result()
                    if any(p.over.is_set() for p in pipes.values()):
                        continue  # the last of it came with the exit: refused above
                    break
                cpu_used = max(cpu_used, _cpu_seconds(self._proc.pid))
                rss = _rss_bytes(self._proc.pid)
                if rss > self.max_plan_rss_bytes:
                    kill_group(self._proc.pid, grace_s=0.5, proc=self._proc)
                    self._store(scene["id"], None, f"holo plan used more than {self.max_plan_rss_bytes / 1e9:.1f} "
                                                   "GB of memory and was stopped; make the scene smaller")
                    return
                if time.monotonic() > deadline:
                    kill_group(self._proc.pid, grace_s=0.5, proc=self._proc)
                    self._store(scene["id"], None,
                                f"holo plan timed out after {self.settings.plan_timeout_s:.0f} s")
                    return
            rc = self._proc.returncode
        finally:
            self._proc = None
        if self._stop.is_set():
            return  # stopped mid-plan: the scene stays 'running' and is planned again on the next start
        if rc != 0:
            text = err.decode(errors="replace")
            stopped = explain_limit("holo plan", rc, text[-4000:], cpu_used, limits)
            if stopped is not None:
                self._store(scene["id"], None, f"{stopped}; make the scene smaller")
                return
            if rc < 0 and -rc in _EXTERNAL_SIGNALS:
                self._killed_from_outside(scene["id"], signal.Signals(-rc).name)
                return
            lines = [ln for ln in text.strip().splitlines() if ln.strip()]
            msg = next((ln for ln in reversed(lines) if ln.startswith("error:")), lines[-1] if lines else "")
            if work is not None:  # the copy's path is nobody's business; say the bundle's
                msg = msg.replace(str(bundle), str(self.settings.scenes_dir / scene["id"] / "bundle"))
            self._store(scene["id"], None, f"holo plan failed (exit {rc}): {msg.removeprefix('error: ')[:500]}")
            return
        try:
            doc = json.loads(out)
        except ValueError:
            self._store(scene["id"], None, "holo plan printed no JSON")
            return
        if isinstance(doc, dict):
            doc["picture"] = keep_picture(cwd / PICTURE_NAME, self.settings.scenes_dir / scene["id"],
                                          doc.get("picture"))
        self._store(scene["id"], doc, None)

    def _killed_from_outside(self, scene_id: str, name: str) -> None:
        """Back to pending, to be planned again (KILLED_RETRIES times; then a failure saying so)."""
        import time

        n = self._killed[scene_id] = self._killed.get(scene_id, 0) + 1
        if n <= KILLED_RETRIES:
            log.warning("scene %s: holo plan was killed by %s (not by a limit of its own): planned again",
                        scene_id, name)
            self.db.update_scene(scene_id, where_plan_state="running", plan_state="pending",
                                 plan_updated_at=time.time())
            return
        del self._killed[scene_id]
        self._store(scene_id, None, f"{KILLED_ERROR} ({name}) {n} times, none a limit of its own (most likely the "
                                    "machine ran short of memory); upload the scene again to plan it again")

    def _store(self, scene_id: str, plan: Optional[dict], error: Optional[str]) -> None:
        import time

        self._killed.pop(scene_id, None)
        if error is not None:  # bundle-relative paths only; no server path reaches the user or the database
            error = scrub_message(error, roots=[self.settings.scenes_dir / scene_id / "bundle",
                                                self.settings.sandbox_dir / f"plan-{scene_id}" / "bundle",
                                                self.settings.data_dir])
        self.db.update_scene(scene_id, where_plan_state="running", plan_state="ready" if plan else "failed",
                             plan=plan, plan_error=error, plan_updated_at=time.time())
        log.info("scene %s: plan %s", scene_id, "ready" if plan else f"failed: {error}")
        if plan is None:
            self._fail_queued_jobs(scene_id, error)

    def _fail_queued_jobs(self, scene_id: str, error: Optional[str]) -> None:
        """Jobs queued on a scene before its plan failed never start: Mitsuba failed (or crashed) loading the
        scene, and a job would load it again. New jobs on it are refused at submit."""
        import time

        while True:
            queued = self.db.list_jobs(state="queued", scene_id=scene_id, limit=100)
            failed = [j for j in queued if self.db.update_job(
                j["id"], where_state=("queued",), state="failed", finished_at=time.time(),
                error=f"the scene's plan failed: {error}")]
            for j in failed:
                log.warning("job %s: failed before it started: the plan of scene %s failed", j["id"], scene_id)
            if len(queued) < 100:
                return
