"""The sizes of the padded FFT grids the propagations use, in plain math (no numpy or torch), so that the time
model (``holocore.plan.estimate``) counts the very grids the encoder and the ASM transform.

Why the encoder's grid may be smaller than 2x, and by how much, is :mod:`holocore.encode.operator`'s docstring
("Padding"); :func:`padded_shape` is the plain ASM's 2x grid (docs/design.md §5)."""

from __future__ import annotations

import math

from holocore import validate
from holocore.validate import PitchLike

__all__ = ["smooth_at_least", "fast_fft_size", "padded_shape", "spread_px", "reach_grid", "encoder_grid"]


def _smallest_at_least(n: int, most: dict[int, int]) -> int:
    """Smallest integer >= n whose prime factors are the keys of ``most``, each at most its value times (-1: any)."""
    m = max(1, n)
    while True:
        k = m
        for p, cap in most.items():
            e = 0
            while k % p == 0:
                k //= p
                e += 1
            if 0 <= cap < e:
                break
        else:
            if k == 1:
                return m
        m += 1


def smooth_at_least(n: int) -> int:
    """Smallest 2,3,5,7-smooth integer >= n (fast FFT sizes; 2x of 1024, 1080 and 1920 are already smooth)."""
    return _smallest_at_least(n, {2: -1, 3: -1, 5: -1, 7: -1})


def fast_fft_size(n: int) -> int:
    """Smallest integer >= n of the form 2^a 3^b 5^c with b, c <= 2: the sizes on which FFTW's and MKL's CPU
    transforms keep their speed per point (measured, single-threaded FFTW on the encoder's grids: 1536 x 2400
    6.7 ns a point, 1440 x 2400 6.6, 1536 x 2304 7.1, but 1458 x 2304 (1458 = 2 3^6) 10.1 and 1440 x 2268
    (2268 = 2^2 3^4 7) 8.1)."""
    return _smallest_at_least(n, {2: -1, 3: 2, 5: 2})


def padded_shape(shape_hw: tuple[int, int], pad_factor: float = 2) -> tuple[int, int]:
    """Padded FFT grid (rows, cols) that ``propagation.asm`` uses: ceil(n * pad_factor), rounded up to a
    7-smooth size."""
    pf = validate.real("pad_factor", pad_factor)
    if pf < 1.0:
        raise ValueError(f"pad_factor must be >= 1, got {pf}")
    h, w = (int(s) for s in shape_hw)
    if h < 1 or w < 1:
        raise ValueError(f"shape_hw must be two sizes >= 1, got {shape_hw}")
    return smooth_at_least(math.ceil(h * pf - 1e-9)), smooth_at_least(math.ceil(w * pf - 1e-9))


def spread_px(z_m: float, wavelength_m: float, pitch_m: PitchLike) -> int:
    """Sideways reach r (pixels) of the full-band ASM over |z|: ceil(|z| s / (p sqrt(1 - 2 s^2))), s = lambda/2p
    (``holocore.encode.operator``); -1 when the band contains evanescent corners (2 s^2 >= 1): no finite bound."""
    py, px = validate.pitch_pair(pitch_m)
    p = min(py, px)
    s = wavelength_m / (2.0 * p)
    if 2.0 * s * s >= 1.0:
        return -1
    return int(math.ceil(abs(z_m) * s / (p * math.sqrt(1.0 - 2.0 * s * s)) - 1e-9))


def reach_grid(shape_hw: tuple[int, int], z_m: float, wavelength_m: float, pitch_m: PitchLike) -> tuple[int, int]:
    """Padded FFT grid (rows, cols) of an ASM over ``z_m`` whose output is cropped to the input's window: the
    smallest :func:`fast_fft_size` >= n + r + 8 + n/64 (r = :func:`spread_px`), at most 2x (why this is exact:
    ``holocore.encode.operator``, "Padding")."""
    full = padded_shape(shape_hw, 2)
    r = spread_px(z_m, wavelength_m, pitch_m)
    if r < 0:
        return full
    return tuple(min(fast_fft_size(n + r + 8 + n // 64), m) for n, m in zip(shape_hw, full))  # type: ignore


encoder_grid = reach_grid  # the encoder's operator uses the same grid (holocore.encode.operator)
