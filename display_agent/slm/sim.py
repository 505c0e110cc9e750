"""Simulated SLM: records every frame it is asked to show.

Each distinct frame is written once to ``DIR/{stack_id}_c{color}_f{frame:03d}.png`` (8-bit grayscale, the
exact gray levels), and every presentation appends a line to ``DIR/slm.log``:
``<unix time> show <stack_id> c=<color> f=<frame> n=<count> sha256=<hex of the frame's bytes>``
(plus ``load`` and ``blank`` lines)."""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path
from typing import Union

import numpy as np
from PIL import Image

from display_agent.slm.base import SLM

__all__ = ["SimSLM", "frame_png_name"]


def frame_png_name(stack_id: str, color: int, frame: int) -> str:
    return f"{stack_id}_c{color}_f{frame:03d}.png"


class SimSLM(SLM):
    @classmethod
    def from_spec(cls, arg: str) -> "SimSLM":
        if not arg:
            raise ValueError("slm 'sim' needs a directory: sim:DIR")
        return cls(arg)

    def __init__(self, directory: Union[str, Path]) -> None:
        super().__init__()
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self._log = open(self.dir / "slm.log", "a", buffering=1)
        self._written: set[tuple[int, int]] = set()
        self._digests: dict[tuple[int, int], str] = {}

    def _line(self, text: str) -> None:
        self._log.write(f"{time.time():.6f} {text}\n")

    def _prepare(self, levels: np.ndarray, stack_id: str) -> None:
        self._written = set()
        self._digests = {(f, c): hashlib.sha256(np.ascontiguousarray(levels[f, c]).tobytes()).hexdigest()
                         for f in range(levels.shape[0]) for c in range(levels.shape[1])}
        f, c, h, w = levels.shape
        self._line(f"load {stack_id} frames={f} colors={c} size={w}x{h}")

    def _present(self, frame: int, color: int) -> None:
        assert self._levels is not None and self.stack_id is not None
        key = (frame, color)
        if key not in self._written:
            path = self.dir / frame_png_name(self.stack_id, color, frame)
            tmp = path.with_name(f".{path.name}.tmp")
            Image.fromarray(self._levels[frame, color]).save(tmp, format="PNG")
            os.replace(tmp, path)  # readers never see half a PNG
            self._written.add(key)
        self._line(f"show {self.stack_id} c={color} f={frame} n={self.shown + 1} sha256={self._digests[key]}")

    def _blank(self) -> None:
        self._line("blank")

    def close(self) -> None:
        if not self._log.closed:
            self._log.close()
