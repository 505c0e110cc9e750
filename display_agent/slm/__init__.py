"""Phase-only SLM backends behind one interface: :class:`SLM` (load frames, ``show(frame, color)``).

``open_slm(spec)``: ``sim:DIR`` (records what it shows), ``window[:MONITOR]`` (fullscreen pygame window),
``null`` (shows nothing, counts frames), or a driver another package declares (display_agent.slm.drivers)."""

from display_agent.slm.base import SLM, NullSLM, SLMError
from display_agent.slm.drivers import open_slm

__all__ = ["SLM", "SLMError", "NullSLM", "open_slm"]
