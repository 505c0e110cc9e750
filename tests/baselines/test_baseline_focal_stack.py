"""The focal-stack baseline (holocore.baselines.focal_stack): phase-only frames optimised on the
frame-averaged amplitude of a focal stack reconstruct each plane sharp at its own focus and blurred at the
other's, the loss falls, and the RESULT (and STACK) go through `holo view` and `holo evaluate`'s code paths."""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from holocore.baselines.focal_stack import (
    optimise_focal_stack,
    stack_of,
    stack_plane_depths,
)

P, F_M, LAM = 8e-6, 0.05, 516.5e-9


def _psnr(recon: np.ndarray, ref: np.ndarray) -> float:
    s = float((recon * ref).sum() / (recon * recon).sum())  # one least-squares brightness scale
    return 10 * math.log10(float(ref.max()) ** 2 / float(np.mean((s * recon - ref) ** 2)))


def _disc_blur(img: np.ndarray, radius_px: float) -> np.ndarray:
    if radius_px < 0.5:
        return img.copy()
    H, W = img.shape
    yy, xx = np.mgrid[-H // 2:H // 2, -W // 2:W // 2]
    k = (xx * xx + yy * yy <= radius_px ** 2).astype(float)
    return np.real(np.fft.ifft2(np.fft.fft2(img) * np.fft.fft2(np.fft.ifftshift(k / k.sum()))))


def test_plane_depths_follow_the_paper_and_stay_in_the_volume():
    zi = 0.08
    # the paper's 5 planes at 1.25 mm, centred on its 80.25..85 mm volume
    zs = stack_plane_depths(z_inf_m=zi, z_far_m=zi + 0.25e-3, z_near_m=zi + 5e-3)
    np.testing.assert_allclose(np.diff(zs), 1.25e-3, rtol=1e-9)
    assert zs.mean() == pytest.approx(zi + 2.625e-3)
    # never beyond optical infinity, never at or beyond the WRP
    zs = stack_plane_depths(z_inf_m=zi, z_far_m=zi, z_near_m=zi + 1e-3)
    assert zs[0] >= zi - 1e-15
    zs = stack_plane_depths(z_inf_m=zi, z_far_m=zi + 4e-3, z_near_m=zi + 6e-3, z_limit_m=zi + 6.2e-3)
    assert zs[-1] < zi + 6.2e-3 and zs[0] >= zi
    with pytest.raises(ValueError, match="do not fit"):
        stack_plane_depths(z_inf_m=zi, z_far_m=zi, z_near_m=zi + 1e-3, z_limit_m=zi + 2e-3)
    # spacing None: uniform from the far to the near end
    np.testing.assert_allclose(stack_plane_depths(z_inf_m=zi, z_far_m=zi + 1e-3, z_near_m=zi + 3e-3, planes=3,
                                                  spacing_m=None), zi + np.array([1e-3, 2e-3, 3e-3]))


@pytest.mark.slow
def test_each_plane_is_sharp_at_its_own_focus_and_the_loss_falls():
    # Two textured planes side by side in hologram space: A (left half) at z_A, B (right half) at z_B. The
    # focal stack at z_A, z_B and halfway: each half blurred by the pupil's geometric defocus disc, radius
    # |z - z_obj| NA / p (NA = D / 2f).
    H = W = 64
    D = 2e-3
    na = D / (2 * F_M)
    zi = 1e-3
    z_a, z_b = zi + 1.0e-3, zi + 3.5e-3
    rng = np.random.default_rng(0)
    tex = (rng.random((H // 4, W // 4)) > 0.5).repeat(4, 0).repeat(4, 1) * 0.9 + 0.05
    left = np.zeros((H, W))
    left[:, :W // 2] = 1.0
    zs = [z_a, 0.5 * (z_a + z_b), z_b]

    def target(z):
        return _disc_blur(tex * left, abs(z - z_a) * na / P) + _disc_blur(tex * (1 - left), abs(z - z_b) * na / P)

    T = np.stack([target(z) for z in zs])[:, None].clip(min=0)
    fit = optimise_focal_stack(T, zs, wavelengths_m=[LAM], pitch_m=P, focal_length_m=F_M, pupil_diameter_m=D,
                               frames=4, iterations=150, lr=0.05, seed=0)
    assert fit.phase.shape == (4, 1, H, W) and fit.phase.min() >= 0 and fit.phase.max() < 2 * math.pi
    assert len(fit.loss) == 151 and fit.loss[-1] < 0.1 * fit.loss[0]
    assert all(np.isfinite(fit.loss)) and fit.loss[-1] < fit.loss[75] < fit.loss[0]

    from holocore.evaluate.scoring import eye_view

    meta = {"focal_length_m": F_M, "pitch_m": P, "z_inf_m": zi, "wavelengths_m": [LAM]}
    u = np.exp(1j * fit.phase).astype(np.complex64)
    views = {z: eye_view(u, meta, focus_z_m=z, pupil_diameter_m=D)[0] for z in (z_a, z_b)}
    m = 12  # the SLM-aperture border at these depths: z NA / p <= 9 px
    reg_a = (slice(m, H - m), slice(m, W // 2 - 4))
    reg_b = (slice(m, H - m), slice(W // 2 + 4, W - m))
    a_own, a_other = _psnr(views[z_a][reg_a], tex[reg_a]), _psnr(views[z_b][reg_a], tex[reg_a])
    b_own, b_other = _psnr(views[z_b][reg_b], tex[reg_b]), _psnr(views[z_a][reg_b], tex[reg_b])
    # sharp at its own depth (the blurred target itself scores ~7 dB against the sharp texture), not at the other
    assert a_own > 20 and b_own > 20, (a_own, b_own)
    assert a_own > a_other + 12 and b_own > b_other + 12, (a_own, a_other, b_own, b_other)


@pytest.mark.slow
def test_a_time_limit_stops_each_colour_early_and_otherwise_changes_nothing():
    """The equal-time report gives the stack a wall-time budget. Under a limit no step can meet (1 ms) every
    colour takes exactly one step (a step's duration is known only after one) and the fit is the one-step fit,
    phases and loss; under a limit nothing reaches it is the unlimited fit. Both deterministic: no timing."""
    rng = np.random.default_rng(2)
    T = rng.random((2, 2, 24, 24))
    kw = dict(wavelengths_m=[640e-9, 455.4e-9], pitch_m=P, focal_length_m=F_M, pupil_diameter_m=1.6e-3, frames=3,
              lr=0.05, seed=3)
    zs = [2e-3, 3e-3]
    tight = optimise_focal_stack(T, zs, iterations=50, time_limit_s=1e-3, **kw)
    one = optimise_focal_stack(T, zs, iterations=1, **kw)
    assert tight.iterations == [1, 1] and one.iterations == [1, 1]
    assert np.array_equal(tight.phase, one.phase) and tight.loss == one.loss and len(tight.loss) == 2
    loose = optimise_focal_stack(T, zs, iterations=6, time_limit_s=1e6, **kw)
    free = optimise_focal_stack(T, zs, iterations=6, **kw)
    assert loose.iterations == [6, 6] and np.array_equal(loose.phase, free.phase) and loose.loss == free.loss
    assert loose.loss[-1] < loose.loss[0]
    with pytest.raises(ValueError, match="time_limit_s"):
        optimise_focal_stack(T, zs, iterations=2, time_limit_s=0.0, **kw)


def two_card_bundle(folder, *, near_m: float = 0.5, far_m: float = 0.9):
    """Two glowing textured cards: the left one ``near_m`` away, the right one ``far_m``, seen by an eye at the
    origin; each fills its half of a 64-px view and more."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    tex = ((rng.random((16, 16)) > 0.5) * 200 + 30).astype(np.uint8).repeat(8, 0).repeat(8, 1)
    Image.fromarray(np.stack([tex] * 3, axis=-1)).save(folder / "tex.png")
    card = """    <shape type="rectangle">
        <transform name="to_world"><scale x="{h}" y="{h}"/><translate x="{x}" z="{z}"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        <emitter type="area"><texture type="bitmap" name="radiance"><string name="filename" value="tex.png"/></texture></emitter>
    </shape>
"""
    # 64 px x 8 µm at f = 50 mm: tan within +-0.0051; each card fills its half of the view
    xml = folder / "scene.xml"
    xml.write_text(f"""<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="0.587"/><string name="fov_axis" value="x"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, 0, -1" up="0, 1, 0"/></transform>
    </sensor>
{card.format(h=0.008 * near_m, x=-0.008 * near_m, z=-near_m)}{
    card.format(h=0.007 / 0.9 * far_m, x=0.007 / 0.9 * far_m, z=-far_m)}</scene>
""")
    return folder


@pytest.fixture(scope="module")
def fs_result(tmp_path_factory):
    from holocore.baselines.focal_stack import render_focal_stack
    from holocore.display.profiles import PAPER, display_optics
    from holocore.io import save_result
    from holocore.scene.load import load_scene

    root = tmp_path_factory.mktemp("fs")
    scene = two_card_bundle(root / "scene")
    optics = display_optics(PAPER, overrides={"resolution_hw": (64, 64), "wavelengths_nm": [516.5], "frames": 3,
                                              "z_inf_mm": 2.0})
    # the centred fit: these tests check its planes and its views through its own pupil (the pupil-aware
    # default has its own test below)
    res = render_focal_stack(load_scene(scene), optics, planes=2, spacing_m=None, iterations=120, gt_spp=16,
                             display=PAPER, fit="centred")
    save_result(root / "RESULT.npz", slm_field=res.slm_field, wrp_field=res.wrp_field, meta=res.meta)
    return root, scene, res


@pytest.mark.slow
def test_render_focal_stack_puts_its_planes_at_the_cards(fs_result):
    _, _, res = fs_result
    m = res.meta
    fs = m["focal_stack"]
    assert m["method"] == "focal-stack" and m["display_profile"] == "paper"
    # planes across the image volume: the 0.9 m and the 0.5 m card, z_inf + f^2 / zc
    np.testing.assert_allclose(fs["plane_z_m"], [0.002 + F_M ** 2 / 0.9, 0.002 + F_M ** 2 / 0.5], atol=2e-6)
    assert fs["loss_final"] < 0.2 * fs["loss_first"]
    u = res.slm_field
    assert u.shape == (3, 1, 64, 64) and np.allclose(np.abs(u), 1.0, atol=1e-5)  # phase-only, one colour
    assert np.all(np.isfinite(res.wrp_field))


@pytest.mark.slow
def test_the_result_and_its_stack_load_in_view_and_evaluate(fs_result, tmp_path):
    from holo.app import app
    from holocore.evaluate.groundtruth import GroundTruth
    from holocore.evaluate.scoring import evaluate, eye_view, load_slm_field
    from holocore.io import save_stack
    from holocore.scene.load import load_scene

    root, scene, res = fs_result
    phase, smeta = stack_of(res)
    save_stack(tmp_path / "STACK.npz", phase=phase, meta=smeta)
    f_res, meta, kind = load_slm_field(root / "RESULT.npz")
    f_stk, _, kind2 = load_slm_field(tmp_path / "STACK.npz")
    assert (kind, kind2) == ("result", "stack")
    assert np.abs(f_res - f_stk).max() < 2e-5  # the same display: phase and laser power
    # sharper at its own card's plane: the left (0.5 m) half at the near plane, the right (0.9 m) at the far
    z_far, z_near = meta["focal_stack"]["plane_z_m"]
    D = meta["focal_stack"]["pupil_diameter_m"]
    truth = GroundTruth(load_scene(scene), meta, shape_hw=(64, 64), spp=16)
    score = {}
    for z in (z_far, z_near):
        rec = eye_view(f_res, meta, focus_z_m=z, pupil_diameter_m=D)[0]
        sharp_l = truth.channels(focus_z_m=z_near, pupil_diameter_m=D)[0]
        sharp_r = truth.channels(focus_z_m=z_far, pupil_diameter_m=D)[0]
        score[z] = (_psnr(rec[10:54, 10:28], sharp_l[10:54, 10:28]), _psnr(rec[10:54, 36:54], sharp_r[10:54, 36:54]))
    assert score[z_near][0] > score[z_far][0] + 3, score
    assert score[z_far][1] > score[z_near][1] + 3, score
    ev = evaluate(f_res, meta, truth, focus_planes=2, views=1, view_deg=0.0, pupil_diameter_m=D)
    assert len(ev.cells) == 2 and all(np.isfinite(c.score.psnr_db) for c in ev.cells)
    runner = CliRunner()
    for src in (root / "RESULT.npz", tmp_path / "STACK.npz"):
        out = tmp_path / f"{src.stem}.png"
        r = runner.invoke(app, ["view", str(src), "--focus-mm", f"{z_near * 1e3:.4f}", "--pupil-mm", "1",
                                "--out", str(out)])
        assert r.exit_code == 0, r.output
        assert out.stat().st_size > 0
    r = runner.invoke(app, ["evaluate", str(root / "RESULT.npz"), "--scene", str(scene), "--out",
                            str(tmp_path / "ev"), "--focus-planes", "1", "--views", "1", "--gt-spp", "4",
                            "--no-images"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "ev" / "metrics.json").is_file()


@pytest.mark.slow
def test_cli_writes_result_and_stack(tmp_path):
    from holo.app import app
    from holocore.io import load_result, load_stack

    scene = two_card_bundle(tmp_path / "scene")
    r = CliRunner().invoke(app, ["baseline", "focal-stack", str(scene), "--out", str(tmp_path / "R.npz"),
                                 "--stack", str(tmp_path / "S.npz"), "--resolution", "32x32", "--wavelengths-nm",
                                 "516.5", "--frames", "2", "--z-inf-mm", "2", "--planes", "2", "--spacing-mm", "1",
                                 "--iterations", "5", "--gt-spp", "4"])
    assert r.exit_code == 0, r.output
    slm, _, meta = load_result(tmp_path / "R.npz")
    phase, u8, smeta = load_stack(tmp_path / "S.npz")
    assert slm.shape == phase.shape == u8.shape == (2, 1, 32, 32)
    assert meta["focal_stack"]["planes"] == 2 and smeta["encoder"]["method"] == "focal-stack"
    np.testing.assert_allclose(np.diff(meta["focal_stack"]["plane_z_m"]), 1e-3, rtol=1e-9)
    assert meta["focal_stack"]["iterations_done"] == [5] and meta["focal_stack"]["time_limit_s"] is None
    # the default fit is the pupil-aware one: the score's 5 pupils x a 3 x 3 eye grid at each of the 2 planes
    fs = meta["focal_stack"]
    assert fs["fit"] == "pupil-aware" and fs["bank"]["views"] == 45 and fs["target_renders"] == 90
    for flag, value in (("--planes", "0"), ("--time-limit-s", "0"), ("--time-limit-s", "nan")):
        bad = CliRunner().invoke(app, ["baseline", "focal-stack", str(scene), "--out", str(tmp_path / "x.npz"),
                                       flag, value])
        assert bad.exit_code == 2 and "Traceback" not in bad.output, (flag, value, bad.output)
        assert not (tmp_path / "x.npz").exists()


@pytest.mark.slow
def test_the_pupil_aware_fit_scores_higher_than_the_centred_one_as_an_eye_sees_it(tmp_path):
    """The viewer-faithful score looks through pupils up to 6 mm from a jittered grid of eye positions; a stack
    fitted through one centred pupil was never asked for those views, the pupil-aware fit was (a bank drawn
    with another seed than the score's). Same scene, planes, frames and Adam steps for both."""
    from holocore.baselines.focal_stack import FIT_EYE_SEED, render_focal_stack
    from holocore.display.profiles import PAPER, display_optics
    from holocore.evaluate.groundtruth import GroundTruth
    from holocore.evaluate.viewer import eye_grid_m, viewer_score
    from holocore.scene.load import load_scene

    loaded = load_scene(two_card_bundle(tmp_path / "scene"))
    optics = display_optics(PAPER, overrides={"resolution_hw": (48, 48), "wavelengths_nm": [516.5], "frames": 2,
                                              "z_inf_mm": 2.0})
    pupils = [2e-3, 6e-3]
    kw = dict(planes=2, spacing_m=None, iterations=50, gt_spp=4, display=PAPER, fit_pupils_m=pupils)
    fits = {fit: render_focal_stack(loaded, optics, fit=fit, **kw) for fit in ("centred", "pupil-aware")}
    bank = fits["pupil-aware"].meta["focal_stack"]["bank"]
    score_seed = 3
    assert bank["eye_seed"] == optics.seed + FIT_EYE_SEED != score_seed
    assert bank["eye_offsets_m"] != [list(e) for _i, e in eye_grid_m(fits["centred"].meta, n=3, seed=score_seed)]
    truth = GroundTruth(loaded, fits["centred"].meta, shape_hw=(48, 48), spp=4, seed=11)
    scores = {fit: viewer_score(r.slm_field, r.meta, truth, pupils_m=pupils, eye_grid=3, seed=score_seed,
                                focus_planes=2) for fit, r in fits.items()}
    ce, pa = scores["centred"], scores["pupil-aware"]
    # 12.2 dB -> 14.5 dB mean on this scene (2 mm: 13.2 -> 15.8, 6 mm: 11.2 -> 13.1)
    assert pa.mean_psnr_db > ce.mean_psnr_db + 1.5, (ce.mean_psnr_db, pa.mean_psnr_db)
    assert pa.mean_over([6.0]) > ce.mean_over([6.0]) + 1.0, (ce.mean_over([6.0]), pa.mean_over([6.0]))
