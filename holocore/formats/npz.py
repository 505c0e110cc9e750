"""Plain uncompressed .npz files (zip, one .npy member per array), written whole and atomically, or member by
member and slab by slab (:class:`NpzWriter`), and read back slab by slab (:class:`NpyMember`), so no stage needs
a whole [F, C, H, W] array in memory: the bytes are the ones ``np.savez`` writes, and ``np.load`` reads them.
numpy only (no torch, no Mitsuba)."""

from __future__ import annotations

import json
import os
import struct
import tempfile
import zipfile
from pathlib import Path
from typing import Any, Iterator, Optional, Protocol, Sequence

import numpy as np

__all__ = ["atomic_savez", "require_fchw", "npz_members", "read_npz_meta", "NpyMember", "NpzWriter",
           "PieceSource", "MemberShapeError"]


class MemberShapeError(ValueError):
    """A member whose header declares another shape than the reader allows (found before its data is read)."""

    def __init__(self, path: Path, name: str, shape: tuple[int, ...], expected: tuple[int, ...]) -> None:
        super().__init__(f"{path.name}: {name} is {list(shape)}, expected {list(expected)}")
        self.shape, self.expected = shape, expected


def _read_header(fh) -> tuple[tuple[int, ...], bool, np.dtype]:
    version = np.lib.format.read_magic(fh)
    read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, fortran, dtype = read_header(fh)
    return tuple(int(s) for s in shape), bool(fortran), np.dtype(dtype)


class PieceSource(Protocol):
    """An array held elsewhere (a scratch file) that yields its C-order bytes in pieces."""

    shape: tuple[int, ...]
    dtype: np.dtype

    def pieces(self) -> Iterator[memoryview]: ...


def atomic_savez(path: Path, **arrays: Any) -> None:
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


def require_fchw(name: str, a: np.ndarray) -> None:
    """ValueError unless ``a`` is 4-D ([F, C, H, W])."""
    if a.ndim != 4:
        raise ValueError(f"{name} must be [F, C, H, W], got shape {a.shape}")


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
    (``np.savez_compressed``) is loaded whole once, so every file numpy can write still opens. ``shape``: the
    shape the caller allows; a member declaring another is refused (:class:`MemberShapeError`) from its .npy
    header, before any of its data is inflated or read: a compressed member of a few hundred kB can inflate to
    gigabytes.
    """

    def __init__(self, path: str | Path, name: str, *, shape: Optional[Sequence[int]] = None) -> None:
        self.path, self.name = Path(path), name
        self._whole: Optional[np.ndarray] = None
        expected = None if shape is None else tuple(int(s) for s in shape)
        with zipfile.ZipFile(self.path) as zf:
            try:
                info = zf.getinfo(name + ".npy")
            except KeyError:
                raise ValueError(f"{self.path} has no array {name!r}") from None
            if info.compress_type != zipfile.ZIP_STORED:
                with zf.open(info) as fh:  # inflates lazily: the header alone first
                    declared = _read_header(fh)[0]
                if expected is not None and declared != expected:
                    raise MemberShapeError(self.path, name, declared, expected)
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
            shape, fortran, dtype = _read_header(fh)
            self.offset = fh.tell()
        if expected is not None and shape != expected:
            raise MemberShapeError(self.path, name, shape, expected)
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

    def copy_from(self, name: str, scratch: "PieceSource") -> None:
        """A member holding an array's contents (``holocore.io.ScratchArray``, say), copied in pieces."""
        s = self.stream(name, scratch.shape, scratch.dtype)
        for piece in scratch.pieces():
            s.write_bytes(piece)
        s.close()

    def __enter__(self) -> "NpzWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                self._zf.close()
                self._fh.close()
                os.replace(self._tmp, self.path)
            else:  # abandon the file, and let the caller's error through (zipfile refuses to close with a member open)
                try:
                    if self._open is not None and not self._open.fh.closed:
                        self._open.fh.close()
                    self._zf.close()
                except Exception:  # noqa: BLE001 - the file is dropped anyway; the caller's error is the one to see
                    pass
                self._fh.close()
        finally:
            Path(self._tmp).unlink(missing_ok=True)
