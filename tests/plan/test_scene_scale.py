"""The scene scale (docs/design.md §3, "Scene scale"): a scene rendered at scale s is the scene built s times as
large about its camera, rendered at scale 1, in its plan, its hologram and its ground truth; and the plan says how
many depths of field the light spans and which scale would bring it to where an eye focuses."""

from __future__ import annotations

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.evaluate.groundtruth import GroundTruth
from holocore.pipeline import RenderOptions, plan_scene, render_loaded
from holocore.plan.focus_depth import NEAR_TARGET_M, focus_depth
from holocore.runtime.mitsuba_env import mitsuba
from holocore.scene.load import from_mitsuba_scene
from tests.trace.scenes import T, camera

pytestmark = pytest.mark.slow

FAR_M = (20.0, 60.0)  # a card and a wall, metres from the camera: a fraction of one depth of field for the eye
F_M = 0.05  # the paper's eyepiece: 0.44 degrees on this small SLM, so the scene below is 10 cm across
OPT = OpticsConfig(resolution_hw=(32, 48), frames=1, seed=3, focal_length_mm=F_M * 1e3)


def _world(k: float):
    """A glowing card at 20 k m (the view's right part), a wall at 60 k m, and a tilted mirror at 30 k m (the
    view's left part) that shows a glowing panel behind the camera: all k times their size about the camera."""
    mi = mitsuba()

    def glow(z, size, x, rgb, turn=0.0):
        return {"type": "rectangle", "to_world": T().translate([x * k, 0, -z * k]).rotate([0, 1, 0], turn)
                .scale(size * k), "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
                "emitter": {"type": "area", "radiance": {"type": "rgb", "value": rgb}}}

    mirror = {"type": "rectangle", "bsdf": {"type": "conductor"},
              "to_world": T().translate([-0.08 * k, 0, -30.0 * k]).rotate([0, 1, 0], 20.0).scale(0.045 * k)}
    return from_mitsuba_scene(mi.load_dict({
        "type": "scene", "sensor": camera(fov=10.0),
        "card": glow(FAR_M[0], 0.04, 0.05, [1.0, 0.6, 0.3]), "wall": glow(FAR_M[1], 20.0, 0.0, [0.2, 0.4, 0.9]),
        "back": glow(-10.0, 40.0, 0.0, [0.3, 0.9, 0.3], turn=180.0), "mirror": mirror}))


@pytest.fixture(scope="module")
def scaled_pair():
    """(the scene at scale 1 rendered with scene_scale 0.025, the scene built 0.025 times as large)."""
    s = 0.025
    return s, _world(1.0), _world(s)


def test_the_plan_of_a_scaled_scene_is_the_plan_of_the_scene_built_smaller(scaled_pair):
    s, big, small = scaled_pair
    at_scale = plan_scene(big, OPT.model_copy(update={"scene_scale": s}), RenderOptions(preset="fast"))
    built = plan_scene(small, OPT, RenderOptions(preset="fast"))
    for name in ("z_wrp_m", "z_near_holo_m", "z_far_holo_m"):
        a, b = getattr(at_scale.analysis, name), getattr(built.analysis, name)
        assert a == pytest.approx(b, rel=1e-5), name
    assert at_scale.focus.depths_of_field == pytest.approx(built.focus.depths_of_field, rel=1e-3)
    assert at_scale.plan.spp == built.plan.spp


def test_the_plan_says_the_depth_and_suggests_the_scale_that_brings_focus(scaled_pair):
    _s, big, _small = scaled_pair
    pl = plan_scene(big, OPT, RenderOptions(preset="fast"))
    f, lam, D = F_M, 516.5e-9, 4e-3
    dof = lam / min(D / (2 * f), 455.4e-9 / (2 * OPT.pitch_m)) ** 2  # the blue cone limits it, not the pupil
    # the light lies beyond the card (the panel seen in the mirror farther than the wall): f^2 / 20 m at most
    assert f * f * (1 / FAR_M[0] - 1 / FAR_M[1]) * 0.99 <= pl.focus.span_mm * 1e-3 <= f * f / FAR_M[0]
    assert pl.focus.depths_of_field == pytest.approx(pl.focus.span_mm * 1e-3 / dof, rel=1e-6)
    assert pl.focus.depths_of_field < 1
    s = pl.focus.suggested_scene_scale
    assert s == pytest.approx(NEAR_TARGET_M / pl.focus.near_m, rel=0.05)  # two significant digits
    assert "--scene-scale" in pl.focus.summary and pl.focus.summary in pl.plan.summary
    then = plan_scene(big, OPT.model_copy(update={"scene_scale": s}), RenderOptions(preset="fast"))
    assert then.focus.depths_of_field > 1 and then.focus.suggested_scene_scale is None
    assert then.focus.near_m == pytest.approx(NEAR_TARGET_M, rel=0.05)


def test_the_hologram_at_a_scale_is_the_hologram_of_the_scene_built_at_it(scaled_pair):
    s, big, small = scaled_pair
    opts = RenderOptions(preset="fast", spp=16)
    a = render_loaded(big, OPT.model_copy(update={"scene_scale": s}), opts)
    b = render_loaded(small, OPT, opts)
    assert a.meta["scene_scale"] == s and b.meta["scene_scale"] == 1.0
    fa, fb = np.asarray(a.slm_field), np.asarray(b.slm_field)
    assert np.isfinite(fa).all() and np.abs(fb).max() > 0
    assert np.linalg.norm(fa - fb) <= 1e-2 * np.linalg.norm(fb)  # float32 intersections at 60 m against 1.5 m
    # and not the hologram of the unscaled scene, whose image points lie 40 times nearer to infinity
    c = np.asarray(render_loaded(big, OPT, opts).slm_field)
    assert np.linalg.norm(c - fb) > 0.3 * np.linalg.norm(fb)


def test_the_ground_truth_at_a_scale_focuses_as_the_scene_built_at_it(scaled_pair):
    s, big, small = scaled_pair
    meta = {"focal_length_m": F_M, "z_inf_m": OPT.z_inf_m, "pitch_m": OPT.pitch_m,
            "wavelengths_m": list(OPT.wavelengths_m)}
    z_card = OPT.z_inf_m + F_M ** 2 / (s * FAR_M[0])  # focus on the card
    kw = dict(focus_z_m=z_card, pupil_diameter_m=4e-3, view_offset_m=(0.5e-3, 0.0))
    a = GroundTruth(big, {**meta, "scene_scale": s}, shape_hw=(32, 48), spp=64).rgb(**kw)
    b = GroundTruth(small, meta, shape_hw=(32, 48), spp=64).rgb(**kw)
    unscaled = GroundTruth(big, meta, shape_hw=(32, 48), spp=64)
    assert np.abs(a - b).max() <= 1e-3 * b.max()
    # the unscaled scene cannot focus that near (a pupil 40 times smaller in the world blurs nothing)
    assert np.abs(unscaled.rgb(**kw) - b).max() > 0.05 * b.max()


def test_focus_depth_words_for_deep_flat_and_empty_scenes():
    f, zi = 0.05, 0.08
    deep = [zi + f * f / z for z in np.linspace(0.5, 2.0, 64)]
    r = focus_depth(image_depths_holo_m=deep, z_inf_m=zi, focal_length_m=f, wavelengths_m=[516.5e-9],
                    pitch_m=8e-6, scene_scale=1.0)
    assert r.depths_of_field > 5 and r.suggested_scene_scale is None and "--scene-scale" not in r.summary
    near_flat = [zi + f * f / 0.4 + 1e-6 * k for k in range(64)][::-1]  # a card 0.4 m away: no scale helps
    r = focus_depth(image_depths_holo_m=near_flat, z_inf_m=zi, focal_length_m=f, wavelengths_m=[516.5e-9],
                    pitch_m=8e-6, scene_scale=1.0)
    assert r.depths_of_field < 1 and r.suggested_scene_scale is None and "nearly flat" in r.summary
    r = focus_depth(image_depths_holo_m=[], z_inf_m=zi, focal_length_m=f, wavelengths_m=[516.5e-9],
                    pitch_m=8e-6, scene_scale=1.0)
    assert r.depths_of_field == 0 and "no light" in r.summary
    # an eyepiece fitted to a wide camera (f = 5 mm): 0.5 m is not enough, the eye's near point is suggested
    far = [zi + 25e-6 / z for z in np.linspace(3.0, 12.0, 64)]
    r = focus_depth(image_depths_holo_m=far, z_inf_m=zi, focal_length_m=5e-3, wavelengths_m=[516.5e-9],
                    pitch_m=8e-6, scene_scale=1.0)
    assert r.suggested_scene_scale == pytest.approx(0.25 / r.near_m, rel=0.05) and "flat for this display" in r.summary


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "1e9"])
def test_a_bad_scene_scale_is_refused_in_one_line(bad, tmp_path):
    from typer.testing import CliRunner

    from holo.app import app
    from holocore.scene.demo import write_demo_scene

    entry = write_demo_scene(tmp_path / "demo")
    res = CliRunner().invoke(app, ["plan", str(entry), "--resolution", "16x16", "--scene-scale", bad])
    assert res.exit_code == 2
    lines = [ln for ln in res.output.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "scene_scale" in lines[0], res.output


def test_a_stored_plan_read_at_another_scale_is_the_plan_made_at_it(scaled_pair):
    from holocore.options import HologramOptions
    from holocore.plan.stored_plan import plan_at_options, stored, wrp_distance_m

    s, big, _small = scaled_pair
    at = OPT.model_copy(update={"scene_scale": s})
    saved = stored(plan_scene(big, OPT, RenderOptions(preset="fast")), OPT)
    fresh = plan_scene(big, at, RenderOptions(preset="fast"))
    assert wrp_distance_m(saved, at) == pytest.approx(fresh.analysis.z_wrp_m, rel=1e-6)
    words = plan_at_options(saved, at, HologramOptions(preset="fast"))["summary"]
    focus = [w for w in words if w.startswith("focus:")]
    assert focus and f"{fresh.focus.depths_of_field:.2g} depths of field" in focus[0]
