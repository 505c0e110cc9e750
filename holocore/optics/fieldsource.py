"""An SLM field [F, C, H, W] read in chunks of frames of one color, from memory or from a file, so that viewing and
evaluation never hold a whole full-size field (docs/design.md §7).

From a STACK.npz the field is exp(i phase) lit with the encoder's relative laser power per frame and color
(``meta["encoder"]["illumination"]``, the scene's colour balance) unless ``equal_power``; ``quantized`` shows
the 8-bit SLM levels. From a RESULT.npz it is ``slm_field``. A chunk's values are those of the whole field
computed at once (the same elementwise operations), so chunked views equal unchunked ones.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Union

import numpy as np

from holocore.formats.meta import parse_view_meta
from holocore.io import NpyMember, npz_members, phase_to_u8, read_npz_meta

__all__ = ["SlmFieldSource", "open_slm_field"]


class SlmFieldSource:
    """``shape`` (F, C, H, W), ``meta``, ``kind`` ("stack", "result" or "array") and :meth:`chunk`."""

    def __init__(self, shape, meta: dict, kind: str, *, array=None, member=None, power=None,
                 quantized: bool = False, path: Optional[Path] = None) -> None:
        self.shape = tuple(int(s) for s in shape)
        self.meta, self.kind, self.path = meta, kind, path
        self._array, self._member, self._power, self._quantized = array, member, power, quantized

    @classmethod
    def from_array(cls, field, meta: Optional[dict] = None) -> "SlmFieldSource":
        """A complex [F, C, H, W] array (numpy or torch) already in memory."""
        if field.ndim != 4:
            raise ValueError(f"field must be [F, C, H, W], got shape {tuple(field.shape)}")
        return cls(field.shape, meta or {}, "array", array=field)

    def chunk(self, f0: int, f1: int, c: int):
        """Frames f0..f1-1 of color c: complex64 [f1 - f0, H, W] (a numpy array, or a torch tensor where the
        source is one)."""
        if self._array is not None:
            a = self._array[f0:f1, c]
            return a if not isinstance(a, np.ndarray) else np.ascontiguousarray(a, dtype=np.complex64)
        raw = self._member.read_fc(f0, f1, c)
        if self.kind == "result":
            out = np.ascontiguousarray(raw, dtype=np.complex64)
        else:
            phase = raw
            if self._quantized:  # the 8-bit SLM levels of docs/design.md §2, without a lookup table

                phase = phase_to_u8(phase).astype(np.float32) * np.float32(2 * np.pi / 256)
            out = np.exp(1j * phase.astype(np.float32)).astype(np.complex64)
            if self._power is not None:
                out *= np.sqrt(self._power[f0:f1, c]).astype(np.float32)[:, None, None]
        if not np.all(np.isfinite(out)):
            raise ValueError(f"{self.path}: the field holds NaN or infinite values")
        return out

    def to_array(self) -> np.ndarray:
        """The whole field in memory (complex64 [F, C, H, W])."""
        F, C, H, W = self.shape
        out = np.empty(self.shape, np.complex64)
        for c in range(C):
            out[:, c] = np.asarray(self.chunk(0, F, c))
        return out


def open_slm_field(path: Union[str, Path], *, quantized: bool = False, equal_power: bool = False) -> SlmFieldSource:
    """A STACK.npz (phase) or RESULT.npz (slm_field) as a chunked source, reading nothing but the meta yet."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"input not found: {p}")
    names = npz_members(p)
    if "phase" in names:
        if "frames_u8" not in names or "meta" not in names:
            raise ValueError(f"{p} is not a phase stack (needs phase, frames_u8, meta)")
        member, kind = NpyMember(p, "phase"), "stack"
        meta = read_npz_meta(p)
        power = (meta.get("encoder") or {}).get("illumination")
        pw = None
        if power is not None and not equal_power:
            pw = np.asarray(power, dtype=np.float64)
            if pw.shape != tuple(member.shape[:2]) or not np.all(np.isfinite(pw)) or np.any(pw < 0):
                raise ValueError(f"{p}: encoder illumination must be [F, C] powers >= 0, got shape {pw.shape}")
        if member.dtype.kind not in "fiu":
            raise ValueError(f"{p}: phase must be real, got {member.dtype}")
    elif "slm_field" in names:
        if quantized:
            raise ValueError("quantized viewing applies to a STACK.npz only (a RESULT.npz holds a complex field)")
        if "meta" not in names:
            raise ValueError(f"{p} is not a render result (needs slm_field, wrp_field, meta)")
        member, kind, pw = NpyMember(p, "slm_field"), "result", None
        meta = read_npz_meta(p)
    else:
        raise ValueError(f"{p} is neither a STACK.npz (phase) nor a RESULT.npz (slm_field)")
    meta = parse_view_meta(meta, what=str(p))  # MetaError (a ValueError) naming the field
    if len(member.shape) != 4 or member.shape[1] != len(meta.wavelengths_m):
        raise ValueError(f"{p}: field must be [F, C, H, W] with one color per wavelength, got {member.shape}")
    return SlmFieldSource(member.shape, meta, kind, member=member, power=pw, quantized=quantized, path=p)
