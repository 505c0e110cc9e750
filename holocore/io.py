"""The two artifact files, readable with numpy alone (no torch, no Mitsuba), and a scratch array on disk.

The file formats live in :mod:`holocore.formats` (RESULT.npz, STACK.npz, streamed .npz members, 8-bit levels,
hashes); this module re-exports them under their historical names for the core's callers. What stays here is
:class:`ScratchArray`, the render's [F, C, H, W] working array in a temporary file.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from holocore.formats.hashing import file_sha256
from holocore.formats.levels import phase_to_u8
from holocore.formats.npz import NpyMember, NpzWriter, npz_members, read_npz_meta
from holocore.formats.result import RESULT_META_KEYS, load_result, save_result
from holocore.formats.stack import load_stack, save_stack

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

_COPY_BYTES = 64 << 20


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
