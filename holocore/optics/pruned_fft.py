"""A filter between two windows of a zero-padded grid, G{ M . F{P x} } cropped, with FFTW's 1-D plans, pruned.

Both the encoder's operator and the render's ASM step are this shape: a field on an h x w window, zero-padded to
an hp x wp grid, transformed, multiplied by a transfer function M, transformed again (forward, or backward:
unnormalised), and cropped back to the window. A whole-grid 2-D transform spends a third of its row transforms on
rows that are zero on the way in or cropped on the way out. Here each frame goes through four 1-D passes:

    1. the h input rows, out of place into the grid (the grid's other rows are zeroed first);
    2. every column, in place;                 3. the product with M, in place;
    4. every column, in place (G);             5. the h output rows, out of place into the output (G).

Steps 1 and 5 are the only row transforms; the grid's rows h..hp never pass a row transform. Out of place column
plans run at a third of the speed of in-place ones on this layout (bench/results/encode.md), so the grid is a
single frame's workspace reused frame after frame and the columns are transformed in it.

FFTW (through pyFFTW, an optional dependency: the ``fftw`` extra; FFTW itself is GPL) is the fastest library here
for these transforms; without it :func:`available` is False and callers keep torch's ``fft2``. Plans are made
once per layout with FFTW_MEASURE (about a second at the paper's size; FFTW keeps the wisdom for the process).
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections import OrderedDict
from typing import Iterator, Optional

import numpy as np
import torch

try:
    import pyfftw
except ImportError:  # the optional ``fftw`` extra
    pyfftw = None

__all__ = ["available", "disabled", "WindowFilter"]

_DTYPES = {torch.complex64: "complex64", torch.complex128: "complex128"}
_MAX_FILTERS = 8  # per thread: the filters (plans and a grid workspace each) of the layouts used last
_local = threading.local()  # each thread its own filters: a filter's grid workspace is not shared
_planning = threading.Lock()  # FFTW's planner is not thread-safe
_state = {"off": os.environ.get("HOLO_FFTW", "1") == "0"}  # HOLO_FFTW=0: torch's fft2 everywhere


def available(dtype: torch.dtype = torch.complex64) -> bool:
    """True where pyFFTW is installed, not switched off (``HOLO_FFTW=0``, :func:`disabled`) and ``dtype`` is one
    FFTW transforms here."""
    return pyfftw is not None and not _state["off"] and dtype in _DTYPES


@contextlib.contextmanager
def disabled() -> Iterator[None]:
    """Inside, :func:`available` is False: callers take torch's path (process-wide; for tests and benchmarks)."""
    before, _state["off"] = _state["off"], True
    try:
        yield
    finally:
        _state["off"] = before


def _aligned(shape: tuple[int, ...], dtype: str) -> np.ndarray:
    return pyfftw.zeros_aligned(shape, dtype=dtype)


class WindowFilter:
    """G{ M . F{P x} } cropped to the h x w window, frame by frame, for frames laid out [b, h, wp] (columns w..wp
    zero: :meth:`inputs`). One per (window, grid, dtype, second direction, threads): :meth:`get`."""

    def __init__(self, shape_hw: tuple[int, int], grid: tuple[int, int], dtype: torch.dtype, *,
                 second_forward: bool, threads: int) -> None:
        if not available(dtype):
            raise RuntimeError("pyFFTW is not installed (pip install 'holopathtracer[fftw]')")
        self.h, self.w = shape_hw
        self.hp, self.wp = grid
        self.dtype = dtype
        self.threads = threads
        kind = _DTYPES[dtype]
        grid_buf = _aligned((self.hp, self.wp), kind)
        row_in, row_out = _aligned((self.h, self.wp), kind), _aligned((self.h, self.wp), kind)
        self.itemsize = grid_buf.itemsize
        # frames after the first sit h * wp items further on: plan for unaligned arrays unless each one is aligned
        flags = ("FFTW_MEASURE",) if (self.h * self.wp * self.itemsize) % pyfftw.simd_alignment == 0 else \
            ("FFTW_MEASURE", "FFTW_UNALIGNED")
        second = "FFTW_FORWARD" if second_forward else "FFTW_BACKWARD"
        with _planning:
            self._plan(grid_buf, row_in, row_out, flags, second)
        self._grid = grid_buf
        self._grid_t = torch.from_numpy(grid_buf)

    def _plan(self, grid_buf: np.ndarray, row_in: np.ndarray, row_out: np.ndarray, flags: tuple, second: str) -> None:
        mk, threads = pyfftw.FFTW, self.threads
        self._rows_in = mk(row_in, grid_buf[:self.h], axes=(1,), threads=threads, flags=flags)
        self._cols_in = mk(grid_buf, grid_buf, axes=(0,), threads=threads, flags=flags)
        self._cols_out = mk(grid_buf, grid_buf, axes=(0,), direction=second, threads=threads, flags=flags)
        self._rows_out = mk(grid_buf[:self.h], row_out, axes=(1,), direction=second, threads=threads, flags=flags)

    @classmethod
    def get(cls, shape_hw: tuple[int, int], grid: tuple[int, int], dtype: torch.dtype, *,
            second_forward: bool, threads: Optional[int] = None) -> "WindowFilter":
        """This thread's filter of this layout, planned on first use and kept with the last few used."""
        threads = threads or torch.get_num_threads()
        key = (tuple(shape_hw), tuple(grid), dtype, second_forward, threads)
        filters = _local.__dict__.setdefault("filters", OrderedDict())
        if key not in filters:
            filters[key] = cls(shape_hw, grid, dtype, second_forward=second_forward, threads=threads)
            while len(filters) > _MAX_FILTERS:
                filters.popitem(last=False)
        filters.move_to_end(key)
        return filters[key]

    def inputs(self, b: int) -> torch.Tensor:
        """A zeroed [b, h, wp] tensor on FFTW-aligned memory: write frames into its [:, :, :w] window."""
        return torch.from_numpy(_aligned((b, self.h, self.wp), _DTYPES[self.dtype]))

    def __call__(self, x: torch.Tensor, mult: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
        """Filter each frame of ``x`` [b, h, wp] (columns w..wp zero) by ``mult`` [hp, wp] into ``out`` [b, h, wp]
        (both from :meth:`inputs`); returns the [b, h, w] window of ``out``."""
        xs, outs = x.numpy(), out.numpy()
        top, bottom = self._grid[:self.h], self._grid[self.h:]
        for i in range(x.shape[0]):
            self._rows_in.update_arrays(xs[i], top)
            self._rows_in.execute()
            bottom.fill(0)
            self._cols_in.execute()
            self._grid_t.mul_(mult)
            self._cols_out.execute()
            self._rows_out.update_arrays(top, outs[i])
            self._rows_out.execute()
        return out[:, :, :self.w]
