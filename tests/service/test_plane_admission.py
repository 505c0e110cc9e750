"""The service keeps and refuses the recording planes the CLI's render would (holocore.plan.memory_estimate's
admit_planes, on the planes placed from the scene's stored plan): at 0.25 µm pitch a deeper plane's grid grows
to terabytes, so ``auto`` is admitted with the planes that fit, and a count asked for that cannot fit is refused
with the CLI's own line."""

from __future__ import annotations

import pytest

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions, plan_scene
from holocore.plan import stored_plan
from tests.service.test_hostile_service import App
from tests.trace.scenes import camera, emitting_plane, scene, T

BUDGET_MB = 1024
OPTICS = {"resolution_hw": [16, 24], "wavelengths_nm": [640.0, 455.4], "frames": 2, "focal_length_mm": 20.0}


def _optics(pitch_um: float) -> OpticsConfig:
    return OpticsConfig(**{**OPTICS, "resolution_hw": tuple(OPTICS["resolution_hw"])}, pitch_um=pitch_um)


@pytest.fixture(scope="module")
def deep():
    """Two emitters far apart in depth (auto places a deeper plane) and its plan stored at 8 µm."""
    loaded = scene(sensor=camera(fov=10.0), near=emitting_plane(-0.3, size=0.01, x=-0.01),
                   far={**emitting_plane(-3.0, size=2.0), "to_world": T().translate([0, 0, -3.0]).scale(2.0)})
    return loaded, stored_plan.stored(plan_scene(loaded, _optics(8.0), RenderOptions()), _optics(8.0))


@pytest.fixture
def svc(tmp_path, monkeypatch):
    monkeypatch.setenv("HOLO_MEMORY_BUDGET_MB", str(BUDGET_MB))  # the render's budget, which the workers inherit
    return App(tmp_path / "data")


def _job(sid: str, wrp_planes) -> dict:
    return {"scene_id": sid, "optics": {**OPTICS, "pitch_um": 0.25}, "preset": "fast", "spp": 2,
            "encoder": "dpac", "wrp_planes": wrp_planes}


def test_auto_planes_at_a_quarter_micron_are_admitted_with_the_planes_that_fit(svc, deep):
    loaded, plan = deep
    cli = plan_scene(loaded, _optics(0.25), RenderOptions(preset="fast"), memory_budget_bytes=BUDGET_MB << 20)
    assert any("cut to" in s for s in cli.plan.summary)  # the CLI keeps fewer planes than it placed
    o = _optics(0.25)
    theta = max(o.theta_max(lam) for lam in o.wavelengths_m)
    widest = max(cli.planes.border_px(k, pitch_m=o.pitch_m, theta_max=theta) for k in range(cli.planes.count))
    sid = svc.scene("default", plan=plan)
    with svc.client(svc.token("submit")) as c:
        est = c.post("/v1/jobs/estimate", json=_job(sid, "auto"))
        assert est.status_code == 200, est.text
        assert est.json()["estimate"]["memory"]["plane_border_px"] == widest
        r = c.post("/v1/jobs", json=_job(sid, "auto"))
        assert r.status_code == 202, r.text


def test_a_plane_count_that_cannot_fit_is_refused_with_the_clis_line(svc, deep):
    loaded, plan = deep
    with pytest.raises(ValueError) as cli:
        plan_scene(loaded, _optics(0.25), RenderOptions(preset="fast", wrp_planes=2),
                   memory_budget_bytes=BUDGET_MB << 20)
    sid = svc.scene("default", plan=plan)
    with svc.client(svc.token("submit")) as c:
        for path in ("/v1/jobs/estimate", "/v1/jobs"):
            r = c.post(path, json=_job(sid, 2))
            assert r.status_code == 422, r.text
            assert r.json()["detail"] == str(cli.value)
            assert "need about" in str(cli.value) and "memory budget of 1024 MiB" in str(cli.value)


def test_the_scheduler_refuses_a_queued_plane_count_that_cannot_fit(svc, deep):
    from service.workers.admission import admit

    _, plan = deep
    sid = svc.scene("default", plan=plan)
    svc.db.update_scene(sid, plan_state="pending", plan=None)
    with svc.client(svc.token("submit")) as c:
        r = c.post("/v1/jobs", json=_job(sid, 2))
        assert r.status_code == 202, r.text  # no depths known yet: queued
    svc.db.update_scene(sid, plan_state="ready", plan=plan)
    got = admit(svc.db.get_job(r.json()["id"]), svc.db.get_scene(sid), svc.settings)
    assert got.need_bytes == -1 and "need about" in got.refusal and "memory budget" in got.refusal
