"""A job's quality flag over the API, in process (no workers, no renders: a finished job is a row and files
written here): the predicted viewer-faithful PSNR before an evaluation, the measured one after it, each against
the one level below which the estimate's own warning calls a hologram unrecognisable; none for a cancelled job."""

from __future__ import annotations

import json

import pytest

from holocore.plan.quality import UNRECOGNISABLE_DB
from tests.service.test_hostile_service import App, small


@pytest.fixture
def svc(tmp_path) -> App:
    return App(tmp_path / "data")


def _evaluated(svc: App, jid: str, viewer_db: float) -> None:
    stack = svc.finish(jid)
    row = svc.db.get_job(jid)
    (stack.parent / "evaluation").mkdir()
    (stack.parent / "evaluation" / "index.json").write_text(json.dumps(
        {"stack_sha256": row["stack_sha256"], "mean_psnr_db": viewer_db + 3, "viewer": {"mean_psnr_db": viewer_db}}))


def test_predicted_then_measured_quality_against_one_floor(svc):
    tok = svc.token("submit", owner="alice")
    sid = svc.scene("alice")
    with svc.client(tok) as c:
        low = c.post("/v1/jobs", json=small(sid, frames=1, evaluate=True)).json()
        q = low["quality"]
        assert q["source"] == "predicted" and q["floor_db"] == UNRECOGNISABLE_DB
        assert q["psnr_db"] == pytest.approx(low["estimate"]["quality"]["psnr_db"], abs=0.01)
        assert q["too_low"] == (q["psnr_db"] < UNRECOGNISABLE_DB)
        _evaluated(svc, low["id"], UNRECOGNISABLE_DB - 3)
        got = c.get(f"/v1/jobs/{low['id']}").json()["quality"]
        assert got == {"psnr_db": UNRECOGNISABLE_DB - 3, "source": "measured", "floor_db": UNRECOGNISABLE_DB,
                       "too_low": True}
        listed = {j["id"]: j for j in c.get("/v1/jobs").json()["jobs"]}
        assert listed[low["id"]]["quality"]["too_low"] is True
        good = c.post("/v1/jobs", json=small(sid, frames=2, evaluate=True)).json()
        _evaluated(svc, good["id"], UNRECOGNISABLE_DB + 10)
        assert c.get(f"/v1/jobs/{good['id']}").json()["quality"]["too_low"] is False
        gone = c.post("/v1/jobs", json=small(sid, frames=3)).json()
        c.delete(f"/v1/jobs/{gone['id']}")
        assert c.get(f"/v1/jobs/{gone['id']}").json()["quality"] is None
