"""Never NaN: the tracer's hard cases give finite fields (docs/design.md §4)."""

from __future__ import annotations

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions, render_loaded
from tests.trace.scenes import T, camera, emitting_plane, scene

OPTICS = OpticsConfig(resolution_hw=(24, 32), wavelengths_nm=(640.0, 455.4), frames=2, focal_length_mm=20.0)
OPTS = RenderOptions(preset="fast", spp=4)


def _render(loaded, optics=OPTICS, options=OPTS):
    res = render_loaded(loaded, optics, options)
    for name in ("slm_field", "wrp_field"):
        arr = getattr(res, name)
        assert arr.shape == (optics.frames, len(optics.wavelengths_nm), *optics.resolution_hw)
        assert np.isfinite(arr).all(), f"{name} has NaN/Inf"
    return res


def _diffuse(value=0.7):
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": value}}


def _light_above():
    return {"type": "rectangle", "to_world": T().translate([0, 3, -1]).rotate([1, 0, 0], 90).scale(2),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 5.0}}}


def test_grazing_floor():
    floor = {"type": "rectangle", "to_world": T().translate([0, -0.05, -2]).rotate([1, 0, 0], -90).scale(10),
             "bsdf": _diffuse()}
    res = _render(scene(floor=floor, light=_light_above()))
    assert np.abs(res.wrp_field).max() > 0


@pytest.mark.slow
def test_total_internal_reflection_in_glass_block():
    # Looking obliquely into a thick glass block: rays refract in and meet the side walls beyond the
    # critical angle.
    block = {"type": "cube", "to_world": T().translate([0, 0, -1.5]).rotate([0, 1, 0], 40).scale([0.3, 0.3, 0.6]),
             "bsdf": {"type": "dielectric", "int_ior": 1.8}}
    res = _render(scene(sensor=camera(fov=30), block=block, back=emitting_plane(-4.0)))
    assert res.meta["stats"]["delta_paths"] > 0


@pytest.mark.slow
def test_two_facing_mirrors_hit_the_cap():
    # A mirror hall: one mirror ahead, one behind the eye, facing each other; rays bounce until the cap.
    ahead = {"type": "rectangle", "to_world": T().translate([0, 0, -1]).scale(5), "bsdf": {"type": "conductor"}}
    behind = {"type": "rectangle", "to_world": T().translate([0, 0, 0.5]).rotate([0, 1, 0], 180).scale(5),
              "bsdf": {"type": "conductor"}}
    res = _render(scene(ahead=ahead, behind=behind, light=_light_above()))
    assert res.meta["stats"]["capped"] > 0
    assert res.meta["plan"]["max_delta"] >= 4
    assert np.abs(res.wrp_field).max() == 0  # nothing but mirrors: no image point survives


@pytest.mark.slow
def test_camera_inside_glass():
    ball = {"type": "sphere", "center": [0, 0, 0], "radius": 0.5, "bsdf": {"type": "dielectric"}}
    _render(scene(ball=ball, back=emitting_plane(-3.0)))


@pytest.mark.slow
def test_rays_escape_and_emitter_seen_directly():
    small = emitting_plane(-2.0, size=0.005)
    res = _render(scene(sensor=camera(fov=30), small=small))
    assert res.meta["stats"]["escaped"] > 0
    assert np.abs(res.wrp_field).max() > 0


def test_black_scene_gives_zero_field():
    wall = {"type": "rectangle", "to_world": T().translate([0, 0, -2]).scale(5), "bsdf": _diffuse()}
    res = _render(scene(wall=wall))
    assert np.abs(res.wrp_field).max() == 0
    assert "black" in " ".join(res.meta["plan"]["summary"])


@pytest.mark.slow
def test_surface_close_to_the_wrp_margin():
    # A surface 5 cm from the eye maps far from z_inf; the WRP must still lie in front of it.
    near = emitting_plane(-0.05, size=0.5)
    res = _render(scene(near=near), OpticsConfig(resolution_hw=(16, 16), wavelengths_nm=(516.5,), frames=1,
                                                  focal_length_mm=20.0))
    m = res.meta
    assert m["z_wrp_m"] > m["analysis"]["z_near_holo_m"]


@pytest.mark.slow
def test_point_like_emitter_between_the_prepass_rays_keeps_the_wrp_in_front():
    """A 0.1 mm glowing square 0.5 m away falls between the analysis grid's rays (0.16 mm apart there). Without
    its bounding box the WRP lands behind it: the rays then start beyond the dot and its light is lost."""
    import math

    W, H, P, F = 64, 48, 8e-6, 0.025
    fov = 2 * math.degrees(math.atan(W * P / (2 * F)))
    dot = {"type": "rectangle", "to_world": T().translate([0.0021, 0.0011, -0.5]).scale(0.00005),
           "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}}
    optics = OpticsConfig(resolution_hw=(H, W), wavelengths_nm=(516.5,), frames=1, focal_length_mm=F * 1e3,
                          z_inf_mm=4.0)
    res = _render(scene(sensor=camera(fov=fov), dot=dot), optics, RenderOptions(preset="balanced", spp=512))
    z_dot = 0.004 + F * F / 0.5
    assert res.meta["z_wrp_m"] > z_dot
    assert res.meta["stats"]["valid"] > 50
    assert np.abs(res.wrp_field).max() > 0


@pytest.mark.slow
def test_sub_wavelength_pitch_hemisphere():
    optics = OpticsConfig(resolution_hw=(16, 16), wavelengths_nm=(640.0,), pitch_um=0.25, frames=1,
                          focal_length_mm=20.0)
    _render(scene(back=emitting_plane(-1.0)), optics)


@pytest.mark.slow
def test_scene_that_cannot_fit_is_refused():
    near = emitting_plane(-0.001, size=0.5)
    optics = OpticsConfig(resolution_hw=(16, 16), wavelengths_nm=(516.5,), frames=1, focal_length_mm=50.0,
                          max_wrp_distance_mm=10.0)
    with pytest.raises(ValueError, match="max_wrp_distance_mm"):
        render_loaded(scene(near=near), optics, OPTS)
