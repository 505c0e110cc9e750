"""The two artifact files, readable with numpy alone (no torch, no Mitsuba).

RESULT.npz (from `holo render`): ``slm_field``, ``wrp_field`` complex64 ``[F, C, H, W]`` and ``meta``,
a JSON string whose top level holds at least ``focal_length_m``, ``z_inf_m``, ``z_wrp_m``, ``pitch_m``,
``wavelengths_m``.

STACK.npz (from `holo encode`): ``phase`` float32 ``[F, C, H, W]`` in [0, 2pi), ``frames_u8`` uint8 of the
same shape, ``meta`` (the render's meta carried forward plus the encoder's under ``"encoder"``).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "RESULT_META_KEYS",
    "save_result",
    "load_result",
    "save_stack",
    "load_stack",
    "phase_to_u8",
    "file_sha256",
]

RESULT_META_KEYS = ("focal_length_m", "z_inf_m", "z_wrp_m", "pitch_m", "wavelengths_m")


def _atomic_savez(path: Path, **arrays: Any) -> None:
    """Write an .npz next to its destination and rename it in place: readers never see half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _check4(name: str, a: np.ndarray) -> None:
    if a.ndim != 4:
        raise ValueError(f"{name} must be [F, C, H, W], got shape {a.shape}")


def save_result(path: str | Path, *, slm_field: np.ndarray, wrp_field: np.ndarray, meta: dict) -> None:
    """Save a render: complex fields [F, C, H, W] (stored complex64) and JSON metadata."""
    missing = [k for k in RESULT_META_KEYS if k not in meta]
    if missing:
        raise ValueError(f"result meta lacks {missing}")
    slm = np.asarray(slm_field, dtype=np.complex64)
    wrp = np.asarray(wrp_field, dtype=np.complex64)
    _check4("slm_field", slm)
    _check4("wrp_field", wrp)
    _atomic_savez(Path(path), slm_field=slm, wrp_field=wrp, meta=np.array(json.dumps(meta)))


def load_result(path: str | Path) -> tuple[np.ndarray, np.ndarray, dict]:
    """Load RESULT.npz -> (slm_field, wrp_field, meta)."""
    with np.load(path, allow_pickle=False) as z:
        if "slm_field" not in z or "meta" not in z:
            raise ValueError(f"{path} is not a render result (needs slm_field, wrp_field, meta)")
        return z["slm_field"], z["wrp_field"], json.loads(str(z["meta"]))


def phase_to_u8(phase: np.ndarray) -> np.ndarray:
    """8-bit SLM levels: round(phase / 2pi * 256) mod 256 (DESIGN §2). Level 255 covers phases within half
    a level of 2pi*255/256; phases closer to 2pi than that, and 2pi itself, are level 0 (the same phase)."""
    p = np.asarray(phase, dtype=np.float64)
    return (np.round(p / (2 * np.pi) * 256.0).astype(np.int64) % 256).astype(np.uint8)


def save_stack(path: str | Path, *, phase: np.ndarray, meta: dict, frames_u8: np.ndarray | None = None) -> None:
    """Save a phase stack [F, C, H, W] (wrapped to [0, 2pi), float32) with its 8-bit frames and meta."""
    ph = np.mod(np.asarray(phase, dtype=np.float64), 2 * np.pi).astype(np.float32)
    ph[ph >= np.float32(2 * np.pi)] = 0.0  # float32 rounding of values just under 2pi
    _check4("phase", ph)
    u8 = phase_to_u8(ph) if frames_u8 is None else np.asarray(frames_u8, dtype=np.uint8)
    if u8.shape != ph.shape:
        raise ValueError(f"frames_u8 shape {u8.shape} differs from phase shape {ph.shape}")
    _atomic_savez(Path(path), phase=ph, frames_u8=u8, meta=np.array(json.dumps(meta)))


def load_stack(path: str | Path) -> tuple[np.ndarray, np.ndarray, dict]:
    """Load STACK.npz -> (phase, frames_u8, meta)."""
    with np.load(path, allow_pickle=False) as z:
        if "phase" not in z or "frames_u8" not in z or "meta" not in z:
            raise ValueError(f"{path} is not a phase stack (needs phase, frames_u8, meta)")
        return z["phase"], z["frames_u8"], json.loads(str(z["meta"]))


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (the content hash used for ETags and cache checks)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
