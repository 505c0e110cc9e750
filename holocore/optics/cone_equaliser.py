"""The angular spectrum of the ray estimator's point response near its recording plane, and the radial equaliser
that gives it the band-limited point's flat spectrum (DESIGN.md §4, "Cone equaliser"; docs/physics.md).

The rays of an image point Q at distance d from its recording plane fill the cone of half-angle theta_c, so
their expected field on the plane is the spherical wave cut at the cone's rim (:mod:`holocore.trace.tile`):

    U_d(rho) = exp(i k sqrt(rho^2 + d^2)) / sqrt(rho^2 + d^2)   for rho <= R = d tan(theta_c), 0 beyond.   (C1)

The band-limited point the ground truth and the viewer assume has a flat angular spectrum inside the cone,
|H(f)|^2 proportional to 1 / cos^2(theta(f)) (Weyl's expansion of exp(ikr)/r), cut at f_c = sin(theta_c) /
lambda. The two agree when the sub-hologram holds many Fresnel zones, N_F = R^2 / (lambda d) >> 1. At the
recording plane's margin (4 pixel footprints: N_F = 2 for the widest color) the hard cut in space rings in
angle: the spectrum of (C1), the Hankel transform

    H_d(f) = 2 pi int_0^R U_d(rho) J_0(2 pi f rho) rho drho,                                           (C2)

swings between 0.1 and 2.7 times its mean, differently for each color (its N_F differs), so a view through
the middle of the cone sees other colors than a view through its side (on the mirror paper scene: red 14 %
too dim in the centre view against the side views, blue 11 % too bright). The equaliser divides that out on
average over the image points a plane records (their distances d_j, luminance-weighted samples from the
analysis):

    E(f) = sqrt(G_ideal(f) / S(f)),  S(f) = sum_{m,n in -1..1} mean_j |H_{d_j}(g)|^2 B(g),  g = f + (m, n)/p,
    B(g) = sinc^2(g_x p) sinc^2(g_y p)     inside the cone (clipped to E_MAX), 0 outside,               (C3)

S being what the plane's pixels hold: the rim's diffraction reaches past the grid's Nyquist frequency and
folds back (the aliases add in power, the image points sitting anywhere in their pixels; the rays leave
the pixel centres, DESIGN §4). B is the power spectrum of one random-phase cell: the tracer looks phi_m(Q) up
in the bank cell that holds Q, so the image points of a surface form a sheet whose phase is constant over
p x p cells, and its light falls off with angle as B does (at the cone's rim, sin theta_c = lambda / 2p, to
0.41 on the axes). The viewer's pupil spans a wider part of the cone the shorter the wavelength, so without B
a white card came out red about 4 % too bright and blue 3-5 % too dim in every view (measured at the paper's
wavelengths). B holds for every point, so a plane whose points are all far (Weyl's spectrum) is filtered
too, by 1 / sqrt(B). Both spectra are in absolute units (the cut spherical
wave's power, pi ln(1 + tan^2 theta_c) for every d, partly leaks past the cone's rim at small N_F; the
ideal's is pi sin^2 theta_c). The filter is applied to each recording plane's own field before anything is
added to it or it is propagated (:mod:`holocore.optics.plane_chain`). Outside the cone the field of a
band-limited point is zero: what the estimator put there is Monte Carlo noise and the rim's diffraction,
which no view inside the cone sees, so the filter is 0 there. Image points more than ``MAX_FRESNEL`` zones
from their plane count with Weyl's spectrum (times B); a plane that records no point is untouched.

Units: metres; frequencies in cycles per metre; rho_n = f / f_c (dimensionless).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Optional, Sequence

import numpy as np
import torch

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, theta_max_rad
from holocore.optics.propagation import ifft2, smooth_at_least

__all__ = ["point_power_spectrum", "ideal_power_spectrum", "mean_point_spectrum", "equaliser_gain", "equalise_plane",
           "PlaneEqualiser", "plane_equalisers", "RHO_N", "E_MAX", "MAX_FRESNEL"]

E_MAX = 2.5  # largest gain of the equaliser (ripple minima of a single distance would otherwise amplify noise)
MAX_FRESNEL = 40.0  # Fresnel zones beyond which a point's spectrum counts as Weyl's (its ringing is fine-grained)
RHO_N = np.linspace(0.0, 5.0, 641)  # normalised radial frequencies f / f_c of the tables (the aliases reach 5)
_MAX_DISTANCES = 16  # distinct distances per plane the mean of (C3) is computed at (quantiles of the samples)


def _cone(wavelength_m: float, pitch_m: float) -> tuple[float, float]:
    """(tan theta_c, f_c) of the recording cone, theta_c capped at 89 degrees as in the tracer."""
    th = min(theta_max_rad(wavelength_m, pitch_m), MAX_CONE_HALF_ANGLE_RAD)
    return math.tan(th), math.sin(th) / wavelength_m


def _fresnel_zones(distance_m, wavelength_m: float, pitch_m: float):
    """N_F = d tan^2(theta_c) / lambda of points at ``distance_m`` (m; a number or an array) from their plane."""
    return distance_m * _cone(wavelength_m, pitch_m)[0] ** 2 / wavelength_m


def point_power_spectrum(distance_m: float, wavelength_m: float, pitch_m: float) -> np.ndarray:
    """|H_d(f)|^2 of Eq. C2 (the cone-cut spherical wave at ``distance_m`` m; m^2) at f = RHO_N f_c, float64."""
    d = float(distance_m)
    if not (math.isfinite(d) and d > 0):
        raise ValueError(f"distance_m must be a positive number, got {distance_m!r}")
    return _tabulated(float(f"{d:.4e}"), float(wavelength_m), float(pitch_m)).copy()  # 4 digits: reused


@lru_cache(maxsize=512)
def _tabulated(distance_m: float, wavelength_m: float, pitch_m: float) -> np.ndarray:
    from scipy.special import j0

    tan_c, f_c = _cone(wavelength_m, pitch_m)
    d = float(distance_m)
    R = d * tan_c
    # The chirp's local frequency reaches f_c at the rim, J0's 5 f_c: 12 samples per cycle there, midpoint rule.
    n = max(64, int(math.ceil(12.0 * R * f_c * RHO_N[-1])))
    rho = (np.arange(n) + 0.5) * (R / n)
    r = np.hypot(rho, d)
    u = np.exp(1j * (2.0 * math.pi / wavelength_m) * r) / r * rho * (R / n)
    f = RHO_N * f_c
    out = np.empty(f.shape, dtype=np.float64)
    for a in range(0, f.size, 32):  # [32, n] Bessel blocks: bounded memory for wide sub-holograms
        h = 2.0 * math.pi * (j0(2.0 * math.pi * np.outer(f[a:a + 32], rho)) @ u)
        out[a:a + 32] = np.abs(h) ** 2
    return out


def ideal_power_spectrum(wavelength_m: float, pitch_m: float, rho_n: np.ndarray = RHO_N) -> np.ndarray:
    """The band-limited point's |H(f)|^2 = lambda^2 / cos^2 theta(f) inside the cone, 0 outside (m^2; the
    plane-wave expansion of exp(ikr)/r, whose spectrum is i lambda exp(i k_z d) / cos theta), float64."""
    _tan_c, f_c = _cone(wavelength_m, pitch_m)
    rho_n = np.asarray(rho_n, dtype=np.float64)
    s = np.clip(rho_n * f_c * wavelength_m, 0.0, 1.0 - 1e-12)
    return np.where(rho_n <= 1.0, wavelength_m ** 2 / (1.0 - s * s), 0.0)


def mean_point_spectrum(distances_m: Sequence[float], wavelength_m: float, pitch_m: float) -> Optional[np.ndarray]:
    """mean_j |H_{d_j}|^2 at RHO_N for image points at ``distances_m`` (m, equal weights) from their plane;
    None when there are none or the nearest is more than ``MAX_FRESNEL`` zones away (Weyl's spectrum)."""
    d = np.asarray(distances_m, dtype=np.float64).reshape(-1)
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0 or _fresnel_zones(d.min(), wavelength_m, pitch_m) > MAX_FRESNEL:
        return None
    qs = np.quantile(d, (np.arange(_MAX_DISTANCES) + 0.5) / _MAX_DISTANCES)
    ideal = ideal_power_spectrum(wavelength_m, pitch_m)
    far = _fresnel_zones(qs, wavelength_m, pitch_m) > MAX_FRESNEL  # these count with Weyl's spectrum: costly, flat
    return np.mean([ideal if fj else point_power_spectrum(dj, wavelength_m, pitch_m) for dj, fj in zip(qs, far)],
                   axis=0)


def _cell_box(f: torch.Tensor, pitch_m: float) -> torch.Tensor:
    """B's factor along one axis at frequency ``f`` (1/m): sinc^2(f p), the power spectrum of a random-phase
    cell p wide. (Rays that leave points spread over their pixel, with several planes, still estimate the
    field at the pixel's centre: no further factor.)"""
    return torch.sinc(f * pitch_m) ** 2


def equaliser_gain(spectrum: Optional[np.ndarray], wavelength_m: float, pitch_m: float,
                   shape_hw: tuple[int, int]) -> torch.Tensor:
    """E(f) of Eq. C3 on the DFT grid ``shape_hw`` (numpy's frequency order), float64: ``spectrum`` the mean
    point spectrum at RHO_N (None: Weyl's, which leaves 1 / sqrt(B) inside the cone)."""
    _tan_c, f_c = _cone(wavelength_m, pitch_m)
    table = torch.from_numpy(ideal_power_spectrum(wavelength_m, pitch_m) if spectrum is None else spectrum)
    step = RHO_N[1] - RHO_N[0]

    def lookup(rho: torch.Tensor) -> torch.Tensor:  # linear interpolation, 0 beyond the table
        pos = rho / step
        i0 = pos.floor().long().clamp(max=len(RHO_N) - 2)
        t = pos - i0
        return torch.where(rho <= RHO_N[-1], table[i0] * (1 - t) + table[i0 + 1] * t, 0.0)

    fy = torch.fft.fftfreq(shape_hw[0], d=pitch_m, dtype=torch.float64)[:, None]
    fx = torch.fft.fftfreq(shape_hw[1], d=pitch_m, dtype=torch.float64)[None, :]
    s = torch.zeros(shape_hw, dtype=torch.float64)
    for m in (-1, 0, 1):
        for n in (-1, 0, 1):
            gy, gx = fy + m / pitch_m, fx + n / pitch_m
            s += lookup(torch.sqrt(gy * gy + gx * gx) / f_c) * _cell_box(gy, pitch_m) * _cell_box(gx, pitch_m)
    rho = torch.sqrt(fy * fy + fx * fx) / f_c
    ideal = torch.from_numpy(ideal_power_spectrum(wavelength_m, pitch_m, rho.numpy()))
    gain = torch.sqrt(ideal / s.clamp_min(1e-300)).clamp(max=E_MAX)
    return gain.masked_fill(rho > 1.0, 0.0)


def equalise_plane(field_: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
    """The recording plane's field [..., H, W] filtered by ``gain`` (:func:`equaliser_gain` on a grid at least
    [H, W]; zero padding beyond the field, so the filter does not wrap around). Returns a new tensor of the
    field's shape."""
    h, w = field_.shape[-2], field_.shape[-1]
    spec = torch.fft.fft2(field_, s=tuple(gain.shape))
    spec.mul_(gain.to(device=field_.device, dtype=field_.real.dtype))  # a no-op for a PlaneEqualiser's gains
    return ifft2(spec)[..., :h, :w].contiguous()


@dataclass(frozen=True)
class PlaneEqualiser:
    """The equaliser of one recording plane: per lit color its mean point spectrum at RHO_N (None: Weyl's),
    the zero padding its filter needs (px), and the Fresnel zones of its nearest image point in the widest
    color's cone (None: it records no point)."""

    spectra: tuple[Optional[np.ndarray], ...]
    border_px: int
    fresnel_zones: Optional[float]
    _gains: dict = field(default_factory=dict, compare=False, repr=False)  # color -> gain grid of one shape

    def active(self, color: int) -> bool:
        """Whether the plane's field of lit color ``color`` is filtered at all: whenever it records a point (the
        cell spectrum B of Eq. C3 holds for all of them)."""
        return self.fresnel_zones is not None and 0 <= color < len(self.spectra)

    def apply(self, field_: torch.Tensor, color: int, wavelength_m: float, pitch_m: float) -> torch.Tensor:
        """``field_`` [..., H, W] of lit color ``color`` equalised (the same tensor when there is nothing to do)."""
        if not self.active(color):
            return field_
        h, w = field_.shape[-2], field_.shape[-1]
        b = min(self.border_px, h, w)  # at most the ASM's own 2x padding
        shape = (smooth_at_least(h + b), smooth_at_least(w + b))
        g = self._gains.get(color)
        if g is None or tuple(g.shape) != shape or g.device != field_.device:
            # once per color of a plane (its chunks of frames alternate colors), in the field's precision
            g = equaliser_gain(self.spectra[color], wavelength_m, pitch_m, shape)
            g = self._gains[color] = g.to(device=field_.device, dtype=field_.real.dtype)
        return equalise_plane(field_, g)


def plane_equalisers(distances_by_plane_m: Sequence[Sequence[float]], wavelengths_m: Sequence[float],
                     pitch_m: float) -> list[PlaneEqualiser]:
    """One :class:`PlaneEqualiser` per recording plane from the distances (m) of the image points it records
    (:meth:`holocore.plan.wrp_planes.WrpPlanes.distances_by_plane_m`), for the lit ``wavelengths_m``."""
    out = []
    tan_w = max(_cone(lam, pitch_m)[0] for lam in wavelengths_m)
    for dists in distances_by_plane_m:
        d = np.asarray(dists, dtype=np.float64).reshape(-1)
        d = d[np.isfinite(d) & (d > 0)]
        spectra = tuple(mean_point_spectrum(d, lam, pitch_m) for lam in wavelengths_m)
        zones = float(d.min() * tan_w ** 2 / min(wavelengths_m)) if d.size else None
        # The filter's reach: about the diameter of the widest sub-hologram it was computed from.
        border = int(math.ceil(2.0 * float(np.max(d, initial=0.0)) * tan_w / pitch_m)) + 8
        out.append(PlaneEqualiser(spectra, border, zones))
    return out
