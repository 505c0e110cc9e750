"""Plug-ins found by entry point, so that a lab adds a frame-phase mode or a baseline as a package of its own:
one module and a line in its ``pyproject.toml``, no edit here::

    [project.entry-points."holocore.frame_phases"]
    lab_mode = "lab_holo.modes:LabMode"        # a holocore.display.phase_modes.FramePhases subclass
    [project.entry-points."holocore.baselines"]
    lab-fit = "lab_holo.fit:LabFitBaseline"    # a holocore.baselines.registry.Baseline subclass

The project's built-ins are declared the same way in its own ``pyproject.toml``. Each registry asks this module
for its group the first time it is read (:func:`discovered`), loads what it finds and registers it as its own
decorator would. A plug-in that fails to load is left out with a warning naming it and why: one broken package
does not take the renderer down. (The display agent's SLM drivers are found the same way:
``display_agent.slm.drivers``.)

Imports nothing of holocore: every stage may ask it.
"""

from __future__ import annotations

import warnings
from importlib.metadata import entry_points
from typing import Any, Callable

__all__ = ["FRAME_PHASES", "BASELINES", "discovered", "register_discovered"]

FRAME_PHASES = "holocore.frame_phases"
BASELINES = "holocore.baselines"


def discovered(group: str) -> list[tuple[str, Any]]:
    """(entry point name, the object it names) for every installed entry point of ``group``, the project's own
    (module ``holocore.*``) first, each part in the order the packages declare them."""
    found: list[tuple[str, Any]] = []
    for ep in entry_points(group=group):
        try:
            found.append((ep.name, ep.load()))
        except Exception as exc:  # noqa: BLE001 - a plug-in's own error, whatever it is, must not stop the caller
            warnings.warn(f"plug-in {ep.name!r} ({ep.value}, group {group}) left out: {type(exc).__name__}: {exc}",
                          RuntimeWarning, stacklevel=2)
    return sorted(found, key=lambda item: not getattr(item[1], "__module__", "").startswith("holocore."))


def register_discovered(group: str, register: Callable[[type], Any], base: type, what: str) -> None:
    """Pass each class ``group``'s entry points name to ``register`` (a registry's own decorator); one that is
    not a subclass of ``base``, or that the registry refuses (a clash of names), is left out with a warning."""
    for name, cls in discovered(group):
        try:
            if not (isinstance(cls, type) and issubclass(cls, base)):
                raise TypeError(f"{cls!r} is not a {base.__name__} subclass")
            register(cls)
        except (TypeError, ValueError) as exc:
            warnings.warn(f"{what} plug-in {name!r} left out: {exc}", RuntimeWarning, stacklevel=3)
