"""STACK.npz (from `holo encode`): ``phase`` float32 ``[F, C, H, W]`` in [0, 2pi), ``frames_u8`` uint8 of the
same shape, ``meta`` (the render's meta carried forward plus the encoder's under ``"encoder"``).

:func:`save_stack` / :func:`load_stack` write and read one; :func:`open_stack` reads one from elsewhere (a
download, a cache) and accepts it only if: the file opens as an npz without pickles, ``phase`` is float
[F, C, H, W] with finite values in [0, 2pi], ``frames_u8`` is uint8 of the same shape, ``meta`` is JSON whose
``wavelengths_m`` lists C positive wavelengths. Anything else raises :class:`StackError`.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Union

import numpy as np

from holocore.formats.hashing import file_sha256
from holocore.formats.levels import phase_to_u8
from holocore.formats.meta import MetaError, StackMeta, parse_stack_meta
from holocore.formats.npz import atomic_savez, require_fchw

__all__ = ["save_stack", "load_stack", "Stack", "StackError", "open_stack", "check_stack", "MAX_STACK_BYTES"]

MAX_STACK_BYTES = 4 << 30


def save_stack(path: str | Path, *, phase: np.ndarray, meta: Union[StackMeta, Mapping[str, Any]],
               frames_u8: np.ndarray | None = None) -> None:
    """Save a phase stack [F, C, H, W] (wrapped to [0, 2pi), float32) with its 8-bit frames and meta (checked
    as :class:`StackMeta`; a dict is written back with every key it has)."""
    m = parse_stack_meta(meta, what=f"stack {Path(path).name}")
    ph = np.mod(np.asarray(phase, dtype=np.float64), 2 * np.pi).astype(np.float32)
    ph[ph >= np.float32(2 * np.pi)] = 0.0  # float32 rounding of values just under 2pi
    require_fchw("phase", ph)
    u8 = phase_to_u8(ph) if frames_u8 is None else np.asarray(frames_u8, dtype=np.uint8)
    if u8.shape != ph.shape:
        raise ValueError(f"frames_u8 shape {u8.shape} differs from phase shape {ph.shape}")
    if len(m.wavelengths_m) != ph.shape[1]:
        raise ValueError(f"stack meta lists {len(m.wavelengths_m)} wavelengths for {ph.shape[1]} colors")
    atomic_savez(Path(path), phase=ph, frames_u8=u8, meta=np.array(json.dumps(m.to_dict())))


def load_stack(path: str | Path) -> tuple[np.ndarray, np.ndarray, StackMeta]:
    """Load STACK.npz -> (phase, frames_u8, meta)."""
    with np.load(path, allow_pickle=False) as z:
        if "phase" not in z or "frames_u8" not in z or "meta" not in z:
            raise ValueError(f"{path} is not a phase stack (needs phase, frames_u8, meta)")
        raw = json.loads(str(z["meta"]))
        return z["phase"], z["frames_u8"], parse_stack_meta(raw, what=f"stack {Path(path).name}")


class StackError(ValueError):
    """A stack file that is unreadable, inconsistent, or not what was announced."""


@dataclass(frozen=True)
class Stack:
    """A verified stack: phase float32 [F, C, H, W] (radians), the file's sha256 and its meta."""

    path: Path
    sha256: str
    phase: np.ndarray
    frames_u8: np.ndarray
    meta: StackMeta = field(repr=False)

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return tuple(self.phase.shape)  # type: ignore[return-value]

    @property
    def wavelengths_m(self) -> list[float]:
        return [float(w) for w in self.meta.wavelengths_m]


def open_stack(path: Union[str, Path], *, expected_sha256: Optional[str] = None,
               max_bytes: int = MAX_STACK_BYTES) -> Stack:
    """Load and check a STACK.npz; ``expected_sha256`` (hex) must match the file if given."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise StackError(f"cannot read stack {path}: {exc}") from exc
    if size > max_bytes:
        raise StackError(f"stack {path} is {size} bytes, over the {max_bytes}-byte limit")
    digest = file_sha256(path)
    if expected_sha256 is not None and digest != expected_sha256.lower():
        raise StackError(f"stack {path.name}: sha256 {digest[:16]}.. differs from the expected "
                         f"{expected_sha256[:16]}..")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("phase", "frames_u8", "meta") if k not in z.files]
            if missing:
                raise StackError(f"stack {path.name} lacks {missing}")
            phase = z["phase"]
            frames = z["frames_u8"]
            meta_raw = z["meta"]
    except StackError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise StackError(f"stack {path.name} is not a readable npz: {type(exc).__name__}: {exc}") from exc
    try:
        meta: Any = json.loads(str(meta_raw))
    except (json.JSONDecodeError, TypeError) as exc:
        raise StackError(f"stack {path.name}: meta is not JSON: {exc}") from exc
    meta = check_stack(path.name, phase, frames, meta)
    return Stack(path=path, sha256=digest, phase=phase.astype(np.float32, copy=False), frames_u8=frames, meta=meta)


def check_stack(name: str, phase: np.ndarray, frames: np.ndarray, meta: Any) -> StackMeta:
    """The typed meta; StackError (naming ``name``) unless phase, frames_u8 and meta form a consistent stack."""
    if phase.ndim != 4 or min(phase.shape, default=0) < 1:
        raise StackError(f"stack {name}: phase must be a non-empty [F, C, H, W], got shape {phase.shape}")
    if not np.issubdtype(phase.dtype, np.floating):
        raise StackError(f"stack {name}: phase must be floating point, got {phase.dtype}")
    if frames.dtype != np.uint8 or frames.shape != phase.shape:
        raise StackError(f"stack {name}: frames_u8 must be uint8 of shape {phase.shape}, "
                         f"got {frames.dtype} {frames.shape}")
    if not np.all(np.isfinite(phase)):
        raise StackError(f"stack {name}: phase holds NaN or infinite values")
    lo, hi = float(phase.min()), float(phase.max())
    if lo < 0.0 or hi > 2 * np.pi + 1e-5:
        raise StackError(f"stack {name}: phase must lie in [0, 2pi), got [{lo:.4g}, {hi:.4g}]")
    try:
        m = parse_stack_meta(meta, what=f"stack {name}")
    except MetaError as exc:
        raise StackError(str(exc)) from None
    if len(m.wavelengths_m) != phase.shape[1]:
        raise StackError(f"stack {name}: meta.wavelengths_m must list {phase.shape[1]} wavelengths, "
                         f"got {list(m.wavelengths_m)!r}")
    return m
