"""Sweeps over the API, in process (no workers, no renders: a finished job is a row and files written here): one
job per value through the submission of POST /v1/jobs, a value that would be refused refuses the whole sweep
before any job exists (and one refused at its own submit takes the jobs made before it), the predicted and
measured quality and time per value, cancelling a sweep, and another owner's sweep is not there."""

from __future__ import annotations

import json
import time

import pytest

from tests.service.test_hostile_service import App, small


@pytest.fixture
def svc(tmp_path) -> App:
    return App(tmp_path / "data")


def _sweep(scene_id: str, option: str = "frames", values=(1, 2, 4), **job) -> dict:
    return {"job": small(scene_id, **job), "option": option, "values": list(values)}


def test_a_frames_sweep_makes_one_job_per_value_with_its_estimate(svc):
    tok = svc.token("submit", owner="alice")
    sid = svc.scene("alice")
    with svc.client(tok) as c:
        r = c.post("/v1/sweeps", json=_sweep(sid, name="lab"))
        assert r.status_code == 202, r.text
        made = r.json()
        assert made["option"] == "frames" and made["values"] == [1, 2, 4] and len(made["jobs"]) == 3
        assert r.headers["Location"] == f"/v1/sweeps/{made['id']}"
        got = c.get(f"/v1/sweeps/{made['id']}").json()
        assert [j["id"] for j in got["jobs"]] == made["jobs"] and [j["value"] for j in got["jobs"]] == [1, 2, 4]
        for job, frames in zip(got["jobs"], (1, 2, 4)):
            assert job["state"] == "queued" and job["name"] == f"lab · frames={frames}"
            assert job["estimate_s"] > 0 and isinstance(job["predicted_psnr_db"], float)
            assert job["run_s"] is None and job["measured_psnr_db"] is None
            assert c.get(f"/v1/jobs/{job['id']}").json()["options"]["optics"]["frames"] == frames
        assert [s["id"] for s in c.get("/v1/sweeps").json()["sweeps"]] == [made["id"]]
        later = c.post("/v1/sweeps", json=_sweep(sid, option="preset", values=("fast", "balanced"))).json()
        assert [s["id"] for s in c.get("/v1/sweeps?limit=1").json()["sweeps"]] == [later["id"]]


def test_a_refused_value_refuses_the_sweep_before_any_job(svc):
    tok = svc.token("submit", owner="alice")
    sid = svc.scene("alice")
    with svc.client(tok) as c:
        for body, words in ((_sweep(sid, values=(1, 2, 100000)), "frames=100000"),
                            (_sweep(sid, option="encoder", values=("dpac", "nope")), "encoder=nope"),
                            (_sweep(sid, values=(2, 2)), "frames=2 is given twice")):
            r = c.post("/v1/sweeps", json=body)
            assert r.status_code == 422, r.text
            assert words in r.json()["detail"]
        assert c.post("/v1/sweeps", json=_sweep(sid, values=(1,))).status_code == 422  # 2 to 12 values
        assert c.post("/v1/sweeps", json=_sweep(sid, option="scene_id", values=("a", "b"))).status_code == 422
        assert c.get("/v1/jobs").json()["jobs"] == [] and c.get("/v1/sweeps").json()["sweeps"] == []


def test_another_owners_sweep_is_not_there(svc):
    alice, bob = svc.token("submit", owner="alice"), svc.token("submit", owner="bob")
    sid = svc.scene("alice")
    with svc.client(alice) as c:
        made = c.post("/v1/sweeps", json=_sweep(sid, option="spp", values=(2, 4))).json()
    with svc.client(bob) as c:
        assert c.get(f"/v1/sweeps/{made['id']}").status_code == 404
        assert c.delete(f"/v1/sweeps/{made['id']}").status_code == 404
        assert c.get("/v1/sweeps").json()["sweeps"] == []
        # nor may bob sweep over alice's scene
        assert c.post("/v1/sweeps", json=_sweep(sid)).status_code == 422
    with svc.client(alice) as c:
        assert all(j["state"] == "queued" for j in c.get(f"/v1/sweeps/{made['id']}").json()["jobs"])


def test_cancel_a_sweep_and_read_its_measured_time_and_quality(svc):
    tok = svc.token("submit", owner="alice")
    sid = svc.scene("alice")
    with svc.client(tok) as c:
        made = c.post("/v1/sweeps", json=_sweep(sid, evaluate=True)).json()
        first = made["jobs"][0]
        stack = svc.finish(first)
        row = svc.db.get_job(first)
        svc.db.update_job(first, timings={"run_s": 12.5}, started_at=time.time() - 13)
        (stack.parent / "evaluation").mkdir()
        (stack.parent / "evaluation" / "index.json").write_text(json.dumps(
            {"stack_sha256": row["stack_sha256"], "mean_psnr_db": 20.5, "viewer": {"mean_psnr_db": 18.25}}))
        r = c.delete(f"/v1/sweeps/{made['id']}")
        assert r.status_code == 202, r.text
        jobs = r.json()["jobs"]
        assert [j["state"] for j in jobs] == ["succeeded", "cancelled", "cancelled"]
        assert jobs[0]["run_s"] == 12.5 and jobs[0]["measured_psnr_db"] == 18.25
        assert jobs[0]["measured_kind"] == "viewer"
        assert c.delete(f"/v1/sweeps/{made['id']}").status_code == 202  # nothing left to cancel: the same answer
        # a deleted job leaves its sweep
        assert c.post(f"/v1/jobs/{made['jobs'][1]}/delete").status_code == 204
        assert [j["value"] for j in c.get(f"/v1/sweeps/{made['id']}").json()["jobs"]] == [1, 4]


def test_a_value_refused_at_its_submit_leaves_no_job_of_the_sweep(svc, monkeypatch):
    """A limit only the sweep's earlier jobs reach (what the owner stores) refuses a later value at its submit:
    the jobs made before it go too."""
    from service.api import submission
    from service.api.problems import ApiError

    real, calls = submission.submit_job, []

    def third_refused(ctx, req, principal, key=None):
        calls.append(req.frames)
        if len(calls) == 3:
            raise ApiError(403, "past what one owner may store")
        return real(ctx, req, principal, key)

    monkeypatch.setattr(submission, "submit_job", third_refused)
    tok = svc.token("submit", owner="alice")
    sid = svc.scene("alice")
    with svc.client(tok) as c:
        r = c.post("/v1/sweeps", json=_sweep(sid))
        assert r.status_code == 403 and "frames=4 is refused: past what one owner may store" in r.json()["detail"]
        assert c.get("/v1/jobs").json()["jobs"] == [] and c.get("/v1/sweeps").json()["sweeps"] == []


def test_a_job_names_the_sweep_that_made_it(svc):
    tok = svc.token("submit", owner="alice")
    sid = svc.scene("alice")
    with svc.client(tok) as c:
        made = c.post("/v1/sweeps", json=_sweep(sid, values=(1, 2))).json()
        for jid in made["jobs"]:
            assert c.get(f"/v1/jobs/{jid}").json()["sweep_id"] == made["id"]
        alone = c.post("/v1/jobs", json=small(sid, frames=3)).json()
        assert c.get(f"/v1/jobs/{alone['id']}").json()["sweep_id"] is None
