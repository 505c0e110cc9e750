"""Hostile corpus, the service's side: limits, lockouts, bodies, cross-tenant facts, integrity, fairness and
deployment defaults that a hostile client or job could walk past. Most tests drive the app in process (no
workers, no renders: scenes and finished jobs are rows and files written here); the ones about sockets (slow
bodies, unread bodies) start a real `holo serve`."""

from __future__ import annotations

import hashlib
import os
import socket
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Optional

import pytest
import warnings

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

from service.auth import create_token
from service.settings import JobLimits, ServiceSettings

SCENE_SHA = "ab" * 32


class App:
    """The service app in this process (no scheduler, no planner) with a token maker and row writers."""

    def __init__(self, data_dir: Path, **settings) -> None:
        from service.api.app import create_app

        self.settings = ServiceSettings(data_dir=data_dir, **settings)
        self.app = create_app(self.settings, start_workers=False)
        self.ctx = self.app.state.ctx
        self.db = self.ctx.db

    def token(self, *scopes: str, owner: str = "default") -> str:
        return create_token(self.db, scopes=scopes or ("submit",), owner=owner, name=f"{owner}-test")[1]

    @contextmanager
    def client(self, token: Optional[str] = None, *, address: str = "10.0.0.1") -> Iterator[TestClient]:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        with TestClient(self.app, headers=headers, client=(address, 40000), raise_server_exceptions=False) as c:
            yield c

    def scene(self, owner: str, *, scene_id: str = "stest", plan: Optional[dict] = None) -> str:
        """A scene row (ready plan by default) owned by ``owner``, with an empty bundle folder."""
        (self.settings.scenes_dir / scene_id / "bundle").mkdir(parents=True, exist_ok=True)
        self.db.insert_scene({"id": scene_id, "sha256": SCENE_SHA, "entry": "scene.xml", "report": {},
                              "plan_state": "ready", "plan": plan or {"summary": []}, "created_at": time.time()})
        self.db.add_scene_owner(scene_id, owner)
        return scene_id

    def finish(self, job_id: str, data: bytes = b"stack bytes") -> Path:
        """Mark a queued job succeeded with a stack file of ``data`` (what a worker would leave)."""
        row = self.db.get_job(job_id)
        d = Path(row["artifact_dir"])
        d.mkdir(parents=True, exist_ok=True)
        (d / "stack.npz").write_bytes(data)
        sha = hashlib.sha256(data).hexdigest()
        self.db.update_job(job_id, state="succeeded", finished_at=time.time(), stack_sha256=sha,
                           stack_bytes=len(data), artifacts={"stack.npz": {"sha256": sha, "bytes": len(data)}})
        return d / "stack.npz"


@pytest.fixture
def svc(tmp_path) -> App:
    return App(tmp_path / "data")


def small(scene_id: str, **over) -> dict:
    return {"scene_id": scene_id, "optics": {"resolution_hw": [64, 64]}, "preset": "fast", "spp": 4,
            "encoder": "dpac", **over}


# ---- the preset's most rays are counted and clamped ------------------------------------------------------------

def test_a_preset_without_spp_is_admitted_by_its_most_rays_and_clamped_to_max_spp(svc):
    """``preset: reference`` without spp may choose up to 8192 rays per pixel from the scene depth; admission
    counted a typical 1024, so 2304x4096x3 (2.9e10 typical, 2.3e11 at most) was admitted past the 4e10 budget,
    and the render could trace 8192 per pixel past max_spp 4096."""
    from holocore.plan.effects import choose_spp
    from service.jobfiles import JobFile
    from service.workers.driver import render_args

    sid = svc.scene("default")
    with svc.client(svc.token("submit")) as c:
        big = {"scene_id": sid, "optics": {"resolution_hw": [2304, 4096]}, "preset": "reference",
               "encoder": "dpac", "frames": 1}
        for path in ("/v1/jobs", "/v1/jobs/estimate"):
            r = c.post(path, json=big)
            assert r.status_code == 422, (path, r.status_code, r.text)
            assert "rays" in r.json()["detail"] and "4096 rays per pixel" in r.json()["detail"], r.text
        r = c.post("/v1/jobs", json={**big, "optics": {"resolution_hw": [256, 256]}})
        assert r.status_code == 202, r.text
        job = r.json()
    assert job["options"]["max_spp"] == 4096  # the render is told the clamp
    assert job["estimate"]["spp_assumed"] is None or job["estimate"]["spp_assumed"] <= 4096
    spec = JobFile(**{k: v for k, v in job["options"].items() if k != "optics"}, job_id=job["id"],
                   scene_path="/x/scene.xml")
    args = render_args(spec, "p.jsonl")
    assert args[args.index("--max-spp") + 1] == "4096" and "--spp" not in args
    # the renderer's choice for a deep scene: 8192 unclamped, 4096 with the service's cap
    assert choose_spp("reference", 1e4, 0.05) == 8192 and choose_spp("reference", 1e4, 0.05, 4096) == 4096
    from holocore.plan.effects import SceneInventory, make_plan

    plan = make_plan(SceneInventory(shapes=1, primitives=1), preset="reference", frames=1, n_colors=1, subhologram_radius_px=1e4,
                     max_spp=4096)
    assert plan.spp == 4096
    # the fast preset's own bound is below max_spp: nothing to clamp, the spec and cache key are as before
    with svc.client(svc.token("submit")) as c:
        fast = c.post("/v1/jobs", json=small(sid, spp=None)).json()
    assert fast["options"]["max_spp"] is None


def test_the_render_cli_takes_the_clamp():
    from holocore.pipeline import RenderOptions

    assert RenderOptions(preset="reference", max_spp=4096).max_spp == 4096
    with pytest.raises(ValueError, match="max_spp must be in"):
        RenderOptions(max_spp=0)
