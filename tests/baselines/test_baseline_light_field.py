"""The light-field baseline (holocore.baselines.light_field): a holographic stereogram on a
ray-sampling plane. Its rays are the hologram's straight rays mapped to the world, each hogel's field is the plane
waves of its directions with the traced radiance, and a card on the RS plane comes back sharp and with the right
parallax, while a card far from it cannot be brought to focus."""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from holocore.baselines.light_field import hogel_rays, rs_plane_depth, stereogram_fields
from holocore.trace.mapping import HologramMap
from tests.baselines.test_baseline_focal_stack import two_card_bundle

P, F_M, LAM = 8e-6, 0.05, 516.5e-9


def test_each_ray_is_the_hologram_ray_of_its_hogel_and_direction():
    # Independent of the module's formula: the hologram ray through the hogel centre with direction sine
    # s = lambda f must pass, in eye-camera space, through T^-1 of two of its own points on either side of the RS
    # plane (T is projective: straight lines stay straight).
    zi, zr, B, H, W = 2e-3, 5e-3, 4, 8, 12
    o, d, inside = hogel_rays((H, W), hogel_px=B, pitch_m=P, wavelength_m=LAM, focal_length_m=F_M, z_inf_m=zi,
                              z_rs_m=zr)
    hmap = HologramMap(cam_to_world=np.eye(4), focal_length_m=F_M, z_inf_m=zi)
    assert o.shape == d.shape == (H * W, 3) and inside.shape == (H * W,)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-12)
    for i, j in [(0, 0), (1, 2), (5, 9), (7, 11), (6, 3)]:
        a, u, b, v = i // B, i % B, j // B, j % B
        x0 = ((b * B + (B - 1) / 2) - (W - 1) / 2) * P
        y0 = ((H - 1) / 2 - (a * B + (B - 1) / 2)) * P
        fx = (v - (B - 1) / 2) / (B * P)
        fy = -(u - (B - 1) / 2) / (B * P)  # rows run downwards
        s = np.array([LAM * fx, LAM * fy])
        t = s / math.sqrt(1 - s @ s)
        k = i * (W) + j
        for z in (zr + 1e-3, zr - 2e-3):
            q = hmap.holo_to_camera(np.array([x0 + t[0] * (z - zr), y0 + t[1] * (z - zr), z]))
            w = q - o[k]
            w /= np.linalg.norm(w)
            np.testing.assert_allclose(w, d[k], atol=1e-9)
    # the cone is the disc |f| <= 1 / 2p: a 4-px hogel's 4 corner directions lie outside it, 12 inside
    assert inside.reshape(H // B, B, W // B, B).sum(axis=(1, 3)).tolist() == [[12] * 3] * 2
    # an even hogel's directions are symmetric about the axis: their eye-plane points sum to zero
    np.testing.assert_allclose(o[:, :2].sum(axis=0), 0.0, atol=1e-12)
    with pytest.raises(ValueError, match="optical infinity"):
        hogel_rays((4, 4), hogel_px=2, pitch_m=P, wavelength_m=LAM, focal_length_m=F_M, z_inf_m=zi, z_rs_m=zi)


def test_a_hogel_field_is_the_plane_wave_of_its_direction_with_the_traced_power():
    H, W, B = 24, 36, 6
    rad = np.zeros((1, 3, H, W))
    u0, v0 = 1, 4
    rad[0, 1, u0::B, v0::B] = 2.0  # green holds 516.5 nm; one direction per hogel
    U = stereogram_fields(rad, shape_hw=(H, W), hogel_px=B, pitch_m=P, wavelengths_m=[LAM], frames=2, seed=0,
                          coded=False).numpy()[:, 0]
    fk = (np.arange(B) - (B - 1) / 2) / (B * P)
    # one plane wave per hogel: constant power 2 / n_in (n_in directions of the cone), the phase gradient of the
    # direction (f_x, f_y) with f_y = -f_row (rows run downwards)
    n_in = int(((fk[:, None] ** 2 + fk[None, :] ** 2) <= (1 / (2 * P)) ** 2).sum())
    np.testing.assert_allclose(np.abs(U) ** 2, 2.0 / n_in, rtol=1e-4)
    gx = np.angle(U[0, :, 1:] * np.conj(U[0, :, :-1]))
    gy = np.angle(U[0, :-1, :] * np.conj(U[0, 1:, :]))  # along +y: from row i+1 up to row i
    inner_x = (np.arange(W - 1) % B) != B - 1
    inner_y = (np.arange(H - 1) % B) != B - 1
    np.testing.assert_allclose(gx[:, inner_x], 2 * math.pi * fk[v0] * P, atol=1e-4)
    np.testing.assert_allclose(gy[inner_y, :], 2 * math.pi * (-fk[u0]) * P, atol=1e-4)
    # uniform radiance L: mean power L over the SLM (Parseval), whatever the random phases
    U = stereogram_fields(np.full((1, 3, H, W), 0.7), shape_hw=(H, W), hogel_px=B, pitch_m=P, wavelengths_m=[LAM],
                          frames=3, seed=1).numpy()
    np.testing.assert_allclose((np.abs(U) ** 2).mean(axis=(-2, -1)), 0.7, rtol=1e-4)
    with pytest.raises(ValueError, match="radiance must be"):
        stereogram_fields(rad[:, :, :5], shape_hw=(H, W), hogel_px=B, pitch_m=P, wavelengths_m=[LAM], frames=1)


def test_the_rs_plane_sits_in_the_image_volume():
    assert rs_plane_depth(z_inf_m=2e-3, z_wrp_m=9e-3, z_far_m=3e-3, z_near_m=5e-3) == pytest.approx(4e-3)
    assert rs_plane_depth(z_inf_m=2e-3, z_wrp_m=9e-3, z_far_m=None, z_near_m=None) == pytest.approx(3.75e-3)
    assert 2e-3 < rs_plane_depth(z_inf_m=2e-3, z_wrp_m=9e-3, z_far_m=2e-3, z_near_m=2e-3) < 9e-3
    assert rs_plane_depth(z_inf_m=2e-3, z_wrp_m=9e-3, z_far_m=8e-3, z_near_m=12e-3) < 9e-3


N = 128
ZI = 0.5e-3
NEAR_M, FAR_M = 1.5, 5.0  # the cards: hologram depths ZI + f^2 / zc = 2.17 and 1.0 mm


@pytest.fixture(scope="module", params=["stereogram", "sgd"])
def lf_result(request, tmp_path_factory):
    from holocore.baselines.light_field import render_light_field
    from holocore.display.profiles import PAPER, display_optics
    from holocore.io import save_result
    from holocore.scene.load import load_scene

    root = tmp_path_factory.mktemp("lf")
    scene = two_card_bundle(root / "scene", near_m=NEAR_M, far_m=FAR_M)
    optics = display_optics(PAPER, overrides={"resolution_hw": (N, N), "wavelengths_nm": [516.5], "frames": 6,
                                              "z_inf_mm": ZI * 1e3})
    res = render_light_field(load_scene(scene), optics, hogel_px=2, spp=8, z_rs_m=ZI + F_M ** 2 / NEAR_M,
                             display=PAPER, fit=request.param, iterations=100, lr=0.1)
    save_result(root / "RESULT.npz", slm_field=res.slm_field, wrp_field=res.wrp_field, meta=res.meta)
    return root, scene, res


def _psnr(recon: np.ndarray, ref: np.ndarray) -> float:
    s = float((recon * ref).sum() / (recon * recon).sum())  # one least-squares brightness scale
    return 10 * math.log10(float(ref.max()) ** 2 / float(np.mean((s * recon - ref) ** 2)))


@pytest.mark.slow
def test_parallax_is_right_and_the_card_off_the_rs_plane_never_focuses(lf_result):
    from holocore.evaluate.groundtruth import GroundTruth
    from holocore.evaluate.scoring import eye_view, lit_margin_px
    from holocore.scene.load import load_scene

    _, scene, res = lf_result
    m = res.meta
    assert m["method"] == "light-field" and m["display_profile"] == "paper"
    assert m["light_field"]["hogels_hw"] == [N // 2, N // 2]
    assert res.slm_field.shape == (6, 1, N, N) and np.all(np.isfinite(res.slm_field))
    z_near, z_far = ZI + F_M ** 2 / NEAR_M, ZI + F_M ** 2 / FAR_M
    D, e = 2e-3, 1e-3
    truth = GroundTruth(load_scene(scene), m, shape_hw=(N, N), spp=16)

    def halves(z):
        g = max(lit_margin_px(m, focus_z_m=z, pupil_diameter_m=D, view_offset_m=(v, 0.0)) for v in (-e, e))
        return (slice(g, N - g), slice(g, N // 2 - 3)), (slice(g, N - g), slice(N // 2 + 3, N - g))

    def view(z, ex):
        return eye_view(res.slm_field, m, focus_z_m=z, pupil_diameter_m=D, view_offset_m=(ex, 0.0))[0]

    def gt(z, ex):
        return truth.channels(focus_z_m=z, pupil_diameter_m=D, view_offset_m=(ex, 0.0))[0]

    # Measured (stereogram / SGD fit): own / other side view near card 14.6 / 6.2 and 10.1 / 5.3 dB, far card
    # 14.4 / 11.3 and 9.4 / 8.2 dB; the near card 14.1 and 10.4 dB; the far card at its focus against the blurred
    # / sharp view 14.1 / 11.9 and 9.8 / 8.7 dB. The fit matches every hogel's 2 x 2 direction powers and leaves
    # what lies inside a hogel free: a noisier image, with the same rays.
    margin, floor, blur = (2.0, 12.0, 1.0) if m["light_field"]["fit"] == "stereogram" else (1.0, 9.0, 0.5)
    # Parallax, focused on the RS plane: between eyes 2 mm apart the near card moves 8.3 px, the far one 2.5 px.
    # Each side view must match its own ground truth better than the other side's, for both cards (a mirrored
    # or missing parallax fails).
    near, far = halves(z_near)
    for ex in (-e, e):
        r, own, other = view(z_near, ex), gt(z_near, ex), gt(z_near, -ex)
        for reg in (near, far):
            assert _psnr(r[reg], own[reg]) > _psnr(r[reg], other[reg]) + margin, (ex, reg)
    # The near card on the RS plane comes back (a 2-px hogel and 6 frames of speckle limit it) ...
    assert _psnr(view(z_near, 0.0)[near], gt(z_near, 0.0)[near]) > floor
    # ... the far card never focuses: at its own depth it still looks as it does out of focus
    near, far = halves(z_far)
    r = view(z_far, 0.0)
    assert _psnr(r[far], gt(z_near, 0.0)[far]) > _psnr(r[far], gt(z_far, 0.0)[far]) + blur


@pytest.mark.slow
def test_cli_light_field_writes_a_result_and_rejects_bad_input(lf_result, tmp_path):
    from holo.app import app

    root, scene, _ = lf_result
    runner = CliRunner()
    out = tmp_path / "R.npz"
    r = runner.invoke(app, ["baseline", "light-field", str(scene), "--out", str(out), "--resolution", "32x32",
                            "--frames", "2", "--spp", "2", "--hogel-px", "4"])
    assert r.exit_code == 0, r.output
    assert out.exists() and "8x8 hogels of 4 px" in r.output
    r = runner.invoke(app, ["baseline", "light-field", str(scene), "--out", str(out), "--resolution", "24x24",
                            "--frames", "2", "--spp", "2", "--fit", "sgd", "--iterations", "3"])
    assert r.exit_code == 0 and "3/3/3 Adam steps" in r.output, r.output
    for bad, msg in ((["--hogel-px", "0"], "--hogel-px"), (["--spp", "0"], "--spp"), (["--rs-mm", "-1"], "--rs-mm"),
                     (["--rs-mm", "1"], "between optical infinity"), (["--fit", "best"], "--fit"),
                     (["--fit", "sgd", "--lr", "0"], "--lr"), (["--device", "tpu"], "--device")):
        r = runner.invoke(app, ["baseline", "light-field", str(scene), "--out", str(tmp_path / "x.npz"),
                                "--resolution", "32x32", "--frames", "1", "--spp", "1", *bad])
        assert r.exit_code != 0 and msg in r.output and "Traceback" not in r.output, r.output
        assert not (tmp_path / "x.npz").exists()


@pytest.mark.slow
def test_a_black_scene_and_an_emitter_seen_edge_on_stay_finite():
    """Never NaN: a scene with nothing lit gives a zero field; a glowing card seen almost edge-on (grazing hogel
    rays) and the sky behind it give finite radiance and a finite field."""
    from holocore.baselines.light_field import render_light_field
    from holocore.display.profiles import PAPER, display_optics
    from tests.trace.scenes import T, camera, emitting_plane, scene

    optics = display_optics(PAPER, overrides={"resolution_hw": (24, 32), "frames": 2, "z_inf_mm": 1.0})
    wall = {"type": "rectangle", "to_world": T().translate([0, 0, -2]).scale(5),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}}
    res = render_light_field(scene(sensor=camera(fov=0.4), wall=wall), optics, hogel_px=4, spp=2)
    assert res.slm_field.shape == (2, 3, 24, 32) and np.abs(res.slm_field).max() == 0
    grazing = emitting_plane(-1.0, size=0.5, rotate_y_deg=89.9)
    res = render_light_field(scene(sensor=camera(fov=0.4), card=grazing), optics, hogel_px=4, spp=2)
    assert np.all(np.isfinite(res.slm_field)) and np.all(np.isfinite(res.wrp_field))
    assert np.abs(res.slm_field).max() > 0  # the card is seen: a thin glowing line


@pytest.mark.slow
def test_the_fit_reads_a_stereogram_back_and_fits_phase_only_frames_to_a_light_field():
    """The SGD fit's light field (holocore.baselines.light_field_fit) is the exact analysis of the stereogram's
    synthesis: a complex stereogram taken to the SLM and back gives its own hogel powers. Phase-only frames fitted
    to that light field reach it far closer than random phases do."""
    import torch

    from holocore.baselines.light_field import hogel_amplitudes, stereogram_fields
    from holocore.baselines.light_field_fit import light_field_of, optimise_light_field
    from holocore.optics.propagation import asm

    H, W, B, zr = 36, 48, 3, 0.6e-3
    rng = np.random.default_rng(4)
    rad = rng.random((1, 3, H, W)) + 0.2
    target = hogel_amplitudes(rad, shape_hw=(H, W), hogel_px=B, pitch_m=P, wavelengths_m=[LAM])[0].astype(float) ** 2
    rs = stereogram_fields(rad, shape_hw=(H, W), hogel_px=B, pitch_m=P, wavelengths_m=[LAM], frames=4, seed=2)[:, 0]
    # on the RS plane itself (a vanishing distance): exactly its hogel powers, in every frame's average
    got = light_field_of(rs, hogel_px=B, z_rs_m=1e-12, wavelength_m=LAM, pitch_m=P).numpy()
    np.testing.assert_allclose(got, target, rtol=1e-4, atol=1e-5 * target.max())
    # through the SLM 0.6 mm away and back: the same up to the light the SLM's window crops (1 % in amplitude)
    slm = asm(rs, -zr, LAM, P)
    got = light_field_of(slm, hogel_px=B, z_rs_m=zr, wavelength_m=LAM, pitch_m=P).numpy()
    inner = (slice(6, H - 6), slice(6, W - 6))
    assert np.corrcoef(got[inner].ravel(), target[inner].ravel())[0, 1] > 0.995

    fit = optimise_light_field(target[None], shape_hw=(H, W), hogel_px=B, z_rs_m=zr, wavelengths_m=[LAM], pitch_m=P,
                               frames=4, iterations=150, lr=0.1, seed=0)
    assert fit.phase.shape == (4, 1, H, W) and fit.iterations == [150]
    assert all(np.isfinite(fit.loss)) and fit.loss[-1] < 0.5 * fit.loss[0], fit.loss[::30]
    u = torch.polar(torch.ones(4, H, W), torch.from_numpy(fit.phase[:, 0]))
    lf = light_field_of(u, hogel_px=B, z_rs_m=zr, wavelength_m=LAM, pitch_m=P).numpy()
    lit = target > 0
    corr_fit = np.corrcoef(np.sqrt(lf[lit]), np.sqrt(target[lit]))[0, 1]
    u0 = torch.polar(torch.ones(4, H, W), torch.from_numpy(rng.random((4, H, W)).astype(np.float32) * 6.283))
    lf0 = light_field_of(u0, hogel_px=B, z_rs_m=zr, wavelength_m=LAM, pitch_m=P).numpy()
    corr_rand = np.corrcoef(np.sqrt(lf0[lit]), np.sqrt(target[lit]))[0, 1]
    assert corr_fit > corr_rand + 0.3
