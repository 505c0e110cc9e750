"""Writing stacks: 8-bit frames, lookup tables, STACK.npz (in memory, or streamed block by block).

See docs/encoding.md. Only numpy, json and zipfile here; the streamed writer produces the same file layout as
``io.save_stack`` (uncompressed .npz members ``phase``, ``frames_u8``, ``meta``).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Optional, Sequence, Union

import numpy as np
import torch

from holocore.encode.core import ArrayLike, wrap_phase
from holocore.formats.lut import check_lut_table, load_lut_file
from holocore.formats.meta import MetaLike
from holocore.io import phase_to_u8, save_stack

if TYPE_CHECKING:
    from holocore.encode.encoder import EncodeResult


# ---- 8-bit output and lookup tables ------------------------------------------------------------------------
def load_lut(source: Union[str, Path, ArrayLike], *, wavelengths_m: Sequence[float]) -> np.ndarray:
    """Per-color 8-bit lookup tables, uint8 [C, 256] (row c: SLM level for phase level 0..255 of color c).

    ``source``: an array [256] (shared) or [C, 256]; a ``.npy`` file holding one; or a JSON calibration file
    ``{"luts": [{"wavelength_nm": 640.0, "table": [256 integers]}, ...]}`` matched to each wavelength within
    1 nm (entries without ``wavelength_nm``: one applies to every color, C of them go by index). Files are read
    and checked by :func:`holocore.formats.lut.load_lut_file`, as the display agent reads them.
    """
    lams_nm = [float(v) * 1e9 for v in wavelengths_m]
    if not lams_nm:
        raise ValueError("wavelengths_m must not be empty")
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():
            raise ValueError(f"lookup table file not found: {path}")
        entries = load_lut_file(path)
        if all(wl is None for wl, _ in entries):
            tables = [t for _, t in entries]
            if len(tables) not in (1, len(lams_nm)):
                raise ValueError(f"{path}: {len(tables)} tables without wavelengths for {len(lams_nm)} colors")
            return np.stack(tables * len(lams_nm) if len(tables) == 1 else tables)
        rows = []
        for lam in lams_nm:
            match = [t for wl, t in entries if wl is not None and abs(wl - lam) <= 1.0]
            if len(match) != 1:
                raise ValueError(f"{path}: need exactly one table within 1 nm of {lam:.1f} nm, "
                                 f"have {[wl for wl, _ in entries]}")
            rows.append(match[0])
        return np.stack(rows)
    arr = np.asarray(source.detach().cpu().numpy() if isinstance(source, torch.Tensor) else source)
    if arr.ndim == 1:
        return np.stack([check_lut_table("lut", arr)] * len(lams_nm))
    if arr.ndim != 2 or arr.shape[0] != len(lams_nm):
        raise ValueError(f"lut must be [256] or [C={len(lams_nm)}, 256], got shape {arr.shape}")
    return np.stack([check_lut_table(f"lut[{c}]", arr[c]) for c in range(arr.shape[0])])


def quantize(phase: ArrayLike, *, lut: Optional[np.ndarray] = None, wrapped: bool = False) -> np.ndarray:
    """8-bit SLM frames uint8 [F, C, H, W]: round(phase / 2pi * 256) mod 256 (docs/design.md §2, ``io.phase_to_u8``),
    then, if given, each color's row of ``lut`` (uint8 [C, 256] from :func:`load_lut`)."""
    ph = phase.detach().cpu().numpy() if isinstance(phase, torch.Tensor) else np.asarray(phase)
    if ph.ndim != 4:
        raise ValueError(f"phase must be [F, C, H, W], got shape {ph.shape}")
    levels = phase_to_u8(ph if wrapped else wrap_phase(ph))
    if lut is None:
        return levels
    table = np.asarray(lut)
    if table.shape != (ph.shape[1], 256) or table.dtype != np.uint8:
        raise ValueError(f"lut must be uint8 [C={ph.shape[1]}, 256] (see load_lut), got {table.dtype} {table.shape}")
    out = np.empty_like(levels)
    for c in range(ph.shape[1]):
        out[:, c] = table[c][levels[:, c]]
    return out


def stack_meta(meta: MetaLike, result: "EncodeResult", *, lut: Optional[np.ndarray] = None,
               lut_source: Optional[str] = None) -> dict:
    """A stack's meta: the render's carried forward (``display_profile`` and ``display`` always present) with
    ``encoder`` = the result's summary and the lookup table used."""
    if not isinstance(meta, Mapping):
        raise ValueError(f"meta must be a mapping (a render's meta), got {type(meta).__name__}")
    enc = result.summary()
    enc["lut"] = None if lut is None else {"source": lut_source or "array",
                                            "identity": bool(np.all(np.asarray(lut) == np.arange(256)))}
    return {**meta, "display_profile": meta.get("display_profile"), "display": meta.get("display"), "encoder": enc}


def save_encoded(path: Union[str, Path], result: "EncodeResult", *, meta: MetaLike, lut: Optional[np.ndarray] = None,
                 lut_source: Optional[str] = None) -> None:
    """Write STACK.npz (``io.save_stack``): the phase, its 8-bit frames (through ``lut`` if given) and
    :func:`stack_meta`."""
    out_meta = stack_meta(meta, result, lut=lut, lut_source=lut_source)
    save_stack(path, phase=result.phase, meta=out_meta, frames_u8=quantize(result.phase, lut=lut))
