"""``GET /v1/queue``: the jobs waiting and running (everyone's and the caller's), the workers' slots and the
planner's waiting scenes, as the database and the scheduler know them."""

from __future__ import annotations

import time

import pytest

from tests.service.helpers import SMALL_JOB, upload, wait_for, wait_state


def _token(server, owner: str, *scopes: str) -> str:
    from service.auth import create_token
    from service.db import Database

    return create_token(Database(server.data_dir / "service.db"), scopes=scopes or ("submit",), owner=owner)[1]


def _queued_job(db_path, owner: str, scene_id: str, job_id: str) -> None:
    """A queued job row as a submit writes it, on a scene still being planned (the scheduler leaves such a job
    queued until its scene is planned, so the count holds still while the test reads it)."""
    from service.db import Database

    db = Database(db_path)
    now = time.time()
    db.execute("INSERT INTO jobs (id, owner, scene_id, state, spec, cache_key, created_at, updated_at, attempts) "
               "VALUES (?, ?, ?, 'queued', '{}', ?, ?, ?, 0)", (job_id, owner, scene_id, f"k-{job_id}", now, now))


@pytest.fixture
def quiet_server(server_factory):
    """A server with 2 worker slots."""
    return server_factory(workers=2).start()


def test_queue_counts_jobs_workers_and_the_planner(quiet_server, tmp_path):
    s = quiet_server
    with s.client("reader") as c:
        q = c.get("/v1/queue")
        assert q.status_code == 200, q.text
        q = q.json()
    assert q["jobs"] == {"queued": 0, "queued_yours": 0, "running": 0, "running_yours": 0}
    assert q["workers"]["engine"] == "local" and q["workers"]["slots"] == 2 and q["workers"]["busy_slots"] == 0
    assert q["workers"]["running_here"] is True and q["workers"]["alive"] is True
    assert q["planner"] == {"pending_scenes": 0, "pending_scenes_yours": 0, "planning": False, "state": "idle"}

    # Two scenes being planned, written straight into the database as 'running' (the planner claims only
    # pending ones, so they hold still), one job of this owner and two of another queued on them.
    from service.db import Database

    db = Database(s.data_dir / "service.db")
    now = time.time()
    for sid, owner in (("spend1", "default"), ("spend2", "lab-b")):
        db.execute("INSERT INTO scenes (id, sha256, entry, report, plan_state, created_at) VALUES "
                   "(?, ?, 'scene.xml', '{}', 'running', ?)", (sid, sid * 4, now))
        db.execute("INSERT INTO scene_owners (scene_id, owner, created_at) VALUES (?, ?, ?)", (sid, owner, now))
    _queued_job(s.data_dir / "service.db", "default", "spend1", "jmine1")
    _queued_job(s.data_dir / "service.db", "lab-b", "spend2", "jother1")
    _queued_job(s.data_dir / "service.db", "lab-b", "spend2", "jother2")
    with s.client("reader") as c:
        q = c.get("/v1/queue").json()
    assert q["jobs"]["queued"] == 3 and q["jobs"]["queued_yours"] == 1
    assert q["planner"]["pending_scenes"] == 2 and q["planner"]["pending_scenes_yours"] == 1
    assert q["planner"]["planning"] is True and q["planner"]["state"] == "planning"
    with s.client(_token(s, "lab-b", "read")) as c:  # the other owner sees the same totals, its own share
        q = c.get("/v1/queue").json()
    assert q["jobs"]["queued"] == 3 and q["jobs"]["queued_yours"] == 2 and q["planner"]["pending_scenes_yours"] == 1
    db.execute("DELETE FROM jobs")
    db.execute("DELETE FROM scene_owners WHERE scene_id LIKE 'spend%'")
    db.execute("DELETE FROM scenes WHERE id LIKE 'spend%'")


def test_a_running_job_holds_a_slot(quiet_server, tmp_path):
    from holocore.scene.demo import write_demo_scene

    s = quiet_server
    write_demo_scene(tmp_path / "demo")
    with s.client("submit") as c:
        sid = upload(c, tmp_path / "demo").json()["id"]
        wait_for(lambda: c.get(f"/v1/scenes/{sid}").json()["plan_state"] == "ready", timeout=120, what="the plan")
        # a job long enough to be seen running: many samples on a small SLM
        r = c.post("/v1/jobs", json={"scene_id": sid, **{**SMALL_JOB, "spp": 4096, "frames": 4}})
        assert r.status_code == 202, r.text
        jid = r.json()["id"]
        try:
            wait_state(c, jid, ("running",), timeout=60)
            q = wait_for(lambda: (lambda q: q if q["workers"]["busy_slots"] == 1 else None)(
                c.get("/v1/queue").json()), timeout=10, what="the queue to show the running job")
            assert q["jobs"]["running"] == 1 and q["jobs"]["running_yours"] == 1
            assert q["workers"]["slots"] == 2
        finally:
            c.delete(f"/v1/jobs/{jid}")


def test_the_queue_needs_a_token(quiet_server):
    with quiet_server.client(None) as c:
        r = c.get("/v1/queue")
    assert r.status_code == 401
