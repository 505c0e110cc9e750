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

(B1) is applied in two parts. The lateral part k u_m . Q_xy is a bank of phase maps on the cell lattice
(:func:`beam_phase_frames`; u_m rounded to the lattice's DFT grid, so the map is periodic like a random bank); the
depth part is k (Q_z - z_ref) (the same in every frame: added to the ray's own phase in the tracer) times the
per-frame factor exp(-i k (1 - w_m)(Q_z - z_ref)) (:class:`BeamDepthTerms`, one value per ring of directions).

Units: metres, radians; directions as sines of the angle to the axis (hologram space).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, theta_max_rad

__all__ = ["RHO", "beam_layout", "beam_disc_sine", "beam_gain", "beam_phase_frames", "BeamDepthTerms"]

RHO = 0.9  # the directions fill this fraction of the smallest colour's cone (radius), clear of its rim


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


def _directions(frames: int, wavelengths_m: Sequence[float], pitch_m: float) -> np.ndarray:
    return beam_layout(frames) * beam_disc_sine(wavelengths_m, pitch_m)


def beam_phase_frames(frames: int, shape_hw: tuple[int, int], wavelength_m: float, pitch_m: float, *,
                      wavelengths_m: Sequence[float], first_frame: int = 0,
                      bank_frames: int | None = None) -> Iterator[np.ndarray]:
    """The lateral part of (B1) on the cell lattice, k u_m . x (x the cell centre), float32 [H, W] in [0, 2 pi) per
    frame m = first_frame .. first_frame + frames - 1 of a bank of ``bank_frames`` (default: frames) directions.
    u_m / lambda is rounded to the lattice's DFT grid, so the map is periodic on H x W (cells wrap, DESIGN §4)."""
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
    ``one_minus_w``: 1 - w of each ring of directions; ``frame_ring``: the ring of each frame of the pass;
    ``ring_runs``: (ring, first frame, end frame) of each run of consecutive frames of one ring."""

    ks: tuple[float, ...]
    one_minus_w: tuple[float, ...]
    frame_ring: tuple[int, ...]
    ring_runs: tuple[tuple[int, int, int], ...]

    @classmethod
    def make(cls, *, frames: int, first_frame: int, bank_frames: int, wavelengths_m: Sequence[float],
             pitch_m: float, all_wavelengths_m: Sequence[float] | None = None) -> "BeamDepthTerms":
        u = _directions(bank_frames, all_wavelengths_m or wavelengths_m, pitch_m)[first_frame:first_frame + frames]
        s2 = np.round((u * u).sum(axis=1), 15)
        rings, ring_of = np.unique(s2, return_inverse=True)
        omw = [float(v / (1.0 + math.sqrt(1.0 - v))) for v in rings]  # 1 - sqrt(1 - s^2) without cancellation
        runs: list[tuple[int, int, int]] = []
        for f, r in enumerate(int(v) for v in ring_of):
            if runs and runs[-1][0] == r and runs[-1][2] == f:
                runs[-1] = (r, runs[-1][1], f + 1)
            else:
                runs.append((r, f, f + 1))
        return cls(ks=tuple(2.0 * math.pi / float(lam) for lam in wavelengths_m), one_minus_w=tuple(omw),
                   frame_ring=tuple(int(r) for r in ring_of), ring_runs=tuple(runs))

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

    def scaled_base(self, base, dz):
        """base [R, C] times each ring's depth factor of the rays (dz [R], m): complex [R, C, rings]."""
        return base[:, :, None] * self.ring_phasors(dz)

    def apply(self, rows, scaled):
        """rows [R, C, F] (the bank's rows of each ray) times :meth:`scaled_base` [R, C, rings]: complex [R, C, F],
        one complex product per element (each run of one ring's frames takes its factor at once)."""
        import torch

        out = rows.new_empty(rows.shape)
        for r, a, b in self.ring_runs:
            torch.mul(rows[:, :, a:b], scaled[:, :, r:r + 1], out=out[:, :, a:b])
        return out
