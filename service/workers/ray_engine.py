"""The same jobs on a Ray cluster: one Ray task per run, which starts the job driver
(``python -m service.workers.driver JOB_DIR``) in its own process group on whichever node Ray picks.

Results go to shared storage: every node must see the data dir at the same path (compose mounts one volume at
``/data`` everywhere). A job asks Ray for ``ray_gpus_per_job`` GPUs (0: CPU only). Cancelling force-cancels the
task: Ray kills the worker and its children (the driver), and the driver's CLIs get SIGKILL when the driver dies
(``PR_SET_PDEATHSIG``); had the worker died alone, the driver (SIGTERM when its parent dies) kills its group.
Optional: needs the ``ray`` extra (``pip install .[ray]``).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Optional

from service.settings import ServiceSettings
from service.workers.engine import kill_group
from service.workers.engine import Handle

__all__ = ["RayEngine", "RayUnavailable", "connect", "run_driver"]

log = logging.getLogger("holo.service.ray")


def run_driver(job_dir: str) -> int:
    """Body of the Ray task: run the job driver as a child in a new session; returns its exit code."""
    env = dict(os.environ)
    repo = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (repo, env.get("PYTHONPATH", "")) if p)
    with open(Path(job_dir) / "driver.log", "ab") as logf:
        proc = subprocess.Popen([sys.executable, "-m", "service.workers.driver", job_dir, "--parent-pid",
                                 str(os.getpid())], stdin=subprocess.DEVNULL, stdout=logf, stderr=subprocess.STDOUT,
                                cwd=job_dir, env=env, start_new_session=True)
    (Path(job_dir) / "ray_driver.pid").write_text(f"{proc.pid}\n")
    try:
        while True:  # short waits: Ray's cancel arrives as an async exception between bytecodes
            try:
                return proc.wait(timeout=0.5)
            except subprocess.TimeoutExpired:
                continue
    except BaseException:  # ray.cancel raises KeyboardInterrupt here: stop the job's whole process group

        kill_group(proc.pid, grace_s=2.0, proc=proc)
        raise


def _signal_handlers() -> dict:
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}


def _restore_signal_handlers(handlers: dict) -> None:
    for sig, handler in handlers.items():
        if handler is not None and signal.getsignal(sig) is not handler:
            signal.signal(sig, handler)


class RayUnavailable(RuntimeError):
    """The Ray cluster could not be reached (one line: the address and Ray's last error)."""


CONNECT_ATTEMPTS = 3
CONNECT_BACKOFF_S = 3.0


def connect(ray, address: str) -> None:
    """``ray.init`` with a few attempts: a head that is still starting, or a Ray Client server that failed to
    start for one connection (seen on a loaded 2-core machine), is not a reason to refuse to serve."""
    for attempt in range(1, CONNECT_ATTEMPTS + 1):
        # ray.init installs a SIGTERM handler that just exits (no graceful shutdown: running jobs would not
        # be requeued nor the data dir unlocked); keep the server's own handlers
        keep = _signal_handlers()
        try:
            ray.init(address=address, namespace="holo", ignore_reinit_error=True, log_to_driver=False,
                     logging_level=logging.WARNING)
            return
        except Exception as exc:  # noqa: BLE001 - Ray raises ConnectionError, RuntimeError, grpc errors
            last = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
            try:
                ray.shutdown()
            except Exception:  # noqa: BLE001 - nothing left to close
                pass
            if attempt == CONNECT_ATTEMPTS:
                raise RayUnavailable(f"cannot connect to the Ray cluster at {address} after {attempt} attempts: "
                                     f"{last}") from None
            log.warning("ray engine: connecting to %s failed (attempt %d of %d: %s); retrying", address, attempt,
                        CONNECT_ATTEMPTS, last)
            time.sleep(CONNECT_BACKOFF_S * attempt)
        finally:
            _restore_signal_handlers(keep)


class RayEngine:
    """Runs job drivers as Ray tasks (``ray.init(address=settings.ray_address)``)."""

    name = "ray"

    def __init__(self, settings: ServiceSettings) -> None:
        import ray

        self._ray = ray
        address = settings.ray_address or "auto"
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage report leaves the lab unless asked for
        if not ray.is_initialized():
            connect(ray, address)
        self._task = ray.remote(max_retries=0)(run_driver)
        self._gpus = settings.ray_gpus_per_job
        log.info("ray engine: connected to %s (%s GPUs per job)", address, self._gpus)
        try:
            have = float(ray.cluster_resources().get("GPU", 0.0))
        except Exception:  # noqa: BLE001 - only for the warning below
            have = None
        if self._gpus > 0 and have is not None and have < self._gpus:
            log.warning("ray engine: each job asks for %s GPU(s) but the cluster has %s now; jobs wait until a GPU "
                        "node joins", self._gpus, have)

    def launch(self, job_id: str, attempt: int, job_dir: Path) -> Handle:
        (job_dir / "ray_driver.pid").unlink(missing_ok=True)
        ref = self._task.options(num_cpus=1, num_gpus=self._gpus, name=f"holo-job-{job_id}-{attempt}").remote(
            str(job_dir))
        return Handle(job_id=job_id, attempt=attempt, job_dir=job_dir, pid=None, obj=ref)

    def poll(self, handle: Handle) -> Optional[int]:
        ready, _ = self._ray.wait([handle.obj], timeout=0)
        if not ready:
            return None
        try:
            return int(self._ray.get(handle.obj))
        except Exception as exc:  # noqa: BLE001 - worker died, node lost, task cancelled: retryable
            log.warning("job %s: ray task ended with %s: %s", handle.job_id, type(exc).__name__,
                        (str(exc).strip().splitlines() or [""])[-1][:300])
            return -9

    def kill(self, handle: Handle, *, grace_s: float) -> None:  # noqa: ARG002 - the task's own grace applies
        """Force-cancel the task: Ray kills the worker and its child (the driver); each CLI of the driver gets
        SIGKILL when the driver dies (PR_SET_PDEATHSIG), so the whole job stops."""
        try:
            self._ray.cancel(handle.obj, force=True)
        except Exception as exc:  # noqa: BLE001 - already finished
            log.debug("cancel of job %s: %s", handle.job_id, exc)

    def close(self) -> None:
        try:
            self._ray.shutdown()
        except Exception:  # noqa: BLE001
            pass
