"""Robustness against a real `holo serve`: cancelling a running job kills its process group; `kill -9` of a
worker (the driver, or the render CLI under it) requeues the job until it succeeds or runs out of attempts;
killing or stopping the server mid-queue loses nothing and leaves no job running."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from service.workers.engine import group_alive
from tests.service.helpers import SMALL_JOB, upload, wait_for, wait_state

pytestmark = pytest.mark.scenes


def group_members(pgid: int) -> list[tuple[int, str]]:
    """(pid, cmdline) of the live processes in group ``pgid``."""
    out = []
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            raw = (p / "stat").read_bytes()
            rest = raw[raw.rfind(b")") + 2:].split()
            if int(rest[2]) != pgid or rest[0] == b"Z":
                continue
            out.append((int(p.name), (p / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")))
        except (OSError, IndexError, ValueError):
            continue
    return out


def process_alive(pid: int) -> bool:
    """Whether ``pid`` exists and is not a zombie (a zombie has stopped running; only its reaping is left)."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_bytes()
    except OSError:
        return False
    return raw[raw.rfind(b")") + 2:].split()[0] != b"Z"


def running_render(c, job_id: str, timeout: float = 60.0) -> tuple[int, int]:
    """Wait until the job's `holo render` child runs; returns (driver pid = pgid, render pid)."""
    def check():
        job = c.get(f"/v1/jobs/{job_id}").json()
        assert job["state"] in ("queued", "running"), job
        pid = job["worker_pid"]
        if job["state"] != "running" or not pid:
            return None
        renders = [p for p, cmd in group_members(pid) if " holo render " in f" {cmd} " or "-m holo render" in cmd]
        return (pid, renders[0]) if renders else None

    return wait_for(check, timeout=timeout, interval=0.05, what=f"job {job_id} rendering")


def job_body(scene_id: str, seed: int, **over) -> dict:
    return {"scene_id": scene_id, **SMALL_JOB, "optics": {**SMALL_JOB["optics"], "seed": seed}, **over}


SLOW = {"optics": {"resolution_hw": [256, 256], "seed": 1}, "preset": "balanced", "frames": 8, "spp": 256,
        "encoder": "sgd", "iterations": 300}


@pytest.mark.slow
def test_cancel_running_and_queued_jobs(server_factory, scene_bundle):
    srv = server_factory("cancel", workers=1).start()
    with srv.client("submit") as c:
        sid = upload(c, scene_bundle("cbox-mirror-glass")).json()["id"]
        slow = c.post("/v1/jobs", json={"scene_id": sid, **SLOW}).json()
        small = c.post("/v1/jobs", json=job_body(sid, 11)).json()
        pgid, render_pid = running_render(c, slow["id"])
        assert c.get(f"/v1/jobs/{small['id']}").json()["state"] == "queued"
        r = c.delete(f"/v1/jobs/{slow['id']}")
        assert r.status_code == 202 and r.json()["state"] == "cancelled"
        wait_for(lambda: not group_alive(pgid), timeout=10, what="the cancelled job's process group to exit")
        # the render CLI is gone too: reaped, or a zombie whose new parent (an init that may not reap) has it
        assert not process_alive(render_pid), f"render {render_pid} outlived its cancelled job"
        # the next job in the queue runs; cancelling a queued job means it never starts
        queued = c.post("/v1/jobs", json=job_body(sid, 12)).json()
        r2 = c.delete(f"/v1/jobs/{queued['id']}")
        assert r2.status_code == 202 and r2.json()["state"] == "cancelled"
        done = wait_state(c, small["id"], ("succeeded", "failed"))
        assert done["state"] == "succeeded", done["error"]
        time.sleep(1.0)
        q = c.get(f"/v1/jobs/{queued['id']}").json()
        assert q["state"] == "cancelled" and q["attempts"] == 0 and q["started_at"] is None
        s = c.get(f"/v1/jobs/{slow['id']}").json()
        assert s["state"] == "cancelled" and s["stack_sha256"] is None
        again = c.delete(f"/v1/jobs/{slow['id']}")
        assert again.status_code == 409 and "already cancelled" in again.json()["detail"]
        assert c.get(f"/v1/jobs/{slow['id']}/stack").status_code == 409
    assert not (srv.data_dir / "jobs" / slow["id"] / "stack.npz").exists()


@pytest.mark.slow
def test_kill_9_of_a_worker_requeues_until_it_succeeds(server_factory, scene_bundle):
    srv = server_factory("kill", workers=1, extra=("--max-attempts", "3")).start()
    with srv.client("submit") as c:
        sid = upload(c, scene_bundle("cbox-mirror-glass")).json()["id"]
        job = c.post("/v1/jobs", json=job_body(sid, 21)).json()
        pgid1, _ = running_render(c, job["id"])
        os.kill(pgid1, signal.SIGKILL)  # the driver: its render child is orphaned and must be cleaned up
        wait_for(lambda: not group_alive(pgid1), timeout=10, what="the killed driver's group to be gone")
        wait_for(lambda: c.get(f"/v1/jobs/{job['id']}").json()["attempts"] >= 2, timeout=30, what="attempt 2")
        pgid2, render2 = running_render(c, job["id"])
        assert pgid2 != pgid1
        os.kill(render2, signal.SIGKILL)  # the CLI under the driver this time
        done = wait_state(c, job["id"], ("succeeded", "failed"), timeout=120)
    assert done["state"] == "succeeded", done["error"]
    assert done["attempts"] == 3 and done["stack_sha256"]
    assert "requeued" in srv.log()


@pytest.mark.slow
def test_a_job_that_keeps_dying_fails_with_a_reason(server_factory, scene_bundle):
    srv = server_factory("giveup", workers=1, extra=("--max-attempts", "1")).start()
    with srv.client("submit") as c:
        sid = upload(c, scene_bundle("cbox-mirror-glass")).json()["id"]
        job = c.post("/v1/jobs", json=job_body(sid, 31)).json()
        pgid, _ = running_render(c, job["id"])
        os.kill(pgid, signal.SIGKILL)
        done = wait_state(c, job["id"], ("succeeded", "failed"), timeout=30)
    assert done["state"] == "failed" and "killed by signal 9" in done["error"] and "1 attempts" in done["error"]


@pytest.mark.slow
def test_server_killed_then_stopped_mid_queue_loses_nothing(server_factory, scene_bundle):
    srv = server_factory("restart", workers=1).start()
    with srv.client("submit") as c:
        sid = upload(c, scene_bundle("cbox-mirror-glass")).json()["id"]
        jobs = [c.post("/v1/jobs", json=job_body(sid, 40 + i)).json()["id"] for i in range(2)]  # running, queued
        pgid, _ = running_render(c, jobs[0])
    srv.stop(signal.SIGKILL)  # a crash: the drivers die with it (PR_SET_PDEATHSIG)
    wait_for(lambda: not group_alive(pgid), timeout=10, what="the dead server's job to stop")
    srv.start()
    with srv.client("submit") as c:
        first = c.get(f"/v1/jobs/{jobs[0]}").json()
        assert first["state"] in ("queued", "running") and first["attempts"] >= 1
        pgid2, _ = running_render(c, jobs[0])
    srv.stop(signal.SIGTERM)  # a clean stop: the running job goes back to the queue, the run does not count
    assert not group_alive(pgid2)
    srv.start()
    with srv.client("reader") as c:
        states = [wait_state(c, j, ("succeeded", "failed", "cancelled"), timeout=120) for j in jobs]
        assert [s["state"] for s in states] == ["succeeded"] * 2, [s["error"] for s in states]
        assert [s["attempts"] for s in states] == [2, 1]
        assert len(c.get("/v1/jobs").json()["jobs"]) == 2
        assert c.get("/v1/jobs", params={"state": "running"}).json()["jobs"] == []
        shas = {s["stack_sha256"] for s in states}
        assert len(shas) == 2  # two seeds, two different stacks
