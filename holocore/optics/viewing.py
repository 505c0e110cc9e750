"""Simulated viewing of a hologram through an eye pupil (docs/design.md §7, the pupil disc Eq. D8).

An eye of pupil diameter D behind an eyepiece of focal length f, looking from lateral offset e, accepts the
plane waves whose direction sines (lambda f_x, lambda f_y) lie in the disc of centre e / f and radius
NA = D / (2 f). We keep those in the angular spectrum of the field, propagate the rest by ``distance_m`` to the
focus plane (band-limited ASM, docs/design.md §5) in the same padded FFT pass, take |.|^2 and average over frames
(time multiplexing).

A display with a Fourier filter (``fourier_filter``; docs/design.md §6, the encoder's "cone" supervision) passes only
each colour's recording cone, the disc of direction sines <= lambda / 2p: the view then keeps the plane waves
inside both the pupil and that disc. Without it a phase-only hologram's light outside the cone (where the encoder
parks what a phase-only SLM cannot help sending) reaches any pupil wider than the cone as a haze, and more of
blue's and green's than of red's, whose cone is the widest: a cast the real display does not have.

An SLM's pixels are squares of side p with no gap (fill factor 1), not points (``pixel_orders``): its field is the
sampled field convolved with that square, so its spectrum is the sampled field's, periodic in 1/p (the diffraction
orders), times the square's sinc(p f_x) sinc(p f_y). The view weighs each order relative to the zeroth, sinc(p (f +
n/p)) / sinc(p f): the zeroth order's own roll-off towards the band's edge is the same for every method and for a
display with a filter, and an encoder could undo it, so it is left out here as there. Without a Fourier filter an
eye whose pupil reaches past the band |sine| <= lambda / 2p takes light from the neighbouring orders: ghosts of the
image, moved by z lambda / p at depth z. On the SLM's grid, bin f also stands for order n's frequency f + n/p, where
the sampled field's spectrum is the same; so each order the pupil takes (:func:`orders_factor` bounds the orders to
try) gets its own filter there (the sinc, the pupil, the propagation, the content shift, all at f + n/p), is viewed,
and the orders' intensities add. Where two orders share the pupil they also interfere, in fringes of period p or
finer: a pixel's mean holds none of that, so the sum is each pixel's mean intensity, and the view costs one inverse
FFT per order the pupil takes.

Sign of the row frequency: rows run down while y runs up (y = ((H-1)/2 - i) p), so a wave exp(i 2 pi f_y y)
travelling upwards (f_y > 0) has DFT frequency -f_y along the row axis. The pupil therefore sits at
row frequency -e_y / (f lambda).

Memory: the field is read in chunks of frames of one color (:func:`view_intensities` takes anything with
``shape`` and ``chunk(f0, f1, c)``, e.g. :class:`holocore.optics.fieldsource.SlmFieldSource` streaming from a file), the
chunk sized by the memory budget (:mod:`holocore.runtime.membudget`) and at most ``_CHUNK_BYTES`` of padded spectra.
Each frame's intensity is summed in float64, so the view does not depend on the chunking beyond float32
rounding of the FFTs.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Union

import numpy as np
import torch

from holocore import validate
from holocore.optics.propagation import (
    PitchLike,
    ifft2,
    padded_shape,
    transfer_at,
    transfer_function,
)
from holocore.display.optics import theta_max_rad
from holocore.runtime.membudget import frames_per_chunk
from holocore.runtime.membudget import memory_budget_bytes as _budget

__all__ = ["simulate_view", "view_intensities", "pupil_mask", "eye_mask", "stack_to_field", "depth_of_field_m",
           "orders_factor"]

_CHUNK_BYTES = 256 << 20  # padded spectra processed at once, per channel


def depth_of_field_m(wavelength_m: float, focal_length_m: float, pupil_diameter_m: float) -> float:
    """Hologram-space depth of field (m) of a pupil: lambda / NA^2 with NA = D / (2 f)."""
    lam = validate.positive("wavelength_m", wavelength_m)
    f = validate.positive("focal_length_m", focal_length_m)
    d = validate.positive("pupil_diameter_m", pupil_diameter_m)
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
               focal_length_m: float, pupil_diameter_m: float, view_offset_m: tuple[float, float] = (0.0, 0.0),
               device: Union[str, torch.device] = "cpu") -> torch.Tensor:
    """Boolean [Hp, Wp] mask (unshifted DFT order) of the plane waves the pupil accepts.

    Keeps (lambda f_x - e_x / f)^2 + (lambda f_y - e_y / f)^2 <= (D / 2f)^2 with f_y = -(row frequency).
    ``view_offset_m`` is (e_x, e_y) in m, x right and y up (docs/design.md §3).
    """
    hp, wp = (int(s) for s in shape_hw_padded)
    lam = validate.positive("wavelength_m", wavelength_m)
    py, px = validate.pitch_pair(pitch_m)
    f = validate.positive("focal_length_m", focal_length_m)
    d = validate.positive("pupil_diameter_m", pupil_diameter_m)
    if len(view_offset_m) != 2:
        raise ValueError(f"view_offset_m must be (e_x, e_y) in m, got {view_offset_m!r}")
    ex, ey = validate.real("view_offset_m[0]", view_offset_m[0]), validate.real("view_offset_m[1]", view_offset_m[1])
    sx = lam * torch.fft.fftfreq(wp, d=px, dtype=torch.float64, device=device)  # direction sine along x
    sy = -lam * torch.fft.fftfreq(hp, d=py, dtype=torch.float64, device=device)  # rows run down: f_y = -f_row
    return _in_disc(sx, sy, (ex / f, ey / f), d / (2.0 * f))


def _in_disc(sx: torch.Tensor, sy: torch.Tensor, centre: tuple[float, float], radius: float) -> torch.Tensor:
    """[len(sy), len(sx)]: whether the direction sines (sx, sy) lie in the disc of ``centre`` and ``radius``."""
    return ((sx[None, :] - centre[0]) ** 2 + (sy[:, None] - centre[1]) ** 2) <= radius * radius


def _cone_sine(wavelength_m: float, pitch_m: PitchLike) -> float:
    """The sine a Fourier filter passes for this colour: its recording cone's, edge kept."""
    return math.sin(theta_max_rad(wavelength_m, max(validate.pitch_pair(pitch_m)))) * (1.0 + 1e-9)


def eye_mask(shape_hw_padded: tuple[int, int], wavelength_m: float, pitch_m: PitchLike, *, focal_length_m: float,
             pupil_diameter_m: float, view_offset_m: tuple[float, float] = (0.0, 0.0), fourier_filter: bool = False,
             device: Union[str, torch.device] = "cpu") -> torch.Tensor:
    """Boolean [Hp, Wp] mask of the plane waves an eye takes: its pupil (:func:`pupil_mask`) and, where the
    display has a Fourier filter, each colour's recording cone, a centred disc of sine lambda / 2p (edge kept)."""
    mask = pupil_mask(shape_hw_padded, wavelength_m, pitch_m, focal_length_m=focal_length_m,
                      pupil_diameter_m=pupil_diameter_m, view_offset_m=view_offset_m, device=device)
    if fourier_filter:
        mask &= pupil_mask(shape_hw_padded, wavelength_m, pitch_m, focal_length_m=focal_length_m,
                           pupil_diameter_m=2.0 * focal_length_m * _cone_sine(wavelength_m, pitch_m), device=device)
    return mask


def orders_factor(wavelength_m: float, pitch_m: PitchLike, *, focal_length_m: float, pupil_diameter_m: float,
                  view_offset_m: tuple[float, float] = (0.0, 0.0), fourier_filter: bool = False) -> int:
    """k = 2 n + 1 for the highest order n (per axis) the pupil can reach: orders up to n span sines up to
    k lambda / 2p, enough for the pupil's reach |e| / f + D / 2f. 1 where the pupil stays inside the SLM's band or
    a Fourier filter cuts the other orders."""
    if fourier_filter:
        return 1
    lam = validate.positive("wavelength_m", wavelength_m)
    f = validate.positive("focal_length_m", focal_length_m)
    na = validate.positive("pupil_diameter_m", pupil_diameter_m) / (2.0 * f)
    k = 1
    for e, p in zip((abs(float(view_offset_m[1])), abs(float(view_offset_m[0]))), validate.pitch_pair(pitch_m)):
        reach = e / f + na
        k = max(k, 2 * math.ceil((reach * 2.0 * p / lam - 1.0) / 2.0 - 1e-9) + 1)
    return k


# An order bringing less of the pupil's light than this (for a flat spectrum) is left out: a ghost that faint
# moves a score of 15-20 dB (an error of 1-3 % of the white, squared) by less than 0.05 dB.
_ORDER_FLOOR = 1e-2


def _order_filters(shape_hw_padded: tuple[int, int], k: int, wavelength_m: float, pitch_m: PitchLike, *,
                   distance_m: float, focal_length_m: float, pupil_diameter_m: float,
                   view_offset_m: tuple[float, float], shift_px: tuple[float, float], fourier_filter: bool,
                   device: torch.device) -> list[torch.Tensor]:
    """One [Hp, Wp] filter (unshifted order) per diffraction order n = (n_y, n_x), |n| <= k // 2, that the pupil
    takes: on the SLM's grid, each bin f stands for order n's frequency f + n/p (where the sampled field's
    spectrum is the same), and the filter is the pixel's sinc relative to the zeroth order's, the eye's mask (a
    Fourier filter's cone only at k = 1, :func:`orders_factor`), the propagation by ``distance_m`` and the content
    shift, all at f + n/p. Orders that bring less than ``_ORDER_FLOOR`` of the light (for a flat spectrum) are left
    out."""
    hp, wp = (int(v) for v in shape_hw_padded)
    py, px = validate.pitch_pair(pitch_m)
    lam, f = float(wavelength_m), float(focal_length_m)
    ex, ey = (float(v) for v in view_offset_m)
    na = float(pupil_diameter_m) / (2.0 * f)
    fy0 = torch.fft.fftfreq(hp, d=py, dtype=torch.float64, device=device)  # row frequency, cycles / m
    fx0 = torch.fft.fftfreq(wp, d=px, dtype=torch.float64, device=device)
    a_row, a_col = (float(v) for v in shift_px)
    cone = _cone_sine(lam, pitch_m) if fourier_filter and k == 1 else None
    out, power = [], []
    for ny in range(-(k // 2), k // 2 + 1):
        for nx in range(-(k // 2), k // 2 + 1):
            fy, fx = fy0 + ny / py, fx0 + nx / px
            sx, sy = lam * fx, -lam * fy  # direction sines; rows run down (module docstring)
            mask = _in_disc(sx, sy, (ex / f, ey / f), na)
            if cone is not None:
                mask &= _in_disc(sx, sy, (0.0, 0.0), cone)
            if not bool(mask.any()):
                continue
            # relative to the zeroth order: its own roll-off, the same for every method and for a display with a
            # filter, is left out (module docstring); the ratio is bounded, |p f| <= 1/2 on the SLM's grid
            amp = (torch.sinc(fy * py) / torch.sinc(fy0 * py))[:, None] * \
                (torch.sinc(fx * px) / torch.sinc(fx0 * px))[None, :] * mask
            g = torch.polar(amp, 2 * math.pi * ((fy * py * a_row)[:, None] + (fx * px * a_col)[None, :]))
            if distance_m != 0.0:
                g.mul_(transfer_at(fy, fx, distance_m, lam, extent_m=(hp * py, wp * px)))
            out.append(g.to(torch.complex64))
            power.append(float(amp.square().sum()))
    total = sum(power) or 1.0
    return [g for g, pw in zip(out, power) if pw >= _ORDER_FLOOR * total]


class _TensorSource:
    def __init__(self, field: torch.Tensor) -> None:
        self.shape = tuple(field.shape)
        self._f = field

    def chunk(self, f0: int, f1: int, c: int) -> torch.Tensor:
        return self._f[f0:f1, c]


_VIEW_FIXED_BYTES = 0.6 * 2**30  # interpreter, torch, filters, accumulators outside the chunk


def _view_layout(shape: tuple[int, int, int, int], lams: list[float], n_planes: int, *, pitch_m: PitchLike,
                 focal_length_m: float, pupil_diameter_m: float, view_offset_m: tuple[float, float],
                 shift_px: tuple[float, float], pad_factor: float, memory_budget_bytes: Optional[int],
                 fourier_filter: bool, pixel_orders: bool) -> tuple[int, tuple[int, int], list[int], int]:
    """(m, padded shape (hp, wp), diffraction orders k per colour, frames per chunk): the border m (px) a shift
    needs on each side, the FFT grid of the view padded by it, and the chunk that keeps the working set within the
    memory budget."""
    F, C, h, w = shape
    a_row, a_col = shift_px
    m = int(math.ceil(max(abs(a_col), abs(a_row)))) + 2 if (abs(a_col) > 1e-9 or abs(a_row) > 1e-9) else 0
    hs, ws = h + 2 * m, w + 2 * m
    hp, wp = padded_shape((hs, ws), pad_factor)
    ks = [orders_factor(lam, pitch_m, focal_length_m=focal_length_m, pupil_diameter_m=pupil_diameter_m,
                        view_offset_m=view_offset_m, fourier_filter=fourier_filter) if pixel_orders else 1
          for lam in lams]
    cap = max(1, _CHUNK_BYTES // (hp * wp * 8))  # bound the padded working set
    per_frame = 8 * ((4 if pixel_orders else 3) * hp * wp + (3 * hs * ws if m else 0) + 2 * h * w)
    fixed = _VIEW_FIXED_BYTES + n_planes * C * h * w * 4 + 16 * h * w + 80 * hp * wp + 8 * max(ks) ** 2 * hp * wp
    chunk = frames_per_chunk(F, per_frame_bytes=per_frame, fixed_bytes=fixed,
                             budget_bytes=_budget(memory_budget_bytes), cap=cap)
    return m, (hp, wp), ks, chunk


def _load_chunk(source, f0: int, f1: int, c: int, dev: Optional[torch.device]) -> torch.Tensor:
    """Frames f0..f1 of colour ``c`` of ``source``, complex64 [k, H, W] (on ``dev`` when given); ValueError for a
    real field."""
    u0 = source.chunk(f0, f1, c)
    u0 = torch.from_numpy(u0) if isinstance(u0, np.ndarray) else u0
    if not u0.is_complex():
        raise ValueError("field must be complex")
    if dev is not None:
        u0 = u0.to(dev)
    if u0.dtype != torch.complex64:
        u0 = u0.to(torch.complex64)
    return u0


def _shifted_chunk(u0: torch.Tensor, m: int, shift_px: tuple[float, float], pixel_orders: bool,
                   ramp: Optional[torch.Tensor]) -> tuple[torch.Tensor, Optional[torch.Tensor]]:
    """(the chunk zero-padded by ``m`` px on each side and, without pixel orders, shifted by ``shift_px`` on its
    spectrum (with pixel orders the shift goes into each order's filter); the shift's phase ramp, made once)."""
    h, w = u0.shape[-2:]
    hs, ws = h + 2 * m, w + 2 * m
    a_row, a_col = shift_px
    big = torch.zeros((u0.shape[0], hs, ws), dtype=torch.complex64, device=u0.device)
    big[..., m:m + h, m:m + w] = u0
    if pixel_orders:
        return big, ramp
    if ramp is None:
        ky = torch.fft.fftfreq(hs, dtype=torch.float64)
        kx = torch.fft.fftfreq(ws, dtype=torch.float64)
        ramp = torch.polar(torch.ones(hs, ws, dtype=torch.float64),
                           2 * math.pi * (ky[:, None] * a_row + kx[None, :] * a_col)
                           ).to(torch.complex64).to(u0.device)
    return ifft2(torch.fft.fft2(big) * ramp), ramp


def _plane_filters(padded_hw: tuple[int, int], k: int, lam: float, pitch_m: PitchLike, z: float, *,
                   focal_length_m: float, pupil_diameter_m: float, view_offset_m: tuple[float, float],
                   shift_px: tuple[float, float], fourier_filter: bool, pixel_orders: bool,
                   u0: torch.Tensor) -> list[torch.Tensor]:
    """The spectrum filters of one colour at distance ``z``, on ``u0``'s device: one per diffraction order taken
    (:func:`_order_filters`) with pixel orders, else the one transfer function times the eye's mask."""
    if pixel_orders:
        return _order_filters(padded_hw, k, lam, pitch_m, distance_m=z, focal_length_m=focal_length_m,
                              pupil_diameter_m=pupil_diameter_m, view_offset_m=view_offset_m,
                              shift_px=shift_px, fourier_filter=fourier_filter, device=u0.device)
    mask = eye_mask(padded_hw, lam, pitch_m, focal_length_m=focal_length_m, pupil_diameter_m=pupil_diameter_m,
                    view_offset_m=view_offset_m, fourier_filter=fourier_filter, device=u0.device)
    filt = transfer_function(padded_hw, z, lam, pitch_m, device=u0.device, dtype=u0.dtype) \
        if z != 0.0 else torch.ones(padded_hw, dtype=u0.dtype, device=u0.device)
    return [filt.mul_(mask.to(filt.real.dtype))]


def view_intensities(source, *, wavelengths_m: Sequence[float], pitch_m: PitchLike, focal_length_m: float,
                     pupil_diameter_m: float, distances_m: Sequence[float],
                     view_offset_m: tuple[float, float] = (0.0, 0.0), shift_px: tuple[float, float] = (0.0, 0.0),
                     pad_factor: float = 2, device: Optional[Union[str, torch.device]] = None,
                     memory_budget_bytes: Optional[int] = None, fourier_filter: bool = False,
                     pixel_orders: Optional[bool] = False) -> torch.Tensor:
    """What an eye sees at each of ``distances_m``: float32 [D, C, H, W], frame-averaged (docs/design.md §7).

    ``source``: ``shape`` (F, C, H, W) and ``chunk(f0, f1, c)`` -> complex [k, H, W] (numpy or torch) on the
    plane; see :func:`simulate_view` for the optics. ``shift_px`` = (rows, cols): the view is first shifted by
    that many pixels (U'[i, j] = U[i + a_row, j + a_col], exactly, on the spectrum of a grid padded by the
    shift; evaluate's off-axis eye). ``device``: where the FFTs run (default: the chunks' device).
    ``fourier_filter``: the display's filter passes only each colour's recording cone (module docstring).
    ``pixel_orders``: the SLM's square pixels, their sinc and the diffraction orders the pupil reaches (module
    docstring; :func:`orders_factor` bounds the orders tried); None: exactly where there is no Fourier filter,
    the display the callers that follow a display profile model.
    """
    F, C, h, w = (int(v) for v in source.shape)
    lams = [float(v) for v in wavelengths_m]
    if len(lams) != C:
        raise ValueError(f"wavelengths_m has {len(lams)} entries but the field has {C} channels")
    zs = [validate.real("distance_m", z) for z in distances_m]
    validate.pitch_pair(pitch_m)
    a_row, a_col = (float(v) for v in shift_px)
    if pixel_orders is None:
        pixel_orders = not fourier_filter
    optics = dict(focal_length_m=focal_length_m, pupil_diameter_m=pupil_diameter_m, view_offset_m=view_offset_m,
                  fourier_filter=fourier_filter, pixel_orders=pixel_orders)
    m, (hp, wp), ks, chunk = _view_layout((F, C, h, w), lams, len(zs), pitch_m=pitch_m, shift_px=(a_row, a_col),
                                          pad_factor=pad_factor, memory_budget_bytes=memory_budget_bytes, **optics)
    hs, ws = h + 2 * m, w + 2 * m
    dev = None if device is None else torch.device(device)
    out = None
    ramp = None
    for c, lam in enumerate(lams):
        k = ks[c]
        for di, z in enumerate(zs):
            acc = None
            filt = None
            for f0 in range(0, F, chunk):
                u0 = _load_chunk(source, f0, min(F, f0 + chunk), c, dev)
                if out is None:
                    out = torch.empty((len(zs), C, h, w), dtype=torch.float32, device=u0.device)
                if m:
                    u0, ramp = _shifted_chunk(u0, m, (a_row, a_col), pixel_orders, ramp)
                if filt is None:
                    filt = _plane_filters((hp, wp), k, lam, pitch_m, z, shift_px=(a_row, a_col), u0=u0, **optics)
                    acc = torch.zeros((hs, ws), dtype=torch.float64, device=u0.device)
                spec = torch.fft.fft2(u0, s=(hp, wp))
                del u0
                for i, g in enumerate(filt):  # one per diffraction order taken; the last one in place
                    u = ifft2(spec.mul_(g) if i == len(filt) - 1 else spec * g)[..., :hs, :ws]
                    acc += (u.real.square() + u.imag.square()).to(torch.float64).sum(dim=0)
                    del u
                del spec
            out[di, c] = (acc / F).to(torch.float32)[m:m + h, m:m + w]
    return out


def simulate_view(field: torch.Tensor, *, wavelengths_m: Sequence[float], pitch_m: PitchLike, focal_length_m: float,
                  pupil_diameter_m: float, distance_m: float, view_offset_m: tuple[float, float] = (0.0, 0.0),
                  shift_px: tuple[float, float] = (0.0, 0.0), pad_factor: float = 2,
                  memory_budget_bytes: Optional[int] = None, fourier_filter: bool = False,
                  pixel_orders: Optional[bool] = False) -> torch.Tensor:
    """What an eye sees: float32 intensity [C, H, W], frame-averaged (docs/design.md §7).

    ``field`` complex [F, C, H, W] (or [C, H, W], one frame) on a plane; ``distance_m`` (m) from that plane to
    the focus plane z_f (negative: focus behind it); pupil of ``pupil_diameter_m`` behind an eyepiece of
    ``focal_length_m``, centred at ``view_offset_m`` = (e_x, e_y) (m). One wavelength per channel.
    ``shift_px``: the off-axis eye's shift of the focus plane's content (:func:`view_intensities`).
    ``fourier_filter``: the display passes only each colour's recording cone (module docstring). ``pixel_orders``:
    the SLM's square pixels and the diffraction orders the pupil reaches (module docstring; None: where there is
    no filter). Differentiable
    in ``field`` (the focal stack's pupil-aware fit back-propagates through it).
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
    z = validate.real("distance_m", distance_m)
    return view_intensities(_TensorSource(field), wavelengths_m=lams, pitch_m=pitch_m, focal_length_m=focal_length_m,
                            pupil_diameter_m=pupil_diameter_m, distances_m=[z], view_offset_m=view_offset_m,
                            shift_px=shift_px, pad_factor=pad_factor, memory_budget_bytes=memory_budget_bytes,
                            fourier_filter=fourier_filter, pixel_orders=pixel_orders)[0]
