"""Phase -> 8-bit SLM levels (docs/design.md §2): ``round(phase / 2pi * L) mod L``, L = 256 by default."""

from __future__ import annotations

import numpy as np

from holocore.formats.chunks import map_pieces

__all__ = ["phase_to_u8", "phase_levels"]

_TWO_PI = 2.0 * np.pi


def phase_to_u8(phase: np.ndarray) -> np.ndarray:
    """8-bit SLM levels: round(phase / 2pi * 256) mod 256 (docs/design.md §2). Level 255 covers phases within half
    a level of 2pi*255/256; phases closer to 2pi than that, and 2pi itself, are level 0 (the same phase)."""
    return _levels(np.asarray(phase), 256)


def phase_levels(phase: np.ndarray, *, levels_per_2pi: int = 256) -> np.ndarray:
    """uint8 levels ``round(phase / 2pi * L) mod L`` (float64 arithmetic, as :func:`phase_to_u8`), for an SLM
    whose 2pi lies at gray level L (2..256); ValueError on NaN or infinite phase."""
    if not (2 <= int(levels_per_2pi) <= 256):
        raise ValueError(f"levels_per_2pi must be in [2, 256], got {levels_per_2pi}")
    p = np.asarray(phase)
    if not np.all(np.isfinite(p)):
        raise ValueError("phase holds NaN or infinite values")
    return _levels(p, int(levels_per_2pi))


def _levels(phase: np.ndarray, lv: int) -> np.ndarray:
    """round(phase / 2pi * lv) mod lv in float64 (round half to even), non-finite phases at level 0."""
    def piece(p: np.ndarray) -> np.ndarray:
        t = p.astype(np.float64)
        t /= _TWO_PI
        t *= lv
        np.rint(t, out=t)
        with np.errstate(invalid="ignore"):  # inf mod lv is NaN, set to 0 below
            np.mod(t, lv, out=t)  # exact on whole numbers; [0, lv) for negative ones too
        return np.nan_to_num(t, copy=False, nan=0.0)  # NaN and +-inf (NaN after mod) -> level 0
    return map_pieces(piece, phase, np.uint8)
