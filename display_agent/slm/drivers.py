"""The SLM drivers, found by entry point (group ``display_agent.slm``; holocore.plugins): the project's ``sim``
(records what it shows), ``window`` (a fullscreen pygame window on a monitor) and ``null`` (shows nothing, counts
frames), and any a lab installs as a package of its own::

    [project.entry-points."display_agent.slm"]
    meadowlark = "lab_slm.meadowlark:MeadowlarkSLM"   # a display_agent.slm.base.SLM subclass

A spec names a driver and, after a colon, what its :meth:`SLM.from_spec` takes: ``sim:DIR``,
``window[:MONITOR[:WxH]]``, ``null``, ``meadowlark:...``.
"""

from __future__ import annotations

from display_agent.slm.base import SLM
from holocore.plugins import discovered

__all__ = ["GROUP", "driver_names", "open_slm"]

GROUP = "display_agent.slm"


def _drivers() -> dict[str, type[SLM]]:
    return {name: cls for name, cls in discovered(GROUP) if isinstance(cls, type) and issubclass(cls, SLM)}


def driver_names() -> tuple[str, ...]:
    """The installed drivers' names, the project's own first."""
    return tuple(_drivers())


def open_slm(spec: str) -> SLM:
    """The driver a spec names, opened (ValueError in one line for an unknown driver or a bad argument)."""
    kind, _, arg = spec.partition(":")
    drivers = _drivers()
    if kind not in drivers:
        raise ValueError(f"slm driver must be one of {', '.join(drivers)} (sim:DIR, window[:MONITOR[:WxH]], null, "
                         f"or an installed plug-in's), got {spec!r}")
    return drivers[kind].from_spec(arg)
