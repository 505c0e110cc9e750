"""Simulated viewing (docs/design.md §7): focus, defocus blur, frame averaging and view direction."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from holocore.evaluate.metrics import speckle_contrast
from holocore.optics.rs_reference import grid_coordinates
from holocore.optics.viewing import (
    depth_of_field_m,
    pupil_mask,
    simulate_view,
    stack_to_field,
)
from holocore.trace.randomfield import phase_bank

LAM, P, N, F_EYE = 0.5e-6, 4e-6, 512, 20e-3  # sin(theta_max) = lambda / 2p = 0.0625; a 2 mm window


def point_source(z0: float, *, xp: float = 0.0, yp: float = 0.0, converging: bool = False, n: int = N) -> torch.Tensor:
    """Spherical wave exp(+-ikr)/r of a point at lateral (xp, yp), distance z0 from the plane; +: diverging from
    a point behind the plane, -: converging to a point in front. Sampled inside the band limit: the amplitude is
    flat for direction sines up to 0.045 and tapers (raised cosine) to zero at 0.058 < lambda/2p = 0.0625, so the
    local frequency never aliases. The phase k(r - z0) is formed in float64 and wrapped (docs/design.md §2)."""
    x, y = grid_coordinates((n, n), P)
    X, Y = np.meshgrid(x, y)
    rho2 = (X - xp) ** 2 + (Y - yp) ** 2
    r = np.sqrt(rho2 + z0**2)
    s = np.sqrt(rho2) / r
    s1, s2 = 0.045, 0.058
    win = np.where(s <= s1, 1.0, np.where(s >= s2, 0.0, 0.5 * (1 + np.cos(np.pi * (s - s1) / (s2 - s1)))))
    sign = -1.0 if converging else 1.0
    u = win * np.exp(1j * sign * np.mod(2 * np.pi / LAM * (r - z0), 2 * np.pi)) * (z0 / r)
    return torch.tensor(u[None], dtype=torch.complex64)


def view(u, d, D, **kw):
    return simulate_view(u, wavelengths_m=[LAM], pitch_m=P, focal_length_m=F_EYE, pupil_diameter_m=D,
                         distance_m=d, **kw)[0].numpy()


def test_depth_of_field_formula():
    na = 0.8e-3 / (2 * F_EYE)
    assert depth_of_field_m(LAM, F_EYE, 0.8e-3) == pytest.approx(LAM / na**2)
    assert depth_of_field_m(LAM, F_EYE, 1.6e-3) == pytest.approx(depth_of_field_m(LAM, F_EYE, 0.8e-3) / 4)
    with pytest.raises(ValueError, match="pupil_diameter_m"):
        depth_of_field_m(LAM, F_EYE, 0.0)


@pytest.mark.slow
@pytest.mark.parametrize("converging", [False, True])
def test_point_source_focuses_at_its_depth(converging):
    """A point z0 = 5 mm behind the plane (diverging wave) is in focus at distance -z0 (back-propagation to the
    point); a converging wave to a point z0 in front focuses at +z0. Peak intensity peaks there to within a
    small fraction of the depth of field, and the spot sits at the point's lateral position (y up)."""
    z0, xp, yp = 5e-3, 0.2e-3, 0.1e-3
    u = point_source(z0, xp=xp, yp=yp, converging=converging)
    D = 0.8e-3  # NA = 0.02 < 0.045: the pupil sees the flat part of the wave
    dof = depth_of_field_m(LAM, F_EYE, D)  # 1.25 mm
    focus = z0 if converging else -z0
    offsets = np.linspace(-0.5, 0.5, 9) * dof
    peaks = np.array([view(u, focus + o, D).max() for o in offsets])
    assert int(np.argmax(peaks)) == 4
    a, b, _ = np.polyfit(offsets, peaks, 2)
    assert a < 0 and abs(-b / (2 * a)) < 0.03 * dof  # vertex of the focus curve at the point's depth
    assert peaks[4] > 1.15 * max(peaks[0], peaks[-1])
    I = view(u, focus, D)
    i, j = np.unravel_index(np.argmax(I), I.shape)
    x, y = grid_coordinates(I.shape, P)
    assert abs(x[j] - xp) <= P and abs(y[i] - yp) <= P


def _blur_diameter(I: np.ndarray) -> float:
    """Diameter of a uniform disc with the same 50 % encircled-energy radius: 2 sqrt(2) r50 (robust to the
    faint far diffraction tails that make second moments unreliable)."""
    x, y = grid_coordinates(I.shape, P)
    X, Y = np.meshgrid(x, y)
    tot = I.sum()
    cx, cy = (I * X).sum() / tot, (I * Y).sum() / tot
    rr = np.hypot(X - cx, Y - cy).ravel()
    order = np.argsort(rr)
    cum = np.cumsum(I.ravel()[order]) / tot
    return 2 * math.sqrt(2) * rr[order][np.searchsorted(cum, 0.5)]


@pytest.mark.slow
def test_defocus_blur_grows_with_pupil_as_geometry_predicts():
    """Defocus dz in hologram space through a pupil of NA = D/(2f): the cone of half-angle NA gives a blur disc
    of diameter 2 NA |dz| (geometric optics, valid when the Fresnel number (NA dz)^2/(lambda dz) >> 1: 4.5 and
    9 here, and dz = 8-32 depths of field)."""
    z0 = 5e-3
    u = point_source(z0)
    measured = {}
    for na in (0.015, 0.03):
        D = 2 * F_EYE * na
        for dz in (10e-3, -10e-3):
            d = _blur_diameter(view(u, -z0 + dz, D))
            expected = 2 * na * abs(dz)
            assert abs(d / expected - 1) < 0.25, (na, dz, d, expected)
            measured[(na, dz)] = d
    assert measured[(0.03, 10e-3)] / measured[(0.015, 10e-3)] == pytest.approx(2.0, rel=0.25)
    # In focus the spot is much smaller than either blur disc.
    assert _blur_diameter(view(u, -z0, 2 * F_EYE * 0.03)) < 0.2 * measured[(0.03, 10e-3)]


@pytest.mark.slow
def test_frame_averaging_reduces_speckle_like_inverse_sqrt_frames():
    """A uniform diffuse patch (random phases of the bank) seen through a pupil is fully developed speckle;
    F independent frames average it down to contrast 1/sqrt(F)."""
    n = 256
    ph = phase_bank(16, (n, n), LAM, P, seed=3)
    patch = torch.zeros(n, n)
    patch[32:224, 32:224] = 1.0
    u = (stack_to_field(ph) * patch)[:, None]  # [F, C=1, H, W]
    D = 0.8e-3  # NA 0.02: speckle grain lambda / (2 NA) = 12.5 um ~ 3 px; ~1800 grains in the region
    region = np.zeros((n, n), bool)
    region[64:192, 64:192] = True
    c = {}
    for frames in (1, 4, 16):
        I = simulate_view(u[:frames], wavelengths_m=[LAM], pitch_m=P, focal_length_m=F_EYE, pupil_diameter_m=D,
                          distance_m=0.0)[0]
        c[frames] = speckle_contrast(I, mask=region)
    assert c[1] == pytest.approx(1.0, abs=0.1)  # fully developed speckle
    for frames in (4, 16):
        assert c[1] / c[frames] == pytest.approx(math.sqrt(frames), rel=0.25)


def test_view_offset_selects_the_right_direction():
    """A beam travelling up (+y) and slightly right is seen from a +y view offset, not from -y (rows run down)."""
    x, y = grid_coordinates((N, N), P)
    X, Y = np.meshgrid(x, y)
    sx, sy = 0.01, 0.03  # direction sines
    u = np.exp(-(X**2 + Y**2) / (0.4e-3) ** 2 + 2j * np.pi / LAM * (sx * X + sy * Y))
    u = torch.tensor(u[None], dtype=torch.complex64)
    D = 0.4e-3  # NA = 0.01
    e = {}
    for name, off in {"up": (sx * F_EYE, sy * F_EYE), "down": (sx * F_EYE, -sy * F_EYE),
                      "left": (-sx * F_EYE, sy * F_EYE), "centre": (0.0, 0.0)}.items():
        e[name] = view(u, 0.0, D, view_offset_m=off).sum()
    total = float((u.abs() ** 2).sum())
    assert e["up"] > 0.95 * total
    assert e["down"] < 1e-6 * total and e["left"] < 1e-6 * total and e["centre"] < 1e-6 * total


def test_pupil_mask_geometry():
    shape = (256, 384)
    m = pupil_mask(shape, LAM, P, focal_length_m=F_EYE, pupil_diameter_m=0.8e-3, view_offset_m=(0.2e-3, -0.3e-3))
    fx = np.fft.fftfreq(shape[1], P)
    fy = -np.fft.fftfreq(shape[0], P)  # y up
    sx, sy = LAM * fx[None, :], LAM * fy[:, None]
    expected = (sx - 0.2e-3 / F_EYE) ** 2 + (sy + 0.3e-3 / F_EYE) ** 2 <= (0.8e-3 / (2 * F_EYE)) ** 2
    assert np.array_equal(m.numpy(), expected)
    na = 0.02
    assert m.sum().item() == pytest.approx(math.pi * (na / LAM) ** 2 / (fx[1] * abs(fy[1])), rel=0.05)


def test_channels_frames_and_shapes():
    """Each channel is viewed at its own wavelength; [C, H, W] is one frame; output float32 [C, H, W]."""
    u1 = point_source(5e-3, n=128)[0]
    field = torch.stack([u1, u1])  # [C=2, H, W]
    lams = [LAM, 0.6e-6]
    out = simulate_view(field, wavelengths_m=lams, pitch_m=P, focal_length_m=F_EYE, pupil_diameter_m=0.8e-3,
                        distance_m=-5e-3)
    assert out.dtype == torch.float32 and out.shape == (2, 128, 128)
    one = simulate_view(field[1:], wavelengths_m=lams[1:], pitch_m=P, focal_length_m=F_EYE,
                        pupil_diameter_m=0.8e-3, distance_m=-5e-3)
    assert torch.allclose(out[1], one[0], rtol=1e-5, atol=1e-6 * float(one.max()))
    assert not torch.allclose(out[0], out[1], rtol=0.05)
    frames = torch.stack([field, 2 * field])  # mean intensity over frames: (1 + 4) / 2
    avg = simulate_view(frames, wavelengths_m=lams, pitch_m=P, focal_length_m=F_EYE, pupil_diameter_m=0.8e-3,
                        distance_m=-5e-3)
    assert torch.allclose(avg, 2.5 * out, rtol=1e-4, atol=1e-6 * float(out.max()))
    assert torch.all(torch.isfinite(avg)) and float(avg.min()) >= 0


def test_stack_to_field():
    ph = np.array([[0.0, np.pi / 2], [np.pi, 3 * np.pi / 2]], dtype=np.float32)
    u = stack_to_field(ph)
    assert u.dtype == torch.complex64 and u.shape == (2, 2)
    assert torch.allclose(u, torch.tensor([[1, 1j], [-1, -1j]], dtype=torch.complex64), atol=1e-6)
    assert torch.allclose(stack_to_field(torch.from_numpy(ph)), u)
    with pytest.raises(ValueError, match="NaN"):
        stack_to_field(np.array([np.nan]))


def test_invalid_inputs():
    u = torch.ones(1, 8, 8, dtype=torch.complex64)
    kw = dict(wavelengths_m=[LAM], pitch_m=P, focal_length_m=F_EYE, pupil_diameter_m=1e-3, distance_m=0.0)
    with pytest.raises(ValueError, match="wavelengths_m"):
        simulate_view(u, **{**kw, "wavelengths_m": [LAM, LAM]})
    with pytest.raises(ValueError, match="complex"):
        simulate_view(u.real, **kw)
    with pytest.raises(ValueError, match="pupil_diameter_m"):
        simulate_view(u, **{**kw, "pupil_diameter_m": -1.0})
    with pytest.raises(ValueError, match="distance_m"):
        simulate_view(u, **{**kw, "distance_m": float("nan")})
    with pytest.raises(ValueError, match=r"\[F, C, H, W\]"):
        simulate_view(u[0], **kw)


def _plane_wave(k_col: int, k_row: int, n: int = 256) -> torch.Tensor:
    """A plane wave on exactly k cycles of the n x n window along each axis: direction sines lambda k / (n p)."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    return torch.tensor(np.exp(2j * np.pi * (k_col * j + k_row * i) / n)[None, None], dtype=torch.complex64)


@pytest.mark.parametrize("k, inside", [((110, 110), False), ((60, 0), True)])
def test_fourier_filter_removes_light_outside_the_cone_only(k, inside):
    """A display's Fourier filter passes each colour's recording cone, direction sines <= lambda / 2p = 0.0625
    here. A plane wave in the spectrum's corner (sines 0.0537 along both axes, 0.076 off axis) reaches a 4 mm
    pupil (NA 0.1) without the filter and is gone with it; one inside the cone (0.029) is untouched."""
    from holocore.evaluate.scoring import eye_view

    u = _plane_wave(*k)
    kw = dict(wavelengths_m=[LAM], pitch_m=P, focal_length_m=F_EYE, pupil_diameter_m=4e-3, distance_m=0.0)
    bare = simulate_view(u, **kw)[0, 64:-64, 64:-64].mean().item()
    filtered = simulate_view(u, **kw, fourier_filter=True)[0, 64:-64, 64:-64].mean().item()
    assert bare == pytest.approx(1.0, rel=0.02)
    if inside:
        assert filtered == pytest.approx(bare, rel=1e-3)
    else:
        assert filtered < 0.02
    # eye_view follows the display profile in the meta: a display with a filter, and one without a profile,
    # whose square pixels then also send the wave's diffraction orders the pupil reaches (each weighted by the
    # pixel's sinc^2 relative to the zeroth order's)
    meta = {"focal_length_m": F_EYE, "z_inf_m": 0.0, "pitch_m": P, "wavelengths_m": [LAM]}
    with_filter = eye_view(u.numpy(), {**meta, "display": {"fourier_filter": True}}, focus_z_m=0.0,
                           pupil_diameter_m=4e-3)[0, 64:-64, 64:-64].mean()
    without = eye_view(u.numpy(), meta, focus_z_m=0.0, pupil_diameter_m=4e-3)[0, 64:-64, 64:-64].mean()
    na_in_orders = 4e-3 / (2 * F_EYE) * P / LAM  # the pupil's radius in units of 1/p
    fr = [kk / 256 for kk in k]  # the wave's frequency, units of 1/p
    orders = [(nx, ny) for nx in (-1, 0, 1) for ny in (-1, 0, 1)
              if math.hypot(fr[0] + nx, fr[1] + ny) <= na_in_orders]
    want = sum((np.sinc(fr[0] + nx) * np.sinc(fr[1] + ny) / (np.sinc(fr[0]) * np.sinc(fr[1]))) ** 2
               for nx, ny in orders)
    assert without == pytest.approx(want * bare, rel=0.01)
    assert len(orders) > 1 and want > 1.05  # the ghosts of other orders add their light
    assert with_filter == pytest.approx(filtered, rel=1e-3, abs=1e-4)
