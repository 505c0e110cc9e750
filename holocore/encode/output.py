"""Writing stacks: 8-bit frames, lookup tables, STACK.npz (in memory, or streamed block by block).

See docs/encoding.md. Only numpy, json and zipfile here; the streamed writer produces the same file layout as
``io.save_stack`` (uncompressed .npz members ``phase``, ``frames_u8``, ``meta``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Optional, Sequence, Union

import numpy as np
import torch

from holocore.encode.core import ArrayLike, wrap_phase
from holocore.formats.meta import MetaLike
from holocore.io import phase_to_u8, save_stack

if TYPE_CHECKING:
    from holocore.encode.encoder import EncodeResult


# ---- 8-bit output and lookup tables ------------------------------------------------------------------------
def _check_table(name: str, table: object) -> np.ndarray:
    arr = np.asarray(table)
    if arr.shape != (256,):
        raise ValueError(f"{name} must have 256 entries (input level 0..255 -> output level), got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or arr.dtype == bool:
        raise ValueError(f"{name} must hold numbers, got dtype {arr.dtype}")
    if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)) or arr.min() < 0 or arr.max() > 255:
        raise ValueError(f"{name} entries must be integers in 0..255")
    return arr.astype(np.uint8)


def load_lut(source: Union[str, Path, ArrayLike], *, wavelengths_m: Sequence[float]) -> np.ndarray:
    """Per-color 8-bit lookup tables, uint8 [C, 256] (row c: SLM level for phase level 0..255 of color c).

    ``source``: an array [256] (shared) or [C, 256]; a ``.npy`` file holding one; or a JSON calibration file
    ``{"luts": [{"wavelength_nm": 640.0, "table": [256 integers]}, ...]}`` matched to each wavelength within
    1 nm (a single entry without ``wavelength_nm`` applies to every color).
    """
    lams_nm = [float(v) * 1e9 for v in wavelengths_m]
    if not lams_nm:
        raise ValueError("wavelengths_m must not be empty")
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():
            raise ValueError(f"lookup table file not found: {path}")
        if path.suffix.lower() == ".npy":
            return load_lut(np.load(path, allow_pickle=False), wavelengths_m=wavelengths_m)
        try:
            doc = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"cannot read lookup table {path}: {exc}") from None
        entries = doc.get("luts") if isinstance(doc, dict) else None
        if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
            raise ValueError(f"{path}: a JSON lookup table needs a non-empty list 'luts' of "
                             "{'wavelength_nm': ..., 'table': [256 levels]} objects")
        if len(entries) == 1 and "wavelength_nm" not in entries[0]:
            return np.stack([_check_table(f"{path}: luts[0].table", entries[0].get("table"))] * len(lams_nm))
        rows = []
        for lam in lams_nm:
            match = [e for e in entries if isinstance(e.get("wavelength_nm"), (int, float))
                     and abs(float(e["wavelength_nm"]) - lam) <= 1.0]
            if len(match) != 1:
                have = [e.get("wavelength_nm") for e in entries]
                raise ValueError(f"{path}: need exactly one table within 1 nm of {lam:.1f} nm, have {have}")
            rows.append(_check_table(f"{path}: table for {lam:.1f} nm", match[0].get("table")))
        return np.stack(rows)
    arr = np.asarray(source.detach().cpu().numpy() if isinstance(source, torch.Tensor) else source)
    if arr.ndim == 1:
        return np.stack([_check_table("lut", arr)] * len(lams_nm))
    if arr.ndim != 2 or arr.shape[0] != len(lams_nm):
        raise ValueError(f"lut must be [256] or [C={len(lams_nm)}, 256], got shape {arr.shape}")
    return np.stack([_check_table(f"lut[{c}]", arr[c]) for c in range(arr.shape[0])])


def quantize(phase: ArrayLike, *, lut: Optional[np.ndarray] = None) -> np.ndarray:
    """8-bit SLM frames uint8 [F, C, H, W]: round(phase / 2pi * 256) mod 256 (DESIGN §2, ``io.phase_to_u8``),
    then, if given, each color's row of ``lut`` (uint8 [C, 256] from :func:`load_lut`)."""
    ph = phase.detach().cpu().numpy() if isinstance(phase, torch.Tensor) else np.asarray(phase)
    if ph.ndim != 4:
        raise ValueError(f"phase must be [F, C, H, W], got shape {ph.shape}")
    levels = phase_to_u8(wrap_phase(ph))
    if lut is None:
        return levels
    table = np.asarray(lut)
    if table.shape != (ph.shape[1], 256) or table.dtype != np.uint8:
        raise ValueError(f"lut must be uint8 [C={ph.shape[1]}, 256] (see load_lut), got {table.dtype} {table.shape}")
    out = np.empty_like(levels)
    for c in range(ph.shape[1]):
        out[:, c] = table[c][levels[:, c]]
    return out


def save_encoded(path: Union[str, Path], result: "EncodeResult", *, meta: MetaLike, lut: Optional[np.ndarray] = None,
                 lut_source: Optional[str] = None) -> None:
    """Write STACK.npz (``io.save_stack``): the phase, its 8-bit frames (through ``lut`` if given) and
    ``meta`` (the render's, carried forward) with ``meta["encoder"]`` = the result's summary."""
    if not isinstance(meta, Mapping):
        raise ValueError(f"meta must be a mapping (a render's meta), got {type(meta).__name__}")
    enc = result.summary()
    enc["lut"] = None if lut is None else {"source": lut_source or "array",
                                            "identity": bool(np.all(np.asarray(lut) == np.arange(256)))}
    out_meta = {**meta, "display_profile": meta.get("display_profile"), "display": meta.get("display"), "encoder": enc}
    save_stack(path, phase=result.phase, meta=out_meta, frames_u8=quantize(result.phase, lut=lut))
