"""Band-limited angular spectrum propagation between parallel planes (docs/design.md §5, its band limit Eq. D6).

    U(x, y, z) = IFFT{ FFT{U(x, y, 0)} * H(f_x, f_y; z) },   H = exp(i 2 pi z sqrt(1/lambda^2 - f_x^2 - f_y^2))

on a grid zero-padded by ``pad_factor`` (linear, not circular, convolution) and cropped back. Evanescent
components (f_x^2 + f_y^2 > 1/lambda^2) are dropped, and, with ``band_limit``, the band limit of Matsushima &
Shimobaba (Opt. Express 17(22), 2009, Eq. 13) is applied per axis on the exact DFT frequency grid:

    |f_x| <= 1 / (lambda sqrt((2 df_x z)^2 + 1)),   df_x = 1 / (padded_W p_x)   (same for y with rows)

which keeps the sampled transfer function free of aliasing. With ``cone_sine`` s the passband is also cut to the
directions of sine <= s, f_x^2 + f_y^2 <= (s / lambda)^2: the common eyebox of a colour display (docs/physics.md,
"One eyebox for every colour"), applied at z = 0 too. H is built in float64 with its phase wrapped to
[-pi, pi) before the cast (docs/design.md §2: 2 pi z / lambda is ~1.4e7 rad at 1 m), cached in a bounded LRU, and
applied in the input's dtype. Frequencies stay in unshifted FFT order (no fftshift copies).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import Sequence, Union

import torch

import holocore.runtime.torch_runtime  # noqa: F401  (reproducible CPU vector math; see its docstring)
from holocore import validate
from holocore.optics.grids import padded_shape, smooth_at_least  # noqa: F401  (re-exported: the ASM's grid)
from holocore.validate import PitchLike

__all__ = ["asm", "asm_to", "ifft2", "transfer_function", "transfer_at", "padded_shape", "clear_cache", "PitchLike"]


_TF_CACHE_MAX_ENTRIES = 16
_TF_CACHE_MAX_BYTES = 1 << 30  # 1 GiB of transfer functions at most
_WS_MAX_BYTES = 1 << 30  # per thread: zero-padded input workspaces (CPU fast path)

_tf_cache: "OrderedDict[tuple, torch.Tensor]" = OrderedDict()
_tf_lock = threading.Lock()
_ws_local = threading.local()


# ---- validation ------------------------------------------------------------------------------------------
def _check_field(field: object) -> torch.Tensor:
    if not isinstance(field, torch.Tensor):
        raise ValueError(f"field must be a torch tensor, got {type(field).__name__}")
    if not field.is_complex():
        raise ValueError(f"field must be complex (complex64 or complex128), got {field.dtype}")
    if field.dim() < 2:
        raise ValueError(f"field must be [..., H, W], got shape {tuple(field.shape)}")
    if field.shape[-1] < 1 or field.shape[-2] < 1:
        raise ValueError(f"field must have H, W >= 1, got shape {tuple(field.shape)}")
    return field


# ---- transfer function -----------------------------------------------------------------------------------
def _build_tf(shape: tuple[int, int], z: float, lam: float, py: float, px: float, band_limit: bool,
              device: torch.device, dtype: torch.dtype, cone_sine: float | None = None) -> torch.Tensor:
    """H(f_x, f_y; z) in float64 on the unshifted DFT grid, phase wrapped, then cast to ``dtype``."""
    ph, pw = shape
    fx = torch.fft.fftfreq(pw, d=px, dtype=torch.float64, device=device)  # cycles / m, unshifted FFT order
    fy = torch.fft.fftfreq(ph, d=py, dtype=torch.float64, device=device)
    return transfer_at(fy, fx, z, lam, extent_m=(ph * py, pw * px), band_limit=band_limit,
                       cone_sine=cone_sine).to(dtype)


def transfer_at(fy: torch.Tensor, fx: torch.Tensor, distance_m: float, wavelength_m: float, *,
                extent_m: tuple[float, float], band_limit: bool = True,
                cone_sine: float | None = None) -> torch.Tensor:
    """complex128 H [len(fy), len(fx)] of the ASM at the row / column frequencies ``fy``, ``fx`` (cycles / m,
    float64; any frequencies, such as those of an SLM's higher diffraction orders): evanescent part zero, phase
    wrapped in float64, and the Matsushima-Shimobaba band limit of a padded grid of ``extent_m`` (rows, cols)."""
    z, lam = float(distance_m), float(wavelength_m)
    fx2 = (fx * fx)[None, :]
    fy2 = (fy * fy)[:, None]
    arg = (1.0 / (lam * lam)) - fx2 - fy2  # w^2 = 1/lambda^2 - f_x^2 - f_y^2
    keep = arg > 0.0  # evanescent components dropped
    w = torch.sqrt(torch.clamp_(arg, min=0.0))
    phase = w.mul_(2.0 * math.pi * z)
    phase = torch.remainder(phase + math.pi, 2.0 * math.pi).sub_(math.pi)  # wrap to [-pi, pi) in float64
    if band_limit:
        # Matsushima & Shimobaba 2009, Eq. 13, per axis with the padded grid's frequency step.
        dfy, dfx = 1.0 / float(extent_m[0]), 1.0 / float(extent_m[1])
        lim_x = 1.0 / (lam * math.sqrt((2.0 * dfx * z) ** 2 + 1.0))
        lim_y = 1.0 / (lam * math.sqrt((2.0 * dfy * z) ** 2 + 1.0))
        keep &= (fx.abs() <= lim_x)[None, :] & (fy.abs() <= lim_y)[:, None]
    if cone_sine is not None:  # the directions of sine <= cone_sine only (the common eyebox)
        keep &= (fx2 + fy2) * (lam * lam) <= cone_sine * cone_sine * (1.0 + 1e-12)
    return torch.polar(keep.to(torch.float64), phase)


def _cached_tf(shape: tuple[int, int], z: float, lam: float, py: float, px: float, band_limit: bool,
               device: torch.device, dtype: torch.dtype, *, conj_scaled: bool = False,
               cone_sine: float | None = None) -> torch.Tensor:
    """The cached H; with ``conj_scaled`` the cached conj(H) / (Hp Wp) that :func:`ifft2`'s identity needs."""
    key = (shape, py, px, lam, z, bool(band_limit), str(device), dtype, conj_scaled, cone_sine)
    with _tf_lock:
        tf = _tf_cache.get(key)
        if tf is not None:
            _tf_cache.move_to_end(key)
            return tf
    if conj_scaled:
        tf = _cached_tf(shape, z, lam, py, px, band_limit, device, dtype,
                        cone_sine=cone_sine).conj_physical().div_(shape[0] * shape[1])
    else:
        tf = _build_tf(shape, z, lam, py, px, band_limit, device, dtype, cone_sine)
    nbytes = tf.numel() * tf.element_size()
    if nbytes <= _TF_CACHE_MAX_BYTES:
        with _tf_lock:
            _tf_cache[key] = tf
            _tf_cache.move_to_end(key)
            total = sum(t.numel() * t.element_size() for t in _tf_cache.values())
            while len(_tf_cache) > 1 and (len(_tf_cache) > _TF_CACHE_MAX_ENTRIES or total > _TF_CACHE_MAX_BYTES):
                _, old = _tf_cache.popitem(last=False)
                total -= old.numel() * old.element_size()
    return tf


def clear_cache() -> None:
    """Forget every cached transfer function and this thread's padding workspaces."""
    with _tf_lock:
        _tf_cache.clear()
    _ws_local.__dict__.pop("bufs", None)


def _check_dtype(dtype: torch.dtype) -> None:
    if dtype not in (torch.complex64, torch.complex128):
        raise ValueError(f"dtype must be torch.complex64 or torch.complex128, got {dtype}")


def transfer_function(shape_hw_padded: tuple[int, int], distance_m: float, wavelength_m: float, pitch_m: PitchLike,
                      *, band_limit: bool = True, device: Union[str, torch.device] = "cpu",
                      dtype: torch.dtype = torch.complex64) -> torch.Tensor:
    """ASM transfer function H [Hp, Wp] (unshifted FFT order) for a propagation by ``distance_m`` (m).

    Built in float64, phase wrapped before the cast; evanescent part zero; Matsushima-Shimobaba band limit per
    axis when ``band_limit``. Returns a fresh tensor (the cache inside :func:`asm` is not exposed).
    """
    _check_dtype(dtype)
    hp, wp = (int(s) for s in shape_hw_padded)
    if hp < 1 or wp < 1:
        raise ValueError(f"shape_hw_padded must be two sizes >= 1, got {shape_hw_padded}")
    z = validate.real("distance_m", distance_m)
    lam = validate.positive("wavelength_m", wavelength_m)
    py, px = validate.pitch_pair(pitch_m)
    return _cached_tf((hp, wp), z, lam, py, px, band_limit, torch.device(device), dtype).clone()


# ---- propagation -----------------------------------------------------------------------------------------
def ifft2(spec: torch.Tensor) -> torch.Tensor:
    """Inverse 2-D DFT over the last two axes (numpy's normalisation), as conj(fft2(conj(X))) / N.

    torch 2.13's CPU ``ifft2`` returns garbage for an unbatched 2048 x 2048 complex64 input on more than one
    thread (the grid of a 1024 x 1024 SLM padded 2x; ``ifftn`` too, while ``fft2`` and batched calls are right:
    tests/optics/test_propagation.py checks both at production sizes), so the project never calls it.
    """
    return torch.fft.fft2(spec.conj()).conj_physical_().div_(spec.shape[-2] * spec.shape[-1])


def _workspace(shape: tuple[int, ...], dtype: torch.dtype) -> torch.Tensor:
    """A per-thread zero-padded CPU buffer; only its top-left [..., :H, :W] block is ever written.

    Reusing it avoids allocating (and page-faulting) a fresh zero grid on every call, which alone costs about
    a fifth of an FFT pair on CPU.
    """
    bufs = getattr(_ws_local, "bufs", None)
    if bufs is None:
        bufs = _ws_local.bufs = OrderedDict()
    key = (shape, dtype)
    buf = bufs.get(key)
    if buf is None:
        buf = torch.zeros(shape, dtype=dtype)
        nbytes = buf.numel() * buf.element_size()
        if nbytes <= _WS_MAX_BYTES:
            bufs[key] = buf
            total = sum(b.numel() * b.element_size() for b in bufs.values())
            while len(bufs) > 1 and total > _WS_MAX_BYTES:
                _, old = bufs.popitem(last=False)
                total -= old.numel() * old.element_size()
    else:
        bufs.move_to_end(key)
    return buf


def asm(field: torch.Tensor, distance_m: float, wavelength_m: float, pitch_m: PitchLike, *,
        pad_factor: float = 2, band_limit: bool = True, cone_sine: float | None = None,
        grid: tuple[int, int] | None = None, gain: torch.Tensor | None = None) -> torch.Tensor:
    """Propagate a complex field ``[..., H, W]`` by ``distance_m`` (m; < 0 back-propagates, 0 is a copy).

    ``cone_sine`` (0 < s <= 1, None: no cut): keep only the plane waves whose direction sine is <= s (at any
    distance, 0 included: then a low-pass filter of the field).

    ``wavelength_m`` in m, ``pitch_m`` a float or ``(pitch_y, pitch_x)`` in m. Zero-pads to
    :func:`padded_shape` (``pad_factor`` >= 1), or to ``grid`` (rows, cols) when given (e.g.
    ``holocore.optics.grids.reach_grid``: the field's size plus the distance's sideways reach, exact for the
    cropped output and far smaller than 2x over short distances), applies the band-limited transfer function
    (docs/design.md §5) and crops back. ``gain``: a real filter on the padded grid (unshifted DFT order) applied
    with the transfer function, e.g. a recording plane's equaliser (``holocore.optics.plane_chain``). Returns a
    new tensor of the input's shape, dtype and device. Differentiable.
    """
    return asm_to(field, [distance_m], wavelength_m, pitch_m, pad_factor=pad_factor, band_limit=band_limit,
                  cone_sine=cone_sine, grid=grid, gain=gain)[0]


def asm_to(field: torch.Tensor, distances_m: Sequence[float], wavelength_m: float, pitch_m: PitchLike, *,
           pad_factor: float = 2, band_limit: bool = True, cone_sine: float | None = None,
           grid: tuple[int, int] | None = None, gain: torch.Tensor | None = None) -> list[torch.Tensor]:
    """:func:`asm` of ``field`` by each of ``distances_m`` (same options, the same grid for all), from one
    transform of it: n + 1 FFTs instead of 2 n (e.g. a field cut to the eyebox at 0 and propagated to the SLM)."""
    field = _check_field(field)
    zs = [validate.real("distance_m", d) for d in distances_m]
    lam = validate.positive("wavelength_m", wavelength_m)
    py, px = validate.pitch_pair(pitch_m)
    h, w = field.shape[-2], field.shape[-1]
    hp, wp = padded_shape((h, w), pad_factor) if grid is None else (int(grid[0]), int(grid[1]))
    if not zs:
        raise ValueError("distances_m must hold at least one distance")
    if hp < h or wp < w:
        raise ValueError(f"grid {grid} must be at least the field's size {h}x{w}")
    if cone_sine is not None:
        cone_sine = validate.real("cone_sine", cone_sine)
        if not 0.0 < cone_sine <= 1.0:
            raise ValueError(f"cone_sine must be a direction sine in (0, 1], got {cone_sine}")
    if gain is not None and (tuple(gain.shape) != (hp, wp) or gain.is_complex()):
        raise ValueError(f"gain must be real and on the padded grid {hp}x{wp}, got {tuple(gain.shape)}")
    if cone_sine is None and gain is None and all(z == 0.0 for z in zs):
        return [field.clone() for _ in zs]
    # The inverse transform is a forward one: IFFT(S H) = conj(FFT(conj(S) conj(H) / N)) (see :func:`ifft2`).
    needs_graph = torch.is_grad_enabled() and field.requires_grad
    if needs_graph or field.device.type != "cpu":
        spec = torch.fft.fft2(field, s=(hp, wp))  # pads with zeros at the end of each axis
        spec = spec.conj() if needs_graph else spec.conj_physical_()
    else:  # CPU fast path: reuse a zero-padded workspace, conjugate and multiply in place, one crop copy
        buf = _workspace(tuple(field.shape[:-2]) + (hp, wp), field.dtype)
        buf[..., :h, :w].copy_(field)
        spec = torch.fft.fft2(buf).conj_physical_()
    if gain is not None:  # real: the conjugate of the filtered spectrum is the conjugate filtered
        g = gain.to(device=field.device, dtype=field.real.dtype)
        spec = spec * g if needs_graph else spec.mul_(g)
    out = []
    for i, z in enumerate(zs):
        if z == 0.0 and cone_sine is None and gain is None:
            out.append(field.clone())
            continue
        tfc = _cached_tf((hp, wp), z, lam, py, px, band_limit, field.device, field.dtype, conj_scaled=True,
                         cone_sine=cone_sine)
        last = i == len(zs) - 1 and not needs_graph
        prod = spec.mul_(tfc) if last else spec * tfc  # the last one in place
        out.append(torch.conj_physical(torch.fft.fft2(prod)[..., :h, :w]))
    return out
