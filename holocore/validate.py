"""One validator per kind of physical input, shared by every stage (numpy only; torch scalars pass by duck typing).

Each returns the value in SI units as a plain Python number, or raises ValueError with one line that names the
parameter, the rule and the unit: ``pitch_m must be > 0 m, got -8e-06``.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Union

__all__ = ["PitchLike", "real", "bounded", "positive", "integer", "pitch_pair", "wavelengths"]

PitchLike = Union[float, Sequence[float]]
"""A pixel pitch in metres: one float (square pixels) or a ``(pitch_y, pitch_x)`` pair."""

WAVELENGTH_MAX_M = 1e-5  # 10 um: anything longer is a unit mistake (nm given as m), not a display's light


def real(name: str, value: object) -> float:
    """A finite real scalar (Python, numpy or a one-element torch tensor) as float."""
    is_complex = getattr(value, "is_complex", None)
    if isinstance(value, (bool, str, bytes, complex)) or getattr(value, "ndim", 0) != 0 \
            or (callable(is_complex) and is_complex()) or getattr(getattr(value, "dtype", None), "kind", "") == "c":
        raise ValueError(f"{name} must be a real number, got {value!r}")
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    return v


def bounded(name: str, value: object, *, low: Optional[float] = None, high: Optional[float] = None,
            low_inclusive: bool = True, high_inclusive: bool = True, unit: str = "") -> float:
    """A finite real scalar within [low, high] (each bound open or closed, None: no bound), in ``unit``."""
    v = real(name, value)
    lo_ok = low is None or (v >= low if low_inclusive else v > low)
    hi_ok = high is None or (v <= high if high_inclusive else v < high)
    if not (lo_ok and hi_ok):
        parts = []
        if low is not None:
            parts.append(f"{'>=' if low_inclusive else '>'} {low:g}")
        if high is not None:
            parts.append(f"{'<=' if high_inclusive else '<'} {high:g}")
        raise ValueError(f"{name} must be {' and '.join(parts)}{' ' + unit if unit else ''}, got {value!r}")
    return v


def positive(name: str, value: object, *, unit: str = "m") -> float:
    """A finite real scalar > 0 (a length, a time...) in ``unit``."""
    return bounded(name, value, low=0.0, low_inclusive=False, unit=unit)


def integer(name: str, value: object, lo: int, hi: int) -> int:
    """An integer (not a bool) in lo..hi."""
    if isinstance(value, bool) or not hasattr(value, "__index__") or not lo <= int(value) <= hi:  # type: ignore
        raise ValueError(f"{name} must be an integer in {lo}..{hi}, got {value!r}")
    return int(value)  # type: ignore[arg-type]


def pitch_pair(pitch_m: PitchLike, *, name: str = "pitch_m") -> tuple[float, float]:
    """(pitch_y, pitch_x) in metres from a float or a (pitch_y, pitch_x) pair; each finite and > 0."""
    if isinstance(pitch_m, (list, tuple)) or getattr(pitch_m, "ndim", 0) == 1:
        vals = list(pitch_m)  # type: ignore[arg-type]
        if len(vals) != 2:
            raise ValueError(f"{name} pair must be (pitch_y, pitch_x), got {len(vals)} values")
        return positive(f"{name}[0] (pitch_y)", vals[0]), positive(f"{name}[1] (pitch_x)", vals[1])
    p = positive(name, pitch_m)
    return p, p


def wavelengths(wavelengths_m: Sequence[float], n_colors: Optional[int] = None, *,
                name: str = "wavelengths_m") -> list[float]:
    """Wavelengths in metres, each in (0, 10 um); exactly ``n_colors`` of them when given."""
    if isinstance(wavelengths_m, (str, bytes)) or not hasattr(wavelengths_m, "__iter__"):
        raise ValueError(f"{name} must be a sequence of numbers (m), got {wavelengths_m!r}")
    lams = [bounded(f"{name}[{i}]", v, low=0.0, low_inclusive=False, high=WAVELENGTH_MAX_M, high_inclusive=False,
                    unit="m") for i, v in enumerate(wavelengths_m)]
    if n_colors is not None and len(lams) != n_colors:
        raise ValueError(f"{name} has {len(lams)} entries but the target has {n_colors} colors")
    if not lams:
        raise ValueError(f"{name} must list at least one wavelength")
    return lams
