"""Element-wise numpy work over a large array in cache-sized pieces on a few threads.

Why: the phase -> level and wrap passes over a block of the paper's stack (tens of millions of values) are a
chain of float64 temporaries; whole-array numpy makes one full pass per operation through memory on one core.
Pieces of a million values keep each chain in cache, and numpy's ufuncs release the GIL, so two threads run
two pieces at once. The numbers are those of the whole-array chain: each value goes through the same operations.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import numpy as np

__all__ = ["map_pieces"]

PIECE = 1 << 20  # values a piece: float64 temporaries of 8 MiB


def map_pieces(fn: Callable[[np.ndarray], np.ndarray], src: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """``fn`` applied piece by piece to ``src`` flattened, into a new array of ``src``'s shape and ``dtype``;
    ``fn`` maps a 1-D piece to values of the same length, element by element."""
    flat = np.ascontiguousarray(src).reshape(-1)
    out = np.empty(flat.shape, dtype)

    def one(start: int) -> None:
        out[start:start + PIECE] = fn(flat[start:start + PIECE])

    starts = range(0, flat.size, PIECE)
    workers = min(len(starts), os.cpu_count() or 1, 4)
    if workers <= 1:
        for s in starts:
            one(s)
    else:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(one, starts))
    return out.reshape(np.shape(src))
