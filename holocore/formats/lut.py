"""Per-wavelength SLM lookup tables (level -> gray, 256 entries) from calibration files.

Files use the encoder's format (docs/encoding.md): JSON ``{"luts": [{"wavelength_nm": 640.0, "table": [256
ints]}, ...]}`` (an entry without a wavelength applies to any colour), or a ``.npy`` array [C, 256] or [256].
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional, Union

import numpy as np

__all__ = ["LutEntry", "check_lut_table", "load_lut_file"]

LutEntry = tuple[Optional[float], np.ndarray]
"""(wavelength in nm, or None for any colour / by index; uint8[256])"""


def check_lut_table(name: str, table: object) -> np.ndarray:
    """``table`` as uint8[256] if it holds 256 finite integers in 0..255, else ValueError naming ``name``."""
    arr = np.asarray(table)
    if arr.shape != (256,):
        raise ValueError(f"{name} must hold 256 entries, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must hold finite numbers")
    if np.any(arr != np.round(arr)) or arr.min() < 0 or arr.max() > 255:
        raise ValueError(f"{name} entries must be integers in 0..255")
    return arr.astype(np.uint8)


def load_lut_file(path: Union[str, Path]) -> list[LutEntry]:
    """Read a calibration file -> [(wavelength_nm or None, uint8[256]), ...] (None: any colour / by index)."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".npy":
            arr = np.load(path, allow_pickle=False)
            if arr.ndim == 1:
                return [(None, check_lut_table(f"{path}", arr))]
            if arr.ndim == 2:
                return [(None, check_lut_table(f"{path}[{c}]", arr[c])) for c in range(arr.shape[0])]
            raise ValueError(f"{path}: a .npy lookup table must be [256] or [C, 256], got shape {arr.shape}")
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"cannot read lookup table {path}: {exc}") from exc
    entries = doc.get("luts") if isinstance(doc, dict) else None
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path}: a JSON lookup table needs a non-empty list 'luts' of "
                         "{\"wavelength_nm\": float, \"table\": [256 integers]}")
    out: list[LutEntry] = []
    for i, e in enumerate(entries):
        if not isinstance(e, dict):
            raise ValueError(f"{path}: luts[{i}] must be an object")
        wl = e.get("wavelength_nm")
        if wl is not None and not (isinstance(wl, (int, float)) and np.isfinite(wl) and wl > 0):
            raise ValueError(f"{path}: luts[{i}].wavelength_nm must be a positive number, got {wl!r}")
        out.append((None if wl is None else float(wl),
                    check_lut_table(f"{path}: luts[{i}].table", e.get("table"))))
    return out
