"""Directional frames (``frame_phases="directional"``, holocore.trace.beams, docs/physics.md "Directional frames").

Frame m gives every image point Q the phase of a plane wave of direction u_m (Eq. B1), so the points' waves leave
in phase towards u_m at any depth, and a pupil averages speckle-free coherent images. Checked here: the directions
(symmetric, spread over the disc), the bank (a plane wave on the lattice, the right direction and row sign), the
split of Eq. B1 between the bank, the tracer and the per-ring factor, and with the tracer and the viewer: a
glowing plate's speckle against coded random phases, its colour in every view, and a tilted plate that must stay
as bright from the left as from the right (which needs Eq. B1's depth part).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from holocore.trace.beams import BeamDepthTerms, beam_disc_sine, beam_gain, beam_layout, beam_phase_frames

LAMS = (640e-9, 516.5e-9, 455.4e-9)
PITCH = 8e-6


@pytest.mark.parametrize("frames", [1, 3, 7, 24, 40])
def test_directions_are_symmetric_left_to_right_and_spread_over_the_disc(frames):
    d = beam_layout(frames)
    assert d.shape == (frames, 2) and np.all(np.isfinite(d))
    assert np.all(np.hypot(d[:, 0], d[:, 1]) <= 1.0)
    mirrored = d * np.array([-1.0, 1.0])
    gap = np.abs(mirrored[:, None, :] - d[None, :, :]).sum(axis=2).min(axis=1)
    assert gap.max() < 1e-12  # every direction has its mirror image: left and right views alike
    assert np.allclose(d[0], 0.0)  # frame 0 looks straight on
    if frames >= 7:  # a uniform disc's mean |d|^2 is 1/2; equal-area rings keep it
        assert abs(float((d ** 2).sum(axis=1).mean()) - 0.5) < 0.08
    assert len({(round(x, 9), round(y, 9)) for x, y in d}) == frames  # no two frames alike


def test_each_frame_of_the_bank_is_one_plane_wave_towards_its_direction():
    H, W = 36, 60
    u = beam_layout(24) * beam_disc_sine(LAMS, PITCH)
    for lam in LAMS:
        for m, phi in enumerate(beam_phase_frames(24, (H, W), lam, PITCH, wavelengths_m=LAMS)):
            spec = np.abs(np.fft.fft2(np.exp(1j * phi.astype(np.float64)))) ** 2
            assert spec.max() / spec.sum() > 0.999  # one DFT bin: a plane wave, periodic on the lattice
            ky, kx = np.unravel_index(spec.argmax(), spec.shape)
            fx = np.fft.fftfreq(W, d=PITCH)[kx]
            fy = -np.fft.fftfreq(H, d=PITCH)[ky]  # rows run down while y runs up
            assert abs(fx - u[m, 0] / lam) <= 0.5 / (W * PITCH) + 1e-6
            assert abs(fy - u[m, 1] / lam) <= 0.5 / (H * PITCH) + 1e-6
    # a colour's share in a pupil: amplitude sin(theta_min) / sin(theta_c), blue (the smallest cone) 1
    assert beam_gain(455.4e-9, PITCH, LAMS) == pytest.approx(1.0)
    assert beam_gain(640e-9, PITCH, LAMS) == pytest.approx(455.4 / 640.0, rel=1e-9)


def test_eq_b1_puts_points_at_any_depth_in_phase_towards_the_frame_direction():
    """The three parts the renderer applies (lateral bank, k dz in the tracer, the ring factor) sum to Eq. B1, and
    Eq. B1 cancels a far observer's path difference in direction u_m for points at any depth."""
    rng = np.random.default_rng(3)
    F, lam, z_ref = 24, 516.5e-9, 10e-3
    k = 2 * math.pi / lam
    terms = BeamDepthTerms.make(frames=F, first_frame=0, bank_frames=F, wavelengths_m=[lam],
                                all_wavelengths_m=LAMS, pitch_m=PITCH)
    u = beam_layout(F) * beam_disc_sine(LAMS, PITCH)
    q = np.column_stack([rng.uniform(-1e-3, 1e-3, 50), rng.uniform(-1e-3, 1e-3, 50), rng.uniform(4e-3, 9e-3, 50)])
    dz = q[:, 2] - z_ref
    ring = terms.ring_phasors(torch.from_numpy(dz))[:, 0, :].numpy()  # [points, rings]
    for m in range(F):
        w = math.sqrt(1.0 - u[m] @ u[m])
        applied = k * (q[:, :2] @ u[m]) + k * dz + np.angle(ring[:, terms.frame_ring[m]])
        np.testing.assert_allclose(np.angle(np.exp(1j * (applied - k * (q[:, :2] @ u[m] + w * dz)))), 0.0,
                                   atol=2e-3)
        # far away in direction (u_m, w): the path from Q shortens by u_m . Q_xy + w Q_z, whatever Q's depth
        at_observer = applied - k * (q[:, :2] @ u[m] + w * q[:, 2])
        spread = np.abs(np.angle(np.exp(1j * (at_observer - at_observer[0]))))
        assert spread.max() < 2e-3, m


def _plate_views(frame_phases: str, tilt_deg: float, *, spp: int = 256, frames: int = 24):
    """Centre-view image and per-view mean colour of a glowing white plate (0.5 m, fills the view), focused on it:
    paper display, 135x240, z_inf 4 mm, the paper report's pupil."""
    from holocore.display.profiles import PAPER
    from holocore.evaluate.scoring import default_pupil_m, eye_view, lit_margin_px
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.paper import paper_fov_x_deg
    from tests.trace.scenes import camera, emitting_plane, scene

    loaded = scene(sensor=camera(fov=paper_fov_x_deg()), plate=emitting_plane(-0.5, size=0.2, rotate_y_deg=tilt_deg))
    opt = PAPER.optics(resolution_hw=(135, 240), frames=frames, z_inf_mm=4.0, frame_phases=frame_phases)
    res = render_loaded(loaded, opt, RenderOptions(preset="balanced", spp=spp, wrp_planes=1), display=PAPER)
    meta = res.meta
    f = meta["focal_length_m"]
    z = meta["z_inf_m"] + f * f / 0.5
    pupil = default_pupil_m(meta, view_deg=0.5)
    colours, centre = {}, None
    for deg in (-0.5, 0.0, 0.5):
        e = (f * math.tan(math.radians(deg)), 0.0)
        img = eye_view(res.slm_field, meta, focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=e)
        mg = lit_margin_px(meta, focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=e)
        inner = img[:, mg:-mg, mg:-mg]
        assert np.all(np.isfinite(inner))
        colours[deg] = inner.reshape(3, -1).mean(axis=1)
        if deg == 0.0:
            centre = inner
    return centre, colours


@pytest.fixture(scope="module")
def facing():
    # directional frames at 1024 rays: each beam's per-ray factor 1 / K_rel (beams.py, Eq. B2) amplifies the Monte
    # Carlo noise of blue's outer frames most (gains up to 2.6 at the WRP margin), which tints the side views by
    # ~3 % more blue at 256 rays than at 1024
    return {fp: _plate_views(fp, 0.0, spp=1024 if fp == "directional" else 256) for fp in ("coded", "directional")}


@pytest.mark.slow
def test_a_glowing_plate_has_far_less_speckle_with_directional_frames(facing):
    def contrast(img):
        return float(np.mean(img.reshape(3, -1).std(axis=1) / img.reshape(3, -1).mean(axis=1)))

    coded, beams = contrast(facing["coded"][0]), contrast(facing["directional"][0])
    # coded random phases leave ~0.1 (the cross terms of cells 5 apart, which 24 codes cannot cancel)
    assert coded > 0.07, coded
    assert beams < 0.5 * coded, (beams, coded)


@pytest.mark.slow
def test_a_white_plate_stays_white_in_every_view(facing):
    """beam_gain gives every colour the share a pupil takes of random phases: the directional views' colour is
    the coded ones' within 12 % (unscaled, red / blue would be 2x; measured: 1-8 %, the most for blue in the centre
    view, whose few beams sample the ripple of the plate's sub-holograms at N_F = 2 where random phases average it
    over the pupil), and left and right views agree."""
    for deg, c in facing["directional"][1].items():
        ref = facing["coded"][1][deg]
        for a, b in ((0, 1), (2, 1)):
            assert c[a] / c[b] == pytest.approx(ref[a] / ref[b], rel=0.12), (deg, c, ref)
    d = facing["directional"][1]
    assert d[-0.5].sum() == pytest.approx(d[0.5].sum(), rel=0.05)


@pytest.mark.slow
def test_a_tilted_plate_is_as_bright_from_the_left_as_from_the_right():
    """A plate turned 12 degrees leans ~1.2 degrees in hologram space; without Eq. B1's depth part its points'
    waves would leave in phase towards u_m tilted by twice that, out of the cone for most frames, and one side
    view would go dark."""
    # 128 rays: the side views' balance is geometry, not noise (measured over seeds 0-2: left / right within 0.2 %
    # and the dimmer side 1.12x the centre at 128 rays as at 256), so fewer rays keep the same margins
    _, tilted = _plate_views("directional", 12.0, spp=128)
    left, centre, right = tilted[-0.5].sum(), tilted[0.0].sum(), tilted[0.5].sum()
    assert left / right == pytest.approx(1.0, abs=0.06), (left, right)
    assert min(left, right) > 0.7 * centre, (left, centre, right)


@pytest.mark.slow
def test_every_beam_carries_its_share_at_every_wrp_margin():
    """A glowing plate at the WRP margin (4-8 pixel footprints: N_F = 2-4 for blue, where a hard-rimmed point's
    on-axis spectrum |1 - exp(i pi N_F)| vanishes at 4 and 8): the plane-wave amplitude each frame carries, read
    off the WRP field by projecting it on the frame's beam, is the same for the on-axis frame and the rings, in
    every colour (was 0.005 for blue at margins 4 and 8 before the rim taper and Eq. B2)."""
    from holocore.display.profiles import PAPER
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.paper import paper_fov_x_deg
    from tests.trace.scenes import camera, emitting_plane, scene

    loaded = scene(sensor=camera(fov=paper_fov_x_deg()), plate=emitting_plane(-0.5, size=0.2))
    H, W = 64, 96
    for margin in (4.0, 5.0, 6.0, 8.0):
        opt = PAPER.optics(resolution_hw=(H, W), frames=24, z_inf_mm=4.0, frame_phases="directional")
        opt = opt.model_copy(update={"wrp_margin_px": margin})
        w = render_loaded(loaded, opt, RenderOptions(preset="balanced", spp=64, wrp_planes=1), display=PAPER).wrp_field
        share = np.zeros((3, 3))  # colour x (on-axis frame, first ring, second ring): power over the mean frame
        for c, lam in enumerate(opt.wavelengths_m):
            power = np.array([abs((w[m, c] * np.exp(-1j * phi))[16:-16, 24:-24].mean()) ** 2 for m, phi in
                              enumerate(beam_phase_frames(24, (H, W), lam, opt.pitch_m, wavelengths_m=LAMS))])
            share[c] = [power[0], power[1:8].mean(), power[8:].mean()]
            share[c] /= power.mean()
        assert np.all(np.isfinite(share))
        assert share.min() > 0.8 and share.max() < 1.2, (margin, share.round(3))
        on_axis = share[:, 0]
        assert on_axis.max() / on_axis.min() < 1.2, (margin, on_axis)


@pytest.mark.parametrize("depth_m", [0.3, 2.0])
def test_directional_layers_put_a_plate_at_any_depth_in_phase_with_the_frame_beam_at_the_wrp(depth_m):
    """The layer baseline's directional frames: a plate at one depth, propagated to the WRP, must arrive there as
    frame m's plane wave (the bank's phase), whatever its depth: Eq. B1's depth part per plane cancels the
    propagation's exp(i k w_m dz), so every layer's wave leaves in phase towards u_m. Without it the tilted frames
    would be 1.9 rad off at 0.5 mm; what is left (0.06 rad) is the bank's directions rounded to this small
    lattice's DFT grid (k (w_lattice - w) dz; 20x less on the display's 1080x1920)."""
    from holocore.baselines.layers import layer_fields

    H, W = 48, 64
    f, zi = 0.05, 0.08
    z_holo = zi + f * f / depth_m
    zw = z_holo + 0.5e-3
    rgb = np.ones((3, H, W))
    zc = np.full((H, W), depth_m)
    frames = 7
    _, wrp, zs, counts = layer_fields(rgb, zc, focal_length_m=f, z_inf_m=zi, z_wrp_m=zw, pitch_m=PITCH,
                                      wavelengths_m=LAMS, frames=frames, planes=1, frame_phases="directional")
    assert np.isfinite(wrp).all() and counts.tolist() == [H * W] and abs(zs[0] - z_holo) < 1e-12
    core = (slice(H // 2 - 6, H // 2 + 6), slice(W // 2 - 8, W // 2 + 8))  # far from the plate's edge waves
    for c, lam in enumerate(LAMS):
        bank = np.stack(list(beam_phase_frames(frames, (H, W), lam, PITCH, wavelengths_m=LAMS)))
        want = np.exp(1j * bank)[(slice(None),) + core]
        got = wrp[:, c][(slice(None),) + core]
        amp = np.abs(got).mean()
        rel = np.abs(got / amp - want).mean(axis=(1, 2))  # per frame: 0 when in phase with the beam
        assert rel.max() < 0.15, (lam, rel)
