"""Large temporaries on reused heap pages (glibc): a context under which the padded FFT outputs that every
transform allocates come from the pages the previous ones freed, instead of fresh mmap'd pages that the kernel
faults in and zeroes. The encoder's iterations and the render's plane propagations run under it on a CPU."""

from __future__ import annotations

import contextlib
import ctypes
from typing import Iterator, Optional

__all__ = ["heap_reuse"]

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc mallopt parameters (malloc.h)
_DYN_MMAP_MAX = 32 << 20  # glibc's DEFAULT_MMAP_THRESHOLD_MAX on 64-bit: where its dynamic rule settles
_HEAP_REUSE = {"depth": 0}  # heap_reuse contexts open now (the setting is process-wide)


def _glibc() -> Optional[ctypes.CDLL]:
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return None
    return libc if hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim") else None


@contextlib.contextmanager
def heap_reuse(enabled: bool = True) -> Iterator[None]:
    """Inside: glibc's malloc serves large blocks from its heap, so the padded FFT outputs that every transform
    allocates (``holocore.encode.operator.Operator.apply``) reuse the pages freed by the previous ones instead of
    fresh mmap'd pages (which the kernel faults in and zeroes: at 1536 x 2400 x 2 that is ~10 ms of a ~20 ms
    ``fft2`` on CPU; ``fft2``'s ``out=`` only adds a copy). On exit the thresholds go to the largest values glibc's
    dynamic rule reaches in a process that frees large tensors (mmap 32 MiB, trim 64 MiB) and free pages are
    returned (malloc_trim). The setting is process-wide: overlapping uses from several threads only lose the
    speed-up. A no-op without glibc or with ``enabled`` False (e.g. on CUDA, which caches itself). Nested uses keep the
    setting until the outermost one ends."""
    libc = _glibc() if enabled else None
    if libc is None or (_HEAP_REUSE["depth"] == 0 and not libc.mallopt(_M_MMAP_THRESHOLD, 1 << 30)):
        yield
        return
    if _HEAP_REUSE["depth"] == 0:
        libc.mallopt(_M_TRIM_THRESHOLD, (1 << 31) - 1)
    _HEAP_REUSE["depth"] += 1
    try:
        yield
    finally:
        _HEAP_REUSE["depth"] -= 1
        if _HEAP_REUSE["depth"] == 0:
            libc.mallopt(_M_MMAP_THRESHOLD, _DYN_MMAP_MAX)
            libc.mallopt(_M_TRIM_THRESHOLD, 2 * _DYN_MMAP_MAX)
            libc.malloc_trim(0)
