"""The angular spectrum of what the ray estimator records from a lit surface near its recording plane, and the
equaliser that gives it the band-limited points' flat spectrum (docs/design.md §4, "Cone equaliser"; docs/physics.md).

The rays of an image point Q at distance d from its recording plane fill the cone of half-angle theta_c, so
their expected field on the plane is the spherical wave cut at the cone's rim (:mod:`holocore.trace.tile`):

    U_d(rho) = exp(i k sqrt(rho^2 + d^2)) / sqrt(rho^2 + d^2)   for rho <= R = d tan(theta_c), 0 beyond.   (C1)

The band-limited point the ground truth and the viewer assume has a flat angular spectrum inside the cone,
G_ideal(f) = lambda^2 / cos^2(theta(f)) (Weyl's expansion of exp(ikr)/r), cut at f_c = sin(theta_c) / lambda.
The two agree when the sub-hologram holds many Fresnel zones, N_F = R^2 / (lambda d) >> 1. At the recording
plane's margin (4 pixel footprints: N_F = 2 for the widest color) the hard cut in space rings in angle (its
Hankel transform swings between 0.1 and 2.7 times its mean), differently for each color, so a view through the
middle of the cone saw other colors than a view through its side (mirror paper scene: red 14 % too dim in the
centre view against the side views, blue 11 % too bright).

A surface is not a set of isolated points: the tracer looks phi_m(Q) up in the bank cell that holds Q, so the
image points of a surface form a sheet whose phase c_j is constant over each p x p cell, the cells on the
pixel lattice, and the rays record the field at the pixel centres. The recorded field is then the cell
sequence convolved with the cell's mean of (C1), sampled on the lattice, and its spectrum is c(f) times

    K_d(f) = p^2 sum_n k_d[n] exp(-2 pi i f . n p),  k_d[n] = mean over the cell u of U_d(n p - u),      (C2)

the DFT of the cell-averaged cut wave on the lattice. c(f) is periodic in f with the lattice, so all aliases
of (C2) add coherently, and the cell's average gives the sinc^2(f_x p) sinc^2(f_y p) fall-off that made a white
card red 4 % too bright and blue 3-5 % too dim before it was modelled (the pupil spans more of the cone the
shorter the wavelength). The equaliser divides both out on average over the image points a plane records
(their distances d_j, luminance-weighted samples from the analysis):

    E(f) = sqrt(G_ideal(f) / S(f)),  S(f) = mean_j |K_{d_j}(f)|^2   inside the cone (clipped to E_MAX),
                                                                        0 outside.                     (C3)

With few rays the recording also holds Monte Carlo noise, white over the lattice's band (the pixels' rays are
independent): N per frequency where the signal has A S(f). Through (C3) a view then sees E^2 (A S + N) =
A G + N G / S, brighter where S is weak (the rim, the ripples' minima), by a pattern that differs per colour: a
white card at 128 rays came out red / blue 1.07 in the centre view and 0.95 in the side views (1.00 at 1024
rays). The gain therefore flattens the total power instead:

    E(f) = sqrt(G_ideal(f) / (S(f) + N / A)),   N / A from the least-squares fit P = A S + N of the power
                                                 P(f) of the plane's frame 0 inside the cone.           (C4)

A view then sees the band-limited points' brightness in every colour and direction, on average; the noise
stays (no filter can take it away) but no longer tints. With many rays N / A -> 0 and (C4) is (C3).

Points more than ``MAX_FRESNEL`` zones from their plane count with |K|^2 = G_ideal B, B = sinc^2(f_x p)
sinc^2(f_y p) (their rim's diffraction is negligible), so every plane that records a point is filtered; one
that records none is untouched. S is computed on an M x M DFT grid of the lattice (M at least 4 sub-hologram
diameters, so its ripples are resolved) and interpolated onto each field's grid. The filter is applied to each
recording plane's own field before anything is added to it or it is propagated
(:mod:`holocore.optics.plane_chain`). Outside the cone the field of a band-limited point is zero: what the
estimator put there is Monte Carlo noise and the rim's diffraction, which no view inside the cone sees.

Units: metres; frequencies in cycles per metre; spectra in m^2 (|FT of exp(ikr)/r|^2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import torch

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, theta_max_rad
from holocore.optics.propagation import ifft2, smooth_at_least

__all__ = ["sheet_spectrum", "ideal_power_spectrum", "cell_spectrum", "mean_sheet_spectrum", "equaliser_gain",
           "equalise_plane", "PlaneEqualiser", "plane_equalisers", "NoiseFit", "noise_floor", "E_MAX", "MAX_FRESNEL"]

E_MAX = 2.5  # largest gain of the equaliser (ripple minima of a single distance would otherwise amplify noise)
MAX_FRESNEL = 40.0  # Fresnel zones beyond which a point's spectrum counts as Weyl's (its ringing is fine-grained)
_MAX_DISTANCES = 16  # distinct distances per plane the mean of (C3) is computed at (quantiles of the samples)
_SUB = 6  # sub-samples per cell side of the cell's mean in (C2): at the rim (half a cycle per cell) +2 % power
_MIN_GRID, _MAX_GRID = 64, 2048  # the M of the DFT grid S is computed on


def _cone(wavelength_m: float, pitch_m: float) -> tuple[float, float]:
    """(tan theta_c, f_c) of the recording cone, theta_c capped at 89 degrees as in the tracer."""
    th = min(theta_max_rad(wavelength_m, pitch_m), MAX_CONE_HALF_ANGLE_RAD)
    return math.tan(th), math.sin(th) / wavelength_m


def _fresnel_zones(distance_m, wavelength_m: float, pitch_m: float):
    """N_F = d tan^2(theta_c) / lambda of points at ``distance_m`` (m; a number or an array) from their plane."""
    return distance_m * _cone(wavelength_m, pitch_m)[0] ** 2 / wavelength_m


def _grid_size(distance_m: float, wavelength_m: float, pitch_m: float) -> int:
    """M for a point at ``distance_m``: a power of two >= 4 sub-hologram diameters in pixels (and >= 64), so
    the spectrum's ripple (period 1 / R) has 8 samples or more a period for the interpolation."""
    r_px = distance_m * _cone(wavelength_m, pitch_m)[0] / pitch_m
    return int(min(_MAX_GRID, max(_MIN_GRID, 2 ** math.ceil(math.log2(8.0 * r_px + 16.0)))))


def sheet_spectrum(distance_m: float, wavelength_m: float, pitch_m: float, size: int) -> np.ndarray:
    """|K_d(f)|^2 of Eq. C2 (m^2) on the ``size`` x ``size`` DFT grid of the pixel lattice (numpy's frequency
    order: f = fftfreq(size, p)), float64: a surface's image points at ``distance_m`` m from their plane."""
    d = float(distance_m)
    if not (math.isfinite(d) and d > 0):
        raise ValueError(f"distance_m must be a positive number, got {distance_m!r}")
    lam, p = float(wavelength_m), float(pitch_m)
    tan_c, _ = _cone(lam, p)
    R = d * tan_c
    n = int(math.ceil(R / p + 0.5))  # lags whose cell reaches the cut
    if 2 * n + 1 > size:
        raise ValueError(f"a {size}x{size} grid cannot hold a sub-hologram of radius {R / p:.1f} px")
    lag = np.arange(-n, n + 1) * p
    sub = ((np.arange(_SUB) + 0.5) / _SUB - 0.5) * p
    k = np.zeros((2 * n + 1, 2 * n + 1), dtype=np.complex128)
    for uy in sub:
        y2 = (lag[:, None] - uy) ** 2
        for ux in sub:
            rho2 = y2 + (lag[None, :] - ux) ** 2
            r = np.sqrt(rho2 + d * d)
            k += np.where(rho2 <= R * R, np.exp(1j * (2.0 * math.pi / lam) * r) / r, 0.0)
    k /= _SUB * _SUB
    grid = np.zeros((size, size), dtype=np.complex128)
    idx = np.arange(-n, n + 1) % size
    grid[np.ix_(idx, idx)] = k
    return np.abs(np.fft.fft2(grid) * (p * p)) ** 2


def ideal_power_spectrum(wavelength_m: float, pitch_m: float, f_y, f_x) -> np.ndarray:
    """The band-limited point's |H(f)|^2 = lambda^2 / cos^2 theta(f) inside the cone, 0 outside (m^2; the
    plane-wave expansion of exp(ikr)/r, whose spectrum is i lambda exp(i k_z d) / cos theta) at (f_y, f_x)
    (1/m, broadcast), float64."""
    _tan_c, f_c = _cone(wavelength_m, pitch_m)
    f2 = np.asarray(f_y, dtype=np.float64) ** 2 + np.asarray(f_x, dtype=np.float64) ** 2
    s2 = np.clip(f2 * wavelength_m ** 2, 0.0, 1.0 - 1e-12)
    return np.where(f2 <= f_c * f_c, wavelength_m ** 2 / (1.0 - s2), 0.0)


def cell_spectrum(pitch_m: float, f_y, f_x) -> np.ndarray:
    """B(f) = sinc^2(f_x p) sinc^2(f_y p): the power spectrum of one p x p random-phase cell (dimensionless)."""
    return (np.sinc(np.asarray(f_x, dtype=np.float64) * pitch_m) * np.sinc(np.asarray(f_y, dtype=np.float64)
                                                                        * pitch_m)) ** 2


def _grid_freqs(shape_hw: tuple[int, int], pitch_m: float) -> tuple[np.ndarray, np.ndarray]:
    return np.fft.fftfreq(shape_hw[0], d=pitch_m)[:, None], np.fft.fftfreq(shape_hw[1], d=pitch_m)[None, :]


def mean_sheet_spectrum(distances_m: Sequence[float], wavelength_m: float,
                        pitch_m: float) -> Optional[np.ndarray]:
    """S of Eq. C3 on an M x M DFT grid of the lattice (float32, m^2) for image points at ``distances_m`` (m,
    equal weights) from their plane; None when there are none or the nearest (or every distance quantile) is more
    than ``MAX_FRESNEL`` zones away (Weyl's spectrum times B, computed where it is used)."""
    d = np.asarray(distances_m, dtype=np.float64).reshape(-1)
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0 or _fresnel_zones(d.min(), wavelength_m, pitch_m) > MAX_FRESNEL:
        return None
    qs = np.quantile(d, (np.arange(_MAX_DISTANCES) + 0.5) / _MAX_DISTANCES)
    far = _fresnel_zones(qs, wavelength_m, pitch_m) > MAX_FRESNEL  # these count with Weyl's spectrum times B
    if far.all():  # the nearest point alone is near (a wide cone makes every zone count huge): all far
        return None
    size = max(_grid_size(dj, wavelength_m, pitch_m) for dj in qs[~far])
    total = np.zeros((size, size), dtype=np.float64)
    if far.any():
        f_y, f_x = _grid_freqs((size, size), pitch_m)
        total += far.sum() * ideal_power_spectrum(wavelength_m, pitch_m, f_y, f_x) * cell_spectrum(pitch_m, f_y, f_x)
    near, count = np.unique(qs[~far], return_counts=True)  # a flat surface: 16 equal quantiles, one spectrum
    for dj, n in zip(near, count):
        total += n * sheet_spectrum(dj, wavelength_m, pitch_m, size)
    return (total / qs.size).astype(np.float32)


def _interpolate(spectrum: np.ndarray, f_y: np.ndarray, f_x: np.ndarray, pitch_m: float) -> np.ndarray:
    """The lattice-periodic M x M ``spectrum`` (float64) bilinearly interpolated at (f_y [h, 1], f_x [1, w]) (1/m)."""
    m, s = spectrum.shape[0], spectrum

    def taps(f):
        pos = np.mod(f.reshape(-1) * pitch_m * m, m)
        i0 = np.floor(pos).astype(np.int64) % m
        return i0, (i0 + 1) % m, pos - np.floor(pos)

    y0, y1, ty = taps(f_y)
    x0, x1, tx = taps(f_x)
    ty, tx = ty[:, None], tx[None, :]
    return ((1 - ty) * ((1 - tx) * s[np.ix_(y0, x0)] + tx * s[np.ix_(y0, x1)])
            + ty * ((1 - tx) * s[np.ix_(y1, x0)] + tx * s[np.ix_(y1, x1)]))


def _rows_of_s(spectrum: Optional[np.ndarray], wavelength_m: float, pitch_m: float, shape_hw: tuple[int, int]):
    """Yield (row slice, G, S) in blocks of rows of the DFT grid ``shape_hw`` (float64): the band-limited point's
    G = lambda^2 / cos^2 and the plane's S (``spectrum`` interpolated; None: G B), so that the float64
    temporaries stay small at the paper's size."""
    f_y, f_x = _grid_freqs(shape_hw, pitch_m)
    spectrum = None if spectrum is None else spectrum.astype(np.float64)  # once, not per block
    for a in range(0, shape_hw[0], 256):
        fy = f_y[a:a + 256]
        ideal = ideal_power_spectrum(wavelength_m, pitch_m, fy, f_x)
        s = ideal * cell_spectrum(pitch_m, fy, f_x) if spectrum is None else _interpolate(spectrum, fy, f_x, pitch_m)
        yield slice(a, a + 256), ideal, s


@dataclass(frozen=True)
class NoiseFit:
    """Eq. C4's fit on one recording: ``noise`` = N / A (m^2, S's units; 0: none found) and ``mean_s``, the mean
    of S over the fitted frequencies, so that noise / mean_s is the noise-to-signal power in the cone."""

    noise: float
    mean_s: float

    @property
    def noise_to_signal(self) -> float:
        return self.noise / self.mean_s if self.mean_s > 0 else 0.0


def noise_floor(power: np.ndarray, spectrum: Optional[np.ndarray], wavelength_m: float, pitch_m: float, *,
                lit_px: Optional[float] = None) -> NoiseFit:
    """The Monte Carlo noise of a recording in the units of its plane's S (Eq. C4): N / A of the least-squares
    fit P(f) = A S(f) + N over the cone's inside (to 0.9 of its rim), ``power`` = |DFT|^2 of one frame of the
    recorded field on the gain's grid (float, [H', W']), ``lit_px`` the number of pixels the field lights (its
    spectrum has about that many independent samples on the whole band, fewer than the padded grid's). Noise 0
    when the fit finds no noise or no signal, shrunk towards 0 by its standard error."""
    sums = np.zeros(6)  # n, sum S, sum S^2, sum P, sum S P, sum P^2
    shape = tuple(power.shape)
    lim = (0.9 / (2.0 * pitch_m)) ** 2  # f_c = 1 / 2p for every wavelength below 2p (sin theta_c = lambda / 2p)
    f_y, f_x = _grid_freqs(shape, pitch_m)
    for rows, ideal, s in _rows_of_s(spectrum, wavelength_m, pitch_m, shape):
        m = (ideal > 0) & (f_y[rows] ** 2 + f_x ** 2 <= lim)
        sv, pv = s[m], power[rows][m].astype(np.float64)
        sums += (sv.size, sv.sum(), (sv * sv).sum(), pv.sum(), (sv * pv).sum(), (pv * pv).sum())
    n, sx, sxx, sy, sxy, syy = sums
    mean_s = float(sx / n) if n > 0 else 0.0
    det = n * sxx - sx * sx
    if n < 16 or not det > 0:
        return NoiseFit(0.0, mean_s)
    a = (n * sxy - sx * sy) / det
    noise = (sy - a * sx) / n
    if not (math.isfinite(a) and math.isfinite(noise) and a > 0 and noise > 0):
        return NoiseFit(0.0, mean_s)
    # The fit's own uncertainty: one frame's signal fluctuates per frequency (its random phases' spectrum), so on a
    # small grid N is poorly determined (+-0.05 of the signal at 48 x 48). N is shrunk towards 0 by its standard
    # error, so a noise the fit cannot tell from zero is not divided out (3 standard errors: none of it).
    var_res = max(0.0, syy - a * sxy - noise * sy) / max(1.0, n - 2.0)
    se = math.sqrt(var_res * sxx / det)
    if lit_px is not None:  # neighbouring samples of a padded or partly lit field are correlated
        independent = max(1.0, float(lit_px) * n / (shape[0] * shape[1]))
        se *= math.sqrt(max(1.0, n / independent))
    noise *= max(0.0, 1.0 - (3.0 * se / noise) ** 2)
    return NoiseFit(float(noise / a), mean_s)


def equaliser_gain(spectrum: Optional[np.ndarray], wavelength_m: float, pitch_m: float,
                   shape_hw: tuple[int, int], *, noise: float = 0.0) -> torch.Tensor:
    """E(f) of Eq. C3 (``noise`` = 0) or C4 (``noise`` = N / A from :func:`noise_floor`) on the DFT grid
    ``shape_hw`` (numpy's frequency order), float32: ``spectrum`` the plane's S on its M x M grid
    (:func:`mean_sheet_spectrum`; None: Weyl's times B, which leaves 1 / sqrt(B))."""
    out = np.empty(tuple(shape_hw), dtype=np.float32)
    for rows, ideal, s in _rows_of_s(spectrum, wavelength_m, pitch_m, shape_hw):
        den = np.maximum(s + max(0.0, float(noise)), 1e-300)
        out[rows] = np.minimum(np.where(ideal > 0, np.sqrt(ideal / den), 0.0), E_MAX)
    return torch.from_numpy(out)


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
    """The equaliser of one recording plane: per lit color its S on an M x M grid (None: Weyl's times B),
    the zero padding its filter needs (px), and the Fresnel zones of its nearest image point in the widest
    color's cone (None: it records no point)."""

    spectra: tuple[Optional[np.ndarray], ...]
    border_px: int
    fresnel_zones: Optional[float]
    noise_aware: bool = True  # Eq. C4: the gain also divides by the recording's Monte Carlo noise
    _gains: dict = field(default_factory=dict, compare=False, repr=False)  # color -> gain grid of one shape
    noise: dict = field(default_factory=dict, compare=False, repr=False)  # color -> the NoiseFit it used (Eq. C4)

    def active(self, color: int) -> bool:
        """Whether the plane's field of lit color ``color`` is filtered at all: whenever it records a point (the
        cell's mean of Eq. C2 shapes all of them)."""
        return self.fresnel_zones is not None

    def apply(self, field_: torch.Tensor, color: int, wavelength_m: float, pitch_m: float) -> torch.Tensor:
        """``field_`` [..., H, W] of lit color ``color`` equalised (the same tensor when there is nothing to do)."""
        if not self.active(color):
            return field_
        return equalise_plane(field_, self.gain(field_, color, wavelength_m, pitch_m))

    def own_grid(self, shape_hw: tuple[int, int]) -> tuple[int, int]:
        """The padded grid the filter needs on a field of ``shape_hw``: its border more, at most 2x."""
        h, w = shape_hw
        b = min(self.border_px, h, w)  # at most the ASM's own 2x padding
        return smooth_at_least(h + b), smooth_at_least(w + b)

    def gain(self, field_: torch.Tensor, color: int, wavelength_m: float, pitch_m: float,
             grid: Optional[tuple[int, int]] = None) -> torch.Tensor:
        """The gain of lit color ``color`` (active) on ``grid`` (default :meth:`own_grid`; a larger one holds the
        filter followed by a propagation, ``holocore.optics.plane_chain``), in ``field_``'s precision and device.
        Eq. C4's noise is fitted once per color, on the first frame it sees (the render's 0), on the own grid."""
        h, w = field_.shape[-2], field_.shape[-1]
        own = self.own_grid((h, w))
        shape = own if grid is None else tuple(grid)
        g = self._gains.get(color)
        if g is None or tuple(g.shape) != shape or g.device != field_.device:
            # once per color of a plane (its chunks of frames alternate colors), in the field's precision
            fit = self.noise.get(color, NoiseFit(0.0, 0.0))  # fitted once: a gain rebuilt keeps frame 0's fit
            if self.noise_aware and color not in self.noise:
                first = field_.reshape(-1, h, w)[0]
                power = (torch.fft.fft2(first, s=own).abs() ** 2).cpu().numpy()
                pix = first.abs().double() ** 2
                # pixels lit: 2 (sum I)^2 / sum I^2, the count of a uniformly lit region under full speckle
                lit = float(2.0 * pix.sum() ** 2 / max(float((pix * pix).sum()), 1e-300))
                fit = noise_floor(power, self.spectra[color], wavelength_m, pitch_m, lit_px=min(lit, h * w))
                del power
            self.noise[color] = fit
            g = equaliser_gain(self.spectra[color], wavelength_m, pitch_m, shape, noise=fit.noise)
            g = self._gains[color] = g.to(device=field_.device, dtype=field_.real.dtype)
        return g


def plane_equalisers(distances_by_plane_m: Sequence[Sequence[float]], wavelengths_m: Sequence[float],
                     pitch_m: float, *, noise_aware: bool = True, rim_ripple: bool = True) -> list[PlaneEqualiser]:
    """One :class:`PlaneEqualiser` per recording plane from the distances (m) of the image points it records
    (:meth:`holocore.plan.wrp_planes.WrpPlanes.distances_by_plane_m`), for the lit ``wavelengths_m``;
    ``noise_aware``: Eq. C4 (the default) rather than C3. ``rim_ripple=False``: the rays already carry their
    points' ideal spectrum (directional frames, :mod:`holocore.trace.beams` Eq. B2), so every plane divides only
    the cell's B (Weyl's spectrum times B for every point)."""
    out = []
    tan_w = max(_cone(lam, pitch_m)[0] for lam in wavelengths_m)
    for dists in distances_by_plane_m:
        d = np.asarray(dists, dtype=np.float64).reshape(-1)
        d = d[np.isfinite(d) & (d > 0)]
        spectra = tuple(mean_sheet_spectrum(d, lam, pitch_m) if rim_ripple else None for lam in wavelengths_m)
        zones = float(d.min() * tan_w ** 2 / min(wavelengths_m)) if d.size else None
        # The filter's reach: about the diameter of the widest sub-hologram it was computed from.
        border = int(math.ceil(2.0 * float(np.max(d, initial=0.0)) * tan_w / pitch_m)) + 8
        out.append(PlaneEqualiser(spectra, border, zones, noise_aware))
    return out
