"""Rays that fill a wall-time budget: the passes of a render with a time limit (``holo render --time-limit-s``).

A render's field is an unbiased Monte Carlo estimate, linear in its rays: K independent passes of s_k rays per
pixel (each with its own ray seed, the same random-phase bank) combine into the estimate of sum_k s_k rays as

    U = sum_k s_k U_k / sum_k s_k,

exactly what one pass of that many rays would estimate: the recording planes add s_k U_k, and the chain of
recording planes divides by sum_k s_k once (holocore.pipeline, holocore.optics.plane_chain), so the passes cost no
memory and no propagation of their own. This module decides
the s_k, from the seconds the passes before took, so that the passes end near the budget: a pass costs
t = a + b s. The renderer measures a, the part of a pass that does not grow with spp (storing its recordings in
the planes), and b is the largest pass's rest per spp; without a measured a, the line through the two largest
passes gives both (the cost is only locally linear: a 16/64-spp fit missed a 16384-spp render by 2.8x on a glass
scene). A pass is extrapolated at most ``GROWTH`` times beyond the largest pass measured; until the budget's
remainder is within that reach, passes aim at half of it, and then at ``SAFETY`` of the rays that would fill what
is left (the cost grows faster than the line where a tracer tile shrinks to one row: a 4x extrapolation was 28 %
short on a 96-px-wide demo scene), each pass measuring again, until a pass would add fewer than
``MIN_GAIN`` of the rays done. Units: seconds, rays per pixel (spp).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

__all__ = ["SppSchedule", "GROWTH", "MAX_PASSES"]

GROWTH = 4  # a pass has at most this many times the rays of the largest pass measured
MAX_PASSES = 8  # passes in one budget (each repeats the fixed cost a)
MIN_GAIN = 0.02  # a last pass that would add fewer rays than this fraction of those done is not run
SAFETY = 0.75  # a pass within reach has this fraction of the spp that would fill the time left (the last allowed
# pass: all of them)


@dataclass
class SppSchedule:
    """The spp of each pass that fills ``budget_s`` seconds of tracing (at most ``max_spp`` rays per pixel in
    all). Call :meth:`next_spp` with the seconds spent so far; run a pass of that many spp; :meth:`record` its
    seconds; repeat until :meth:`next_spp` gives None."""

    budget_s: float
    max_spp: int = 1_000_000
    first_spp: int = 16
    passes: list[tuple[int, float]] = field(default_factory=list)  # (spp, seconds) of each pass run
    fixed_s: list[float] = field(default_factory=list)  # each pass's measured part that does not grow with spp

    def __post_init__(self) -> None:
        if not (math.isfinite(self.budget_s) and self.budget_s > 0):
            raise ValueError(f"budget_s must be finite and > 0 (s), got {self.budget_s!r}")
        if not 1 <= int(self.max_spp) <= 1_000_000:
            raise ValueError(f"max_spp must be in 1..1000000, got {self.max_spp!r}")
        if not 1 <= int(self.first_spp):
            raise ValueError(f"first_spp must be >= 1, got {self.first_spp!r}")

    @property
    def spp(self) -> int:
        """Rays per pixel of the passes run so far."""
        return sum(s for s, _ in self.passes)

    def record(self, spp: int, seconds: float, *, fixed_s: Optional[float] = None) -> None:
        """A pass of ``spp`` took ``seconds``; ``fixed_s``: the part of them measured not to grow with spp (the
        renderer's: storing each pass's recordings, which at 1080x1920 x 24 frames with five recording planes
        is 20 s a pass, more than a 16-spp trace's share of the line could tell)."""
        self.passes.append((int(spp), max(0.0, float(seconds))))
        if fixed_s is not None:
            self.fixed_s.append(min(max(0.0, float(fixed_s)), self.passes[-1][1]))

    def cost_model(self) -> tuple[float, float]:
        """(a s, b s per spp) of t = a + b spp. With measured fixed parts (every pass recorded one): a is the
        largest of them and b the largest pass's rest per spp. Otherwise the line through the two largest
        passes; with one pass (or a
        line that makes no sense, as timing noise can), a = 0, which overestimates b and so errs short. The fixed
        cost a is at most the quickest pass's time (a cost per spp that falls with the pass's size, as a
        tracer's fuller tiles give, would otherwise read as a fixed cost: 6.7 s on a scene whose 16-spp pass
        took 0.9 s, which stopped its passes 6 % short of the budget)."""
        if not self.passes:
            raise ValueError("no pass measured yet")
        if len(self.fixed_s) == len(self.passes):
            a = max(self.fixed_s)
            k = max(range(len(self.passes)), key=lambda i: self.passes[i][0])
            s, t = self.passes[k]
            return a, max(t - self.fixed_s[k], 1e-9) / s
        by_size = sorted(self.passes)
        (s2, t2) = by_size[-1]
        t2 = max(t2, 1e-9)
        quickest = min(t for _, t in self.passes)
        for s1, t1 in reversed(by_size[:-1]):
            if s1 < s2:
                b = (t2 - t1) / (s2 - s1)
                a = t1 - b * s1
                if b > 0 and a >= 0:
                    a = min(a, quickest)
                    return a, (t2 - a) / s2
                break
        return 0.0, t2 / s2

    def next_spp(self, elapsed_s: float) -> Optional[int]:
        """Rays per pixel of the next pass, or None when the budget (or ``max_spp``) is used up.
        ``elapsed_s``: seconds of the budget spent so far."""
        done = self.spp
        room = int(self.max_spp) - done
        if room <= 0 or len(self.passes) >= MAX_PASSES:
            return None
        if not self.passes:
            return min(int(self.first_spp), room)
        left = self.budget_s - float(elapsed_s)
        a, b = self.cost_model()
        fill = math.floor((left - a) / b) if left > a else 0  # the spp that would end the pass at the budget
        if fill < max(1.0, MIN_GAIN * done):
            return None
        reach = GROWTH * max(s for s, _ in self.passes)
        if fill > reach:  # too far to extrapolate: half of what is left, within reach, and measure again
            n = min(reach, fill // 2)
        elif len(self.passes) >= MAX_PASSES - 1:
            n = fill
        else:
            n = math.floor(SAFETY * fill)
        return int(min(max(1, n), room))
