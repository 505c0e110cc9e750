"""Band-limited ASM (holocore.optics.propagation) against analytic Gaussian beams and direct Rayleigh-Sommerfeld sums.

Accuracy targets: relative L2 error <= 1e-4 in complex64 wherever the sampling allows (docs/design.md §5). Each
geometry below states why its sampling allows it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from holocore.optics import propagation
from holocore.optics.grids import reach_grid, spread_px
from holocore.optics.propagation import asm, padded_shape, transfer_function
from holocore.optics.rs_reference import grid_coordinates, rs_direct


def rel_l2(a, b) -> float:
    a = np.asarray(a, dtype=np.complex128)
    b = np.asarray(b, dtype=np.complex128)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def gaussian_beam(shape, pitch, wavelength, w0, z, *, x0=0.0, y0=0.0) -> np.ndarray:
    """Paraxial Gaussian beam, waist w0 at z = 0 centred at (x0, y0): (q0/q) exp(i k rho^2 / 2q) exp(ikz),
    q = z - i z_R. Including exp(ikz) (wrapped in float64) makes it directly comparable with the ASM."""
    x, y = grid_coordinates(shape, pitch)
    X, Y = np.meshgrid(x, y)
    k = 2 * np.pi / wavelength
    z_r = np.pi * w0**2 / wavelength
    q = z - 1j * z_r
    rho2 = (X - x0) ** 2 + (Y - y0) ** 2
    return (-1j * z_r / q) * np.exp(1j * k * rho2 / (2 * q)) * np.exp(1j * math.remainder(k * z, 2 * np.pi))


def tilted_gaussian(shape, pitch, w0, fx0=0.0, fy0=0.0) -> np.ndarray:
    """exp(-rho^2/w0^2) exp(i 2 pi (fx0 x + fy0 y)), x right and y up (docs/design.md §3)."""
    x, y = grid_coordinates(shape, pitch)
    X, Y = np.meshgrid(x, y)
    return np.exp(-(X**2 + Y**2) / w0**2 + 2j * np.pi * (fx0 * X + fy0 * Y))


def run(u: np.ndarray, z, lam, pitch, dtype=torch.complex64, **kw) -> np.ndarray:
    return asm(torch.tensor(u, dtype=dtype), z, lam, pitch, **kw).numpy()


# ---- analytic Gaussian beams -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "shape,pitch,lam,w0,z",
    [
        # Divergence theta = lambda/(pi w0) = 3.2e-3; the paraxial phase error ~ k z theta^4 / 8 = 8e-6 rad.
        # w(z) = 167 um: the 2 mm window holds +-6 w; local frequency at 4 w is 2.4e4 /m << 1/(2p) = 1.25e5.
        ((512, 512), 4e-6, 0.5e-6, 50e-6, 0.05),
        # 1 m at 455.4 nm: theta = 7.2e-4, paraxial error ~5e-7 rad; w(1 m) = 0.75 mm in a 6.1 mm window.
        ((512, 512), 12e-6, 455.4e-9, 200e-6, 1.0),
        # Same beam back-propagated (a waist at z = 0 is symmetric: U(-z) = conj of U(z) up to exp(ikz)).
        ((512, 512), 12e-6, 455.4e-9, 200e-6, -1.0),
    ],
)
def test_gaussian_beam_matches_paraxial_analytic(shape, pitch, lam, w0, z):
    u0 = gaussian_beam(shape, pitch, lam, w0, 0.0)
    expected = gaussian_beam(shape, pitch, lam, w0, z)
    for dtype in (torch.complex64, torch.complex128):
        assert rel_l2(run(u0, z, lam, pitch, dtype), expected) <= 1e-4


# ---- direct Rayleigh-Sommerfeld sums ---------------------------------------------------------------------
# rs_direct is a midpoint rule, exact when field + kernel frequencies stay below 1/p at every output point;
# the windows below keep the steepest source-to-output angle well inside that (otherwise the sum shows a
# ghost where the kernel's local frequency aliases to 0).
@pytest.mark.parametrize(
    "shape,pitch,lam,w0,z,fx0,fy0",
    [
        # Moderately non-paraxial: w0 = 8 lambda, z = z_R; max angle sin = 0.3 -> 6e5 /m < 1/p = 1e6 /m.
        pytest.param((64, 64), 1e-6, 0.5e-6, 4e-6, 100e-6, 0.0, 0.0, marks=pytest.mark.slow),
        # Sub-wavelength pitch (0.2 um at 455 nm): every propagating angle is sampled; w0 = 0.7 um puts the
        # evanescent part of the spectrum below exp(-23), so ASM (which drops it) and RS agree at z = 11 lambda.
        pytest.param((64, 64), 0.2e-6, 455e-9, 0.7e-6, 5e-6, 0.0, 0.0, marks=pytest.mark.slow),
        # Non-square grid, different pitch per axis, tilt along x only: x/y swaps in the pitch or the grid move
        # or squash the beam and fail by ~100 %.
        ((40, 80), (1.0e-6, 0.8e-6), 0.5e-6, 3e-6, 150e-6, 1e5, 0.0),
        # Tilt along both axes, downwards in y (rows run down): catches the row-direction sign.
        ((40, 80), (1.0e-6, 0.8e-6), 0.5e-6, 3e-6, 150e-6, 1e5, -0.5e5),
    ],
)
def test_asm_matches_rayleigh_sommerfeld(shape, pitch, lam, w0, z, fx0, fy0):
    u = tilted_gaussian(shape, pitch, w0, fx0, fy0)
    ref = rs_direct(u, z, lam, pitch)
    assert np.all(np.isfinite(ref))
    assert rel_l2(run(u, z, lam, pitch), ref) <= 1e-4
    if isinstance(pitch, tuple):  # the test is sensitive: swapping the pitches is far off
        assert rel_l2(run(u, z, lam, pitch[::-1]), ref) > 0.3


def test_rs_direct_far_field_is_fraunhofer():
    """Sanity of the reference itself: far from a small aperture it is the Fraunhofer pattern (1/(i lambda z))
    exp(ikr) A FT[u], i.e. peak |U| = area / (lambda z) on axis."""
    p, lam, z = 1e-6, 0.5e-6, 20e-3
    u = np.zeros((8, 8), complex)
    u[2:6, 2:6] = 1.0  # 4 x 4 um square: Fraunhofer distance a^2/lambda = 32 um << 20 mm
    out = rs_direct(u, z, lam, p, out_shape=(1, 1))
    assert abs(abs(out[0, 0]) - (16e-12) / (lam * z)) < 1e-6 * abs(out[0, 0])


def test_rs_direct_validates():
    u = np.ones((4, 4), complex)
    for bad in (dict(distance_m=0.0), dict(distance_m=-1e-3), dict(distance_m=float("nan"))):
        with pytest.raises(ValueError, match="distance_m"):
            rs_direct(u, bad["distance_m"], 0.5e-6, 1e-6)
    with pytest.raises(ValueError, match="pitch_m"):
        rs_direct(u, 1e-3, 0.5e-6, (1e-6, -1e-6))
    with pytest.raises(ValueError, match="2D"):
        rs_direct(np.ones(4, complex), 1e-3, 0.5e-6, 1e-6)


# ---- band limit per axis ---------------------------------------------------------------------------------
def test_transfer_function_band_limit_per_axis():
    """Support of H along each axis equals the Matsushima-Shimobaba limit of that axis (padded size, pitch)."""
    shape, pitch, lam, z = (64, 256), (1.5e-6, 1.0e-6), 0.5e-6, 1.5e-3
    tf = transfer_function(shape, z, lam, pitch, dtype=torch.complex128).numpy()
    fy = np.fft.fftfreq(shape[0], d=pitch[0])
    fx = np.fft.fftfreq(shape[1], d=pitch[1])
    for f, line, n, p in ((fx, tf[0, :], shape[1], pitch[1]), (fy, tf[:, 0], shape[0], pitch[0])):
        limit = 1.0 / (lam * math.sqrt((2 * z / (n * p)) ** 2 + 1))
        kept = np.abs(line) > 0.5
        assert np.all(np.abs(f[kept]) <= limit)
        assert np.all(np.abs(f[~kept]) > limit)
        assert kept.sum() < n  # the limit does cut on both axes here ...
    # ... and the two axes cut at different frequencies (a swap would exchange them).
    assert np.abs(fx[np.abs(tf[0]) > 0.5]).max() > 2 * np.abs(fy[np.abs(tf[:, 0]) > 0.5]).max()
    assert np.allclose(np.abs(tf[np.abs(tf) > 0.5]), 1.0, atol=1e-12)  # unit modulus where kept
    # Unlimited: only the evanescent components are dropped.
    free = transfer_function(shape, z, lam, pitch, band_limit=False, dtype=torch.complex128).numpy()
    assert np.all(np.abs(free) > 0.5)  # 1/(2p) < 1/lambda on both axes: nothing evanescent here


def test_band_limit_keeps_x_tilt_on_a_short_wide_grid():
    """A beam tilted along x on a 32 x 256 grid: the narrow y axis has the tight limit (1.06e5 /m), the wide x
    axis a loose one (7.8e5 /m). The 2e5 /m tilt must survive; with the axes swapped it would be cut away."""
    shape, p, lam, z, w0, fx0 = (32, 256), 1e-6, 0.5e-6, 600e-6, 6e-6, 2e5
    u = tilted_gaussian(shape, p, w0, fx0, 0.0)
    out = run(u, z, lam, p, torch.complex128)
    # Reference without band limit on an 8x padded grid (no wrap-around for this geometry).
    ref = run(u, z, lam, p, torch.complex128, pad_factor=8, band_limit=False)
    assert rel_l2(out, ref) < 0.05
    x, _ = grid_coordinates(shape, p)
    I = np.abs(out) ** 2
    cx = float((I.sum(0) * x).sum() / I.sum())
    walk = lam * fx0 * z / math.sqrt(1 - (lam * fx0) ** 2)  # geometric walk-off of the tilted beam, 60 um
    assert abs(cx - walk) < 0.02 * walk
    # The same tilt along y on this grid leaves the window; the energy that stays is tiny either way.
    uy = tilted_gaussian(shape, p, w0, 0.0, fx0)
    assert np.sum(np.abs(run(uy, z, lam, p, torch.complex128)) ** 2) < 1e-2 * np.sum(I)


@pytest.mark.parametrize("shape,z", [((128, 256), 2e-3), ((192, 320), 10e-3)])
def test_reach_grid_keeps_the_window_and_a_smaller_grid_wraps(shape, z):
    """The render's short plane-to-plane and WRP-to-SLM steps pad only by the distance's sideways reach
    (grids.reach_grid). On a full-band random-phase field (the worst case: every direction of the band at full
    strength, each pixel a sharp-edged source) that stays within 3 % (rel. L2) of an 8x padded reference, where
    the 2x grid is within 1 %: the rest is the hard band edge's slowly decaying tails, far below the renderer's
    Monte Carlo noise. A grid that pads by a third of the reach wraps the field around (over 10 %)."""
    pitch, lam = 8e-6, 640e-9
    rng = np.random.default_rng(3)
    u = np.exp(2j * np.pi * rng.random(shape))
    ref = run(u, z, lam, pitch, torch.complex128, pad_factor=8)
    grid = reach_grid(shape, z, lam, pitch)
    r = spread_px(z, lam, pitch)
    assert r > 5 and grid[0] < 2 * shape[0] and grid[1] < 2 * shape[1]  # smaller than the 2x grid
    assert rel_l2(run(u, z, lam, pitch, torch.complex128), ref) < 0.01
    assert rel_l2(run(u, z, lam, pitch, torch.complex128, grid=grid), ref) < 0.03
    short = (shape[0] + r // 3, shape[1] + r // 3)
    assert rel_l2(run(u, z, lam, pitch, torch.complex128, grid=short), ref) > 0.1
    with pytest.raises(ValueError, match="at least the field's size"):
        run(u, z, lam, pitch, grid=(shape[0] - 1, shape[1]))


def test_transpose_symmetry_with_swapped_pitch():
    rng = np.random.default_rng(1)
    u = rng.normal(size=(24, 40)) + 1j * rng.normal(size=(24, 40))
    a = run(u, 80e-6, 0.6e-6, (1.3e-6, 0.9e-6), torch.complex128)
    b = run(u.T.copy(), 80e-6, 0.6e-6, (0.9e-6, 1.3e-6), torch.complex128)
    assert np.allclose(a, b.T, rtol=0, atol=1e-12 * np.abs(a).max())


# ---- identities ------------------------------------------------------------------------------------------
def test_zero_distance_is_an_identity_copy():
    u = torch.randn(3, 17, 23, dtype=torch.complex64)
    out = asm(u, 0.0, 0.5e-6, 2e-6)
    assert torch.equal(out, u)
    out[0, 0, 0] = 42.0
    assert u[0, 0, 0] != 42.0  # a copy, not the input itself


def test_round_trip_returns_the_field():
    """z then -z: inside the band limit and the window, the field comes back (complex64)."""
    # w0 = 40 um: spectrum exp(-(pi w0 f)^2) dies far inside the band limits; at 10 mm w = 57 um and the
    # walk-off 25 um, so the beam stays > 6 w inside the 768 um window both ways.
    shape, p, lam, w0 = (384, 384), 2e-6, 0.5e-6, 40e-6
    u = tilted_gaussian(shape, p, w0, 5e3, -2.5e3)
    for z in (2e-3, 10e-3):
        back = run(run(u, z, lam, p), -z, lam, p)
        assert rel_l2(back, u) < 1e-5


@pytest.mark.slow
def test_long_distance_phase_precision_complex64():
    """1 m at 455.4 nm: k z ~ 1.4e7 rad. The complex64 result must match a complex128 computation, which needs
    the transfer function's phase formed and wrapped in float64 (in float32 it would be off by ~1 rad)."""
    shape, p, lam = (256, 256), 8e-6, 455.4e-9
    rng = np.random.default_rng(7)
    u = gaussian_beam(shape, p, lam, 150e-6, 0.0) * np.exp(1j * rng.uniform(0, 0.3, shape))
    for z in (0.1, 0.5, 1.0):
        a = run(u, z, lam, p, torch.complex64)
        b = run(u, z, lam, p, torch.complex128)
        assert rel_l2(a, b) < 1e-5
    tf = transfer_function(shape, 1.0, lam, p, dtype=torch.complex64).numpy()
    dc = np.exp(1j * math.remainder(2 * math.pi / lam * 1.0, 2 * math.pi))
    assert abs(tf[0, 0] - dc) < 1e-6


def test_subwavelength_pitch_has_no_nan_and_no_gain():
    """p = 0.2 um at 455 nm: part of the DFT grid is evanescent. Output finite, energy never grows."""
    rng = np.random.default_rng(3)
    u = rng.normal(size=(64, 96)) + 1j * rng.normal(size=(64, 96))
    e0 = np.sum(np.abs(u) ** 2)
    for z in (1e-6, 50e-6, 1e-3, -1e-3):
        for bl in (True, False):
            out = run(u, z, 455e-9, 0.2e-6, band_limit=bl)
            assert np.all(np.isfinite(out))
            assert np.sum(np.abs(out) ** 2) <= e0 * (1 + 1e-5)
    tf = transfer_function((128, 192), 1e-3, 455e-9, 0.2e-6, band_limit=False, dtype=torch.complex128).numpy()
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(192, 0.2e-6), np.fft.fftfreq(128, 0.2e-6)))
    assert np.all(tf[f > 1 / 455e-9] == 0)  # evanescent dropped
    assert np.all(np.abs(tf[f < 0.99 / 455e-9]) > 0.5)


# ---- production sizes ------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("shape", [(1024, 1024), (1080, 1920)])
def test_production_sizes_against_analytic_and_complex128(shape):
    """Full-size grids padded 2x (2048^2, 2160 x 3840): an off-centre Gaussian beam (so x/y mix-ups show)
    against the paraxial formula, and a tilted beam in complex64 against complex128."""
    assert padded_shape(shape, 2) == (2 * shape[0], 2 * shape[1])
    p, lam, w0, z = 8e-6, 516.5e-9, 250e-6, 0.2  # theta 6.6e-4 -> paraxial error 6e-8 rad; w(z) = 0.28 mm
    x0, y0 = 3.0e-3, -1.0e-3  # 4.7 mm from the x edge at 1920 columns, >= 11 w from every edge
    if shape[1] < 1500:
        x0 = 1.5e-3
    u0 = gaussian_beam(shape, p, lam, w0, 0.0, x0=x0, y0=y0)
    expected = gaussian_beam(shape, p, lam, w0, z, x0=x0, y0=y0)
    out64 = run(u0, z, lam, p, torch.complex64)
    assert np.all(np.isfinite(out64))
    assert rel_l2(out64, expected) <= 1e-4

    ut = tilted_gaussian(shape, p, 400e-6, 2e4, -1e4)  # sines 0.0103 and -0.0052
    a = run(ut, z, lam, p, torch.complex64)
    b = run(ut, z, lam, p, torch.complex128)
    assert rel_l2(a, b) <= 1e-5
    x, y = grid_coordinates(shape, p)
    I = np.abs(a) ** 2
    cx = float((I.sum(0) * x).sum() / I.sum())
    cy = float((I.sum(1) * y).sum() / I.sum())
    sx, sy = lam * 2e4, -lam * 1e4
    cz = math.sqrt(1 - sx**2 - sy**2)
    assert abs(cx - z * sx / cz) < 0.01 * abs(z * sx / cz)
    assert abs(cy - z * sy / cz) < 0.01 * abs(z * sy / cz)


# ---- API behaviour ---------------------------------------------------------------------------------------
def test_batch_dtype_and_shape_preserved():
    u = torch.randn(2, 3, 20, 30, dtype=torch.complex128)
    out = asm(u, 1e-3, 0.5e-6, 2e-6)
    assert out.shape == u.shape and out.dtype == torch.complex128 and out.device == u.device
    one = asm(u[1, 2], 1e-3, 0.5e-6, 2e-6)
    assert torch.allclose(out[1, 2], one, rtol=0, atol=1e-12)
    out32 = asm(u.to(torch.complex64), 1e-3, 0.5e-6, (2e-6, 2e-6))
    assert out32.dtype == torch.complex64
    assert rel_l2(out32.numpy(), out.numpy()) < 1e-5
    # A non-contiguous input is fine.
    v = u.transpose(-1, -2)
    assert torch.allclose(asm(v, 1e-3, 0.5e-6, 2e-6), asm(v.contiguous(), 1e-3, 0.5e-6, 2e-6))


def test_autograd_through_asm():
    """The encoder optimises through asm: gradients must flow and match finite differences."""
    torch.manual_seed(0)
    phi = (torch.rand(6, 10, dtype=torch.float64) * 6.0).requires_grad_(True)
    target = torch.randn(6, 10, dtype=torch.complex128)

    def loss(ph):
        out = asm(torch.polar(torch.ones_like(ph), ph), 30e-6, 0.5e-6, 1e-6)
        return (out - target).abs().square().sum()

    assert torch.autograd.gradcheck(loss, (phi,), eps=1e-6, atol=1e-5)
    with torch.no_grad():
        fast = asm(torch.polar(torch.ones_like(phi), phi), 30e-6, 0.5e-6, 1e-6)
    slow = asm(torch.polar(torch.ones_like(phi), phi), 30e-6, 0.5e-6, 1e-6)
    assert torch.allclose(fast, slow.detach(), rtol=0, atol=1e-12)


def test_transfer_function_is_a_fresh_tensor_and_cache_is_bounded():
    propagation.clear_cache()
    u = torch.randn(16, 16, dtype=torch.complex64)
    before = asm(u, 1e-3, 0.5e-6, 2e-6)
    tf = transfer_function(padded_shape((16, 16)), 1e-3, 0.5e-6, 2e-6)
    tf.zero_()  # must not poison the cache
    assert torch.equal(asm(u, 1e-3, 0.5e-6, 2e-6), before)
    for i in range(3 * propagation._TF_CACHE_MAX_ENTRIES):
        asm(u, 1e-3 + i * 1e-6, 0.5e-6, 2e-6)
    assert len(propagation._tf_cache) <= propagation._TF_CACHE_MAX_ENTRIES


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(field=torch.ones(4, 4)), "complex"),
        (dict(field=np.ones((4, 4), complex)), "torch tensor"),
        (dict(field=torch.ones(4, dtype=torch.complex64)), r"\[\.\.\., H, W\]"),
        (dict(wavelength_m=0.0), "wavelength_m"),
        (dict(wavelength_m=float("nan")), "wavelength_m"),
        (dict(pitch_m=-1e-6), "pitch_m"),
        (dict(pitch_m=(1e-6, float("inf"))), "pitch_x"),
        (dict(pitch_m=(1e-6, 1e-6, 1e-6)), "pitch_y, pitch_x"),
        (dict(distance_m=float("inf")), "distance_m"),
        (dict(distance_m="1"), "distance_m"),
        (dict(pad_factor=0.5), "pad_factor"),
    ],
)
def test_invalid_inputs_raise_clear_errors(kwargs, match):
    args = dict(field=torch.ones(4, 4, dtype=torch.complex64), distance_m=1e-3, wavelength_m=0.5e-6, pitch_m=1e-6)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        asm(args.pop("field"), args.pop("distance_m"), args.pop("wavelength_m"), args.pop("pitch_m"), **args)


@pytest.mark.slow
@pytest.mark.parametrize("shape", [(2048, 2048), (2160, 3840), (1, 2, 2048, 2048)])
def test_inverse_fft_is_right_at_padded_production_sizes(shape):
    """The inverse DFT every module uses (propagation.ifft2) against numpy in float64, on the padded grids of
    1024 x 1024 and 1080 x 1920 SLMs, batched and not (torch's own CPU ifft2 fails on unbatched 2048^2
    complex64 with two threads)."""
    from holocore.optics.propagation import ifft2

    rng = np.random.default_rng(5)
    x = (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64)
    ref = np.fft.ifft2(x.astype(np.complex128))
    assert rel_l2(ifft2(torch.from_numpy(x)).numpy(), ref) <= 1e-6
    assert rel_l2(ifft2(torch.from_numpy(x.astype(np.complex128))).numpy(), ref) <= 1e-12


@pytest.mark.slow
def test_sqrt_is_accurate_and_the_same_in_every_fresh_process():
    """torch's CPU sqrt runs on MKL's vector math over two threads; when its first call raced, about one process
    in three computed the worker thread's half in a low-accuracy mode (2e5 ulp in float64), so one seed gave a
    service job a stack that differed from the CLI's. holocore.runtime.torch_runtime starts MKL on one thread first."""
    import subprocess
    import sys
    code = ("import numpy as np, torch, holocore.optics.propagation as p; torch.set_num_threads(2); "
            "a = torch.linspace(1e9, 3e12, 96 * 96, dtype=torch.float64); r = np.sqrt(a.numpy()); "
            "print(int(np.abs((torch.sqrt(a).numpy() - r) / np.spacing(r)).max()), "
            "p.transfer_function((96, 96), 0.004, 640e-9, 8e-6, dtype=torch.complex128).abs().sum().item())")
    # 8 fresh processes, started together (each spends its seconds importing torch; the race is per process)
    procs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(8)]
    outs = []
    for proc in procs:
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
        outs.append(out.split())
    assert all(int(o[0]) <= 1 for o in outs), outs  # worst error in ulp, in each process
    assert len({o[1] for o in outs}) == 1, outs  # the same transfer function everywhere
