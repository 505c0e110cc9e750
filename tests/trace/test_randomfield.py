"""Band-limited random fields and phase banks (paper Eq. 4, docs/design.md §4)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats

from holocore.trace.randomfield import (
    passband_mask,
    passband_radius,
    phase_bank,
    random_field,
)

LAM, P = 516.5e-9, 8e-6


def test_passband_radius_and_mask():
    assert passband_radius(LAM, P) == pytest.approx(1 / (2 * P))  # sin(theta_max)/lambda = 1/(2p)
    assert passband_radius(455e-9, 0.2e-6) == pytest.approx(1 / 455e-9)  # lambda >= 2p: theta_max = pi/2
    theta = math.asin(LAM / (2 * P))
    assert passband_radius(LAM, P) == pytest.approx(math.sin(theta) / LAM, rel=1e-12)
    m = passband_mask((64, 96), LAM, (8e-6, 6e-6))
    assert m.shape == (64, 96) and m.dtype == bool
    fx = np.fft.fftfreq(96, 6e-6)
    fy = np.fft.fftfreq(64, 8e-6)
    rho = 1 / (2 * 8e-6)  # the coarser axis sets the circle
    f = np.hypot(fx[None, :], fy[:, None])
    assert np.array_equal(m, f <= rho * (1 + 1e-12))
    assert m[0, 0] and not m[32, 48]
    # a circle: its area is close to pi rho^2 in frequency cells
    assert m.sum() == pytest.approx(math.pi * rho**2 / ((fx[1]) * (fy[1])), rel=0.03)


def test_spectrum_inside_passband():
    shape = (96, 128)
    for lam, p in ((LAM, P), (455e-9, 0.2e-6), (640e-9, (8e-6, 4e-6))):
        r = random_field(3, shape, lam, p, seed=5).to(torch.complex128).numpy()
        spec = np.abs(np.fft.fft2(r)) ** 2
        m = passband_mask(shape, lam, p)
        outside = spec[:, ~m].sum() / spec.sum()
        assert outside < 1e-10
        # ... and it fills the passband: every kept frequency carries the same power.
        inside = spec[:, m]
        assert inside.min() > 0.99 * inside.max()
        assert abs(np.mean(np.abs(r) ** 2) - 1) < 1e-5  # unit mean intensity


def test_phase_bank_is_arg_of_random_field_and_in_range():
    ph = phase_bank(4, (64, 80), LAM, P, seed=11)
    r = random_field(4, (64, 80), LAM, P, seed=11)
    assert ph.dtype == torch.float32 and ph.shape == (4, 64, 80)
    assert float(ph.min()) >= 0.0 and float(ph.max()) < 2 * math.pi
    d = torch.remainder(ph.double() - torch.angle(r.to(torch.complex128)) + math.pi, 2 * math.pi) - math.pi
    assert float(d.abs().max()) < 1e-5


def test_phases_are_uniform():
    """arg of a circular random field is exactly uniform on [0, 2pi). With the passband at Nyquist the
    correlation length is ~1 px; subsampling every 3rd pixel gives near-independent samples for a KS test."""
    ph = phase_bank(2, (384, 384), LAM, P, seed=2).numpy()
    samples = ph[:, ::3, ::3].ravel() / (2 * np.pi)
    res = stats.kstest(samples, "uniform")
    assert res.pvalue > 1e-3
    hist, _ = np.histogram(samples, bins=32, range=(0, 1))
    chi2 = stats.chisquare(hist)
    assert chi2.pvalue > 1e-3


def test_frames_are_uncorrelated():
    F, shape = 6, (256, 256)
    ph = phase_bank(F, shape, LAM, P, seed=9).double()
    e = torch.polar(torch.ones_like(ph), ph).reshape(F, -1)
    n = e.shape[1]
    c = (e @ e.conj().T).abs() / n
    off = c[~torch.eye(F, dtype=torch.bool)]
    assert float(off.max()) < 5 / math.sqrt(n)
    assert torch.allclose(torch.diagonal(c), torch.ones(F, dtype=torch.float64))


def test_determinism_and_independence():
    a = phase_bank(3, (48, 64), LAM, P, seed=123)
    b = phase_bank(3, (48, 64), LAM, P, seed=123)
    assert torch.equal(a, b)
    c = phase_bank(3, (48, 64), LAM, P, seed=124)
    assert not torch.equal(a, c)
    assert float((a - c).abs().mean()) > 1.0  # not a small perturbation: a different bank
    # frame m does not depend on how many frames were asked for
    d = phase_bank(5, (48, 64), LAM, P, seed=123)
    assert torch.equal(d[:3], a)
    # each wavelength gets its own stream, even at the same seed and grid
    g = phase_bank(3, (48, 64), 640e-9, P, seed=123)
    e1 = torch.polar(torch.ones_like(a.double()), a.double()).reshape(3, -1)
    e2 = torch.polar(torch.ones_like(g.double()), g.double()).reshape(3, -1)
    assert float(((e1 * e2.conj()).mean(dim=1)).abs().max()) < 5 / math.sqrt(e1.shape[1])


def test_periodic_lookup_wraps_smoothly():
    """The field is periodic on H x W: the step across the wrap behaves like any interior step."""
    r = random_field(1, (128, 128), LAM, P, seed=4)[0].to(torch.complex128)
    interior = (r[:, 1:] - r[:, :-1]).abs().square().mean()
    wrap = (r[:, 0] - r[:, -1]).abs().square().mean()
    assert 0.5 * float(interior) < float(wrap) < 2.0 * float(interior)
    wrap_rows = (r[0, :] - r[-1, :]).abs().square().mean()
    assert 0.5 * float(interior) < float(wrap_rows) < 2.0 * float(interior)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(frames=0), "frames"),
        (dict(frames=2.5), "frames"),
        (dict(seed=-1), "seed"),
        (dict(shape_hw=(0, 4)), "shape_hw"),
        (dict(wavelength_m=float("nan")), "wavelength_m"),
        (dict(pitch_m=0.0), "pitch_m"),
        (dict(pitch_m=(1e-6, 2e-6, 3e-6)), "pitch_m"),
    ],
)
def test_invalid_inputs(kwargs, match):
    args = dict(frames=2, shape_hw=(8, 8), wavelength_m=LAM, pitch_m=P, seed=0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        phase_bank(args["frames"], args["shape_hw"], args["wavelength_m"], args["pitch_m"], seed=args["seed"])


# ---- coded frames (docs/physics.md, "Coded frame phases") ----------------------------------------------------
def test_coded_frames_cancel_every_cross_term_within_the_code_distance():
    from holocore.trace.randomfield import code_multiplier, frame_codes

    F, shape = 24, (40, 48)
    a, dist = code_multiplier(F)
    assert dist >= 5.0  # the best lattice code of 24 frames: no same-code pair closer than 5.1 cells
    ph = phase_bank(F, shape, 516.5e-9, 8e-6, seed=5, coded_frames=F).double().numpy()
    u = np.exp(1j * ph)  # [F, H, W]
    codes = frame_codes(shape, F)
    for di in range(-5, 6):
        for dj in range(-5, 6):
            if (di, dj) == (0, 0) or math.hypot(di, dj) >= dist:
                continue
            a_, b_ = u[:, 8:32, 8:40], np.roll(u, (di, dj), axis=(1, 2))[:, 8:32, 8:40]
            cross = np.abs((a_ * np.conj(b_)).sum(axis=0))  # |sum_m exp(i (phi_m(a) - phi_m(b)))|
            assert np.all(np.roll(codes, (di, dj), axis=(0, 1))[8:32, 8:40] != codes[8:32, 8:40])
            assert cross.max() < 1e-3 * F, (di, dj, cross.max())
    # independent frames: a random walk, |sum| ~ sqrt(F)
    ind = np.exp(1j * phase_bank(F, shape, 516.5e-9, 8e-6, seed=5).double().numpy())
    assert np.abs((ind[:, :, :-1] * np.conj(ind[:, :, 1:])).sum(axis=0)).mean() > 0.5 * math.sqrt(F)


def test_coded_frames_are_chunkable_and_start_from_the_independent_bank():
    F, shape = 8, (16, 20)
    whole = phase_bank(F, shape, 640e-9, 8e-6, seed=2, coded_frames=F)
    part = phase_bank(3, shape, 640e-9, 8e-6, seed=2, coded_frames=F, first_frame=4)
    assert torch.equal(whole[4:7], part)
    assert torch.allclose(whole[0], phase_bank(1, shape, 640e-9, 8e-6, seed=2)[0], atol=1e-6)
    assert float(whole.min()) >= 0.0 and float(whole.max()) < 2 * math.pi
    with pytest.raises(ValueError, match="not in a bank of 8 coded frames"):
        phase_bank(3, shape, 640e-9, 8e-6, seed=2, coded_frames=F, first_frame=6)


def test_coded_frames_cut_the_speckle_seen_through_a_small_pupil():
    # A uniform surface of random-phase cells seen in focus through a pupil of 0.4 of the recording cone (the
    # eye's resolution spot covers ~6 cells): the 24-frame average of independent frames keeps speckle of
    # contrast ~1/sqrt(24) = 0.2; coded frames cancel the cross terms of all cells closer than 5.1 cells (the
    # rest: same-code cells in the spot's side lobes).
    F, n, lam, p = 24, 128, 640e-9, 8e-6
    fx = np.fft.fftfreq(n, p)
    pupil = (fx[None, :] ** 2 + fx[:, None] ** 2) <= (0.4 / (2 * p)) ** 2

    def contrast(ph):
        u = np.exp(1j * ph.double().numpy())
        img = (np.abs(np.fft.ifft2(np.fft.fft2(u) * pupil)) ** 2).mean(axis=0)
        return float(img.std() / img.mean())

    c_ind = contrast(phase_bank(F, (n, n), lam, p, seed=9))
    c_cod = contrast(phase_bank(F, (n, n), lam, p, seed=9, coded_frames=F))
    assert c_ind == pytest.approx(1 / math.sqrt(F), rel=0.3)
    assert c_cod < 0.7 * c_ind, (c_cod, c_ind)  # measured 0.117 against 0.195: 4.4 dB less speckle power


def test_no_frame_code_beats_one_over_sqrt_frames_under_a_wide_defocus_blur():
    # The limit of coded frames (docs/physics.md, "Coded frame phases"): with F frames the cells' phase vectors
    # v_a in C^F can be orthogonal for at most F cells, and the frame potential bound gives a mean squared
    # cross-correlation of at least ~1/F over N >> F cells. Once a defocus blur spans many code distances the
    # F-frame average keeps speckle of contrast 1/sqrt(F), coded or not; in focus coded frames stay well below.
    F, n, lam, p = 24, 192, 640e-9, 8e-6
    fx = np.fft.fftfreq(n, p)
    rho2 = fx[None, :] ** 2 + fx[:, None] ** 2
    pupil = rho2 <= (0.4 / (2 * p)) ** 2  # the paper report's pupil is 0.40-0.57 of the cones
    kz = 2 * np.pi * np.sqrt(np.maximum(0.0, 1 / lam ** 2 - rho2))

    def contrast(ph, dz_m):
        u = np.exp(1j * ph.double().numpy())
        img = (np.abs(np.fft.ifft2(np.fft.fft2(u) * pupil * np.exp(1j * kz * dz_m))) ** 2).mean(axis=0)
        return float(img.std() / img.mean())

    coded = phase_bank(F, (n, n), lam, p, seed=9, coded_frames=F)
    ind = phase_bank(F, (n, n), lam, p, seed=9)
    # 3 mm of hologram depth: a blur of 12 cells, 2.3 code distances across (measured 0.187 / 0.201)
    c_cod, c_ind = contrast(coded, 3e-3), contrast(ind, 3e-3)
    assert c_ind == pytest.approx(1 / math.sqrt(F), rel=0.15)
    assert c_cod > 0.8 / math.sqrt(F), (c_cod, c_ind)
    assert contrast(coded, 0.0) < 0.7 * c_cod  # in focus the code still cancels most of it (measured 0.117)
