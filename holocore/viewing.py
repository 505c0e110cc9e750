"""Simulated viewing of a hologram through an eye pupil (DESIGN.md §7).

An eye of pupil diameter D behind an eyepiece of focal length f, looking from lateral offset e, accepts the
plane waves whose direction sines (lambda f_x, lambda f_y) lie in the disc of centre e / f and radius
NA = D / (2 f). We keep those in the angular spectrum of the field, propagate the rest by ``distance_m`` to the
focus plane (band-limited ASM, DESIGN §5) in the same padded FFT pass, take |.|^2 and average over frames
(time multiplexing).

Sign of the row frequency: rows run down while y runs up (y = ((H-1)/2 - i) p), so a wave exp(i 2 pi f_y y)
travelling upwards (f_y > 0) has DFT frequency -f_y along the row axis. The pupil therefore sits at
row frequency -e_y / (f lambda).
"""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np
import torch

from holocore.propagation import PitchLike, _pitch_pair, _positive, _real, ifft2, padded_shape, transfer_function

__all__ = ["simulate_view", "pupil_mask", "stack_to_field", "depth_of_field_m"]

_CHUNK_BYTES = 256 << 20  # padded spectra processed at once, per channel


def depth_of_field_m(wavelength_m: float, focal_length_m: float, pupil_diameter_m: float) -> float:
    """Hologram-space depth of field (m) of a pupil: lambda / NA^2 with NA = D / (2 f)."""
    lam = _positive("wavelength_m", wavelength_m)
    f = _positive("focal_length_m", focal_length_m)
    d = _positive("pupil_diameter_m", pupil_diameter_m)
    na = d / (2.0 * f)
    return lam / (na * na)


def stack_to_field(phase: Union[np.ndarray, torch.Tensor]) -> torch.Tensor:
    """exp(i phase) as a complex64 tensor of the same shape (phase in rad, numpy or torch, real)."""
    ph = torch.as_tensor(phase)
    if ph.is_complex() or not (ph.is_floating_point() or ph.dtype in (torch.int8, torch.int16, torch.int32,
                                                                        torch.int64, torch.uint8)):
        raise ValueError(f"phase must be a real array, got dtype {ph.dtype}")
    ph = ph.to(torch.float32)
    if not bool(torch.isfinite(ph).all()):
        raise ValueError("phase contains NaN or infinite values")
    return torch.polar(torch.ones_like(ph), ph)


def pupil_mask(shape_hw_padded: tuple[int, int], wavelength_m: float, pitch_m: PitchLike, *,
               focal_length_m: float, pupil_diameter_m: float,
               view_offset_m: tuple[float, float] = (0.0, 0.0), device: Union[str, torch.device] = "cpu") -> torch.Tensor:
    """Boolean [Hp, Wp] mask (unshifted DFT order) of the plane waves the pupil accepts.

    Keeps (lambda f_x - e_x / f)^2 + (lambda f_y - e_y / f)^2 <= (D / 2f)^2 with f_y = -(row frequency).
    ``view_offset_m`` is (e_x, e_y) in m, x right and y up (DESIGN §3).
    """
    hp, wp = (int(s) for s in shape_hw_padded)
    lam = _positive("wavelength_m", wavelength_m)
    py, px = _pitch_pair(pitch_m)
    f = _positive("focal_length_m", focal_length_m)
    d = _positive("pupil_diameter_m", pupil_diameter_m)
    if len(view_offset_m) != 2:
        raise ValueError(f"view_offset_m must be (e_x, e_y) in m, got {view_offset_m!r}")
    ex, ey = _real("view_offset_m[0]", view_offset_m[0]), _real("view_offset_m[1]", view_offset_m[1])
    sx = lam * torch.fft.fftfreq(wp, d=px, dtype=torch.float64, device=device)  # direction sine along x
    sy = -lam * torch.fft.fftfreq(hp, d=py, dtype=torch.float64, device=device)  # rows run down: f_y = -f_row
    na = d / (2.0 * f)
    return ((sx[None, :] - ex / f) ** 2 + (sy[:, None] - ey / f) ** 2) <= na * na


def simulate_view(field: torch.Tensor, *, wavelengths_m: Sequence[float], pitch_m: PitchLike, focal_length_m: float,
                  pupil_diameter_m: float, distance_m: float, view_offset_m: tuple[float, float] = (0.0, 0.0),
                  pad_factor: float = 2) -> torch.Tensor:
    """What an eye sees: float32 intensity [C, H, W], frame-averaged (DESIGN §7).

    ``field`` complex [F, C, H, W] (or [C, H, W], one frame) on a plane; ``distance_m`` (m) from that plane to
    the focus plane z_f (negative: focus behind it); pupil of ``pupil_diameter_m`` behind an eyepiece of
    ``focal_length_m``, centred at ``view_offset_m`` = (e_x, e_y) (m). One wavelength per channel.
    """
    if not isinstance(field, torch.Tensor) or not field.is_complex():
        raise ValueError("field must be a complex torch tensor [F, C, H, W] or [C, H, W]")
    if field.dim() == 3:
        field = field.unsqueeze(0)
    if field.dim() != 4:
        raise ValueError(f"field must be [F, C, H, W] or [C, H, W], got shape {tuple(field.shape)}")
    lams = [float(v) for v in wavelengths_m]
    if len(lams) != field.shape[1]:
        raise ValueError(f"wavelengths_m has {len(lams)} entries but the field has {field.shape[1]} channels")
    z = _real("distance_m", distance_m)
    _pitch_pair(pitch_m)
    h, w = field.shape[-2:]
    hp, wp = padded_shape((h, w), pad_factor)
    out = torch.empty((field.shape[1], h, w), dtype=torch.float32, device=field.device)
    n_frames = field.shape[0]
    chunk = max(1, _CHUNK_BYTES // (hp * wp * field.element_size()))  # bound the padded working set
    for c, lam in enumerate(lams):
        mask = pupil_mask((hp, wp), lam, pitch_m, focal_length_m=focal_length_m, pupil_diameter_m=pupil_diameter_m,
                          view_offset_m=view_offset_m, device=field.device)
        filt = transfer_function((hp, wp), z, lam, pitch_m, device=field.device, dtype=field.dtype) if z != 0.0 \
            else torch.ones((hp, wp), dtype=field.dtype, device=field.device)
        filt.mul_(mask.to(filt.real.dtype))
        acc = torch.zeros((h, w), dtype=torch.float64, device=field.device)
        for f0 in range(0, n_frames, chunk):
            spec = torch.fft.fft2(field[f0:f0 + chunk, c], s=(hp, wp))
            spec.mul_(filt)
            u = ifft2(spec)[..., :h, :w]
            acc += (u.real.square() + u.imag.square()).sum(dim=0).to(torch.float64)
        out[c] = (acc / n_frames).to(torch.float32)
    return out
