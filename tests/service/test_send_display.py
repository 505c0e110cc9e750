"""Sending a finished job to a display, against a real `holo serve` and the real display agent (its simulated
SLM): the display's list puts the most recently sent job first, so the agent, which shows the first job of
``GET /v1/jobs?display=NAME&state=succeeded``, switches to a sent job that is older than its newest one, and
back when the newer one is sent; sending to one display takes the job from no other. A display of another
owner, an unknown one, an unfinished job, another owner's job and a read-only token are refused in one line.
A database from before sends lists its display's jobs as it did, in submit order."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.service.helpers import finished_job, planned_scene, start_agent, wait_for, wait_state, zip_dir

pytestmark = pytest.mark.slow  # two finished jobs and a display agent; tests/service/test_web_phase.py sends a job to a display in the quick tier

JOB = {"optics": {"resolution_hw": [16, 24], "seed": 11}, "preset": "fast", "frames": 1, "spp": 2,
       "encoder": "dpac"}


@pytest.fixture(scope="module")
def jobs(server, tmp_path_factory) -> dict:
    """Three succeeded jobs for display ``lab-1``, oldest first: one rendered, two more of other seeds (the
    newest is the one the display shows before anything is sent), and the scene."""
    from holocore.scene.demo import write_demo_scene
    folder = tmp_path_factory.mktemp("send") / "demo"
    write_demo_scene(folder)
    with server.client("admin") as c:  # lab-1 and lab-2 are the default owner's, far-lab is another lab's
        for name, owner in (("lab-1", "default"), ("lab-2", "default"), ("far-lab", "lab2")):
            assert c.put(f"/v1/displays/{name}", json={"owner": owner}).status_code == 204
    sid = planned_scene(server, zip_dir(folder))["id"]
    ids = [finished_job(server, {"scene_id": sid, **JOB, "optics": {**JOB["optics"], "seed": seed},
                                 "display": "lab-1"})["id"] for seed in (11, 12, 13)]
    return {"ids": ids, "scene_id": sid}


def _first(c, display: str) -> str:
    return c.get("/v1/jobs", params={"display": display, "state": "succeeded", "limit": 5}).json()["jobs"][0]["id"]


def _agent(server, tmp: Path, display: str):
    return start_agent(server, tmp, display, rate_hz=200, poll_interval_s=0.1, heartbeat_interval_s=0.2,
                       max_seconds=120)


def _showing(server, display: str):
    with server.client("reader") as c:
        d = [x for x in c.get("/v1/displays").json()["displays"] if x["name"] == display]
    return (d[0].get("showing") or {}).get("job_id") if d else None


def test_the_agent_shows_the_job_sent_to_its_display_not_the_newest(server, jobs, tmp_path):
    from tests.agent.helpers import slm_shows

    old, _, newest = jobs["ids"]
    with server.client("submit") as c:
        assert _first(c, "lab-1") == newest
    agent, stop, th = _agent(server, tmp_path, "lab-1")
    try:
        wait_for(lambda: _showing(server, "lab-1") == newest, timeout=60, what="lab-1 to show the newest job")
        with server.client("submit") as c:
            r = c.post(f"/v1/jobs/{old}/display", json={"display": "lab-1"})
            assert r.status_code == 200, r.text
            assert r.json()["job_id"] == old and r.json()["display"] == "lab-1" and r.json()["sent_at"]
            listed = c.get("/v1/jobs", params={"display": "lab-1", "state": "succeeded"}).json()["jobs"]
        assert [j["id"] for j in listed] == [old, newest, jobs["ids"][1]]
        assert listed[0]["sent_at"] == r.json()["sent_at"] and listed[0]["display"] == "lab-1"
        wait_for(lambda: _showing(server, "lab-1") == old, timeout=60, what="lab-1 to show the job sent to it")
        wait_for(lambda: any(s["stack"] == old for s in slm_shows(tmp_path / "slm")), timeout=30,
                 what="the sent job's frames on the SLM")
        with server.client("submit") as c:  # the newest again, by sending it: the display follows the last send
            assert c.post(f"/v1/jobs/{newest}/display", json={"display": "lab-1"}).status_code == 200
        wait_for(lambda: _showing(server, "lab-1") == newest, timeout=60, what="lab-1 to show the job sent last")
    finally:
        stop.set()
        th.join(timeout=15)
    assert not th.is_alive()


def test_a_job_sent_to_another_display_stays_on_its_own(server, jobs):
    old, middle, newest = jobs["ids"]
    with server.client("submit") as c:
        r = c.post(f"/v1/jobs/{middle}/display", json={"display": "lab-2"})
        assert r.status_code == 200, r.text
        assert _first(c, "lab-2") == middle
        lab1 = [j["id"] for j in c.get("/v1/jobs", params={"display": "lab-1"}).json()["jobs"]]
        assert middle in lab1 and lab1[0] != middle  # still lab-1's, and not sent there: not first there
        assert c.get(f"/v1/jobs/{middle}").json()["display"] == "lab-1"  # the display it was submitted for
        everyone = [j["id"] for j in c.get("/v1/jobs").json()["jobs"]]
        assert everyone.index(newest) < everyone.index(middle) < everyone.index(old)  # unfiltered: newest first


def test_refusals(server, jobs):
    from service.auth import create_token
    from service.db import Database

    jid = jobs["ids"][0]
    with server.client("submit") as c:
        for display, words in (("far-lab", "no display 'far-lab' among the displays of this job's owner"),
                               ("nowhere", "no display 'nowhere' among the displays of this job's owner")):
            r = c.post(f"/v1/jobs/{jid}/display", json={"display": display})
            assert r.status_code == 404 and words in r.json()["detail"], r.text
            assert "\n" not in r.json()["detail"]
        assert c.post(f"/v1/jobs/{jid}/display", json={"display": "../x"}).status_code == 422
        assert c.post(f"/v1/jobs/{jid}/display", json={"display": "lab-1", "frame": 2}).status_code == 422
        r = c.post("/v1/jobs", json={"scene_id": jobs["scene_id"], **JOB, "render_time_limit_s": 300})
        assert r.status_code == 202, r.text
        unfinished = r.json()["id"]
        r = c.post(f"/v1/jobs/{unfinished}/display", json={"display": "lab-1"})
        assert r.status_code == 409 and "only a succeeded job can be sent" in r.json()["detail"], r.text
        c.delete(f"/v1/jobs/{unfinished}")
        assert unfinished not in [j["id"] for j in c.get("/v1/jobs", params={"display": "lab-1"}).json()["jobs"]]
    with server.client("reader") as c:
        assert c.post(f"/v1/jobs/{jid}/display", json={"display": "lab-1"}).status_code == 403
    other = create_token(Database(server.data_dir / "service.db"), scopes=["submit"], name="t", owner="lab2")[1]
    with server.client(other) as c:  # another lab: the job is not there for it, not even for its own display
        r = c.post(f"/v1/jobs/{jid}/display", json={"display": "far-lab"})
        assert r.status_code == 404 and r.json()["detail"] == f"no job {jid!r}", r.text
        assert c.get("/v1/jobs", params={"display": "far-lab"}).json()["jobs"] == []


def test_a_deleted_job_leaves_no_send_behind(server, jobs):
    with server.client("submit") as c:
        r = c.post("/v1/jobs", json={"scene_id": jobs["scene_id"], **JOB, "display": "lab-2"})  # reuses a result
        jid = wait_state(c, r.json()["id"], ("succeeded", "failed", "cancelled"))["id"]
        assert c.post(f"/v1/jobs/{jid}/display", json={"display": "lab-1"}).status_code == 200
        assert _first(c, "lab-1") == jid
        assert c.post(f"/v1/jobs/{jid}/delete").status_code == 204
        assert _first(c, "lab-1") != jid
    from service.db import Database

    assert Database(server.data_dir / "service.db").query("SELECT * FROM display_sends WHERE job_id = ?", (jid,)) == []


def test_a_database_from_before_sends_lists_a_displays_jobs_in_submit_order(tmp_path):
    import sqlite3

    from service.db import Database

    path = tmp_path / "service.db"
    db = Database(path)
    for i, jid in enumerate(("ja", "jb", "jc")):
        db.insert_job({"id": jid, "state": "succeeded", "display": "lab-1" if jid != "jb" else "lab-9",
                       "scene_id": "s", "spec": {}, "cache_key": "k", "created_at": 100.0 + i})
    conn = sqlite3.connect(path)
    conn.execute("DROP TABLE display_sends")  # as an older release left it
    conn.commit()
    conn.close()
    db = Database(path)  # opening it again adds what this release needs
    assert [r["id"] for r in db.list_jobs(display="lab-1")] == ["jc", "ja"]
    assert [r["sent_at"] for r in db.list_jobs(display="lab-1")] == [102.0, 100.0]
    assert db.send_job("ja", "lab-1", token_id=None) is not None
    assert [r["id"] for r in db.list_jobs(display="lab-1")] == ["ja", "jc"]
    assert [r["id"] for r in db.list_jobs(display="lab-9")] == ["jb"]
