"""The abstract SLM every driver implements (its drivers: display_agent.slm.drivers)."""

from __future__ import annotations

import abc
from typing import Optional

import numpy as np

__all__ = ["SLM", "SLMError", "NullSLM"]


class SLMError(RuntimeError):
    """The SLM cannot show what was asked (no stack loaded, index out of range, device gone)."""


class SLM(abc.ABC):
    """A phase-only SLM. ``load`` preloads one stack's gray levels uint8 [F, C, H, W]; ``show(frame, color)``
    puts one preloaded frame on the panel and returns once it is presented (vsync for real displays)."""

    @classmethod
    def from_spec(cls, arg: str) -> "SLM":
        """The driver opened from what follows its name in a spec (``sim:DIR``: "DIR"; "" when nothing does);
        ValueError in one line for an argument it cannot take."""
        if arg:
            raise ValueError(f"this SLM driver takes no argument, got {arg!r}")
        return cls()

    def __init__(self) -> None:
        self._levels: Optional[np.ndarray] = None
        self.stack_id: Optional[str] = None
        self.shown = 0  # frames presented since creation

    def load(self, *, stack_id: str, levels: np.ndarray) -> None:
        """Preload a stack (replaces the previous one)."""
        lv = np.asarray(levels)
        if lv.dtype != np.uint8 or lv.ndim != 4 or min(lv.shape) < 1:
            raise ValueError(f"levels must be uint8 [F, C, H, W], got {lv.dtype} {lv.shape}")
        if not stack_id or any(ch in stack_id for ch in "/\\\0") or stack_id.startswith("."):
            raise ValueError(f"stack_id must be a plain name (no path separators), got {stack_id!r}")
        self._prepare(lv, stack_id)
        self._levels = np.ascontiguousarray(lv)
        self.stack_id = stack_id

    @property
    def frame_count(self) -> int:
        return 0 if self._levels is None else int(self._levels.shape[0])

    @property
    def color_count(self) -> int:
        return 0 if self._levels is None else int(self._levels.shape[1])

    def show(self, frame: int, color: int = 0) -> None:
        """Present preloaded frame ``frame`` of colour ``color``."""
        if self._levels is None or self.stack_id is None:
            raise SLMError("no stack loaded")
        if not (0 <= frame < self._levels.shape[0]):
            raise ValueError(f"frame must be in [0, {self._levels.shape[0] - 1}], got {frame}")
        if not (0 <= color < self._levels.shape[1]):
            raise ValueError(f"color must be in [0, {self._levels.shape[1] - 1}], got {color}")
        self._present(frame, color)
        self.shown += 1

    def blank(self) -> None:
        """Show nothing (level 0 everywhere) and forget the stack."""
        self._levels = None
        self.stack_id = None
        self._blank()

    def close(self) -> None:
        """Release the device."""

    def __enter__(self) -> "SLM":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # backends
    def _prepare(self, levels: np.ndarray, stack_id: str) -> None:
        """Preload (e.g. build surfaces); called before ``levels`` becomes current."""

    @abc.abstractmethod
    def _present(self, frame: int, color: int) -> None: ...

    def _blank(self) -> None:
        """Clear the panel."""


class NullSLM(SLM):
    """Shows nothing; counts frames (for dry runs and timing)."""

    def _present(self, frame: int, color: int) -> None:
        pass
