"""What the baselines' Adam fits share (the focal stack's, the light field's): their options' checks and the rule
that stops a colour's steps at its share of a wall-time budget."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal, Optional

from pydantic import Field

from holocore import validate
from holocore.baselines.registry import BaselineOptions

__all__ = ["MAX_ITERATIONS", "AdamOptions", "AdamFitOptions", "StepBudget", "torch_device"]

MAX_ITERATIONS = 100_000


@dataclass(frozen=True)
class AdamOptions:
    """Checked options of a phase fit: ``frames`` (1..4096), ``iterations`` (0..100000) Adam steps at learning rate
    ``lr`` (rad), and a wall-time limit ``time_limit_s`` (s, None: no limit)."""

    frames: int
    iterations: int
    lr: float
    time_limit_s: Optional[float]

    @classmethod
    def check(cls, *, frames: int, iterations: int, lr: float, time_limit_s: Optional[float]) -> "AdamOptions":
        return cls(frames=validate.integer("frames", frames, 1, 4096),
                   iterations=validate.integer("iterations", iterations, 0, MAX_ITERATIONS),
                   lr=validate.positive("lr", lr, unit=""),
                   time_limit_s=None if time_limit_s is None else validate.positive("time_limit_s", time_limit_s,
                                                                                    unit="s"))


class StepBudget:
    """Colour c of C gets an equal share of the time left when it starts; a step is taken only if the colour's
    mean step duration so far still fits before its deadline (the first step always is)."""

    def __init__(self, time_limit_s: Optional[float], colours: int) -> None:
        self.limit = time_limit_s
        self.colours = int(colours)
        self.t0 = time.perf_counter()
        self.deadline: Optional[float] = None
        self.t_colour = self.t0

    def start_colour(self, c: int) -> None:
        now = time.perf_counter()
        self.deadline = None if self.limit is None else now + (self.t0 + self.limit - now) / (self.colours - c)
        self.t_colour = now

    def begin_steps(self) -> None:
        """The colour's first step starts now (after its set-up, which the mean step duration leaves out)."""
        self.t_colour = time.perf_counter()

    def last(self, it: int, iterations: int) -> bool:
        """Whether step ``it`` is the final loss evaluation, with no step after it."""
        if it == iterations:
            return True
        if self.deadline is None or it == 0:
            return False
        now = time.perf_counter()
        return now + (now - self.t_colour) / it > self.deadline


class AdamFitOptions(BaselineOptions):
    """The options every Adam phase fit of a baseline takes (the focal stack's, the light field's SGD)."""

    iterations: int = Field(200, ge=0, le=MAX_ITERATIONS, description="Adam steps, the most")
    lr: float = Field(0.05, gt=0, lt=100, description="Adam learning rate on the phases (rad)")
    time_limit_s: Optional[float] = Field(None, gt=0, lt=1e7, description="wall time of the whole baseline (s)")
    device: Literal["cpu", "cuda", "auto"] = Field("cpu", description="torch device: cpu, cuda or auto")


def torch_device(device: str) -> str:
    """cpu, cuda or auto (cuda where there is one) -> the torch device; ValueError for cuda without one."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("device cuda: no CUDA device here")
    return device
