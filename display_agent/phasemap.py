"""Phase -> SLM gray level, per colour (DESIGN.md §2).

The service stores the phase before any table. The default level is ``round(phase / 2pi * 256) mod 256``
(the semantics of ``holocore.io.phase_to_u8``). Two per-wavelength calibrations are supported:

- a lookup table: level -> gray, 256 entries per colour. Files use the encoder's format
  (docs/encoding.md): JSON ``{"luts": [{"wavelength_nm": 640.0, "table": [256 ints]}, ...]}`` matched to
  the stack's wavelengths within 1 nm (a single entry without a wavelength applies to all colours), or a
  ``.npy`` array [C, 256] or [256];
- a scale: the gray level L that means 2pi (an SLM whose 2pi lies at gray 220 has L = 220):
  ``gray = round(phase / 2pi * L) mod L``; L = 256 is the default mapping.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

__all__ = ["PhaseMapping", "phase_levels", "load_lut_file"]

_TWO_PI = 2.0 * np.pi
_MATCH_NM = 1.0


def phase_levels(phase: np.ndarray, *, levels_per_2pi: int = 256) -> np.ndarray:
    """uint8 levels ``round(phase / 2pi * L) mod L`` (float64 arithmetic, as ``holocore.io.phase_to_u8``)."""
    if not (2 <= int(levels_per_2pi) <= 256):
        raise ValueError(f"levels_per_2pi must be in [2, 256], got {levels_per_2pi}")
    p = np.asarray(phase, dtype=np.float64)
    if not np.all(np.isfinite(p)):
        raise ValueError("phase holds NaN or infinite values")
    lv = int(levels_per_2pi)
    return (np.round(p / _TWO_PI * lv).astype(np.int64) % lv).astype(np.uint8)


def _check_table(name: str, table: object) -> np.ndarray:
    arr = np.asarray(table)
    if arr.shape != (256,):
        raise ValueError(f"{name} must hold 256 entries, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must hold finite numbers")
    if np.any(arr != np.round(arr)) or arr.min() < 0 or arr.max() > 255:
        raise ValueError(f"{name} entries must be integers in [0, 255]")
    return arr.astype(np.uint8)


def load_lut_file(path: Union[str, Path]) -> list[tuple[Optional[float], np.ndarray]]:
    """Read a calibration file -> [(wavelength_nm or None, uint8[256]), ...] (None: any colour / by index)."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".npy":
            arr = np.load(path, allow_pickle=False)
            if arr.ndim == 1:
                return [(None, _check_table(f"{path}", arr))]
            if arr.ndim == 2:
                return [(None, _check_table(f"{path}[{c}]", arr[c])) for c in range(arr.shape[0])]
            raise ValueError(f"{path}: a .npy lookup table must be [256] or [C, 256], got shape {arr.shape}")
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"cannot read lookup table {path}: {exc}") from exc
    entries = doc.get("luts") if isinstance(doc, dict) else None
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path}: a JSON lookup table needs a non-empty list 'luts' of "
                         "{\"wavelength_nm\": float, \"table\": [256 integers]}")
    out: list[tuple[Optional[float], np.ndarray]] = []
    for i, e in enumerate(entries):
        if not isinstance(e, dict):
            raise ValueError(f"{path}: luts[{i}] must be an object")
        wl = e.get("wavelength_nm")
        if wl is not None and not (isinstance(wl, (int, float)) and np.isfinite(wl) and wl > 0):
            raise ValueError(f"{path}: luts[{i}].wavelength_nm must be a positive number, got {wl!r}")
        out.append((None if wl is None else float(wl), _check_table(f"{path}: luts[{i}].table", e.get("table"))))
    return out


@dataclass(frozen=True)
class PhaseMapping:
    """How the agent turns a stack's phase [F, C, H, W] into gray levels.

    ``tables``: from :func:`load_lut_file` (None: no table). ``levels_per_2pi``: one scale for all colours
    or one per colour (used only without tables)."""

    tables: Optional[tuple[tuple[Optional[float], np.ndarray], ...]] = None
    levels_per_2pi: Union[int, tuple[int, ...]] = 256
    source: str = "default"

    @classmethod
    def from_options(cls, *, lut: Optional[Union[str, Path]] = None,
                     levels_per_2pi: Union[int, Sequence[int]] = 256) -> "PhaseMapping":
        """A mapping from a calibration file or a scale (not both)."""
        scales = (int(levels_per_2pi),) if isinstance(levels_per_2pi, (int, np.integer)) else tuple(
            int(v) for v in levels_per_2pi)
        if not scales or any(not 2 <= s <= 256 for s in scales):
            raise ValueError(f"levels_per_2pi must be in [2, 256] (one, or one per colour), got {levels_per_2pi}")
        if lut is not None:
            if scales != (256,):
                raise ValueError("give either a lookup table (lut) or a scale (levels_per_2pi), not both")
            return cls(tables=tuple(load_lut_file(lut)), source=f"lut:{Path(lut).name}")
        scale = scales[0] if len(scales) == 1 else scales
        return cls(levels_per_2pi=scale, source="default" if scales == (256,) else f"scale:{scales}")

    def tables_for(self, wavelengths_m: Sequence[float]) -> Optional[np.ndarray]:
        """uint8 [C, 256] for the stack's wavelengths, or None without tables; ValueError if one is missing."""
        if self.tables is None:
            return None
        lams_nm = [float(w) * 1e9 for w in wavelengths_m]
        if len(self.tables) == 1 and self.tables[0][0] is None:
            return np.stack([self.tables[0][1]] * len(lams_nm))
        if all(wl is None for wl, _ in self.tables):  # by index (.npy [C, 256])
            if len(self.tables) != len(lams_nm):
                raise ValueError(f"lookup table has {len(self.tables)} rows, the stack {len(lams_nm)} colours")
            return np.stack([t for _, t in self.tables])
        rows = []
        for lam in lams_nm:
            hits = [t for wl, t in self.tables if wl is not None and abs(wl - lam) <= _MATCH_NM]
            if not hits:
                have = [wl for wl, _ in self.tables]
                raise ValueError(f"no lookup table within {_MATCH_NM} nm of {lam:.1f} nm (have {have})")
            rows.append(hits[0])
        return np.stack(rows)

    def levels(self, phase: np.ndarray, *, wavelengths_m: Sequence[float]) -> np.ndarray:
        """uint8 gray levels [F, C, H, W] for a phase stack in radians."""
        ph = np.asarray(phase)
        if ph.ndim != 4:
            raise ValueError(f"phase must be [F, C, H, W], got shape {ph.shape}")
        if ph.shape[1] != len(wavelengths_m):
            raise ValueError(f"phase has {ph.shape[1]} colours but {len(wavelengths_m)} wavelengths")
        tables = self.tables_for(wavelengths_m)
        if tables is not None:
            lv = phase_levels(ph)
            return np.stack([tables[c][lv[:, c]] for c in range(ph.shape[1])], axis=1)
        scales = self.levels_per_2pi
        if isinstance(scales, int):
            return phase_levels(ph, levels_per_2pi=scales)
        if len(scales) != ph.shape[1]:
            raise ValueError(f"levels_per_2pi has {len(scales)} entries, the stack {ph.shape[1]} colours")
        return np.stack([phase_levels(ph[:, c], levels_per_2pi=s) for c, s in enumerate(scales)], axis=1)
