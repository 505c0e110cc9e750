"""Capped exponential backoff with full jitter (for server outages and serial reconnects)."""

from __future__ import annotations

import random
from dataclasses import dataclass, field

__all__ = ["Backoff"]


@dataclass
class Backoff:
    """Delay before retry n (n = 0, 1, ...): uniform in [(1 - jitter) d, d] with d = min(cap_s, base_s * factor**n).

    ``jitter`` in [0, 1]: 0 gives the plain exponential, 1 "full jitter" (spreads many agents' retries).
    Call :meth:`next_delay` after each failure and :meth:`reset` after a success."""

    base_s: float = 0.5
    factor: float = 2.0
    cap_s: float = 30.0
    jitter: float = 0.5
    rng: random.Random = field(default_factory=random.Random, repr=False)
    failures: int = 0

    def __post_init__(self) -> None:
        if not (self.base_s > 0):
            raise ValueError(f"base_s must be > 0 seconds, got {self.base_s}")
        if not (self.factor >= 1):
            raise ValueError(f"factor must be >= 1, got {self.factor}")
        if not (self.cap_s >= self.base_s):
            raise ValueError(f"cap_s must be >= base_s ({self.base_s} s), got {self.cap_s}")
        if not (0.0 <= self.jitter <= 1.0):
            raise ValueError(f"jitter must be in [0, 1], got {self.jitter}")

    def peek_ceiling(self) -> float:
        """Upper bound of the next delay, seconds."""
        # factor**failures can overflow for long outages: cap the exponent first.
        n = min(self.failures, 64)
        return min(self.cap_s, self.base_s * self.factor**n)

    def next_delay(self) -> float:
        """Seconds to wait before the next try; counts one more failure."""
        ceiling = self.peek_ceiling()
        self.failures += 1
        return ceiling * (1.0 - self.jitter * self.rng.random())

    def reset(self) -> None:
        self.failures = 0
