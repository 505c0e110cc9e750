"""The scheduler: a thread in the server that claims queued jobs atomically (``UPDATE ... WHERE
state='queued'``), launches one driver per job on the engine, follows progress files, stops cancelled or
timed-out runs, and records how each run ended. Crashed runs are requeued until ``max_attempts``.

On start it recovers from a crash: jobs left ``running`` (their drivers are gone or are killed now) are
finished from their ``status.json`` if it says done, else requeued, or failed after ``max_attempts`` runs.
None stays running.

With the sandbox on (local engine; service/workers/engine.py) each running job holds a slot ``k`` and runs as
uid ``sandbox_uid_base + 1 + k``: before launch the scene bundle is copied into ``JOB_DIR/scene/`` (job.json's
``scene_path``) and the job dir is handed to that uid (0700). However the run ends (done, failed, cancelled,
timed out, found on recovery) every process of that uid is killed, the dir is taken back (links and odd files
dropped), the scene copy removed, and only then is the slot free again. ``status.json`` is the worker's word
and is not trusted for integrity: the artifacts' hashes and sizes are the scheduler's own.

Every run's ``job.json`` carries the kernel resource limits of its processes (service/workers/limits.py
``job_limits``: memory, CPU time, open files, the largest file its folder may hold, processes for a sandbox
uid), which the driver applies
to itself before anything else, so every step inherits them.
"""

from __future__ import annotations

import logging
import os
import shutil
import threading
import time
from pathlib import Path
from typing import Optional

from holocore.scene.errors import scrub_message
from service.db import Database
from service.jobfiles import JobFile, JobSpec, RunStatus, read_run_status
from service.settings import ServiceSettings
from service.workers.driver import EXIT_FAILED, write_json_atomic
from service.workers.engine import (
    Engine,
    Handle,
    RunAs,
    give_tree,
    kill_group,
    kill_uids,
    reclaim_tree,
    resolve_sandbox,
    secure_data_dir,
)
from service.workers import admission
from service.workers.limits import job_limits
from service.workers.runfiles import RUN_FILES, hash_artifacts, read_progress, remove_partials

__all__ = ["Scheduler", "pid_is_our_driver"]

log = logging.getLogger("holo.service.scheduler")

_SANDBOX_ONLY = ("scene", "home", "tmp")  # what a sandboxed run gets in its job dir, removed after it


def pid_is_our_driver(pid: int, job_dir: Path) -> bool:
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    return b"service.workers.driver" in cmd and str(job_dir).encode() in cmd


class Scheduler:
    """Runs queued jobs on ``engine``, at most ``settings.workers`` at a time."""

    def __init__(self, settings: ServiceSettings, db: Database, engine: Engine, *, metrics=None) -> None:
        self.settings = settings
        self.db = db
        self.engine = engine
        self.metrics = metrics
        self.running: dict[str, Handle] = {}
        self._memory: dict[str, int] = {}  # predicted peak bytes of each running job
        self._progress: dict[str, dict] = {}
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self.last_tick = 0.0
        self.sandbox_base: Optional[int] = None  # slot k runs as sandbox_base + 1 + k (None: no sandbox)
        self._slot_of: dict[str, int] = {}
        self._draining: set[int] = set()  # slots whose run is being killed and taken back
        self._releasers: list[threading.Thread] = []

    # ---- lifecycle -------------------------------------------------------------------------------------
    def start(self) -> None:
        base = resolve_sandbox(self.settings)
        if base is not None:
            secure_data_dir(self.settings)
            if getattr(self.engine, "sandboxed", False):
                self.sandbox_base = base
                kill_uids(range(base + 1, base + 1 + self.settings.workers))  # a previous server's leftovers
                log.info("sandbox on: jobs run as uids %d..%d, scene planning as uid %d", base + 1,
                         base + self.settings.workers, base)
            else:
                log.warning("sandbox: engine %s runs jobs as its workers' own user; only scene planning is "
                            "sandboxed", self.engine.name)
        self.recover()
        self._thread = threading.Thread(target=self._loop, name="holo-scheduler", daemon=True)
        self._thread.start()

    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive() and time.time() - self.last_tick < 30

    def wake(self) -> None:
        self._wake.set()

    def stop(self, *, requeue: bool = True) -> None:
        """Stop claiming, kill running jobs and put them back in the queue (this run does not count)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        for job_id, h in list(self.running.items()):
            if h.pid is not None:
                kill_group(h.pid, grace_s=min(1.0, self.settings.kill_grace_s), proc=h.obj)
            else:
                self.engine.kill(h, grace_s=0)
            if h.run_as is not None:
                self._take_back(job_id, h)
            if requeue:
                self.db.update_job(job_id, where_state=("running",), state="queued", attempts=max(0, h.attempt - 1),
                                   started_at=None, worker_pid=None, progress=None)
        self.running.clear()
        for t in list(self._releasers):
            t.join(timeout=15)
        self.engine.close()

    def recover(self) -> None:
        """Finish, requeue or fail the jobs a previous server left running."""
        for row in self.db.running_jobs():
            job_dir = Path(row["artifact_dir"] or self.settings.jobs_dir / row["id"])
            pid = row["worker_pid"]
            if pid and pid_is_our_driver(pid, job_dir):
                log.warning("job %s: killing the driver (pid %d) a previous server left behind", row["id"], pid)
                kill_group(pid, grace_s=1.0)
            try:  # a sandboxed run's dir (its uids were killed in start): ours again before anything reads it
                if job_dir.is_dir() and (self.sandbox_base is not None or job_dir.stat().st_uid != os.geteuid()):
                    reclaim_tree(job_dir, remove=_SANDBOX_ONLY)
            except OSError:
                log.exception("job %s: could not take its dir back", row["id"])
            status = read_run_status(job_dir, row["attempts"])
            if status is not None and status.ok:
                self._succeed(row["id"], row["attempts"], status, job_dir)
            elif row["attempts"] >= self.settings.max_attempts:
                self._fail(row["id"], row["attempts"], f"interrupted (server restart or worker crash) on each of "
                                                       f"{row['attempts']} attempts")
            else:
                log.warning("job %s: requeued after a server restart", row["id"])
                self.db.update_job(row["id"], where_state=("running",), state="queued", started_at=None,
                                   worker_pid=None, progress=None)
        self.db.requeue_running_plans()

    # ---- the loop --------------------------------------------------------------------------------------
    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.tick()
            except Exception:  # noqa: BLE001 - keep scheduling; the error is logged
                log.exception("scheduler tick failed")
            self.last_tick = time.time()
            self._wake.wait(self.settings.tick_s)
            self._wake.clear()

    def tick(self) -> None:
        for job_id, h in list(self.running.items()):
            self._watch(job_id, h)
        while len(self.running) < self.settings.workers and not self._stop.is_set():
            if self.sandbox_base is not None and self._free_slot() is None:
                break  # every slot is still being taken back from a stopped run
            nxt, need = None, 0
            for cand in self.db.queued_jobs_fair():  # round robin over owners
                need = self._memory_need(cand)
                if need is not None:
                    nxt = cand
                    break
            if nxt is None:
                break  # nothing queued, or only jobs whose scene is still being planned
            if need < 0:
                continue  # refused: it cannot fit the workers' memory
            held = sum(self._memory.get(j, 0) for j in self.running)
            if self.running and held + need > self.settings.worker_memory_bytes:
                break  # runs start in order, and only while their estimates fit together
            row = self.db.claim_next_job(nxt["id"])
            if row is None:
                continue  # cancelled meanwhile
            self._memory[row["id"]] = need
            self._launch(row)
        for job_id in [j for j in self._memory if j not in self.running]:
            del self._memory[job_id]
        if self.metrics is not None:
            self.metrics.workers_busy.set(len(self.running))

    def _memory_need(self, row: dict) -> Optional[int]:
        """A queued job's predicted peak bytes (service.workers.admission); None to leave it queued for now; -1
        when it cannot run (the job is failed with the reason)."""
        a = admission.admit(row, self.db.get_scene(row["scene_id"]), self.settings)
        if a.refusal is not None:
            self._fail(row["id"], row["attempts"], a.refusal)
            return -1
        if a.estimate is not None:
            self.db.update_job(row["id"], where_state=("queued",), estimate=a.estimate)
        return a.need_bytes

    # ---- sandbox slots ---------------------------------------------------------------------------------
    def _free_slot(self) -> Optional[int]:
        used = set(self._slot_of.values()) | self._draining
        return next((k for k in range(self.settings.workers) if k not in used), None)

    def _slot_user(self, slot: int) -> RunAs:
        uid = self.sandbox_base + 1 + slot
        return RunAs(uid, uid)

    def _take_back(self, job_id: str, h: Handle) -> None:
        """Kill whatever the run's uid still runs, take its dir back and free its slot (once the run stopped)."""
        try:
            kill_uids({h.run_as.uid})
            dropped = reclaim_tree(h.job_dir, remove=_SANDBOX_ONLY)
            if dropped:
                log.warning("job %s: removed from its dir (links or special files): %s", job_id, dropped[:20])
        except OSError:
            log.exception("job %s: could not take its dir back", job_id)
        finally:
            self._slot_of.pop(job_id, None)  # no-op for a draining slot (_release_later frees it)

    def _release_later(self, job_id: str, h: Handle, *, grace_s: float, then=None) -> None:
        """Stop the run (SIGTERM, ``grace_s``, SIGKILL) and take its slot back in a helper thread; the slot
        stays in use until then."""
        slot = self._slot_of.pop(job_id, None)
        if slot is not None:
            self._draining.add(slot)

        def work() -> None:
            try:
                if h.pid is not None:
                    kill_group(h.pid, grace_s=grace_s, proc=h.obj)
                self._take_back(job_id, h)
                if then is not None:
                    then()
            finally:
                self._draining.discard(slot)
                self._releasers.remove(threading.current_thread())
                self.wake()

        t = threading.Thread(target=work, name=f"release-{job_id}", daemon=True)
        self._releasers.append(t)
        t.start()

    def _launch(self, row: dict) -> None:
        job_id, attempt = row["id"], row["attempts"]
        job_dir = Path(row["artifact_dir"])
        run_as = None
        if self.sandbox_base is not None:
            slot = self._free_slot()
            run_as = self._slot_user(slot)
            self._slot_of[job_id] = slot
        try:
            job_dir.mkdir(parents=True, exist_ok=True)
            if run_as is not None:
                os.chmod(job_dir, 0o700)
                reclaim_tree(job_dir, remove=_SANDBOX_ONLY)
            for name in RUN_FILES:  # a fresh run: nothing of a previous attempt may look like this one's
                (job_dir / name).unlink(missing_ok=True)
            spec = JobSpec.model_validate(row["spec"])
            scene = self.db.get_scene(row["scene_id"])
            if scene is None:
                raise FileNotFoundError(f"scene {row['scene_id']} is gone")
            write_json_atomic(job_dir / "optics.json", spec.optics)
            scene_path = self.settings.scenes_dir / scene["id"] / "bundle" / scene["entry"]
            if run_as is not None:  # the job reads its own copy only (scenes/ is closed to it)
                shutil.copytree(self.settings.scenes_dir / scene["id"] / "bundle",
                                job_dir / "scene", symlinks=True)
                scene_path = job_dir / "scene" / scene["entry"]
                for sub in ("home", "tmp"):
                    (job_dir / sub).mkdir(exist_ok=True)
            limits = job_limits(self.settings, sandboxed=run_as is not None,
                                largest_file_bytes=admission.largest_file_bytes(row, spec))
            job_file = JobFile(**spec.options(), job_id=job_id, attempt=attempt, scene_path=str(scene_path),
                               keep_result=self.settings.keep_result, limits=limits.model_dump(exclude_none=True),
                               step_seconds=(row.get("estimate") or {}).get("steps_s"))
            write_json_atomic(job_dir / "job.json", job_file.model_dump(mode="json"))
            if run_as is not None:
                give_tree(job_dir, run_as)
                handle = self.engine.launch(job_id, attempt, job_dir, run_as=run_as)
            else:
                handle = self.engine.launch(job_id, attempt, job_dir)
        except Exception as exc:  # noqa: BLE001
            log.exception("job %s: launch failed", job_id)
            if run_as is not None:
                self._take_back(job_id, Handle(job_id=job_id, attempt=attempt, job_dir=job_dir, run_as=run_as))
            self._fail(job_id, attempt, f"could not start the worker: {exc}")
            return
        self.running[job_id] = handle
        self.db.update_job(job_id, where_state=("running",), worker_pid=handle.pid,
                           progress={"step": "starting", "stage": "starting", "done": 0, "total": 0,
                                     "fraction": 0.0})
        log.info("job %s: attempt %d started (pid %s, %s%s)", job_id, attempt, handle.pid, self.engine.name,
                 f", uid {run_as.uid}" if run_as is not None else "")

    def _watch(self, job_id: str, h: Handle) -> None:
        row = self.db.get_job(job_id)
        if row is None or row["state"] != "running" or row["attempts"] != h.attempt:
            log.info("job %s: %s, stopping its run", job_id, row["state"] if row else "deleted")
            del self.running[job_id]
            self._progress.pop(job_id, None)
            if h.run_as is not None:
                self._release_later(job_id, h, grace_s=self.settings.kill_grace_s,
                                    then=lambda: remove_partials(h.job_dir))
                return
            self.engine.kill(h, grace_s=self.settings.kill_grace_s)
            threading.Thread(target=remove_partials, args=(h.job_dir,), kwargs={"after_s": 2.0}, daemon=True).start()
            return
        rc = self.engine.poll(h)
        if rc is None:
            prog = read_progress(h.job_dir)
            last = self._progress.get(job_id)
            if prog is not None and last is not None and prog["fraction"] < last["fraction"]:
                prog = {**prog, "fraction": last["fraction"]}  # the fraction done only ever grows
            if prog is not None and prog != last:
                self._progress[job_id] = prog
                self.db.update_job(job_id, where_state=("running",), progress=prog)
            if time.monotonic() - h.started > self.settings.job_timeout_s:
                if h.run_as is not None:
                    self._release_later(job_id, h, grace_s=self.settings.kill_grace_s)
                else:
                    self.engine.kill(h, grace_s=self.settings.kill_grace_s)
                del self.running[job_id]
                self._fail(job_id, h.attempt, f"timed out after {self.settings.job_timeout_s:.0f} s")
            return
        del self.running[job_id]
        self._progress.pop(job_id, None)
        if h.run_as is not None:  # the driver is gone: nothing of its uid survives it, its dir is ours again
            self._take_back(job_id, h)
        status = read_run_status(h.job_dir, h.attempt)
        error = status.error if status is not None else None
        if rc == 0 and status is not None and status.ok:
            self._succeed(job_id, h.attempt, status, h.job_dir)
        elif rc == EXIT_FAILED or (status is not None and status.retryable is False):
            self._fail(job_id, h.attempt, error or f"worker exited with code {rc}")
        else:
            if h.pid is not None:  # leftovers of a killed driver (its CLIs share the group)
                self.engine.kill(h, grace_s=0)
            why = error or (f"worker killed by signal {-rc}" if rc < 0
                                                   else f"worker exited with code {rc}")
            if h.attempt >= self.settings.max_attempts:
                self._fail(job_id, h.attempt, f"{why} (gave up after {h.attempt} attempts)")
            else:
                log.warning("job %s: %s; requeued (attempt %d of %d)", job_id, why, h.attempt,
                            self.settings.max_attempts)
                self.db.update_job(job_id, where_state=("running",), state="queued", started_at=None,
                                   worker_pid=None, progress=None, error=f"previous attempt: {why}")
                self.wake()

    # ---- outcomes --------------------------------------------------------------------------------------
    def _succeed(self, job_id: str, attempt: int, status: RunStatus, job_dir: Path) -> None:
        artifacts = hash_artifacts(job_dir)  # our own hashes: status.json is the worker's word only
        stack = artifacts.get("stack.npz")
        if stack is None:
            self._fail(job_id, attempt, "the run reported success but left no stack.npz")
            return
        if status.stack_sha256 != stack["sha256"]:
            self._fail(job_id, attempt, "integrity check failed: stack.npz does not have the SHA-256 its worker "
                                        "reported; the job can be submitted again")
            return
        row = self.db.get_job(job_id)
        timings = dict((row or {}).get("timings") or {})
        timings.update(status.timings)
        timings["engine"] = self.engine.name
        now = time.time()
        if row and row.get("started_at"):
            timings["run_s"] = round(now - row["started_at"], 3)
            timings["queued_s"] = round(row["started_at"] - row["created_at"], 3)
        plan = status.plan
        if status.warnings:  # the steps name files by absolute path: the user sees them in the job's terms
            roots = [self.settings.jobs_dir / job_id, self.settings.data_dir]
            plan = {**(plan or {}), "warnings": [scrub_message(w, roots=roots) for w in status.warnings]}
        changed = self.db.update_job(
            job_id, where_state=("running",), state="succeeded", finished_at=now, stack_sha256=stack["sha256"],
            stack_bytes=stack["bytes"], timings=timings, plan=plan, error=None, artifacts=artifacts,
            progress={"step": "done", "stage": "done", "done": 1, "total": 1, "fraction": 1.0})
        if changed:
            log.info("job %s: succeeded (attempt %d)", job_id, attempt)
            if self.metrics is not None:
                self.metrics.jobs_finished.labels(state="succeeded").inc()

    def _fail(self, job_id: str, attempt: int, error: str) -> None:
        error = scrub_message(error, roots=[self.settings.jobs_dir / job_id, self.settings.data_dir], limit=2000)
        changed = self.db.update_job(job_id, where_state=("running", "queued"), state="failed",
                                     finished_at=time.time(), error=error)
        if changed:
            log.warning("job %s: failed (attempt %d): %s", job_id, attempt, error)
            if self.metrics is not None:
                self.metrics.jobs_finished.labels(state="failed").inc()
