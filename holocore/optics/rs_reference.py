"""Direct Rayleigh-Sommerfeld integration: the slow, float64 reference the propagation tests trust.

First Rayleigh-Sommerfeld solution between parallel planes (Goodman, Introduction to Fourier Optics, Eq. 3-41
written with the exact kernel, no far-field approximation):

    U(x, y, z) = sum_{x', y'} U(x', y', 0) h(x - x', y - y', z) p_x p_y,
    h(dx, dy, z) = (z / (2 pi r^2)) (1/r - i k) exp(i k r),   r = sqrt(dx^2 + dy^2 + z^2)

h = -(1/2pi) d/dz (exp(ikr)/r) is the exact impulse response whose spectrum is the angular-spectrum transfer
function (evanescent part included), so this sum converges to the ASM result as the sampling is refined.
The midpoint rule is exact for integrands band-limited to |f| < 1/p; choose grids where field plus kernel
frequencies (at most 1/lambda each way) stay below that.

Grids follow docs/design.md §3: pixel (i, j) at x = (j - (W-1)/2) p_x, y = ((H-1)/2 - i) p_y, both planes centred on
the axis. Cost is O(N_in * N_out): small grids only (zeros of the input field are skipped).
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Union

import numpy as np

from holocore import validate

__all__ = ["rs_direct", "grid_coordinates"]

_CHUNK_ELEMENTS = 1 << 21  # kernel entries per chunk (~32 MiB of complex128 plus temporaries)


def grid_coordinates(shape_hw: tuple[int, int],
                     pitch_m: Union[float, Sequence[float]]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (x [W], y [H]) in m of a centred grid (docs/design.md §3: y up, rows down)."""
    h, w = (int(s) for s in shape_hw)
    if h < 1 or w < 1:
        raise ValueError(f"shape_hw must be two sizes >= 1, got {shape_hw}")
    py, px = validate.pitch_pair(pitch_m, name="pitch_m")
    x = (np.arange(w, dtype=np.float64) - (w - 1) / 2.0) * px
    y = ((h - 1) / 2.0 - np.arange(h, dtype=np.float64)) * py
    return x, y


def rs_direct(field: np.ndarray, distance_m: float, wavelength_m: float, pitch_m: Union[float, Sequence[float]], *,
              out_shape: Optional[tuple[int, int]] = None,
              out_pitch_m: Union[float, Sequence[float], None] = None) -> np.ndarray:
    """Field (complex128 [H_out, W_out]) on a parallel plane ``distance_m`` > 0 (m) away, by direct RS-I sums.

    ``field`` is a 2D complex array on the centred grid of ``pitch_m`` (m, float or (pitch_y, pitch_x)); the
    output grid defaults to the input's shape and pitch. Vectorised numpy, chunked over output pixels.
    """
    u = np.asarray(field)
    if u.ndim != 2:
        raise ValueError(f"field must be a 2D array [H, W], got shape {u.shape}")
    u = u.astype(np.complex128, copy=False)
    if not np.all(np.isfinite(u)):
        raise ValueError("field contains NaN or infinite values")
    z = float(distance_m)
    if not math.isfinite(z) or z <= 0:
        raise ValueError(f"distance_m must be finite and > 0 (m), got {distance_m!r}")
    lam = float(wavelength_m)
    if not math.isfinite(lam) or lam <= 0:
        raise ValueError(f"wavelength_m must be finite and > 0 (m), got {wavelength_m!r}")
    py, px = validate.pitch_pair(pitch_m, name="pitch_m")
    oshape = u.shape if out_shape is None else tuple(int(s) for s in out_shape)
    if len(oshape) != 2 or oshape[0] < 1 or oshape[1] < 1:
        raise ValueError(f"out_shape must be (H, W) with sizes >= 1, got {out_shape!r}")
    opitch = (py, px) if out_pitch_m is None else validate.pitch_pair(out_pitch_m, name="out_pitch_m")

    xi, yi = grid_coordinates(u.shape, (py, px))
    xo, yo = grid_coordinates(oshape, opitch)
    iy, ix = np.nonzero(u)  # only source pixels that carry light
    src = u[iy, ix] * (px * py)
    sx, sy = xi[ix], yi[iy]
    out = np.zeros(oshape[0] * oshape[1], dtype=np.complex128)
    if src.size == 0:
        return out.reshape(oshape)
    k = 2.0 * math.pi / lam
    global_phase = np.exp(1j * math.remainder(k * z, 2.0 * math.pi))  # exp(ikz), wrapped in float64
    ox = np.tile(xo, oshape[0])
    oy = np.repeat(yo, oshape[1])
    step = max(1, _CHUNK_ELEMENTS // src.size)
    z2 = z * z
    for start in range(0, ox.size, step):
        dx = ox[start:start + step, None] - sx[None, :]
        dy = oy[start:start + step, None] - sy[None, :]
        rho2 = dx * dx + dy * dy
        r = np.sqrt(rho2 + z2)
        excess = rho2 / (r + z)  # r - z without cancellation: k(r - z) stays accurate at any z
        kern = (z / (2.0 * math.pi)) / (r * r) * (1.0 / r - 1j * k) * np.exp(1j * k * excess)
        out[start:start + step] = kern @ src
    return (out * global_phase).reshape(oshape)
