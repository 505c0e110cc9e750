"""The two artifact files, readable with numpy alone (no torch, no Mitsuba).

RESULT.npz (from `holo render`): ``slm_field``, ``wrp_field`` complex64 ``[F, C, H, W]`` and ``meta``,
a JSON string whose top level holds at least ``focal_length_m``, ``z_inf_m``, ``z_wrp_m``, ``pitch_m``,
``wavelengths_m``.

STACK.npz (from `holo encode`): ``phase`` float32 ``[F, C, H, W]`` in [0, 2pi), ``frames_u8`` uint8 of the
same shape, ``meta`` (the render's meta carried forward plus the encoder's under ``"encoder"``).

Both are plain uncompressed .npz files (zip, one .npy member per array). Large ones are written member by member
and slab by slab (:class:`NpzWriter`) and read back slab by slab (:class:`NpyMember`), so no stage needs a whole
[F, C, H, W] array in memory: the bytes are the ones ``np.savez`` writes, and ``np.load`` reads them.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import tempfile
import zipfile
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

__all__ = [
    "RESULT_META_KEYS",
    "save_result",
    "load_result",
    "save_stack",
    "load_stack",
    "phase_to_u8",
    "file_sha256",
    "NpzWriter",
    "NpyMember",
    "ScratchArray",
    "npz_members",
    "read_npz_meta",
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


# ---- streaming: .npz members written and read slab by slab ------------------------------------------------
_COPY_BYTES = 64 << 20


def npz_members(path: str | Path) -> set[str]:
    """Array names in an .npz (without reading any of them)."""
    with zipfile.ZipFile(path) as zf:
        return {n[:-4] if n.endswith(".npy") else n for n in zf.namelist()}


def read_npz_meta(path: str | Path) -> dict:
    """The JSON ``meta`` member of a RESULT.npz or STACK.npz, alone."""
    with np.load(path, allow_pickle=False) as z:
        if "meta" not in z:
            raise ValueError(f"{path} has no meta")
        return json.loads(str(z["meta"]))


class NpyMember:
    """One array of an .npz, read in slabs with plain reads (no mmap, so the resident set stays bounded).

    Uncompressed members (``np.savez``, :class:`NpzWriter`) are read in place; a compressed one
    (``np.savez_compressed``) is loaded whole once, so every file numpy can write still opens.
    """

    def __init__(self, path: str | Path, name: str) -> None:
        self.path, self.name = Path(path), name
        self._whole: Optional[np.ndarray] = None
        with zipfile.ZipFile(self.path) as zf:
            try:
                info = zf.getinfo(name + ".npy")
            except KeyError:
                raise ValueError(f"{self.path} has no array {name!r}") from None
            if info.compress_type != zipfile.ZIP_STORED:
                with zf.open(info) as fh:
                    self._whole = np.lib.format.read_array(fh, allow_pickle=False)
        if self._whole is not None:
            self.shape, self.dtype, self.offset = tuple(self._whole.shape), self._whole.dtype, -1
            return
        with open(self.path, "rb") as fh:
            fh.seek(info.header_offset)
            head = fh.read(30)
            if head[:4] != b"PK\x03\x04":
                raise ValueError(f"{self.path}: bad zip local header for {name}")
            n_name, n_extra = struct.unpack("<HH", head[26:30])
            fh.seek(info.header_offset + 30 + n_name + n_extra)
            version = np.lib.format.read_magic(fh)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
                np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read_header(fh)
            self.offset = fh.tell()
        if fortran and len(shape) > 1:
            raise ValueError(f"{self.path}: {name} is stored in Fortran order")
        self.shape, self.dtype = tuple(shape), np.dtype(dtype)
        if self.dtype.hasobject:
            raise ValueError(f"{self.path}: {name} holds Python objects")

    def read_fc(self, f0: int, f1: int, c: int) -> np.ndarray:
        """Elements [f0:f1, c] of a [F, C, H, W] array, as a new contiguous [f1 - f0, H, W] array."""
        if len(self.shape) != 4:
            raise ValueError(f"{self.path}: {self.name} must be [F, C, H, W], got {self.shape}")
        F, C, H, W = self.shape
        if not (0 <= f0 <= f1 <= F and 0 <= c < C):
            raise IndexError(f"frames {f0}..{f1} color {c} outside {self.shape}")
        if self._whole is not None:
            return np.ascontiguousarray(self._whole[f0:f1, c])
        item = H * W * self.dtype.itemsize
        out = np.empty((f1 - f0, H, W), self.dtype)
        with open(self.path, "rb") as fh:
            for j, f in enumerate(range(f0, f1)):
                fh.seek(self.offset + (f * C + c) * item)
                if fh.readinto(memoryview(out[j].reshape(-1)).cast("B")) != item:
                    raise ValueError(f"{self.path}: truncated array data in {self.name}")
        return out

    def read(self) -> np.ndarray:
        """The whole array."""
        if self._whole is not None:
            return self._whole
        with np.load(self.path, allow_pickle=False) as z:
            return z[self.name]


class _NpyStream:
    """An .npy member of known shape and dtype being written in C-order pieces."""

    def __init__(self, zf: zipfile.ZipFile, name: str, shape: Sequence[int], dtype) -> None:
        self.name, self.shape, self.dtype = name, tuple(int(s) for s in shape), np.dtype(dtype)
        self.total = int(np.prod(self.shape, dtype=np.int64)) * self.dtype.itemsize
        self.written = 0
        self.fh = zf.open(name + ".npy", "w", force_zip64=True)
        header = {"descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False, "shape": self.shape}
        np.lib.format.write_array_header_1_0(self.fh, header)

    def write(self, piece: np.ndarray) -> None:
        a = np.ascontiguousarray(piece)
        if a.dtype != self.dtype:
            raise TypeError(f"{self.name}: expected {self.dtype}, got {a.dtype}")
        self.write_bytes(memoryview(a.reshape(-1)).cast("B"))

    def write_bytes(self, data) -> None:
        n = len(data)
        if self.written + n > self.total:
            raise ValueError(f"{self.name}: more data than its shape {self.shape} holds")
        self.fh.write(data)
        self.written += n

    def close(self) -> None:
        self.fh.close()
        if self.written != self.total:
            raise ValueError(f"{self.name}: {self.written} of {self.total} bytes written")


class NpzWriter:
    """Write an uncompressed .npz member by member, slab by slab; it appears at ``path`` only when complete
    (written next to it and renamed into place), and ``np.load`` reads it like any ``np.savez`` file.

    >>> with NpzWriter(out) as w:
    ...     s = w.stream("slm_field", (F, C, H, W), np.complex64)
    ...     for block in blocks: s.write(block)      # C order: frame blocks [k, C, H, W]
    ...     s.close()
    ...     w.add("meta", np.array(json.dumps(meta)))
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, self._tmp = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.name}.", suffix=".tmp")
        self._fh = os.fdopen(fd, "wb")
        self._zf = zipfile.ZipFile(self._fh, "w", zipfile.ZIP_STORED, allowZip64=True)
        self._open: Optional[_NpyStream] = None

    def stream(self, name: str, shape: Sequence[int], dtype) -> _NpyStream:
        if self._open is not None and not self._open.fh.closed:
            raise RuntimeError(f"close member {self._open.name} before starting {name}")
        self._open = _NpyStream(self._zf, name, shape, dtype)
        return self._open

    def add(self, name: str, arr: np.ndarray) -> None:
        s = self.stream(name, np.shape(arr), np.asarray(arr).dtype)
        s.write(np.asarray(arr))
        s.close()

    def copy_from(self, name: str, scratch: "ScratchArray") -> None:
        """A member holding a :class:`ScratchArray`'s contents, copied in pieces."""
        s = self.stream(name, scratch.shape, scratch.dtype)
        for piece in scratch.pieces():
            s.write_bytes(piece)
        s.close()

    def __enter__(self) -> "NpzWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self._zf.close()
            self._fh.close()
            if exc_type is None:
                os.replace(self._tmp, self.path)
        finally:
            Path(self._tmp).unlink(missing_ok=True)


class ScratchArray:
    """A [F, C, H, W] array in a temporary file (unlinked on close), written and read in slabs with
    pwrite/pread: the page cache holds it, not the process. Starts all zeros."""

    def __init__(self, shape: Sequence[int], dtype, *, dir: Optional[str | Path] = None) -> None:
        self.shape, self.dtype = tuple(int(s) for s in shape), np.dtype(dtype)
        if len(self.shape) != 4:
            raise ValueError(f"scratch arrays are [F, C, H, W], got {self.shape}")
        self.nbytes = int(np.prod(self.shape, dtype=np.int64)) * self.dtype.itemsize
        self._fd, name = tempfile.mkstemp(dir=dir, prefix=".holo-scratch.", suffix=".raw")
        os.unlink(name)
        os.ftruncate(self._fd, self.nbytes)

    def _off(self, f: int, c: int, r: int = 0) -> int:
        _, C, H, W = self.shape
        return (((f * C + c) * H) + r) * W * self.dtype.itemsize

    def write_rows(self, f0: int, colors: Sequence[int], r0: int, block: np.ndarray) -> None:
        """block [k, len(colors), rows, W] into frames f0.., the listed colors, rows r0.."""
        b = np.ascontiguousarray(block, dtype=self.dtype)
        for j in range(b.shape[0]):
            for ci, c in enumerate(colors):
                os.pwrite(self._fd, memoryview(b[j, ci].reshape(-1)).cast("B"), self._off(f0 + j, c, r0))

    def add_rows(self, f0: int, colors: Sequence[int], r0: int, block: np.ndarray) -> None:
        """Add block [k, len(colors), rows, W] to frames f0.., the listed colors, rows r0.. (read, add, write)."""
        b = np.ascontiguousarray(block, dtype=self.dtype)
        cur = np.empty(b.shape[2:], self.dtype)
        buf = memoryview(cur.reshape(-1)).cast("B")
        for j in range(b.shape[0]):
            for ci, c in enumerate(colors):
                if os.preadv(self._fd, [buf], self._off(f0 + j, c, r0)) != len(buf):
                    raise OSError("short read from scratch file")
                cur += b[j, ci]
                os.pwrite(self._fd, buf, self._off(f0 + j, c, r0))

    def read_fc(self, f0: int, f1: int, c: int) -> np.ndarray:
        """[f1 - f0, H, W]: elements [f0:f1, c]."""
        _, _, H, W = self.shape
        out = np.empty((f1 - f0, H, W), self.dtype)
        for j in range(f1 - f0):
            buf = memoryview(out[j].reshape(-1)).cast("B")
            if os.preadv(self._fd, [buf], self._off(f0 + j, c)) != len(buf):
                raise OSError("short read from scratch file")
        return out

    def pieces(self):
        """The whole contents in C order, in pieces of at most 64 MiB."""
        buf = bytearray(min(_COPY_BYTES, max(1, self.nbytes)))
        off = 0
        while off < self.nbytes:
            n = os.preadv(self._fd, [memoryview(buf)[:min(len(buf), self.nbytes - off)]], off)
            if n <= 0:
                raise OSError("short read from scratch file")
            yield memoryview(buf)[:n]
            off += n

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> "ScratchArray":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
