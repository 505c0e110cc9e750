"""The memory budget that sizes the chunks of render, view and evaluate (peak resident set, bytes).

Chosen, in order, by the caller's keyword (``memory_budget_bytes=``; ``--memory-budget-mb`` on the CLI), the
environment variable ``HOLO_MEMORY_BUDGET_MB`` (the service's workers inherit it), or the default, 8 GiB. The
stages hold a fixed part (interpreter, torch, Mitsuba, transfer functions) and a part per frame of a chunk;
:func:`frames_per_chunk` fits as many frames as the budget allows, at least one.
"""

from __future__ import annotations

import os
from typing import Optional

__all__ = ["DEFAULT_BUDGET_MB", "ENV", "memory_budget_bytes", "frames_per_chunk"]

DEFAULT_BUDGET_MB = 8192
ENV = "HOLO_MEMORY_BUDGET_MB"
_MIN_MB = 256
# The planner counts what it allocates itself; allocator slack, fragmentation and library buffers it cannot see
# get this share of the budget.
USABLE = 0.8


def memory_budget_bytes(explicit: Optional[int] = None) -> int:
    """The budget in bytes: ``explicit`` (bytes), else HOLO_MEMORY_BUDGET_MB (MiB), else 8 GiB."""
    if explicit is not None:
        b = int(explicit)
        if b < _MIN_MB << 20:
            raise ValueError(f"memory budget must be at least {_MIN_MB} MiB, got {b / 2**20:.0f} MiB")
        return b
    raw = os.environ.get(ENV)
    if raw is None or raw.strip() == "":
        return DEFAULT_BUDGET_MB << 20
    try:
        mb = float(raw)
    except ValueError:
        raise ValueError(f"{ENV} must be a number of MiB, got {raw!r}") from None
    if not mb >= _MIN_MB:
        raise ValueError(f"{ENV} must be at least {_MIN_MB} MiB, got {raw!r}")
    return int(mb * 2**20)


def frames_per_chunk(total: int, *, per_frame_bytes: float, fixed_bytes: float, budget_bytes: int,
                     cap: Optional[int] = None) -> int:
    """Frames per chunk: as many as ``USABLE * budget - fixed`` holds at ``per_frame_bytes`` each, in 1..total
    (and at most ``cap``)."""
    room = USABLE * budget_bytes - fixed_bytes
    n = int(room // max(1.0, per_frame_bytes)) if room > 0 else 1
    n = max(1, min(int(total), n))
    return min(n, cap) if cap else n
