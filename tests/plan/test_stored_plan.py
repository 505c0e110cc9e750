"""A scene's stored plan read at other optics (holocore.plan.stored_plan) predicts what a fresh plan at those
optics finds: the WRP's distance and the farthest sub-hologram follow hologram depth, z_inf + f^2 / z_c."""

from __future__ import annotations

import pytest

from holocore.display.optics import OpticsConfig
from holocore.options import HologramOptions
from holocore.pipeline import RenderOptions, plan_scene
from holocore.plan import stored_plan
from holocore.scene.load import load_scene

# a long eyepiece so that the room's depth (hologram depth grows with f^2) is several times the WRP's margin
BASE = OpticsConfig(resolution_hw=(48, 64), frames=2, focal_length_mm=60.0)


@pytest.fixture(scope="module")
def scene(project_scene_bundles):
    return load_scene(project_scene_bundles.entry("veach-bidir"))


@pytest.mark.parametrize("changes", [{"focal_length_mm": 150.0}, {"focal_length_mm": 40.0, "z_inf_mm": 8.0},
                                     {"pitch_um": 6.0}])
def test_the_stored_plan_rescaled_matches_a_fresh_plan(scene, changes):
    stored = stored_plan.stored(plan_scene(scene, BASE, RenderOptions()), BASE)
    other = BASE.model_copy(update=changes)
    fresh = plan_scene(scene, other, RenderOptions()).analysis
    assert stored_plan.wrp_distance_m(stored, other) == pytest.approx(fresh.z_wrp_m, rel=0.02)
    # the farthest point's sub-hologram: the stored radius rescaled, against the one a fresh analysis finds
    assert stored_plan.subhologram_radius_px(stored, other) == pytest.approx(fresh.subhologram_radius_px, rel=0.05)
    depth = abs(fresh.z_wrp_m - fresh.z_far_holo_m)
    assert depth > 2 * fresh.margin_m or changes != {"focal_length_mm": 150.0}  # the depth, not the margin, counts
    assert stored_plan.scene_depth_m(stored, other) == pytest.approx(depth, rel=0.02)


def test_the_plan_in_words_follows_the_options_and_a_broken_plan_gives_none(scene):
    stored = stored_plan.stored(plan_scene(scene, BASE, RenderOptions()), BASE)
    words = stored_plan.plan_at_options(stored, BASE, HologramOptions(preset="fast", spp=8, wrp_planes=3))["summary"]
    assert any("3 wave recording planes" in w for w in words) and any("8" in w for w in words)
    direct = stored_plan.plan_at_options(stored, BASE, HologramOptions(method="direct"))["summary"]
    assert any("direct method" in w for w in direct)
    assert stored_plan.plan_at_options({"inventory": "no"}, BASE, HologramOptions()) is None
    assert stored_plan.wrp_distance_m({}, BASE) is None and stored_plan.scene_depth_m(None, BASE) is None


def test_a_stored_plan_raises_the_delta_cap_from_its_stored_bounces_and_an_older_plan_still_reads(scene):
    stored = stored_plan.stored(plan_scene(scene, BASE, RenderOptions()), BASE)
    # half the pre-pass rays need 12 delta bounces: the cap is raised to keep them, as a fresh plan does
    bounces = [50] + [0] * 11 + [50]
    deep = {**stored, "analysis": {**stored["analysis"], "delta_bounces": bounces}}
    words = stored_plan.plan_at_options(deep, BASE, HologramOptions(preset="fast"))["summary"]
    assert any(w.startswith("delta chains capped at 12 bounces (raised from") for w in words), words
    older = {**stored, "analysis": {k: v for k, v in stored["analysis"].items() if k != "delta_bounces"}}
    words = stored_plan.plan_at_options(older, BASE, HologramOptions(preset="fast"))["summary"]
    assert not any("raised from" in w for w in words)
