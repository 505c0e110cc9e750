"""``lab-counter[:N]``: an SLM driver that shows nothing and refuses to show more than N frames (a demonstration
of a lab's driver)."""

from __future__ import annotations

from display_agent.slm.base import SLM, SLMError


class CounterSLM(SLM):
    @classmethod
    def from_spec(cls, arg: str) -> "CounterSLM":
        if arg and not arg.isdigit():
            raise ValueError(f"lab-counter takes a frame count, got {arg!r}")
        return cls(int(arg) if arg else 1000)

    def __init__(self, most: int) -> None:
        super().__init__()
        self.most = most

    def _present(self, frame: int, color: int) -> None:
        if self.shown >= self.most:
            raise SLMError(f"lab-counter shows at most {self.most} frames")
