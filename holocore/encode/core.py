"""Shared pieces of the phase-only encoder (docs/design.md §6, the loss Eq. D7; see :mod:`holocore.encode.encoder`
for the physics): argument checks, the ASM and passband helpers, the complex-field error, the reach margin and
phase wrapping.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Union

import numpy as np
import torch

from holocore import validate
from holocore.formats.chunks import map_pieces
from holocore.optics.propagation import PitchLike, asm, ifft2
from holocore.trace.randomfield import passband_mask

TWO_PI = 2.0 * math.pi
ArrayLike = Union[np.ndarray, torch.Tensor]


# ---- validation --------------------------------------------------------------------------------------------
def _as_field(target: ArrayLike, device: Optional[Union[str, torch.device]]) -> torch.Tensor:
    """complex64 [F, C, H, W] on the chosen device (default: the input's, CPU for numpy)."""
    if isinstance(target, torch.Tensor):
        t = target.detach()
    else:
        arr = np.asarray(target)
        if not np.issubdtype(arr.dtype, np.number) or arr.dtype == bool:
            raise ValueError(f"target_wrp must be a numeric array, got dtype {arr.dtype}")
        t = torch.from_numpy(np.ascontiguousarray(arr))
    if t.dim() != 4:
        raise ValueError(f"target_wrp must be [F, C, H, W], got shape {tuple(t.shape)}")
    if min(t.shape) < 1:
        raise ValueError(f"target_wrp must have every axis >= 1, got shape {tuple(t.shape)}")
    t = t.to(device=device if device is not None else t.device, dtype=torch.complex64)
    if not bool(torch.isfinite(torch.view_as_real(t)).all()):
        raise ValueError("target_wrp contains NaN or infinite values")
    return t


def _common(target_wrp: ArrayLike, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
            device: Optional[Union[str, torch.device]]) -> tuple[torch.Tensor, float, list[float]]:
    t = _as_field(target_wrp, device)
    z = validate.bounded("z_wrp_m", z_wrp_m, low=0.0, low_inclusive=False, unit="m (WRP in front of the SLM)")
    lams = validate.wavelengths(wavelengths_m, t.shape[1])
    validate.pitch_pair(pitch_m)
    return t, z, lams


# ---- propagation helpers -----------------------------------------------------------------------------------
def _per_color(u: torch.Tensor, distance_m: float, lams: list[float], pitch_m: PitchLike) -> torch.Tensor:
    """ASM of [F, C, H, W] by distance_m, one wavelength per color, frames batched (differentiable)."""
    return torch.stack([asm(u[:, c], distance_m, lam, pitch_m) for c, lam in enumerate(lams)], dim=1)


def ideal_slm_field(target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
                    device: Optional[Union[str, torch.device]] = None) -> torch.Tensor:
    """u0 = ASM(U_t, -z_wrp) per color: the complex SLM field [F, C, H, W] (complex64) a perfect SLM would show."""
    t, z, lams = _common(target_wrp, z_wrp_m, wavelengths_m, pitch_m, device)
    with torch.no_grad():
        return _per_color(t, -z, lams, pitch_m)


def propagate_to_wrp(slm_field: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
                     device: Optional[Union[str, torch.device]] = None) -> torch.Tensor:
    """U = ASM(u, +z_wrp) per color: the WRP field [F, C, H, W] (complex64) of an SLM field u."""
    u, z, lams = _common(slm_field, z_wrp_m, wavelengths_m, pitch_m, device)
    with torch.no_grad():
        return _per_color(u, z, lams, pitch_m)


def _band_masks(shape_hw: tuple[int, int], lams: list[float], pitch_m: PitchLike,
                device: torch.device) -> torch.Tensor:
    """Bool [C, H, W] passband of each color on the unshifted DFT grid: the recording cone, radius
    sin(theta_max) / lambda = 1/(2p) (docs/design.md §4, ``randomfield.passband_mask``). The spectrum's corners lie
    outside every traced field; the encoder may put light there."""
    return torch.stack([torch.from_numpy(passband_mask(shape_hw, lam, pitch_m)) for lam in lams]).to(device)


def _band(u: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
    """Project [F, C, H, W] onto the passband (periodic H x W grid; an orthogonal projection)."""
    return ifft2(torch.fft.fft2(u) * masks.to(u.real.dtype))


def passband_filter(field: ArrayLike, *, wavelengths_m: Sequence[float], pitch_m: PitchLike) -> torch.Tensor:
    """A WRP/SLM field [F, C, H, W] with the light outside each color's recording cone removed (complex64)."""
    u = _as_field(field, None)
    lams = validate.wavelengths(wavelengths_m, u.shape[1])
    validate.pitch_pair(pitch_m)
    with torch.no_grad():
        return _band(u, _band_masks(tuple(u.shape[-2:]), lams, pitch_m, u.device))


def field_error(pred: ArrayLike, target: ArrayLike, *, margin_px: int = 0) -> np.ndarray:
    """Scale-free complex-field error E = 1 - rho^2 per (frame, color), float64 [F, C], in [0, 1].

    rho^2 = |<t, p>|^2 / (||t||^2 ||p||^2) over the interior that remains after cropping ``margin_px`` pixels
    from each side; equal to ||p - s t||^2 / ||p||^2 with the best complex scale s (docs/design.md §6). 1 where either
    field is zero there.
    """
    if isinstance(margin_px, bool) or not isinstance(margin_px, (int, np.integer)) or margin_px < 0:
        raise ValueError(f"margin_px must be an integer >= 0, got {margin_px!r}")
    p = torch.as_tensor(pred.detach().cpu().numpy() if isinstance(pred, torch.Tensor) else np.asarray(pred))
    t = torch.as_tensor(target.detach().cpu().numpy() if isinstance(target, torch.Tensor) else np.asarray(target))
    if p.shape != t.shape or p.dim() != 4:
        raise ValueError(f"pred and target must both be [F, C, H, W] of one shape, got {tuple(p.shape)} "
                         f"and {tuple(t.shape)}")
    h, w = p.shape[-2:]
    if 2 * margin_px >= min(h, w):
        raise ValueError(f"margin_px must leave an interior (2 * margin_px < {min(h, w)} for a {h}x{w} field), "
                         f"got {margin_px}")
    sl = (..., slice(margin_px, h - margin_px), slice(margin_px, w - margin_px))
    p = p[sl].to(torch.complex128)
    t = t[sl].to(torch.complex128)
    inner = (t.conj() * p).sum(dim=(-2, -1)).abs().square()
    tt = t.abs().square().sum(dim=(-2, -1))
    pp = p.abs().square().sum(dim=(-2, -1))
    den = tt * pp
    rho2 = torch.where(den > 0, inner / torch.where(den > 0, den, torch.ones_like(den)), torch.zeros_like(den))
    return (1.0 - rho2.clamp(0.0, 1.0)).numpy()


def reach_margin_px(*, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike) -> int:
    """Width in pixels of the WRP border the SLM cannot fully reach: ceil(z_wrp tan(theta_max) / p).

    theta_max = arcsin(lambda / 2p) (docs/design.md §4) for the longest wavelength (the widest cone), p the larger
    pitch. A WRP pixel closer to the edge than this misses part of its cone of SLM pixels.
    """
    z = validate.bounded("z_wrp_m", z_wrp_m, low=0.0, low_inclusive=True, unit="m")
    py, px = validate.pitch_pair(pitch_m)
    lams = validate.wavelengths(wavelengths_m, len(list(wavelengths_m)))
    if not lams:
        raise ValueError("wavelengths_m must not be empty")
    p = max(py, px)
    s = min(max(lams) / (2.0 * min(py, px)), 1.0)
    tan = s / math.sqrt(1.0 - s * s) if s < 1.0 else math.inf
    if not math.isfinite(tan):
        raise ValueError("theta_max is 90 degrees (lambda >= 2p): the whole WRP is within reach of every pixel "
                         "only in the far field; no finite margin")
    return int(math.ceil(z * tan / p - 1e-9))


def wrap_phase(phase: ArrayLike) -> np.ndarray:
    """Phase (rad) wrapped to [0, 2pi) as float32 numpy; float32 rounding never yields 2pi (mapped to 0)."""
    ph = phase.detach().cpu().numpy() if isinstance(phase, torch.Tensor) else np.asarray(phase)

    def piece(p: np.ndarray) -> np.ndarray:
        out = np.mod(p.astype(np.float64), TWO_PI).astype(np.float32)
        out[out >= np.float32(TWO_PI)] = 0.0
        return out
    return map_pieces(piece, ph, np.float32)
