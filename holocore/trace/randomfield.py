"""Band-limited random fields for multi-frame holography (paper Sec. 4.3, Eq. 4; docs/design.md §4).

Frame m of a bank is

    r_m(x, y) = IFFT{ chi(f_x, f_y) exp(i xi_m(f_x, f_y)) },   xi_m ~ U[0, 2pi) i.i.d.,
    phi_m = arg r_m  in [0, 2pi),

with chi the circular passband f_x^2 + f_y^2 <= rho^2, rho = sin(theta_max) / lambda = min(1/(2p), 1/lambda)
(theta_max = arcsin(lambda / 2p), pi/2 when lambda >= 2p). The inverse DFT makes every frame periodic on the
H x W grid, so lookups may wrap. The random stream is derived from (seed, wavelength, frame index) only:
the same seed gives the same bank on any device, frame m does not depend on how many frames are asked for,
and each wavelength gets its own independent bank.

Note: r_m is band-limited; the phase-only field exp(i phi_m) is not exactly (taking the argument spreads
its spectrum), which is the paper's choice and ours.

Coded frames (``coded_frames=F``, the renderer's default; docs/physics.md, "Coded frame phases"). Independent
frames leave speckle of contrast 1/sqrt(F) in the F-frame average: two image cells a, b inside one eye's
resolution spot interfere with the cross term sum_m exp(i (phi_m(a) - phi_m(b))), a random walk of F steps.
Coded frames take one random field psi = phi_0 and give frame m

    phi_m(x) = psi(x) + 2 pi m c(x) / F,   c(i, j) = (i + a j) mod F,

so the cross term is exp(i (psi(a) - psi(b))) sum_m exp(2 pi i m (c(a) - c(b)) / F) = 0 exactly whenever
c(a) != c(b): for every pair of cells closer than the lattice's shortest same-code distance (5.1 cells for
F = 24 with a = 5, chosen to make that distance as long as possible), in every view and at every focus, since
the cancellation happens in the frame average, after any linear propagation. Each frame alone is psi plus a
phase grating: as random as psi.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Iterator, Optional, Sequence, Union

import numpy as np
import torch

import holocore.runtime.torch_runtime  # noqa: F401  (reproducible CPU vector math; see its docstring)

__all__ = ["passband_radius", "passband_mask", "random_field", "phase_bank", "phase_frames", "frame_codes",
           "code_multiplier"]

PitchLike = Union[float, Sequence[float]]
_STREAM_TAG = 0x4F1E1D  # separates these streams from other users of the same seed


def _check(shape_hw: tuple[int, int], wavelength_m: float, pitch_m: PitchLike) -> tuple[int, int, float, float, float]:
    try:
        h, w = (int(s) for s in shape_hw)
    except (TypeError, ValueError):
        raise ValueError(f"shape_hw must be (H, W), got {shape_hw!r}") from None
    if h < 1 or w < 1:
        raise ValueError(f"shape_hw must be two sizes >= 1, got {shape_hw!r}")
    lam = float(wavelength_m)
    if not math.isfinite(lam) or lam <= 0:
        raise ValueError(f"wavelength_m must be finite and > 0 (m), got {wavelength_m!r}")
    p = np.asarray(pitch_m, dtype=np.float64)
    if p.ndim == 0:
        p = np.array([p, p])
    if p.shape != (2,) or not np.all(np.isfinite(p)) or np.any(p <= 0):
        raise ValueError(f"pitch_m must be a finite pitch > 0 (m) or a (pitch_y, pitch_x) pair, got {pitch_m!r}")
    return h, w, lam, float(p[0]), float(p[1])


def passband_radius(wavelength_m: float, pitch_m: PitchLike) -> float:
    """Passband radius rho (cycles/m) = sin(theta_max) / lambda = min(1/(2 p_max), 1/lambda) (paper Eq. 4)."""
    _, _, lam, py, px = _check((1, 1), wavelength_m, pitch_m)
    return min(1.0 / (2.0 * max(py, px)), 1.0 / lam)


def passband_mask(shape_hw: tuple[int, int], wavelength_m: float, pitch_m: PitchLike) -> np.ndarray:
    """Boolean [H, W] mask of the circular passband on the unshifted DFT frequency grid (edge included)."""
    h, w, lam, py, px = _check(shape_hw, wavelength_m, pitch_m)
    rho = passband_radius(lam, (py, px))
    fx = np.fft.fftfreq(w, d=px)
    fy = np.fft.fftfreq(h, d=py)
    # A tiny relative slack keeps grid points that sit exactly on the circle (e.g. the Nyquist bin) inside.
    return (fx[None, :] ** 2 + fy[:, None] ** 2) <= rho * rho * (1.0 + 1e-12)


def _frame_rngs(frames: int, seed: int, lam: float, first: int = 0) -> list[np.random.Generator]:
    lam_key = int(round(lam * 1e15))  # femtometres: distinct laser lines give distinct streams
    root = np.random.SeedSequence(entropy=[int(seed), _STREAM_TAG, lam_key])
    return [np.random.default_rng(child) for child in root.spawn(first + frames)[first:]]


def _check_bank(frames: int, seed: int) -> None:
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or not 1 <= frames <= 4096:
        raise ValueError(f"frames must be an integer in 1..4096, got {frames!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")


def _frames(frames: int, shape_hw: tuple[int, int], wavelength_m: float, pitch_m: PitchLike, seed: int,
            first: int = 0):
    """Yield r_m (complex128 [H, W], unit mean intensity) for m = first..first+F-1, on the CPU."""
    _check_bank(frames, seed)
    if isinstance(first, bool) or not isinstance(first, (int, np.integer)) or first < 0:
        raise ValueError(f"first_frame must be an integer >= 0, got {first!r}")
    h, w, lam, py, px = _check(shape_hw, wavelength_m, pitch_m)
    mask = passband_mask((h, w), lam, (py, px))
    idx = np.flatnonzero(mask)
    # Parseval: mean |r|^2 = n_in / (H W)^2 for the unnormalised inverse DFT; rescale to 1.
    scale = (h * w) / math.sqrt(max(idx.size, 1))
    for rng in _frame_rngs(int(frames), seed, lam, int(first)):
        spec = np.zeros(h * w, dtype=np.complex128)
        spec[idx] = np.exp(1j * rng.uniform(0.0, 2.0 * np.pi, size=idx.size))
        yield np.fft.ifft2(spec.reshape(h, w)) * scale


def random_field(frames: int, shape_hw: tuple[int, int], wavelength_m: float, pitch_m: PitchLike, *, seed: int,
                 device: Union[str, torch.device] = "cpu") -> torch.Tensor:
    """Band-limited complex random fields r_m (Eq. 4), complex64 [F, H, W], unit mean intensity.

    Computed on the CPU in complex128 (the same values on every device), then moved to ``device``.
    """
    return torch.from_numpy(np.stack([r.astype(np.complex64) for r in _frames(frames, shape_hw, wavelength_m,
                                                                               pitch_m, seed)])).to(device)


@lru_cache(maxsize=None)
def code_multiplier(frames: int) -> tuple[int, float]:
    """(a, distance): the multiplier a of the code c(i, j) = (i + a j) mod F whose shortest nonzero same-code
    offset (di, dj) (di + a dj = 0 mod F) is longest, and that length in cells (the radius inside which all cross
    terms of coded frames cancel). F = 1: (0, inf)."""
    F = int(frames)
    if F < 2:
        return 0, math.inf
    best = (1, 0.0)
    for a in range(1, F):
        shortest = float(F)  # (F, 0) is always a same-code offset
        for dj in range(1, F + 1):
            di = (-a * dj) % F
            shortest = min(shortest, math.hypot(di, dj), math.hypot(di - F, dj))
        if shortest > best[1] + 1e-12:
            best = (a, shortest)
    return best


def frame_codes(shape_hw: tuple[int, int], frames: int) -> np.ndarray:
    """The code c(i, j) = (i + a j) mod F of every cell (int64 [H, W]; module docstring), a = code_multiplier(F)."""
    h, w = (int(v) for v in shape_hw)
    a, _ = code_multiplier(frames)
    return (np.arange(h)[:, None] + a * np.arange(w)[None, :]) % max(1, int(frames))


def phase_frames(frames: int, shape_hw: tuple[int, int], wavelength_m: float, pitch_m: PitchLike, *, seed: int,
                 first_frame: int = 0, coded_frames: Optional[int] = None) -> Iterator[np.ndarray]:
    """The maps of :func:`phase_bank` one frame at a time (float32 [H, W] in [0, 2pi), on the CPU): a caller that
    stores each frame elsewhere holds no [F, H, W] temporary, and a coded bank's psi and codes are made once."""
    if coded_frames is not None and int(coded_frames) > 1:
        F = int(coded_frames)
        _check_bank(F, seed)
        if not (0 <= int(first_frame) and int(first_frame) + int(frames) <= F):
            raise ValueError(f"frames {first_frame}..{first_frame + frames - 1} are not in a bank of {F} coded frames")
        psi = np.mod(np.angle(next(_frames(1, shape_hw, wavelength_m, pitch_m, seed, 0))), 2.0 * np.pi)
        step = (2.0 * np.pi / F) * frame_codes(shape_hw, F)
        maps = (np.mod(psi + m * step, 2.0 * np.pi) for m in range(int(first_frame), int(first_frame) + int(frames)))
    else:
        maps = (np.mod(np.angle(r), 2.0 * np.pi) for r in _frames(frames, shape_hw, wavelength_m, pitch_m, seed,
                                                                  first_frame))
    for phi in maps:
        phi = phi.astype(np.float32)
        phi[phi >= np.float32(2.0 * np.pi)] = 0.0  # float32 rounding of values just under 2pi
        yield phi


def phase_bank(frames: int, shape_hw: tuple[int, int], wavelength_m: float, pitch_m: PitchLike, *, seed: int,
               device: Union[str, torch.device] = "cpu", first_frame: int = 0,
               coded_frames: Optional[int] = None) -> torch.Tensor:
    """Random phase maps phi_m = arg r_m, float32 [F, H, W] in [0, 2pi) (paper Eq. 4), periodic on H x W.

    ``seed`` >= 0; the stream is derived from (seed, wavelength, frame index), so the same arguments give the
    same bank on any device and each wavelength an independent one. ``first_frame``: frames first_frame..
    first_frame+frames-1 of the same bank (a chunk of a longer one, equal to its slice). ``coded_frames=F``:
    the frames of an F-frame coded bank instead (module docstring; frame 0 is the same in both).
    """
    phases = list(phase_frames(frames, shape_hw, wavelength_m, pitch_m, seed=seed, first_frame=first_frame,
                               coded_frames=coded_frames))
    return torch.from_numpy(np.stack(phases)).to(device)
