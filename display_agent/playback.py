"""Time-multiplexed, colour-sequential playback of a preloaded stack (paper Sec. 6: 1, 3, 8 or 24 frames).

One pass shows, for each frame f, each colour c in order (colour-sequential illumination): the laser hook is
called when the colour changes, then the SLM shows (f, c). Slots are paced at ``rate_hz`` (SLM refreshes per
second; 0 = as fast as the SLM presents, e.g. locked to vsync). Late slots are counted, never skipped, so
every frame of a pass is shown exactly once. The schedule carries over between calls, so looping pass after
pass keeps the rate (a pass of N slots takes N periods).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional

from display_agent.slm.base import SLM

__all__ = ["PlaybackStats", "Player", "LaserHook"]

LaserHook = Callable[[int], None]
"""Called with the colour index before the first frame of that colour (switch the laser channel)."""


@dataclass
class PlaybackStats:
    passes: int = 0
    frames_shown: int = 0
    late: int = 0  # slots presented more than one period after their due time
    seconds: float = 0.0
    stopped: bool = False


class Player:
    """Plays the SLM's loaded stack. ``stop_event`` set from another thread ends playback after the
    current slot."""

    def __init__(self, slm: SLM, *, rate_hz: float = 0.0, laser_hook: Optional[LaserHook] = None,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
        if not (rate_hz >= 0.0) or rate_hz > 10_000:
            raise ValueError(f"rate_hz must be in [0, 10000] (0 = as fast as the SLM presents), got {rate_hz}")
        self.slm = slm
        self.rate_hz = float(rate_hz)
        self.laser_hook = laser_hook
        self._clock = clock
        self._sleep = sleep
        self._color: Optional[int] = None
        self.last_frame: Optional[int] = None  # index of the frame last presented
        self._next_due: Optional[float] = None  # clock time of the next slot
        self.total = PlaybackStats()

    def play(self, *, passes: int = 1, stop_event: Optional[threading.Event] = None) -> PlaybackStats:
        """Show every (frame, colour) of the loaded stack ``passes`` times; returns this call's counts."""
        if passes < 1:
            raise ValueError(f"passes must be >= 1, got {passes}")
        frames, colors = self.slm.frame_count, self.slm.color_count
        if frames == 0:
            raise ValueError("no stack loaded on the SLM")
        stats = PlaybackStats()
        period = 1.0 / self.rate_hz if self.rate_hz > 0 else 0.0
        t0 = self._clock()
        # the slot schedule runs on across calls (continuous looping keeps the rate); after a pause it restarts
        due = self._next_due if (self._next_due is not None and t0 - self._next_due < period) else t0
        for _ in range(passes):
            for f in range(frames):
                for c in range(colors):
                    if stop_event is not None and stop_event.is_set():
                        stats.stopped = True
                        return self._finish(stats, t0)
                    if period:
                        wait = due - self._clock()
                        if wait > 0:
                            self._sleep(wait)
                        elif wait < -period:
                            stats.late += 1
                        due += period
                    if c != self._color:
                        if self.laser_hook is not None:
                            self.laser_hook(c)
                        self._color = c
                    self.slm.show(f, c)
                    self.last_frame = f
                    stats.frames_shown += 1
                    self._next_due = due
            stats.passes += 1
        return self._finish(stats, t0)

    def _finish(self, stats: PlaybackStats, t0: float) -> PlaybackStats:
        stats.seconds = self._clock() - t0
        self.total.passes += stats.passes
        self.total.frames_shown += stats.frames_shown
        self.total.late += stats.late
        self.total.seconds += stats.seconds
        return stats
