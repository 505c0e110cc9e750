"""Phase -> 8-bit SLM levels (docs/design.md §2): ``round(phase / 2pi * L) mod L``, L = 256 by default."""

from __future__ import annotations

import numpy as np

__all__ = ["phase_to_u8", "phase_levels"]

_TWO_PI = 2.0 * np.pi


def phase_to_u8(phase: np.ndarray) -> np.ndarray:
    """8-bit SLM levels: round(phase / 2pi * 256) mod 256 (docs/design.md §2). Level 255 covers phases within half
    a level of 2pi*255/256; phases closer to 2pi than that, and 2pi itself, are level 0 (the same phase)."""
    p = np.asarray(phase, dtype=np.float64)
    return (np.round(p / (2 * np.pi) * 256.0).astype(np.int64) % 256).astype(np.uint8)


def phase_levels(phase: np.ndarray, *, levels_per_2pi: int = 256) -> np.ndarray:
    """uint8 levels ``round(phase / 2pi * L) mod L`` (float64 arithmetic, as :func:`phase_to_u8`), for an SLM
    whose 2pi lies at gray level L (2..256); ValueError on NaN or infinite phase."""
    if not (2 <= int(levels_per_2pi) <= 256):
        raise ValueError(f"levels_per_2pi must be in [2, 256], got {levels_per_2pi}")
    p = np.asarray(phase, dtype=np.float64)
    if not np.all(np.isfinite(p)):
        raise ValueError("phase holds NaN or infinite values")
    lv = int(levels_per_2pi)
    return (np.round(p / _TWO_PI * lv).astype(np.int64) % lv).astype(np.uint8)
