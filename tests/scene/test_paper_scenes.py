"""The paper scenes with depth (holocore.scene.paper) at the paper display (f = 50 mm, 8 µm,
z_inf 80 mm): their depths land where T says, the mirror image lies at the reflected object's apparent depth,
the glass ball images its card at the paraxial thick-lens position, the glossy highlight moves with the view,
and each renders finite and lit. Physics, not shapes: expectations are computed here from the geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from holo.app import app
from holocore.display.profiles import PAPER, display_optics
from holocore.scene.paper import (
    PAPER_SCENES,
    paper_fov_x_deg,
    scene_facts,
    write_paper_scene,
)

F_M = 0.05
Z_INF = 0.08


def z_holo(zc: float) -> float:
    return Z_INF + F_M * F_M / zc


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("paper-scenes")
    return {name: write_paper_scene(name, root / name).parent for name in PAPER_SCENES}


@pytest.fixture(scope="module")
def loaded(folders):
    from holocore.scene.load import load_scene

    return {name: load_scene(folder) for name, folder in folders.items()}


def _plan(ld, **overrides):
    from holocore.pipeline import RenderOptions, plan_scene

    return plan_scene(ld, display_optics(PAPER, overrides=overrides), RenderOptions(preset="fast"))


def _eye_rays(ld, tans: np.ndarray):
    """World rays from the eye (the sensor's origin) along eye-camera directions (tan_x, tan_y, 1)."""
    from holocore.trace.mapping import HologramMap

    hmap = HologramMap.from_sensor(ld.sensor, focal_length_m=F_M, z_inf_m=Z_INF)
    d_cam = np.concatenate([tans, np.ones((len(tans), 1))], axis=1)
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    o = np.repeat(hmap.camera_to_world(np.zeros((1, 3))), len(tans), axis=0)
    return o, hmap.camera_dir_to_world(d_cam), d_cam


def _chain(ld, tans, seed=3):
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.trace.reference_chain import trace_chain

    o, v, d_cam = _eye_rays(ld, tans)
    integ = mitsuba().load_dict({"type": "path", "max_depth": 4})
    return trace_chain(ld.scene, o, v, max_delta=8, amp_spp=1, integrator=integ, seed=seed), d_cam


@pytest.mark.slow
def test_the_camera_sees_the_paper_display_view(loaded):
    fov = 2 * math.degrees(math.atan(1920 * 8e-6 / (2 * F_M)))
    assert abs(paper_fov_x_deg() - fov) < 1e-9 and abs(fov - 17.46) < 0.01
    for name, ld in loaded.items():
        pl = _plan(ld)
        assert abs(ld.fov_x_deg - fov) < 1e-3, name
        assert pl.focal_length_m == pytest.approx(F_M)
        assert not pl.field_of_view["differs"], (name, pl.field_of_view["summary"])


@pytest.mark.slow
def test_depth_scene_spans_the_paper_image_volume(loaded):
    # 10 m, 0.9 m, 0.5 m at z_inf + 0.25, 2.78, 5 mm (docs/design.md §3); the cards are planes facing the eye
    ana = _plan(loaded["depth"]).analysis
    assert ana.z_far_holo_m - Z_INF == pytest.approx(0.25e-3, abs=2e-6)
    assert ana.z_near_holo_m - Z_INF == pytest.approx(5.0e-3, abs=1e-5)
    assert ana.z_wrp_m > ana.z_near_holo_m
    # the middle card: rays at its centre hit it at 0.9 m -> z_inf + 2.78 mm
    facts = scene_facts("depth")
    reg = facts["regions_tan"]["mid"]
    tans = np.array([[0.04, 0.0], [0.045, 0.02], [0.035, -0.03]])
    assert all(reg["x"][0] < t[0] < reg["x"][1] and reg["y"][0] < t[1] < reg["y"][1] for t in tans)
    res, d_cam = _chain(loaded["depth"], tans)
    zc = res.d * d_cam[:, 2]
    assert np.all(res.valid)
    np.testing.assert_allclose(z_holo(zc) - Z_INF, F_M ** 2 / 0.9, rtol=1e-5)


@pytest.mark.slow
def test_mirror_image_lies_at_the_apparent_depth_of_the_reflected_object(loaded):
    facts = scene_facts("mirror")
    # Directions across the mirror (half-size 25 x 17.5 mm at 0.5 m: |tan| < 0.05, 0.035)
    g = np.linspace(-0.035, 0.035, 5)
    tans = np.array([[x, y] for x in g for y in g * 0.6])
    res, d_cam = _chain(loaded["mirror"], tans)
    ok = res.valid & (res.n_delta == 1)
    assert ok.all(), "every ray across the mirror reflects once and ends on the poster"
    # The poster faces the mirror 1.5 m away, perpendicular to the reflected axis: its mirror image is the
    # plane zc = 0.5 + 1.5 = 2.0 m facing the eye, so every image point has zc = 2.0 (P' = O + d v).
    zc_img = res.d * d_cam[:, 2]
    zc_expect = facts["mirror_zc_m"] + facts["object_distance_m"]
    # 1e-4 relative (the traced distance is 2 m - 0.13 mm here); in hologram depth that is under 0.1 µm
    np.testing.assert_allclose(zc_img, zc_expect, rtol=1e-4)
    assert np.all(np.abs(z_holo(zc_img) - z_holo(zc_expect)) < 1e-6)
    # The mirror surface itself is ~0.5 m away: hologram depths 5 mm and 1.25 mm beyond z_inf
    from holocore.runtime.mitsuba_env import mitsuba

    mi = mitsuba()
    o, v, _ = _eye_rays(loaded["mirror"], tans)
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(o[:, i].astype(np.float32)) for i in range(3)]),
                   mi.Vector3f(*[mi.Float(v[:, i].astype(np.float32)) for i in range(3)]))
    t = np.asarray(loaded["mirror"].scene.ray_intersect(ray).t, dtype=np.float64)
    zc_mirror = t * d_cam[:, 2]
    assert np.all(np.abs(zc_mirror - 0.5) < 0.01)
    gap = z_holo(zc_mirror) - z_holo(zc_img)
    dof = 516.5e-9 / (516.5e-9 / (2 * 8e-6)) ** 2  # lambda / NA^2 at the recording cone: 0.5 mm
    assert np.all(gap > 3.5e-3) and np.all(gap > 7 * dof)


@pytest.mark.slow
def test_glass_ball_images_the_card_at_the_paraxial_thick_lens_position(loaded):
    facts = scene_facts("glass")
    n, R, c, zo = facts["ior"], facts["sphere_radius_m"], facts["sphere_center_zc_m"], facts["card_zc_m"]
    # Ball lens: focal length n R / (2 (n - 1)) from its centre (both principal planes there)
    f_ball = n * R / (2 * (n - 1))
    s_i = 1.0 / (1.0 / f_ball - 1.0 / (zo - c))
    zc_expect = c - s_i  # real image on the eye's side
    assert zc_expect == pytest.approx(0.3446, abs=1e-4)  # 0.345 m: z_inf + 7.25 mm, the surface at + 5 mm
    assert zc_expect < c - R  # in front of the ball's surface, far from the card
    # Rays near the axis: many copies, keep those refracted twice (in and out; a reflection is one bounce)
    # (the ray exactly on the axis, at the sphere's poles: tests/trace/test_sphere_pole.py)
    tans = np.repeat(np.array([[1e-4, 0.0], [0.0015, 0.0], [0.0, -0.0015], [-0.001, 0.001]]), 32, axis=0)
    res, d_cam = _chain(loaded["glass"], tans)
    two = res.valid & (res.n_delta == 2)
    assert two.sum() > 64
    zc = res.d[two] * d_cam[two, 2]
    # paraxial rays: the traced image point at the thick-lens position within 2e-3 relative; in hologram space
    # within 8 µm of z_inf + 7.25 mm, a 60th of a depth of field
    np.testing.assert_allclose(zc, zc_expect, rtol=2e-3)
    assert np.all(np.abs(z_holo(zc) - z_holo(zc_expect)) < 8e-6)
    # far from the ball's surface (0.5 m) and from the card (5.75 m): > 4 depths of field at the recording cone
    # (2.25 mm and 6.8 mm of hologram depth; an eye's 1.6 mm pupil has a depth of field of about 2 mm)
    dof = 516.5e-9 / (516.5e-9 / (2 * 8e-6)) ** 2
    assert z_holo(zc.max()) - z_holo(c - R) > 4 * dof and z_holo(zc.max()) - z_holo(zo) > 12 * dof
    # the plan sees it: the nearest image point of the scene is that image (the WRP goes in front of it)
    ana = _plan(loaded["glass"]).analysis
    assert ana.z_near_holo_m == pytest.approx(z_holo(zc_expect), abs=2e-5)
    assert ana.z_wrp_m > ana.z_near_holo_m


def _highlight_column(img: np.ndarray) -> float:
    """Centroid column of the glossy highlight: pixels brighter than half of the brightest (the white checker
    squares under the sky are ~0.5, the highlight's core several times that)."""
    g = img.mean(axis=0)
    thr = 0.5 * float(np.percentile(g, 99.9))
    w = np.where(g > thr, g - thr, 0.0)
    cols = np.arange(g.shape[1])
    return float((w.sum(axis=0) * cols).sum() / w.sum())


@pytest.mark.slow
def test_glossy_highlight_moves_with_the_view(loaded):
    from holocore.evaluate.groundtruth import render_ground_truth

    facts = scene_facts("glossy")
    ld = loaded["glossy"]
    m = np.array(ld.sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
    H, W, p = 160, 240, 8e-6
    cols = {}
    for ex in (-1.5e-3, 1.5e-3):
        img = render_ground_truth(ld.scene, sensor_to_world=m, focal_length_m=F_M, z_inf_m=Z_INF, pitch_m=p,
                                  shape_hw=(H, W), focus_z_m=z_holo(facts["plate_zc_m"]),
                                  pupil_diameter_m=0.3e-3, view_offset_m=(ex, 0.0), spp=32, seed=1)
        assert np.all(np.isfinite(img)) and img.max() > 1.0
        cols[ex] = _highlight_column(img)
    de = 3e-3
    px_per_rad = F_M / p
    shift = cols[1.5e-3] - cols[-1.5e-3]
    # the highlight is the light's mirror image 2 m away: it moves by -de / 2 m; the plate's texture by
    # -de / 0.5 m, four times as far: relative to the texture the highlight moves with the eye
    expect = -de / facts["highlight_image_zc_m"] * px_per_rad
    texture = -de / facts["plate_zc_m"] * px_per_rad
    assert abs(shift - expect) < 0.3 * abs(expect), (shift, expect, texture)
    assert abs(shift - texture) > 10.0, (shift, texture)


@pytest.mark.slow
@pytest.mark.parametrize("name", PAPER_SCENES)
def test_small_render_is_finite_and_lit(loaded, name):
    from holocore.pipeline import RenderOptions, render_loaded

    optics = display_optics(PAPER, overrides={"resolution_hw": (24, 40), "frames": 1, "z_inf_mm": 2.0})
    res = render_loaded(loaded[name], optics, RenderOptions(preset="fast", spp=16), display=PAPER)
    u = res.slm_field
    assert u.shape == (1, 3, 24, 40) and np.all(np.isfinite(u)) and np.all(np.isfinite(res.wrp_field))
    energy = (np.abs(u) ** 2).sum(axis=(0, 2, 3))
    assert np.all(energy > 0), energy  # every colour lit
    assert res.meta["display_profile"] == "paper" and res.meta["focal_length_m"] == pytest.approx(F_M)


@pytest.mark.slow
def test_demo_renders_a_paper_scene(tmp_path):
    runner = CliRunner()
    out = tmp_path / "demo"
    r = runner.invoke(app, ["demo", "--scene", "depth", "--out", str(out), "--resolution", "24x40",
                            "--frames", "1"])
    assert r.exit_code == 0, r.output
    assert (out / "RESULT.npz").is_file() and (out / "focal_sweep.png").is_file()
    assert (out / "scene" / "scene.xml").is_file() and (out / "scene" / "textures" / "star.png").is_file()
    from holocore.io import load_result

    _, _, meta = load_result(out / "RESULT.npz")
    assert meta["z_inf_m"] == pytest.approx(0.01) and meta["focal_length_m"] == pytest.approx(F_M)
    bad = runner.invoke(app, ["demo", "--scene", "nope", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "must be one of" in bad.output


@pytest.mark.slow
def test_fast_preset_keeps_the_glossy_highlight(loaded):
    # The ambient cache holds view-independent radiance per unit diffuse albedo; a glossy plate's highlight is
    # neither, so the fast preset path traces glossy image points. Without that its highlight vanished (the plate
    # shows only its diffuse part and cache blotches: 7.5 dB against ground truth where balanced scored 12.6 dB at
    # 68x120). The fast view must match the balanced one (relative error after one brightness scale).
    from holocore.evaluate.scoring import eye_view
    from holocore.pipeline import RenderOptions, render_loaded

    optics = display_optics(PAPER, overrides={"resolution_hw": (40, 72), "frames": 2, "z_inf_mm": 4.0})
    z = Z_INF - 0.08 + 4e-3 + F_M * F_M / scene_facts("glossy")["highlight_image_zc_m"]  # the highlight's focus
    views = {}
    for preset in ("fast", "balanced"):
        res = render_loaded(loaded["glossy"], optics, RenderOptions(preset=preset, spp=128), display=PAPER)
        views[preset] = eye_view(res.slm_field, res.meta, focus_z_m=z, pupil_diameter_m=1.6e-3).mean(axis=0)
    f, b = views["fast"].ravel(), views["balanced"].ravel()
    k = float(f @ b / (f @ f))  # one brightness scale, as the evaluation does
    err = float(np.linalg.norm(k * f - b) / np.linalg.norm(b))
    assert err < 0.25, err  # measured 0.16 (Monte Carlo noise of both); 0.41 with the cache on the glossy plate
