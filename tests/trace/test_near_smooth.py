"""Near-smooth surfaces (holocore.trace.near_smooth, docs/physics.md "Near-smooth surfaces"): a rough conductor or
dielectric of small alpha continues the coherent chain through sampled micro-normals, so it shows a blurred image
at the apparent depth of what it reflects or refracts, and the eye's best focus on a highlight seen in it is where
Mitsuba's thin-lens render puts it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.trace.optics_probe import fov_deg
from tests.trace.scenes import T, camera

H, W, P_M, F_M, ZI_M = 96, 128, 8e-6, 0.05, 4e-3


def _mirror_and_card(alpha: float, kind: str = "roughconductor"):
    """A rough mirror 1 m away turned 45 degrees, and a glowing card 1 m to its side: the card's image is 2 m
    away along the axis."""
    from holocore.runtime.mitsuba_env import mitsuba

    return mitsuba().load_dict({
        "type": "scene", "sensor": camera(),
        "mirror": {
            "type": "rectangle", "bsdf": {"type": kind, "alpha": alpha},
            "to_world": T().translate([0, 0, -1]).rotate([0, 1, 0], 45).scale(0.5)},
        "card": {"type": "rectangle", "to_world": T().translate([1, 0, -1]).rotate([0, 1, 0], -90).scale(0.3),
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0}},
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}}})


def _trace(scene, n: int = 20000):
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.trace.kernel import trace_wave_paths
    from holocore.trace.reference_chain import aligned, trace_chain

    mi = mitsuba()
    rng = np.random.default_rng(0)
    v = np.stack([(rng.random(n) * 2 - 1) * 0.02, (rng.random(n) * 2 - 1) * 0.02, -np.ones(n)], axis=1)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(1, n)
    wp = trace_wave_paths(scene, mi.Point3d(*[mi.Float64(aligned(np.zeros(n), np.float64)) for _ in range(3)]),
                          mi.Vector3d(*[mi.Float64(aligned(v[:, i], np.float64)) for i in range(3)]), sampler,
                          max_delta=4, max_depth=4)
    ref = trace_chain(scene, np.zeros((n, 3)), v, max_delta=4, amp_spp=1,
                      integrator=mi.load_dict({"type": "path", "max_depth": 4}), seed=3)
    return (np.asarray(wp.valid).astype(bool), np.asarray(wp.d), np.asarray(wp.n_delta),
            np.asarray(wp.radiance[0]), ref)


def test_a_near_smooth_mirror_shows_a_blurred_image_at_its_apparent_depth():
    spreads = []
    for alpha in (0.001, 0.01, 0.05):
        ok, d, nd, L, ref = _trace(_mirror_and_card(alpha))
        through = ok & (nd == 1)
        assert through.mean() > 0.99  # every ray goes on through the mirror to the card
        assert np.median(d[through]) == pytest.approx(2.0, abs=2e-3)  # 1 m to the mirror, 1 m to the card
        assert np.mean(L) == pytest.approx(1.0, abs=2e-3)  # a white conductor loses no light
        # the reference chain (the pre-pass) agrees
        r_ok = ref.valid & (ref.n_delta == 1)
        assert r_ok.mean() > 0.99 and np.median(ref.d[r_ok]) == pytest.approx(np.median(d[through]), abs=2e-3)
        lo, hi = np.percentile(d[through], [5, 95])
        spreads.append(hi - lo)
    assert spreads[0] < spreads[1] < spreads[2]  # the image blurs in depth as the lobe widens
    # a rough surface beyond the near-smooth limit is the image point itself, as before
    ok, d, nd, _L, _ref = _trace(_mirror_and_card(0.2))
    assert ok.mean() > 0.99 and (nd[ok] == 0).all() and np.median(d[ok]) == pytest.approx(1.0, abs=0.01)


def _highlight_scene(bsdf: dict, *, behind_glass: bool):
    """A small glowing ball 1.5 m away, seen in a plate 0.5 m away turned 12 degrees (mirror) or through a 5 mm
    plate facing the eye (glass)."""
    from holocore.runtime.mitsuba_env import mitsuba

    if behind_glass:
        plate = {"type": "cube", "bsdf": bsdf, "to_world": T().translate([0, 0, -0.5]).scale([0.05, 0.05, 0.0025])}
        light_at = [0.0, 0.0, -1.5]
    else:
        plate = {"type": "rectangle", "bsdf": bsdf,
                 "to_world": T().translate([0, 0, -0.5]).rotate([0, 1, 0], 12.0).scale(0.05)}
        ang = math.radians(24.0)
        light_at = [math.sin(ang), 0.0, -0.5 + math.cos(ang)]
    return mitsuba().load_dict({
        "type": "scene", "sensor": camera(fov=fov_deg(W, P_M, F_M)), "plate": plate,
        "light": {"type": "sphere", "center": light_at, "radius": 0.0015,
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 50.0}}}})


def _r50(img: np.ndarray) -> float:
    """Radius (px) holding half the light of the brightest blob (a window of +-24 px around it)."""
    from holocore.evaluate.metrics import brightest_blob

    return brightest_blob(img)[0]


def _best_focus(view, depths) -> float:
    return float(depths[int(np.argmin([_r50(view(z)) for z in depths]))])


@pytest.mark.slow
@pytest.mark.parametrize("case", ["mirror", "glass"])
def test_a_highlight_in_near_smooth_metal_or_glass_focuses_where_mitsubas_does(case):
    from holocore.display.optics import OpticsConfig
    from holocore.evaluate.groundtruth import GroundTruth
    from holocore.evaluate.scoring import eye_view
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.load import from_mitsuba_scene

    bsdf = ({"type": "roughconductor", "alpha": 0.001} if case == "mirror"
            else {"type": "roughdielectric", "alpha": 0.001, "int_ior": 1.5})
    loaded = from_mitsuba_scene(_highlight_scene(bsdf, behind_glass=case == "glass"))
    opt = OpticsConfig(resolution_hw=(H, W), pitch_um=P_M * 1e6, frames=8, focal_length_mm=F_M * 1e3,
                       z_inf_mm=ZI_M * 1e3, seed=1)
    res = render_loaded(loaded, opt, RenderOptions(preset="fast", spp=256))
    assert any("near-smooth" in s for s in res.meta["plan"]["summary"])
    gt = GroundTruth(loaded, res.meta, shape_hw=(H, W), spp=256)
    z_plate, z_light = ZI_M + F_M ** 2 / 0.5, ZI_M + F_M ** 2 / 1.5
    depths = np.linspace(z_light - 1.5e-3, z_plate + 0.5e-3, 9)
    ours = _best_focus(lambda z: eye_view(res.slm_field, res.meta, focus_z_m=z, pupil_diameter_m=2e-3), depths)
    truth = _best_focus(lambda z: gt.channels(focus_z_m=z, pupil_diameter_m=2e-3), depths)
    step = depths[1] - depths[0]
    # the highlight is sharpest at the ball's (apparent) depth in both, not on the plate 3.3 mm nearer the eye
    assert abs(ours - truth) <= 1.5 * step, (ours, truth)
    assert abs(ours - z_light) < abs(ours - z_plate)
