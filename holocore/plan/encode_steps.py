"""The encoder's optimisers as a plan sees them: how many iterations each runs when none are given, what one of
them costs, and how far one gets. Pure Python (no torch), so that the time and quality models and the service's
API process read the same rules the encoder runs by; the optimisers themselves are :mod:`holocore.encode.sgd`
(Adam) and :mod:`holocore.encode.lbfgs`.

Why L-BFGS with a fixed count is the default: one iteration is four padded FFTs whichever optimiser steps, and
memoryless BFGS reaches Adam's field error in about 1/1.4 of Adam's iterations (the ratio holds from 25 to 50
L-BFGS iterations, bench/results/encode.md). What the eye sees settles long before the field error does: at
540x960 x 24 frames on the mirror scene, 25 and 33 L-BFGS iterations came within 0.24 / 0.42 and 0.15 / 0.27 dB
(viewer-faithful, 4 mm pupil; near / far content) of Adam's stop rule (138 iterations), in a quarter of its
time. At the paper's full size (1080x1920 x 3 colours x 24 frames, the demo scene, viewer-faithful with a 4 mm
pupil) 28 and 30 iterations came within 0.10 and 0.09 dB of Adam run to convergence (bench/results/fullscale.md):
28 is the default, the count that keeps the paper's whole stack within four minutes on two CPU cores. Its stop
rule (the same 0.05 dB over 30 iterations) stays for longer runs; it cannot end a run of 30 or fewer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from holocore.options import DEFAULT_OPTIMISER, OPTIMISERS, Optimiser

__all__ = ["Optimiser", "OPTIMISERS", "DEFAULT_OPTIMISER", "StepRule", "RULES", "rule",
           "default_iterations"]


@dataclass(frozen=True)
class StepRule:
    """One optimiser as the planner sees it."""

    max_iterations: int  # iterations when none are given (Adam: a cap its stop rule ends well before)
    stops_early: bool  # whether its default run usually ends by the stop rule before max_iterations
    cost: float  # one iteration's time / one Adam iteration's (bench/bench_encode.py floor, one run)
    adam_equivalent: float  # Adam iterations that reach the field error one of its iterations reaches


RULES: dict[str, StepRule] = {
    "lbfgs": StepRule(max_iterations=28, stops_early=False, cost=1.17, adam_equivalent=1.4),
    "adam": StepRule(max_iterations=500, stops_early=True, cost=1.0, adam_equivalent=1.0),
}


def rule(optimiser: Optional[str]) -> StepRule:
    """The rule of ``optimiser`` (None: the default's); an unknown name is refused in one line."""
    name = DEFAULT_OPTIMISER if optimiser is None else optimiser
    if name not in RULES:
        raise ValueError(f"optimiser must be one of {', '.join(OPTIMISERS)}, got {optimiser!r}")
    return RULES[name]


def default_iterations(optimiser: Optional[str], iterations: Optional[int]) -> int:
    """The iterations to run: those given, else the optimiser's ``max_iterations``."""
    return rule(optimiser).max_iterations if iterations is None else int(iterations)
