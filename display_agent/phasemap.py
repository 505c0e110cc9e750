"""Phase -> SLM gray level, per colour (docs/design.md §2).

The service stores the phase before any table. The default level is ``round(phase / 2pi * 256) mod 256``
(``holocore.formats.phase_to_u8``; the levels and the table files are read by ``holocore.formats``). Two
per-wavelength calibrations are supported:

- a lookup table: level -> gray, 256 entries per colour. Files use the encoder's format
  (docs/encoding.md): JSON ``{"luts": [{"wavelength_nm": 640.0, "table": [256 ints]}, ...]}`` matched to
  the stack's wavelengths within 1 nm (a single entry without a wavelength applies to all colours), or a
  ``.npy`` array [C, 256] or [256];
- a scale: the gray level L that means 2pi (an SLM whose 2pi lies at gray 220 has L = 220):
  ``gray = round(phase / 2pi * L) mod L``; L = 256 is the default mapping.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from holocore.formats import LutEntry, load_lut_file, phase_levels

__all__ = ["PhaseMapping"]

_MATCH_NM = 1.0


@dataclass(frozen=True)
class PhaseMapping:
    """How the agent turns a stack's phase [F, C, H, W] into gray levels.

    ``tables``: from :func:`load_lut_file` (None: no table). ``levels_per_2pi``: one scale for all colours
    or one per colour (used only without tables)."""

    tables: Optional[tuple[LutEntry, ...]] = None
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
