"""display_agent: the lab daemon beside a holographic display.

It follows the service over HTTP for finished phase stacks meant for its display, keeps a verified local
cache, plays stacks on a phase-only SLM (time-multiplexed, colour-sequential) and steps a focus controller
through focus planes for captures. It depends only on the HTTP API and the STACK.npz format (numpy), never
on Mitsuba, Dr.Jit or torch (docs/design.md §1). See docs/display_agent.md and docs/focus_protocol.md.
"""

__version__ = "0.1.0"
