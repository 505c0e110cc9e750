"""Directional frame phases: frame m lights every image point with one plane wave, towards eye position m
(``frame_phases="directional"``; docs/physics.md, "Directional frames").

Random phases (Eq. 4, :mod:`holocore.trace.randomfield`) make every image point radiate over the whole recording
cone in every frame; two points inside one eye's resolution spot then interfere with a random phase, and the F-frame
average keeps speckle of contrast about 1 / sqrt(F) wherever the codes cannot cancel it (out of focus above all).
Directional frames give the point Q of frame m the phase of a plane wave of direction (u_m, w_m):

    phi_m(Q) = k (u_m . Q_xy + w_m (Q_z - z_ref)),   w_m = sqrt(1 - |u_m|^2),                        (B1)

so that in direction u_m the waves of all points leave in phase, whatever their depth (a surface tilted in hologram
space too): frame m is the scene seen in coherent light from direction u_m, and the F frames together a discrete
source of F directions spread over the cone, as a microscope's Koehler illumination. A pupil averages the frames
whose direction it holds: no speckle in focus or out of it, the defocus blur sampled by those directions, parallax
and view-dependent radiance as with random phases (each ray still carries its own direction's radiance).

The directions (:func:`beam_layout`) lie on rings of equal area in a disc of RHO times the smallest colour's
recording cone, symmetric left to right. All colours use the same directions, so a pupil holds the same frames in
every colour; each colour's amplitude is scaled by :func:`beam_gain` so that a pupil receives the same share of
every colour's light as from random phases (which spread a colour over its own cone, wider for longer waves).

A beam samples each image point's angular spectrum at one frequency, where random phases average it over the
pupil. The rays of a point at distance d from its recording plane fill the cone up to its rim, and that hard cut
rings in angle (Eq. C1 of :mod:`holocore.optics.cone_equaliser`): on the axis the spectrum varies as
|1 - exp(i pi N_F)|, N_F = d tan^2(theta_c) / lambda, zero at every even N_F (blue at the default 4-pixel WRP
margin), and no gain after the fact can restore a zero. So the rays of directional frames are weighted by a
raised-cosine rim taper from RIM_TAPER of the cone's tan(angle) to its rim (:func:`rim_taper`), which keeps the
spectrum of every point away from zero, and each ray's frame m is then divided by the point's spectrum at the
frame's beam relative to Weyl's (:func:`beam_spectrum_ratio`, Eq. B2 below, tabulated per colour and ring of
directions over N_F), so that every beam carries its point's ideal amplitude at any depth, in every colour:

    K_rel(d, f) = 2 pi int_0^R w(rho / R) exp(i k r) / r  J0(2 pi f rho) rho d rho  /  (i lambda exp(i k w_f d) / w_f),
    r = sqrt(rho^2 + d^2), R = d tan(theta_c), w_f = sqrt(1 - (lambda f)^2).                            (B2)

The recording plane's equaliser then divides only the cell's sinc^2 (Eq. C2's cell mean, the same for every
distance).

(B1) is applied in two parts. The lateral part k u_m . Q_xy is a bank of phase maps on the cell lattice
(:func:`beam_phase_frames`; u_m rounded to the lattice's DFT grid, so the map is periodic like a random bank); the
depth part is k (Q_z - z_ref) (the same in every frame: added to the ray's own phase in the tracer) times the
per-frame factor exp(-i k (1 - w_m)(Q_z - z_ref)) (:class:`BeamDepthTerms`, one value per ring of directions).

Units: metres, radians; directions as sines of the angle to the axis (hologram space).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Iterator, Optional, Sequence

import numpy as np

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, theta_max_rad

__all__ = ["RHO", "RIM_TAPER", "beam_layout", "beam_disc_sine", "beam_gain", "beam_phase_frames", "rim_taper",
           "beam_spectrum_ratio", "BeamDepthTerms", "BeamRays"]

RHO = 0.9  # the directions fill this fraction of the smallest colour's cone (radius), clear of its rim
RIM_TAPER = 0.6  # the rim taper starts at this fraction of the cone's tan(angle): |K_rel| >= 0.4 at every beam
MAX_BEAM_GAIN = 4.0  # the largest per-ray factor 1 / K_rel (points nearer than a Fresnel zone to their plane)
_NF_STEP = 1.0 / 16.0  # the table of (B2) over N_F: its ripple has period 2 in N_F
_NF_MAX = 48.0  # beyond: the taper spans > 18 zones and K_rel is the taper's value at the beam (its last entry)
_RADIAL = 4096  # samples of the radial integral
_NF_LATTICE = 8.0  # up to this many zones (B2) is the DFT of the cell-averaged lattice samples (Eq. C2's form)
_LATTICE_STEP = 2  # ... computed on every second entry of the table there, interpolated between
_SUB = 4  # sub-samples per cell side of the cell's mean


def beam_layout(frames: int) -> np.ndarray:
    """F directions in the unit disc, float64 [F, 2] (x, y): one at the centre, then rings of about 6, 12, 18 ...
    (the remainder added to the outer rings), each ring at the radius that halves its share of the disc's area,
    its first point straight up, so the set is symmetric under x -> -x."""
    F = int(frames)
    if F < 1:
        raise ValueError(f"frames must be >= 1, got {frames!r}")
    counts = [1]
    while sum(counts) + 6 * len(counts) <= F:
        counts.append(6 * len(counts))
    rest = F - sum(counts)
    if len(counts) == 1:
        counts += [rest] if rest else []
    else:
        ring_total = sum(counts[1:])
        add = [rest * n // ring_total for n in counts[1:]]
        add[-1] += rest - sum(add)
        counts = [1] + [n + a for n, a in zip(counts[1:], add)]
    pts, done = [], 0
    for n in counts:
        r = math.sqrt((done + 0.5 * n) / F) if done else 0.0
        pts += [(r * math.cos(math.pi / 2 + 2 * math.pi * j / n), r * math.sin(math.pi / 2 + 2 * math.pi * j / n))
                for j in range(n)]
        done += n
    return np.asarray(pts, dtype=np.float64)


def _cone_sine(wavelength_m: float, pitch_m: float) -> float:
    return math.sin(min(theta_max_rad(wavelength_m, pitch_m), MAX_CONE_HALF_ANGLE_RAD))


def beam_disc_sine(wavelengths_m: Sequence[float], pitch_m: float) -> float:
    """Radius (sine of the angle) of the disc the directions fill: RHO times the smallest colour's cone."""
    return RHO * min(_cone_sine(float(lam), pitch_m) for lam in wavelengths_m)


def beam_gain(wavelength_m: float, pitch_m: float, wavelengths_m: Sequence[float]) -> float:
    """Amplitude factor of a colour's frames: sin(theta_min) / sin(theta_c). A pupil takes the same frames in every
    colour, so without it a colour's share would grow with its cone's solid angle (lambda^2 below 2p)."""
    return min(_cone_sine(float(lam), pitch_m) for lam in wavelengths_m) / _cone_sine(wavelength_m, pitch_m)


def rim_taper(x, start: float = RIM_TAPER):
    """The rays' weight at x = tan(angle) / tan(theta_c): 1 up to ``start``, a raised cosine to 0 at the rim."""
    t = np.clip((np.asarray(x, dtype=np.float64) - start) / (1.0 - start), 0.0, 1.0)
    return 0.5 + 0.5 * np.cos(np.pi * t)


def _lattice_ratio(d: float, lam: float, pitch_m: float, tan_c: float, rings: Sequence[np.ndarray],
                   start: float) -> np.ndarray:
    """(B2) as the recording lattice sees it: the DFT at each direction of ``dirs`` ([n, 2] sines) of the tapered
    cut wave averaged over a cell and sampled at the pixel centres (Eq. C2's form, which holds its aliases), over
    Weyl's spectrum times the cell's sinc(f_x p) sinc(f_y p) that the plane's equaliser divides; the mean over
    the directions of each ring: complex128 [rings]."""
    k, R = 2.0 * math.pi / lam, d * tan_c
    n = int(math.ceil(R / pitch_m + 0.5))
    lag = np.arange(-n, n + 1) * pitch_m
    sub = ((np.arange(_SUB) + 0.5) / _SUB - 0.5) * pitch_m
    dy = lag[:, None, None, None] - sub[None, None, :, None]
    dx = lag[None, :, None, None] - sub[None, None, None, :]
    rho = np.sqrt(dy * dy + dx * dx)
    r = np.sqrt(rho * rho + d * d)
    kern = np.where(rho <= R, rim_taper(rho / R, start) * np.exp(1j * k * r) / r, 0.0).mean(axis=(2, 3))
    kern *= pitch_m * pitch_m
    out = []
    for dirs in rings:
        vals = []
        for ux, uy in dirs:
            fx, fy = ux / lam, uy / lam
            val = np.exp(-2j * math.pi * fy * lag) @ kern @ np.exp(-2j * math.pi * fx * lag)
            wz = math.sqrt(max(1e-12, 1.0 - ux * ux - uy * uy))
            vals.append(val / (1j * lam * np.exp(1j * k * wz * d) / wz * np.sinc(fx * pitch_m) * np.sinc(fy * pitch_m)))
        out.append(np.mean(vals))
    return np.asarray(out)


@lru_cache(maxsize=64)
def _ratio_table(wavelength_m: float, pitch_m: float, rings: tuple, start: float) -> np.ndarray:
    """K_rel of (B2) for each ring of directions (``rings``: per ring a tuple of (u_x, u_y) sines) on N_F = 0,
    _NF_STEP, .. _NF_MAX: complex128 [rings, n]; the lattice's DFT up to _NF_LATTICE zones, the radial integral
    beyond (where the two agree to 1 %)."""
    from scipy.special import j0

    lam = float(wavelength_m)
    th = min(theta_max_rad(lam, pitch_m), MAX_CONE_HALF_ANGLE_RAD)
    tan_c, k = math.tan(th), 2.0 * math.pi / lam
    dirs = [np.asarray(r, dtype=np.float64).reshape(-1, 2) for r in rings]
    sines = [float(np.mean(np.hypot(d[:, 0], d[:, 1]))) for d in dirs]
    nf = np.arange(0.0, _NF_MAX + 0.5 * _NF_STEP, _NF_STEP)
    out = np.zeros((len(dirs), nf.size), dtype=np.complex128)
    t = (np.arange(_RADIAL) + 0.5) / _RADIAL  # midpoints in rho / R
    w = rim_taper(t, start)  # rho / R = tan / tan_c
    last = int(round(_NF_LATTICE / _NF_STEP))
    for i in range(_LATTICE_STEP, last + 1, _LATTICE_STEP):
        out[:, i] = _lattice_ratio(nf[i] * lam / (tan_c * tan_c), lam, float(pitch_m), tan_c, dirs, start)
        h = i - _LATTICE_STEP
        for j in range(1, _LATTICE_STEP):  # the entries between, linear in N_F
            out[:, h + j] = out[:, h] + (out[:, i] - out[:, h]) * (j / _LATTICE_STEP)
    uniq, which = np.unique(np.round(sines, 12), return_inverse=True)  # the radial integral depends on |u| only
    for i in range(last + 1, nf.size):
        d = nf[i] * lam / (tan_c * tan_c)
        R = d * tan_c
        rho = t * R
        r = np.sqrt(rho * rho + d * d)
        base = w * np.exp(1j * k * r) / r * rho
        for q, sine in enumerate(uniq):
            wz = math.sqrt(max(1e-12, 1.0 - sine * sine))
            val = 2.0 * math.pi * np.sum(base * j0(2.0 * math.pi * (sine / lam) * rho)) * (R / _RADIAL)
            out[which == q, i] = val / (1j * lam * np.exp(1j * k * wz * d) / wz)
    return out


def beam_spectrum_ratio(distance_m, wavelength_m: float, pitch_m: float, sine: float,
                        start: float = RIM_TAPER) -> np.ndarray:
    """K_rel of (B2): a tapered point's spectrum at direction ``sine`` over Weyl's, at ``distance_m`` (m, array) from
    its plane; complex128, linear in N_F between the table's entries, its last entry beyond."""
    lam = float(wavelength_m)
    th = min(theta_max_rad(lam, pitch_m), MAX_CONE_HALF_ANGLE_RAD)
    table = _ratio_table(lam, float(pitch_m), (((round(float(sine), 12), 0.0),),), float(start))[0]
    pos = np.clip(np.asarray(distance_m, dtype=np.float64) * math.tan(th) ** 2 / lam / _NF_STEP, 0.0, table.size - 1)
    i0 = np.minimum(np.floor(pos).astype(np.int64), table.size - 2)
    f = pos - i0
    return (1.0 - f) * table[i0] + f * table[i0 + 1]


def _directions(frames: int, wavelengths_m: Sequence[float], pitch_m: float) -> np.ndarray:
    return beam_layout(frames) * beam_disc_sine(wavelengths_m, pitch_m)


def beam_phase_frames(frames: int, shape_hw: tuple[int, int], wavelength_m: float, pitch_m: float, *,
                      wavelengths_m: Sequence[float], first_frame: int = 0,
                      bank_frames: int | None = None) -> Iterator[np.ndarray]:
    """The lateral part of (B1) on the cell lattice, k u_m . x (x the cell centre), float32 [H, W] in [0, 2 pi) per
    frame m = first_frame .. first_frame + frames - 1 of a bank of ``bank_frames`` (default: frames) directions.
    u_m / lambda is rounded to the lattice's DFT grid, so the map is periodic on H x W (cells wrap,
    docs/design.md §4)."""
    F = int(bank_frames if bank_frames is not None else frames)
    if not (0 <= int(first_frame) and int(first_frame) + int(frames) <= F):
        raise ValueError(f"frames {first_frame}..{first_frame + frames - 1} are not in a bank of {F} directions")
    H, W = (int(s) for s in shape_hw)
    u = _directions(F, wavelengths_m, pitch_m)
    j = np.arange(W) - (W - 1) / 2.0  # x = j p
    i = (H - 1) / 2.0 - np.arange(H)  # y = i p (rows run down, y up)
    for m in range(int(first_frame), int(first_frame) + int(frames)):
        nx = round(u[m, 0] / wavelength_m * W * pitch_m)  # cycles across the lattice
        ny = round(u[m, 1] / wavelength_m * H * pitch_m)
        phi = np.mod(2.0 * np.pi * (nx * j[None, :] / W + ny * i[:, None] / H), 2.0 * np.pi).astype(np.float32)
        phi[phi >= np.float32(2.0 * np.pi)] = 0.0
        yield phi


@dataclass(frozen=True)
class BeamDepthTerms:
    """The depth part of (B1) that differs between frames, exp(-i k_c (1 - w_m) dz), dz = Q_z - z_ref (m; the
    tracer's z_ref is the WRP), for the frames of one pass. ``ks``: wavenumbers (rad/m) of the colours traced;
    ``one_minus_w``: 1 - w of each ring of directions; ``frame_ring``: the ring of each frame of the pass; ``gains``:
    per colour and frame of the pass the rays' factor 1 / K_rel of (B2) on N_F = 0, _NF_STEP, .. (complex128
    [C, F, n]; None: no taper, no factor), ``nf_per_m``: N_F per metre of distance of each colour."""

    ks: tuple[float, ...]
    one_minus_w: tuple[float, ...]
    frame_ring: tuple[int, ...]
    gains: Optional[np.ndarray] = field(default=None, compare=False, repr=False)
    nf_per_m: tuple[float, ...] = ()
    taper: Optional[float] = None  # the rim taper the tracer applies to the rays (:func:`rim_taper`)
    _tables: dict = field(default_factory=dict, compare=False, repr=False)  # (colour, device) -> torch [n, F]

    @classmethod
    def make(cls, *, frames: int, first_frame: int, bank_frames: int, wavelengths_m: Sequence[float],
             pitch_m: float, all_wavelengths_m: Sequence[float] | None = None,
             taper: Optional[float] = RIM_TAPER) -> "BeamDepthTerms":
        u = _directions(bank_frames, all_wavelengths_m or wavelengths_m, pitch_m)[first_frame:first_frame + frames]
        s2 = np.round((u * u).sum(axis=1), 15)
        rings, ring_of = np.unique(s2, return_inverse=True)
        omw = [float(v / (1.0 + math.sqrt(1.0 - v))) for v in rings]  # 1 - sqrt(1 - s^2) without cancellation
        gains, nf_per_m = None, ()
        if taper is not None:  # (B2) per colour and frame, inverted with its gain capped at MAX_BEAM_GAIN
            # one entry per frame of the bank (the lattice makes (B2) depend on a beam's azimuth by +-5 %), so the
            # table is the same for every pass; the pass takes its frames' rows
            all_u = _directions(bank_frames, all_wavelengths_m or wavelengths_m, pitch_m)
            dirs = tuple(((round(float(x), 12), round(float(y), 12)),) for x, y in all_u)
            kr = np.stack([_ratio_table(float(lam), float(pitch_m), dirs, float(taper))
                           [first_frame:first_frame + frames] for lam in wavelengths_m])
            mag = np.maximum(np.abs(kr), 1.0 / MAX_BEAM_GAIN)
            gains = np.conj(kr) / (mag * mag)
            nf_per_m = tuple(math.tan(min(theta_max_rad(float(lam), pitch_m), MAX_CONE_HALF_ANGLE_RAD)) ** 2
                             / float(lam) for lam in wavelengths_m)
        return cls(ks=tuple(2.0 * math.pi / float(lam) for lam in wavelengths_m), one_minus_w=tuple(omw),
                   frame_ring=tuple(int(r) for r in ring_of), gains=gains,
                   nf_per_m=nf_per_m, taper=taper)

    def ring_phasors(self, dz):
        """complex64 torch [R, C, rings] of the rays' dz (torch float [R], m): one factor per ring of directions."""
        import torch

        d = dz.to(torch.float64)[:, None]
        omw = torch.tensor(self.one_minus_w, dtype=torch.float64, device=dz.device)[None, :]
        out = []
        for k in self.ks:
            ph = torch.remainder(-k * omw * d, 2.0 * math.pi).to(torch.float32)  # [R, rings]
            out.append(torch.polar(torch.ones_like(ph), ph))
        return torch.stack(out, dim=1)

    def plane_factors(self, dz_m: float):
        """The whole depth part of (B1), exp(i k_c w_m dz), of one depth dz (m) for every colour and frame: complex64
        torch [C, F] (a layer at one depth: the tracer's k dz and the ring factor in one)."""
        import torch

        ring = self.ring_phasors(torch.tensor([float(dz_m)], dtype=torch.float64))[0]  # [C, rings]
        common = torch.tensor([complex(np.exp(1j * k * float(dz_m))) for k in self.ks], dtype=torch.complex64)
        return ring[:, list(self.frame_ring)] * common[:, None]

    def _table(self, c: int, device):
        """The gains of colour c as complex64 torch [n, F] on ``device`` (made once)."""
        import torch

        key = (c, str(device))
        if key not in self._tables:
            self._tables[key] = torch.from_numpy(np.ascontiguousarray(self.gains[c].T).astype(np.complex64)).to(device)
        return self._tables[key]

    def rays(self, base, dz, drec=None) -> "BeamRays":
        """The per-ray terms of one tile's rays: base [R, C] (complex) times each ring's depth factor of their dz
        ([R], m), and with ``drec`` (their distances to their recording planes, m) the row of (B2)'s table each ray
        takes (the nearest N_F entry: at most 1/32 of a zone off, against a ripple period of 2 zones)."""
        import torch

        scaled = base[:, :, None] * self.ring_phasors(dz)  # [R, C, rings]
        rows = None
        if drec is not None and self.gains is not None:
            d = drec.to(torch.float64)
            n = self.gains.shape[-1]
            rows = [torch.round(d * (self.nf_per_m[c] / _NF_STEP)).clamp(0, n - 1).long() for c in range(len(self.ks))]
        return BeamRays(self, scaled, rows)


class BeamRays:
    """One tile's rays' terms of :class:`BeamDepthTerms` (see :meth:`BeamDepthTerms.rays`); :meth:`factors` gives a
    chunk of them for every frame."""

    def __init__(self, terms: BeamDepthTerms, scaled, rows) -> None:
        self.terms, self.scaled, self.rows = terms, scaled, rows
        self.frame_ring = list(terms.frame_ring)

    def factors(self, a: int, b: int):
        """Rays a..b: base times every frame's depth factor and 1 / K_rel, complex64 [b - a, C, F]."""
        import torch

        out = self.scaled[a:b][:, :, self.frame_ring]  # [r, C, F]
        if self.rows is not None:
            dev = out.device
            out = out * torch.stack([self.terms._table(c, dev)[r[a:b]] for c, r in enumerate(self.rows)], dim=1)
        return out
