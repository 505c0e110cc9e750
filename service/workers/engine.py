"""Where job drivers run. ``LocalEngine``: a subprocess per job on this machine, each in a new process group
(session), so cancelling kills the driver and every CLI it started in one ``killpg``.

Privilege separation (``--sandbox``) lives in :mod:`service.workers.sandbox`; its names are re-exported here
for the engine's callers.
"""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Protocol

__all__ = ["Handle", "Engine", "LocalEngine", "group_alive", "kill_group", "driver_env", "RunAs",
           "SandboxUnavailable", "resolve_sandbox", "sandbox_blockers", "sandbox_env", "secure_data_dir",
           "give_tree", "reclaim_tree", "kill_uids", "uid_alive", "remove_leftovers", "SHARED_TMP"]

from service.workers.sandbox import (
    SHARED_TMP,
    RunAs,
    SandboxUnavailable,
    driver_env,
    give_tree,
    kill_uids,
    reclaim_tree,
    remove_leftovers,
    resolve_sandbox,
    sandbox_blockers,
    sandbox_env,
    secure_data_dir,
    uid_alive,
)


@dataclass
class Handle:
    """A launched job run: its process (local) or task (Ray), and the process group to kill."""

    job_id: str
    attempt: int
    job_dir: Path
    pid: Optional[int] = None
    started: float = field(default_factory=time.monotonic)
    obj: Any = None  # Popen (local) or an ObjectRef (ray)
    run_as: Optional["RunAs"] = None  # the sandbox user of the run (local engine, sandbox on)


class Engine(Protocol):
    name: str

    def launch(self, job_id: str, attempt: int, job_dir: Path) -> Handle: ...

    def poll(self, handle: Handle) -> Optional[int]: ...

    def kill(self, handle: Handle, *, grace_s: float) -> None: ...

    def close(self) -> None: ...


def group_alive(pgid: int) -> bool:
    """Whether any process of group ``pgid`` is still alive (zombies count as gone)."""
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat", "rb") as fh:
                raw = fh.read()
        except OSError:
            continue
        rest = raw[raw.rfind(b")") + 2:].split()
        if len(rest) > 2 and int(rest[2]) == pgid and rest[0] != b"Z":
            return True
    return False


def kill_group(pgid: int, *, grace_s: float = 3.0, proc: Optional[subprocess.Popen] = None) -> None:
    """SIGTERM the group, wait up to ``grace_s`` for it to go, then SIGKILL it; reaps ``proc``."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(pgid, sig)
        except (ProcessLookupError, PermissionError):
            pass
        deadline = time.monotonic() + (grace_s if sig == signal.SIGTERM else 5.0)
        while time.monotonic() < deadline:
            if proc is not None and proc.poll() is None:
                time.sleep(0.05)
                continue
            if not group_alive(pgid):
                return
            time.sleep(0.05)
    if proc is not None:
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass


class LocalEngine:
    """Job drivers as local subprocesses (``python -m service.workers.driver JOB_DIR``)."""

    name = "local"

    sandboxed = True  # can run drivers as a sandbox user (``run_as``)

    def launch(self, job_id: str, attempt: int, job_dir: Path, run_as: Optional[RunAs] = None) -> Handle:
        """Start the driver; with ``run_as`` as that user, HOME and TMPDIR in ``job_dir`` (which it owns), and
        /tmp, /var/tmp, /dev/shm of its own where the platform allows (service.workers.private_tmp)."""
        # the job's folder is the job's: its log is opened without following a link or waiting on a FIFO, and
        # only a plain file of its own is handed to the driver (and, sandboxed, chowned to the slot's uid)
        fd = os.open(job_dir / "driver.log", os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK
                     | os.O_CLOEXEC, 0o600)
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
            os.close(fd)
            raise OSError(f"{job_dir.name}/driver.log is not a plain file of the job's own")
        log_fh = os.fdopen(fd, "ab")
        cmd = [sys.executable, "-m", "service.workers.driver", str(job_dir), "--parent-pid", str(os.getpid())]
        try:
            if run_as is not None:
                os.fchown(log_fh.fileno(), run_as.uid, run_as.gid)
                # started as root: the wrapper makes the private folders, then drops to the slot's uid
                cmd = [sys.executable, "-m", "service.workers.private_tmp", str(job_dir / "tmp"), str(run_as.uid),
                       str(run_as.gid), "--", *cmd]
            proc = subprocess.Popen(
                cmd, stdin=subprocess.DEVNULL, stdout=log_fh, stderr=subprocess.STDOUT, cwd=job_dir,
                env=driver_env() if run_as is None else sandbox_env(job_dir), start_new_session=True)
        finally:
            log_fh.close()
        return Handle(job_id=job_id, attempt=attempt, job_dir=job_dir, pid=proc.pid, obj=proc, run_as=run_as)

    def poll(self, handle: Handle) -> Optional[int]:
        return handle.obj.poll()

    def kill(self, handle: Handle, *, grace_s: float) -> None:
        """Stop the run's whole process group (in a helper thread: the scheduler never blocks on it)."""
        threading.Thread(target=kill_group, args=(handle.pid,), kwargs={"grace_s": grace_s, "proc": handle.obj},
                         name=f"kill-{handle.job_id}", daemon=True).start()

    def close(self) -> None:
        pass
