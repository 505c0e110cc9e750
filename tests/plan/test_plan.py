"""EffectPlan on the scene bundles (the project's stand-ins, and ../shared's third-party scenes in the cases
whose id says shared), and planned vs forced renders (docs/design.md §8)."""

from __future__ import annotations

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions, plan_scene, render_loaded
from holocore.scene.load import load_scene
from tests.project_scenes import SCENE_SOURCES
from tests.trace.scenes import T, camera, scene

OPT = OpticsConfig(resolution_hw=(32, 32), frames=2, fit_camera_fov=True)  # f from the scene camera: the whole view


@pytest.fixture(scope="module", params=SCENE_SOURCES)
def plans(request, bundles_of):
    bundles = bundles_of(request.param)
    out = {}
    for key, name in {"cbox": "cbox-mirror-glass", "bidir": "veach-bidir", "mis": "veach-mis"}.items():
        out[key] = plan_scene(load_scene(bundles.entry(name)), OPT, RenderOptions(preset="balanced"))
    return out


@pytest.mark.slow
def test_cbox_plan_has_mirror_and_glass(plans):
    pl = plans["cbox"]
    inv, plan, ana = pl.inventory, pl.plan, pl.analysis
    assert inv.mirrors == ["mirrorsphere"] and inv.dielectrics == ["glasssphere"]
    assert plan.coherent_delta and plan.max_delta >= 4
    assert not plan.view_dependent and plan.cache_exact
    assert ana.max_delta_seen >= 2  # the pre-pass went through the glass sphere
    text = " ".join(plan.summary)
    assert "mirror reflection" in text and "refraction: glasssphere" in text
    assert ana.z_wrp_m > ana.z_near_holo_m > ana.z_far_holo_m > OPT.z_inf_m


@pytest.mark.slow
def test_veach_bidir_plan_is_glossy_with_glass(plans):
    pl = plans["bidir"]
    assert pl.inventory.dielectrics == ["Glass"]
    assert pl.plan.view_dependent and pl.plan.coherent_delta
    assert any("glossy" in s for s in pl.plan.summary)


@pytest.mark.slow
def test_veach_mis_plan_has_no_coherent_loop(plans):
    plan = plans["mis"].plan
    assert not plan.coherent_delta and plan.max_delta == 0
    assert plan.view_dependent  # rough plastic plates
    assert any("first hit is the image point" in s for s in plan.summary)


@pytest.mark.parametrize("source", SCENE_SOURCES)
def test_forcing_turns_everything_on(bundles_of, source):
    pl = plan_scene(load_scene(bundles_of(source).entry("veach-mis")),
                    OpticsConfig(resolution_hw=(16, 16), focal_length_mm=20.0, frames=1),
                    RenderOptions(preset="fast", force_all_effects=True))
    p = pl.plan
    assert p.forced and p.coherent_delta and p.max_delta == 16 and p.random_phase and not p.use_cache


def _diffuse_room():
    wall = {"type": "rectangle", "to_world": T().translate([0, 0, -1.0]).scale(3),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.5, 0.3]}}}
    light = {"type": "sphere", "center": [0.0, 0.6, -0.3], "radius": 0.1,
             "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 20.0}}}
    return scene(sensor=camera(fov=20), wall=wall, light=light)


@pytest.mark.slow
def test_diffuse_scene_planned_equals_forced_and_traces_less():
    optics = OpticsConfig(resolution_hw=(48, 48), wavelengths_nm=(640.0,), focal_length_mm=20.0, frames=4)
    planned = render_loaded(_diffuse_room(), optics, RenderOptions(preset="fast", spp=16))
    forced = render_loaded(_diffuse_room(), optics, RenderOptions(preset="fast", spp=16, force_all_effects=True))
    assert planned.meta["plan"]["use_cache"] and not forced.meta["plan"]["use_cache"]
    ip = (np.abs(planned.wrp_field) ** 2).mean()
    jf = (np.abs(forced.wrp_field) ** 2).mean()
    assert abs(ip / jf - 1) < 0.15, (ip, jf)
    sp, sf = planned.meta["stats"], forced.meta["stats"]
    assert sp["path_samples"] < 0.5 * sf["path_samples"], (sp["path_samples"], sf["path_samples"])
