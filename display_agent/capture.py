"""Capture sequence (paper Sec. 6: five focus planes over the volume): for each plane, move the focus
controller, wait for SETTLED, play the loaded stack, fire the camera trigger. Every step is logged (Python
logging and, if given, a JSON-lines sequence log with unix times)."""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal, Optional, Sequence, Union

from display_agent.focus.client import FocusController
from display_agent.playback import Player

__all__ = ["CaptureStep", "run_capture"]

log = logging.getLogger("holo.agent.capture")

Trigger = Callable[..., None]


@dataclass
class CaptureStep:
    index: int
    plane: Optional[int]
    position: Optional[int]
    frames_shown: int = 0
    seconds: float = 0.0
    events: list[dict] = field(default_factory=list)


def run_capture(*, player: Player, stack_id: str, focus: Optional[FocusController],
                planes: Optional[Sequence[int]] = None, positions: Optional[Sequence[int]] = None,
                passes: int = 1, trigger: Optional[Trigger] = None,
                trigger_at: Literal["before_play", "after_play"] = "after_play", settle_timeout_s: float = 30.0,
                sequence_log: Optional[Union[str, Path]] = None) -> list[CaptureStep]:
    """Run the sequence over ``planes`` (controller plane indices) or ``positions`` (motor steps).

    Without a controller (``focus=None``) the planes are only played and triggered (a fixed-focus rig).
    The trigger is called with ``index, plane, position, stack`` keyword fields."""
    if (planes is None) == (positions is None):
        raise ValueError("give exactly one of planes or positions")
    targets = list(planes if planes is not None else positions)  # type: ignore[arg-type]
    if not targets:
        raise ValueError("planes/positions must not be empty")
    if passes < 1:
        raise ValueError(f"passes must be >= 1, got {passes}")
    if trigger_at not in ("before_play", "after_play"):
        raise ValueError(f"trigger_at must be before_play or after_play, got {trigger_at!r}")
    out = Path(sequence_log) if sequence_log is not None else None
    fh = open(out, "a", buffering=1) if out is not None else None

    def event(step: CaptureStep, kind: str, **data: Any) -> None:
        rec = {"t": time.time(), "event": kind, "index": step.index, "plane": step.plane,
               "position": step.position, "stack": stack_id, **data}
        step.events.append(rec)
        if fh is not None:
            fh.write(json.dumps(rec) + "\n")
        log.info("capture %d/%d %s %s", step.index + 1, len(targets), kind,
                 " ".join(f"{k}={v}" for k, v in data.items()))

    steps: list[CaptureStep] = []
    try:
        for i, target in enumerate(targets):
            plane = int(target) if planes is not None else None
            pos = int(target) if positions is not None else None
            step = CaptureStep(index=i, plane=plane, position=pos)
            t0 = time.monotonic()
            if focus is not None:
                event(step, "move")
                st = focus.goto(plane=plane, pos=pos, settle_timeout_s=settle_timeout_s)
                step.position = st.pos
                event(step, "settled", pos=st.pos, reconnects=focus.reconnects)
            fields = {"index": i, "plane": "" if plane is None else plane,
                      "position": "" if step.position is None else step.position, "stack": stack_id}
            if trigger is not None and trigger_at == "before_play":
                event(step, "trigger")
                trigger(**fields)
            event(step, "play", passes=passes)
            stats = player.play(passes=passes)
            step.frames_shown = stats.frames_shown
            event(step, "played", frames=stats.frames_shown, late=stats.late, seconds=round(stats.seconds, 4))
            if trigger is not None and trigger_at == "after_play":
                event(step, "trigger")
                trigger(**fields)
            step.seconds = time.monotonic() - t0
            steps.append(step)
    finally:
        if fh is not None:
            fh.close()
    return steps
