"""Focus controller (an Arduino moving a camera lens) over a serial line: protocol, client, simulator.

The line protocol is documented in docs/focus_protocol.md."""

from display_agent.focus.client import (
    FocusController,
    FocusDisconnected,
    FocusError,
    FocusStatus,
    FocusTimeout,
)

__all__ = ["FocusController", "FocusError", "FocusTimeout", "FocusDisconnected", "FocusStatus"]
