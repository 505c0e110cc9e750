"""Every estimate says what quality its options buy (service/quality.py), and a quality target has the service
choose frames, rays and encoder iterations (``quality_db``): over the API, as `holo submit` and the page use it."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from service.cost import estimate_cost
from service.models import JobRequest
from tests.service.helpers import planned_scene, zip_dir

PLAN = {"analysis": {"subhologram_radius_px": 10.0}, "inventory": {"primitives": 12}, "picture": {"image_q": 0.2}}
OPTICS = {"resolution_hw": [135, 240]}


def _q(**kw) -> dict:
    req = JobRequest(scene_id="s" * 12, optics=OPTICS, **kw)
    return estimate_cost(req, scene_plan=PLAN)["quality"]


def test_the_estimate_predicts_more_db_for_more_frames_and_warns_of_speckle_and_noise():
    one, eight, many = _q(frames=1, spp=16), _q(frames=8, spp=64), _q(frames=32, spp=64)
    assert one["psnr_db"] < eight["psnr_db"] < many["psnr_db"]
    assert any("below 12 dB" in w for w in one["warnings"]), one
    assert one["uncertainty_db"] > 0 and set(one["parts_db"]) == {"speckle", "noise", "encoder"}
    assert "expected about" in one["words"]
    # the alternatives are the estimate's own times: a mix that gains 3 dB or more, quicker ones at par
    assert any("(+" in line for line in one["instead"]), one["instead"]


def test_the_picture_of_a_brighter_scene_predicts_less():
    dim = estimate_cost(JobRequest(scene_id="s" * 12, optics=OPTICS, frames=8),
                        scene_plan={**PLAN, "picture": {"image_q": 0.05}})["quality"]
    bright = estimate_cost(JobRequest(scene_id="s" * 12, optics=OPTICS, frames=8),
                           scene_plan={**PLAN, "picture": {"image_q": 0.5}})["quality"]
    assert dim["psnr_db"] > bright["psnr_db"] + 3


@pytest.mark.parametrize("given", [{"spp": 16}, {"iterations": 40}, {"render_time_limit_s": 5.0}])
def test_a_target_with_the_options_it_chooses_is_refused(given):
    with pytest.raises(ValidationError, match="quality_db chooses"):
        JobRequest(scene_id="s" * 12, quality_db=15.0, **given)
    with pytest.raises(ValidationError):
        JobRequest(scene_id="s" * 12, quality_db=80.0)
    JobRequest(scene_id="s" * 12, quality_db=15.0, frames=8)  # frames: the most the choice may take


@pytest.mark.slow  # a demo scene planned by a server for one quality target over the API; the module's other tests hold the quality model
def test_a_quality_target_over_the_api(server):
    from holocore.scene.demo import write_demo_scene

    tmp = server.data_dir.parent / "quality-scene"
    write_demo_scene(tmp)
    scene = planned_scene(server, zip_dir(tmp))
    assert scene["plan_state"] == "ready", scene.get("plan_error")
    assert 0 < scene["plan"]["picture"]["image_q"] <= 1  # the planner's picture gives the image statistic
    body = {"scene_id": scene["id"], "optics": OPTICS, "preset": "fast"}
    with server.client("submit") as c:
        low = c.post("/v1/jobs/estimate", json={**body, "quality_db": 12.0})
        high = c.post("/v1/jobs/estimate", json={**body, "quality_db": 18.0})
        assert low.status_code == 200 and high.status_code == 200, (low.text, high.text)
        lo, hi = low.json(), high.json()
        assert lo["estimate"]["quality"]["target_db"] == 12.0
        assert lo["estimate"]["quality"]["psnr_db"] >= 12.0 - 0.05, lo["estimate"]["quality"]
        # a higher target costs more predicted time, never less
        assert hi["estimate"]["seconds"] >= lo["estimate"]["seconds"]
        refused = c.post("/v1/jobs/estimate", json={**body, "quality_db": 12.0, "spp": 4})
        assert refused.status_code == 422 and "quality_db chooses" in refused.text
        capped = c.post("/v1/jobs/estimate", json={**body, "quality_db": 40.0, "frames": 4})
        assert capped.status_code == 200 and capped.json()["options"]["frames"] <= 4  # the display's frames
        assert any("beyond" in w for w in capped.json()["warnings"])  # 40 dB is out of reach: it says so


def test_the_estimate_says_the_load_it_assumes_and_sizes_the_encoder_by_the_wrp_distance(monkeypatch):
    """``seconds`` is an idle machine's; ``seconds_at_load`` multiplies it by the slowdown of the load other work
    makes (the service's own running jobs left out, a queued job runs after them); the encoder's share grows
    with the WRP's distance from the SLM (its padded grid), which the scene's plan gives."""
    import os
    import time

    from holocore.plan import estimate

    req = JobRequest(scene_id="s" * 12, optics=OPTICS, frames=8, spp=16)
    monkeypatch.setattr(estimate, "_SAMPLED", {"at": time.monotonic() + 3600, "value": 8.0})  # 8 runnable now
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    busy = estimate_cost(req, scene_plan=PLAN)
    assert busy["load"]["slowdown"] == pytest.approx(5.0)
    assert busy["seconds_at_load"] == pytest.approx(5.0 * busy["seconds"], abs=0.1)
    mine = estimate_cost(req, scene_plan=PLAN, busy_threads=4.0)  # two running jobs of this service, 2 cores
    assert mine["load"]["others"] == pytest.approx(4.0) and mine["load"]["slowdown"] == pytest.approx(3.0)
    plan = {**PLAN, "focal_length_m": 0.05, "optics": {"z_inf_mm": 4.0},
            "analysis": {**PLAN["analysis"], "z_wrp_m": 4.5e-3}}
    near, far = (estimate_cost(req.model_copy(update={"optics": req.optics.model_copy(update={"z_inf_mm": z})}),
                               scene_plan=plan) for z in (4.0, 80.0))
    assert far["encode_s"] > 2.5 * near["encode_s"] > 0
