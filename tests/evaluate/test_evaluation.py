"""Ground truth, evaluation, the layer baseline and the cost estimate.

The physics checked here: the thin-lens ground truth and the simulated eye agree on where a point lands (no
flip, no offset) and on how it moves when the eye moves; a view focused near shows the near card sharp and a
mirror's far image blurred, and the reverse when focused far, in the ground truth and in the reconstruction,
while the layer baseline puts the mirror image at the mirror; more frames average speckle; the layers'
colours are balanced; the estimate counts the render's own work and grows with it as its model says.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.evaluate.groundtruth import (
    GroundTruth,
    focus_distance_m,
    pupil_diffraction,
)
from holocore.evaluate.scoring import (
    compare,
    default_pupil_m,
    eye_view,
    focus_planes_m,
    lit_margin_px,
    load_slm_field,
    view_offsets_m,
)
from tests.project_scenes import SCENE_SOURCES

HOLO = [sys.executable, "-m", "holo"]
LAM = 516.5e-9
P = 8e-6
F_M = 0.025
Z_INF = 0.004
H, W = 48, 64


def run(*args, **kw):
    return subprocess.run([*HOLO, *map(str, args)], capture_output=True, text=True, timeout=600, **kw)


def centroid(img: np.ndarray) -> np.ndarray:
    """(row, col) centroid of the pixels above a quarter of the maximum."""
    a = np.clip(img, 0, None)
    w = a * (a >= 0.25 * a.max())
    ii, jj = np.mgrid[:a.shape[0], :a.shape[1]]
    return np.array([(ii * w).sum(), (jj * w).sum()]) / w.sum()


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / math.sqrt(float((a * a).sum() * (b * b).sum())))


# ---- a glowing dot off axis ---------------------------------------------------------------------------------
DOT = np.array([0.002, 0.001, 0.5])  # eye-camera metres: right, up, ahead


def _dot_render(radius_m: float, spp: int, *, square: bool = False):
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.scene.load import from_mitsuba_scene

    mi = mitsuba()
    fov = 2 * math.degrees(math.atan(W * P / (2 * F_M)))
    scene = mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": fov, "fov_axis": "x",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=[0, 0, -1], up=[0, 1, 0])},
        "dot": ({"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([DOT[0], DOT[1], -DOT[2]])
                 .scale(radius_m)} if square else
                {"type": "sphere", "center": [DOT[0], DOT[1], -DOT[2]], "radius": radius_m})
        | {"emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}},
    })
    loaded = from_mitsuba_scene(scene, name="dot")
    optics = OpticsConfig(resolution_hw=(H, W), wavelengths_nm=(LAM * 1e9,), pitch_um=P * 1e6, frames=1,
                          focal_length_mm=F_M * 1e3, z_inf_mm=Z_INF * 1e3)
    res = render_loaded(loaded, optics, RenderOptions(preset="balanced", spp=spp))  # the dot takes few rays
    return loaded, res, GroundTruth(loaded, res.meta, shape_hw=(H, W), spp=1024)


@pytest.fixture(scope="module")
def dot():
    """A 0.2 mm glowing sphere at 0.5 m: a 2.5-pixel disk in the hologram."""
    return _dot_render(0.0002, 2048)


@pytest.fixture(scope="module")
def point():
    """Point-like as the WRP sees it: a glowing 0.1 mm square at 0.5 m images to a 5 um square 1 mm from the WRP
    (Fresnel number 0.05). The 0.2 mm dot (Fresnel number 0.2) already radiates as a small coherent aperture in
    a one-frame smooth-phase render, so its parallax and best focus drift with seed and spp, and a point
    source's parallax f e / (zc p) no longer holds for it. A square, not a sphere: at 0.5 m Mitsuba's float32
    ray-sphere test resolves a 0.1 mm sphere poorly (a 0.05 mm one is never hit), a plane exactly."""
    return _dot_render(0.00005, 2048, square=True)


def test_focus_distance_inverts_the_hologram_depth():
    assert focus_distance_m(Z_INF + F_M**2 / 0.5, focal_length_m=F_M, z_inf_m=Z_INF) == pytest.approx(0.5)
    assert focus_distance_m(Z_INF, focal_length_m=F_M, z_inf_m=Z_INF) >= 1e6  # optical infinity
    with pytest.raises(ValueError, match="beyond optical infinity"):
        focus_distance_m(Z_INF - 1e-4, focal_length_m=F_M, z_inf_m=Z_INF)


@pytest.mark.slow
def test_ground_truth_puts_the_dot_where_x_equals_f_tan(dot):
    _, res, gt = dot
    z = Z_INF + F_M**2 / DOT[2]
    img = gt.channels(focus_z_m=z, pupil_diameter_m=0.6e-3)[0]
    expect = np.array([(H - 1) / 2 - F_M * DOT[1] / DOT[2] / P, (W - 1) / 2 + F_M * DOT[0] / DOT[2] / P])
    assert np.abs(centroid(img) - expect).max() < 0.3, (centroid(img), expect)
    # The eye 0.5 mm to the right sees the dot 0.5 mm / 0.5 m further left: f e / (zc p) = 3.1 px.
    moved = gt.channels(focus_z_m=z, pupil_diameter_m=0.6e-3, view_offset_m=(0.5e-3, 0.0))[0]
    assert centroid(moved)[1] - centroid(img)[1] == pytest.approx(-F_M * 0.5e-3 / DOT[2] / P, abs=0.3)


@pytest.mark.slow
def test_reconstruction_lands_on_the_ground_truth_pixel(dot):
    _, res, gt = dot
    z_dot = Z_INF + F_M**2 / DOT[2]
    pupil = 0.6e-3
    rec = eye_view(res.slm_field, res.meta, focus_z_m=z_dot, pupil_diameter_m=pupil)[0]
    truth = gt.channels(focus_z_m=z_dot, pupil_diameter_m=pupil)[0]
    assert np.abs(centroid(rec) - centroid(truth)).max() < 0.5, (centroid(rec), centroid(truth))
    assert compare(rec[None], truth[None]).ssim > 0.8


@pytest.mark.parametrize("offset", [pytest.param((0.0, 0.375e-3), marks=pytest.mark.slow),
                                    pytest.param((0.375e-3, 0.0), marks=pytest.mark.slow), (0.0, -0.375e-3)])
def test_a_view_offset_moves_the_reconstruction_like_the_ground_truth(point, offset):
    """Focused 1 mm in front of the dot (defocused), the eye moved by 0.375 mm: the dot moves by
    f e / (zc p) = 2.3 px against the eye's motion in both; a flipped row sign would move it 2x the other way."""
    _, res, gt = point
    z_f = Z_INF + F_M**2 / DOT[2] + 1e-3
    pupil = 0.6e-3
    c0_rec = centroid(eye_view(res.slm_field, res.meta, focus_z_m=z_f, pupil_diameter_m=pupil)[0])
    c0_gt = centroid(gt.channels(focus_z_m=z_f, pupil_diameter_m=pupil)[0])
    c1_rec = centroid(eye_view(res.slm_field, res.meta, focus_z_m=z_f, pupil_diameter_m=pupil,
                               view_offset_m=offset)[0])
    c1_gt = centroid(gt.channels(focus_z_m=z_f, pupil_diameter_m=pupil, view_offset_m=offset)[0])
    d_rec, d_gt = c1_rec - c0_rec, c1_gt - c0_gt
    expect = np.array([offset[1], -offset[0]]) * F_M / DOT[2] / P  # rows down for an eye moving up
    assert np.abs(d_gt - expect).max() < 0.3, (d_gt, expect)
    assert np.abs(d_rec - d_gt).max() < 0.7, (d_rec, d_gt)
    assert np.abs(c1_rec - c1_gt).max() < 0.8


# ---- evaluation pieces --------------------------------------------------------------------------------------
def test_compare_is_scale_free_and_ignores_saturated_emitters():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0.1, 1.0, (3, 32, 32))
    truth[:, :2, :2] = 50.0  # a lamp: above the white level, clipped in both
    noisy = truth * rng.uniform(0.8, 1.2, truth.shape)
    a = compare(noisy, truth)
    b = compare(noisy * 1e-12, truth)
    assert a.psnr_db == pytest.approx(b.psnr_db, abs=1e-6) and a.ssim == pytest.approx(b.ssim, abs=1e-6)
    assert b.scale == pytest.approx(1e12, rel=0.05)
    assert compare(truth, truth).psnr_db == math.inf and compare(truth, truth).ssim == pytest.approx(1.0)
    black = compare(np.zeros_like(truth), np.zeros_like(truth))
    assert black.psnr_db == math.inf and np.isfinite(black.ssim)
    worse = compare(truth * rng.uniform(0.5, 1.5, truth.shape), truth)
    assert worse.psnr_db < a.psnr_db
    with pytest.raises(ValueError, match="NaN"):
        compare(np.full_like(truth, np.nan), truth)


def test_pupil_diffraction_keeps_energy_and_blurs_to_the_airy_width():
    img = np.zeros((1, 129, 129))
    img[0, 64, 64] = 1.0
    na = LAM / (2 * P) / 2  # half the grid's bandwidth
    out = pupil_diffraction(img, wavelengths_m=[LAM], pitch_m=P, numerical_aperture=na)
    # Energy stays, up to the Airy tails that the edges' reflection folds back (1 / r^3: under 1 % here).
    assert out.sum() == pytest.approx(1.0, rel=1e-2) and out.min() >= 0
    flat = pupil_diffraction(np.ones((1, 40, 50)), wavelengths_m=[LAM], pitch_m=P, numerical_aperture=na)
    assert np.allclose(flat, 1.0, atol=1e-9)  # a uniform image is left alone, edges included
    row = out[0, 64]
    half = row.max() / 2
    above = np.flatnonzero(row >= half)
    fwhm_px = above[-1] - above[0] + 1
    airy_fwhm_px = 0.514 * LAM / na / P  # incoherent Airy FWHM = 0.514 lambda / NA
    assert abs(fwhm_px - airy_fwhm_px) <= 1.5, (fwhm_px, airy_fwhm_px)


def test_grid_helpers():
    meta = {"focal_length_m": F_M, "z_inf_m": Z_INF, "pitch_m": P, "wavelengths_m": [640e-9, 516.5e-9, 455.4e-9],
            "analysis": {"z_near_holo_m": Z_INF + 2e-3, "z_far_holo_m": Z_INF + 1e-3}}
    zs = focus_planes_m(meta, 5)
    assert zs[0] == pytest.approx(Z_INF + 2e-3) and zs[-1] == pytest.approx(Z_INF + 1e-3) and len(zs) == 5
    views = view_offsets_m(meta, 7, 0.5)
    assert len(views) == 49 and views[24][1] == (0.0, 0.0)
    (col, row), (ex, ey) = views[0]
    assert (col, row) == (0, 0) and ex < 0 < ey  # top-left: the eye moved left and up
    assert ey == pytest.approx(F_M * math.sin(math.radians(0.5)))
    pupil = default_pupil_m(meta, view_deg=0.5)
    reach = pupil / (2 * F_M) + math.sqrt(2) * math.sin(math.radians(0.5))
    assert reach == pytest.approx(455.4e-9 / (2 * P))  # the corner views touch the blue cone's edge
    with pytest.raises(ValueError, match="view-deg"):
        default_pupil_m(meta, view_deg=1.5)
    assert lit_margin_px(meta, focus_z_m=Z_INF, pupil_diameter_m=pupil) == math.ceil(Z_INF * pupil / (2 * F_M) / P)
    with pytest.raises(ValueError, match="views"):
        view_offsets_m(meta, 0, 0.5)


def test_views_at_middle_scores_a_cross_and_pairs_are_written_at_one_white(tmp_path):
    """``views_at="middle"``: the centre view at every focus, the other views at the middle focus only; with
    ``pairs`` each cell's view (at its scale) and ground truth as PNGs at one white level, named in metrics.json."""
    from PIL import Image

    from holocore.evaluate.score_files import write_outputs
    from holocore.evaluate.scoring import evaluate

    meta = {"focal_length_m": F_M, "z_inf_m": Z_INF, "pitch_m": P, "wavelengths_m": [LAM]}
    rng = np.random.default_rng(1)
    field = np.exp(2j * np.pi * rng.random((1, 1, 64, 64))).astype(np.complex64)

    class Flat:  # a ground truth whose brightness grows with the focus depth
        def channels(self, *, focus_z_m, pupil_diameter_m, view_offset_m):
            return np.full((1, 64, 64), focus_z_m * 100.0) + rng.random((1, 64, 64))

    zs = [Z_INF + 1e-4, Z_INF + 5e-4, Z_INF + 9e-4]
    ev = evaluate(field, meta, Flat(), focus_z_m=zs, views=3, views_at="middle", keep_images=True)
    got = [(c.focus_index, c.view_index) for c in ev.cells]
    assert got == [(0, (1, 1)), *[(1, (col, row)) for row in range(3) for col in range(3)], (2, (1, 1))]
    with pytest.raises(ValueError, match="odd"):
        evaluate(field, meta, Flat(), focus_z_m=zs, views=2, views_at="middle")
    paths = write_outputs(ev, tmp_path, sheets=False, pairs=True)
    doc = json.loads(paths["json"].read_text())
    assert "focus_sheet" not in paths and not (tmp_path / "cells").exists()
    assert doc["pair_white"] == pytest.approx(max(c.score.white for c in ev.cells)) and doc["pair_gamma"] == 2.2
    row = doc["cells"][0]
    assert row["truth_png"] == "pairs/truth-f00-v04.png" and row["recon_png"] == "pairs/recon-f00-v04.png"
    assert doc["cells"][1]["truth_png"] == "pairs/truth-f01-v00.png"
    near = np.asarray(Image.open(tmp_path / doc["cells"][-1]["truth_png"]), dtype=float)
    far = np.asarray(Image.open(tmp_path / row["truth_png"]), dtype=float)
    assert near.mean() > far.mean()  # one white for all: the brighter truth is brighter in its PNG


# ---- depth: a near card and a mirror showing a far card ------------------------------------------------------
@pytest.fixture(scope="module")
def cards(tmp_path_factory):
    from bench.accuracy_report import write_mirror_cards
    from holocore.baselines.layers import render_layers
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.load import load_scene

    h, w, f = 64, 96, 0.03
    fov = 2 * math.degrees(math.atan(w * P / (2 * f)))
    loaded = load_scene(write_mirror_cards(tmp_path_factory.mktemp("cards"), fov_deg=fov))
    optics = OpticsConfig(resolution_hw=(h, w), wavelengths_nm=(LAM * 1e9,), frames=16, focal_length_mm=f * 1e3,
                          z_inf_mm=3.0)
    ours = render_loaded(loaded, optics, RenderOptions(preset="balanced", spp=192))
    layers = render_layers(loaded, optics, planes=8, spp=32)
    gt = GroundTruth(loaded, ours.meta, shape_hw=(h, w), spp=128)
    return ours, layers, gt, (h, w)


@pytest.mark.slow
def test_near_and_far_focus_like_the_ground_truth_and_layers_misplace_the_mirror_image(cards):
    ours, layers, gt, (h, w) = cards
    m = ours.meta
    near, far = m["analysis"]["z_near_holo_m"], m["analysis"]["z_far_holo_m"]
    pupil = 2 * m["focal_length_m"] * 0.03
    assert (near - far) > 2 * LAM / 0.03**2  # the scene spans more than two depths of field
    cut = max(lit_margin_px(m, focus_z_m=z, pupil_diameter_m=pupil) for z in (near, far))
    rows, card, mirror = slice(cut, h - cut), slice(cut, w // 2 - 2), slice(w // 2 + 2, w - cut)
    g = {z: gt.channels(focus_z_m=z, pupil_diameter_m=pupil)[0] for z in (near, far)}
    sharp_card, sharp_mirror = g[near][rows, card], g[far][rows, mirror]
    # Ground truth: the card is sharp at the near focus only, the mirror image at the far focus only.
    assert ncc(g[far][rows, card], sharp_card) < 0.5 and ncc(g[near][rows, mirror], sharp_mirror) < 0.5
    rec = {z: eye_view(ours.slm_field, m, focus_z_m=z, pupil_diameter_m=pupil)[0] for z in (near, far)}
    lay = {z: eye_view(layers.slm_field, layers.meta, focus_z_m=z, pupil_diameter_m=pupil)[0] for z in (near, far)}
    # Ours: the same.
    assert ncc(rec[near][rows, card], sharp_card) > 0.6
    assert ncc(rec[far][rows, mirror], sharp_mirror) > 0.45
    assert ncc(rec[far][rows, card], sharp_card) < ncc(rec[near][rows, card], sharp_card) - 0.3
    assert ncc(rec[near][rows, mirror], sharp_mirror) < ncc(rec[far][rows, mirror], sharp_mirror) - 0.3
    # Layers: the mirror image sits on the mirror's layer, sharp at the near focus, blurred at the far one.
    assert ncc(lay[near][rows, mirror], sharp_mirror) > ncc(lay[far][rows, mirror], sharp_mirror) + 0.3
    assert ncc(rec[far][rows, mirror], sharp_mirror) > ncc(lay[far][rows, mirror], sharp_mirror) + 0.3
    ours_far = compare(rec[far][None, rows, mirror], g[far][None, rows, mirror]).psnr_db
    lay_far = compare(lay[far][None, rows, mirror], g[far][None, rows, mirror]).psnr_db
    assert ours_far > lay_far + 1.0, (ours_far, lay_far)


# ---- the Cornell box with mirror and glass: the project's own; the speckle and colour test on ../shared's too ---
@pytest.fixture(scope="module")
def cbox(request, bundles_of):
    """The box rendered once per source: ``project`` unless a test asks for another (indirect parametrisation)."""
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.load import load_scene

    loaded = load_scene(bundles_of(getattr(request, "param", "project")).entry("cbox-mirror-glass"))
    optics = OpticsConfig(resolution_hw=(48, 64), frames=8, z_inf_mm=2.0, fit_camera_fov=True)  # the whole box
    res = render_loaded(loaded, optics, RenderOptions(preset="balanced", spp=64))
    return loaded, optics, res


@pytest.mark.slow
@pytest.mark.parametrize("cbox", SCENE_SOURCES, indirect=True)
def test_cbox_frames_average_speckle_and_layers_keep_colour_balance(cbox):
    from holocore.baselines.layers import render_layers

    loaded, optics, res = cbox
    gt = GroundTruth(loaded, res.meta, shape_hw=(48, 64), spp=128)
    pupil = default_pupil_m(res.meta, view_deg=0.5)
    z = focus_planes_m(res.meta, 1)[0]
    truth = gt.channels(focus_z_m=z, pupil_diameter_m=pupil)
    m = lit_margin_px(res.meta, focus_z_m=z, pupil_diameter_m=pupil)
    crop = (slice(None), slice(m, 48 - m), slice(m, 64 - m))
    one = compare(eye_view(res.slm_field[:1], res.meta, focus_z_m=z, pupil_diameter_m=pupil)[crop], truth[crop])
    eight = compare(eye_view(res.slm_field, res.meta, focus_z_m=z, pupil_diameter_m=pupil)[crop], truth[crop])
    assert eight.psnr_db > one.psnr_db + 2.0, (one, eight)  # speckle variance / 8: about +3 to +6 dB
    lay = render_layers(loaded, optics, planes=8, spp=32)
    rec = eye_view(lay.slm_field, lay.meta, focus_z_m=z, pupil_diameter_m=pupil)[crop]
    per_colour = [float(truth[crop][c].sum() / rec[c].sum()) for c in range(3)]  # mean ratios: speckle-free
    assert max(per_colour) / min(per_colour) < 1.2, per_colour  # colours keep their balance
    assert np.isfinite(lay.slm_field).all() and lay.meta["method"] == "layers"


@pytest.mark.slow
def test_holo_evaluate_and_baseline_cli(cbox, tmp_path, scene_bundle):
    from holocore.io import save_result

    _, _, res = cbox
    src = tmp_path / "R.npz"
    save_result(src, slm_field=res.slm_field[:2], wrp_field=res.wrp_field[:2], meta=res.meta)
    scene = scene_bundle("cbox-mirror-glass")
    p = run("evaluate", src, "--scene", scene, "--out", tmp_path / "ev", "--focus-planes", 2, "--views", 2,
            "--gt-spp", 16)
    assert p.returncode == 0, p.stderr
    lines = (tmp_path / "ev" / "metrics.csv").read_text().splitlines()
    assert len(lines) == 1 + 2 * 4 and "psnr_db" in lines[0]
    doc = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert all(math.isfinite(c["psnr_db"]) and c["psnr_db"] > 5 for c in doc["cells"])
    assert len(list((tmp_path / "ev" / "cells").glob("*.png"))) == 8
    assert (tmp_path / "ev" / "focus_sheet.png").is_file() and "mean over 8 cells" in p.stdout
    out = tmp_path / "L.npz"
    p = run("baseline", "layers", scene, "--out", out, "--planes", 3, "--spp", 4, "--resolution", "24x32",
            "--frames", 2, "--z-inf-mm", 2, "--fit-camera-fov")  # the whole box, as the cbox render above
    assert p.returncode == 0, p.stderr
    field, meta, kind = load_slm_field(out)
    assert kind == "result" and field.shape == (2, 3, 24, 32) and len(meta["layers"]["plane_z_m"]) == 3
    bad = run("evaluate", out, "--scene", scene, "--out", tmp_path / "ev2", "--views", 0)
    assert bad.returncode == 2 and "--views" in bad.stderr


@pytest.mark.slow
def test_a_phase_stack_is_lit_with_its_laser_powers(cbox, tmp_path):
    from holocore.encode.encoder import encode_sgd, save_encoded

    _, _, res = cbox
    enc = encode_sgd(res.wrp_field[:2], z_wrp_m=res.meta["z_wrp_m"], wavelengths_m=res.meta["wavelengths_m"],
                     pitch_m=res.meta["pitch_m"], iterations=5)
    save_encoded(tmp_path / "S.npz", enc, meta=res.meta)
    field, meta, kind = load_slm_field(tmp_path / "S.npz")
    assert kind == "stack" and field.shape == (2, 3, 48, 64)
    power = np.asarray(meta["encoder"]["illumination"])
    assert np.allclose(np.abs(field) ** 2, power[..., None, None], rtol=1e-4)


# ---- the cost estimate --------------------------------------------------------------------------------------
def test_estimate_grows_with_the_work_and_reads_the_calibration(tmp_path):
    from holocore.pipeline import RenderOptions
    from holocore.plan.estimate import (
        CALIBRATION_VERSION,
        estimate_breakdown,
        estimate_layers_seconds,
        estimate_seconds,
        load_calibration,
    )

    cal = load_calibration()
    o = OpticsConfig(resolution_hw=(96, 128), frames=8)
    t = estimate_seconds(o, RenderOptions(preset="balanced", spp=64))
    assert 0 < t < 1e4
    assert estimate_seconds(o, RenderOptions(preset="balanced", spp=256)) > 2 * t
    assert estimate_seconds(o.model_copy(update={"frames": 24}), RenderOptions(preset="balanced", spp=64)) > t
    assert estimate_seconds(o, RenderOptions(preset="balanced", spp=64), encode_iterations=100) > t
    b = estimate_breakdown(o, RenderOptions(preset="fast", spp=64))
    assert b["cache"] > 0 and b["total"] == pytest.approx(sum(v for k, v in b.items() if k != "total"))
    assert estimate_layers_seconds(o, planes=16, spp=64) > estimate_layers_seconds(o, planes=4, spp=64)
    broken = tmp_path / "cal.json"
    broken.write_text(json.dumps({"version": CALIBRATION_VERSION, "rates": {"ray": {}}}))
    with pytest.raises(ValueError, match="rates"):
        load_calibration(broken)
    with pytest.raises(ValueError, match="encode_iterations"):
        estimate_seconds(o, RenderOptions(), encode_iterations=-1, calibration=cal)
    from holocore.calibration import calibrate

    with pytest.raises(ValueError, match="z_inf_mm"):  # refused before anything is rendered
        calibrate(optics={"z_inf_mm": -4.0})


@pytest.mark.slow
def test_the_estimate_counts_the_work_the_render_does(tmp_path):
    """The cost model multiplies rates by counts; the counts must be the render's own: its rays per pixel (given,
    or chosen by the preset from the scene's depth), the rays traced, and a term for every stage it times. Each
    term then grows as its count does: the trace linearly in rays, the ASM as F C P log2 P. (How close the
    predicted seconds come to a measured run depends on the machine and its load: bench/estimate_vs_measured.py
    measures that, results in bench/results/estimate_vs_measured.md.)"""
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.plan.estimate import (
        DEFAULT_CALIBRATION,
        estimate_breakdown,
        features,
        load_calibration,
    )
    from holocore.scene.demo import write_demo_scene
    from holocore.scene.load import load_scene

    cal = load_calibration(DEFAULT_CALIBRATION)
    rates = cal["rates"]
    loaded = load_scene(write_demo_scene(tmp_path / "demo", fov_deg=10.0))
    optics = OpticsConfig(resolution_hw=(24, 32), frames=2)
    for options in (RenderOptions(preset="balanced", spp=8), RenderOptions(preset="fast")):
        res = render_loaded(loaded, optics, options)
        radius_px = res.meta["analysis"]["subhologram_radius_px"]
        x = features(optics, options, subhologram_radius_px=radius_px)
        assert x["spp"] == res.meta["plan"]["spp"]
        assert x["rays"] == res.meta["stats"]["rays"] == 24 * 32 * x["spp"]
        b = estimate_breakdown(optics, options, subhologram_radius_px=radius_px, calibration=cal)
        for stage in ("analysis", "bank", "trace", "propagate"):
            assert f"{stage}_s" in res.meta["timings"] and b[stage] > 0, stage
        assert (b["cache"] > 0) == ("cache_s" in res.meta["timings"]) == res.meta["plan"]["use_cache"]

    # Twice the rays: the trace term's per-ray part doubles (the per-tile part stays).
    o = OpticsConfig(resolution_hw=(96, 128), frames=8)
    b1 = estimate_breakdown(o, RenderOptions(preset="balanced", spp=16), calibration=cal)
    b2 = estimate_breakdown(o, RenderOptions(preset="balanced", spp=32), calibration=cal)
    tiles = features(o, RenderOptions(preset="balanced", spp=16))["tiles"]
    assert features(o, RenderOptions(preset="balanced", spp=32))["tiles"] == tiles  # one tile either way
    per_tile = rates["tile"] * tiles
    assert b2["trace"] - per_tile == pytest.approx(2 * (b1["trace"] - per_tile), rel=1e-12)
    # Twice the pixels each way: P = 4 H W grows 4x, the ASM as P log2 P; three times the frames: 3x.
    big = o.model_copy(update={"resolution_hw": (192, 256)})
    b4 = estimate_breakdown(big, RenderOptions(preset="balanced", spp=16), calibration=cal)
    P = 4 * 96 * 128
    assert b4["propagate"] / b1["propagate"] == pytest.approx(4 * math.log2(4 * P) / math.log2(P), rel=1e-12)
    b3 = estimate_breakdown(o.model_copy(update={"frames": 24}), RenderOptions(preset="balanced", spp=16),
                            calibration=cal)
    assert b3["propagate"] == pytest.approx(3 * b1["propagate"], rel=1e-12)
    assert b4["total"] > b1["total"] and b3["total"] > b1["total"] and b2["total"] > b1["total"]


@pytest.mark.slow
def test_render_estimate_cli(tmp_path):
    from holocore.scene.demo import write_demo_scene

    scene = write_demo_scene(tmp_path / "demo")
    p = run("render", scene, "--out", tmp_path / "never.npz", "--estimate", "--resolution", "96x128")
    assert p.returncode == 0, p.stderr
    err = " ".join(p.stderr.split())  # rich wraps long lines
    assert "estimated time of `holo render`" in err and "estimated warm render time" in err, err
    assert "estimated peak memory" in err and not (tmp_path / "never.npz").exists()
    # the encode's time, from its stop rule's measured iterations at this size, and the load the times assume
    assert "estimated `holo encode` time (sgd)" in err and "its stop rule's median at this size" in err, err
    assert "threads are running or ready on its" in err, err
