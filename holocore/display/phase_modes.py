"""The frame-phase registry: how the F frames give each image point its phase (``OpticsConfig.frame_phases``).

One interface, :class:`FramePhases`, and a registry, as Mitsuba registers integrators: a mode is a subclass with a
``name``, registered by :func:`register_frame_phases`; ``OpticsConfig.frame_phases`` accepts exactly the registry's
keys, and the renderer (:mod:`holocore.pipeline`) and the baselines ask the mode object for what differs:

* :meth:`FramePhases.lateral_phases`: the bank, one float32 [H, W] phase map per frame on the cell lattice (each
  image point takes the value of its cell; docs/design.md §4), with :meth:`FramePhases.gain` its amplitude per
  colour;
* :meth:`FramePhases.depth_terms`: a per-ray factor that depends on the ray's depth (directional frames' Eq. B1),
  None for phases that are the same at any depth;
* what the cone equaliser may assume (:attr:`FramePhases.noise_aware`, :attr:`FramePhases.rim_ripple`) and which
  phases the light-field stereogram keeps (:attr:`FramePhases.stereogram_coded`).

The modes themselves are found by entry point (group ``holocore.frame_phases``: holocore.plugins), the project's
built-ins (:mod:`holocore.trace.frame_phases`) the same way as a lab's own package's. It sits with the display
because the display's optics validate against its keys; it imports nothing of holocore but the plug-in finder, and
nothing heavy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar, Iterator, Optional, Sequence

from holocore.plugins import FRAME_PHASES, register_discovered

if TYPE_CHECKING:  # numpy only in annotations: the API process and the agent import this module for its names
    import numpy as np

__all__ = ["FramePhases", "register_frame_phases", "frame_phase_modes", "get_frame_phases"]

_REGISTRY: dict[str, "FramePhases"] = {}


class FramePhases:
    """A frame-phase mode. Subclasses set ``name`` and ``summary`` and implement :meth:`lateral_phases`."""

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""  # one line for the CLI's help and the docs
    noise_aware: ClassVar[bool] = True  # the cone equaliser may use Eq. C4 (its gain divided by the noise) over C3
    rim_ripple: ClassVar[bool] = True  # False: the rays carry their points' ideal spectrum, the equaliser only B
    # the light-field stereogram's per-plane-wave phases: coded, else independent
    stereogram_coded: ClassVar[bool] = True

    def gain(self, wavelength_m: float, *, pitch_m: float, wavelengths_m: Sequence[float]) -> float:
        """Amplitude factor of colour ``wavelength_m`` (m) in every frame (1: none)."""
        return 1.0

    def lateral_phases(self, frames: int, shape_hw: tuple[int, int], wavelength_m: float, *, pitch_m: float,
                       wavelengths_m: Sequence[float], seed: int, first_frame: int = 0,
                       bank_frames: Optional[int] = None) -> Iterator[np.ndarray]:
        """Frames first_frame .. first_frame + frames - 1 of a bank of ``bank_frames`` (default: frames): one
        float32 [H, W] map in [0, 2 pi) per frame, periodic on H x W. Wavelengths and pitch in m."""
        raise NotImplementedError

    def depth_terms(self, *, frames: int, first_frame: int, bank_frames: int, wavelengths_m: Sequence[float],
                    all_wavelengths_m: Sequence[float], pitch_m: float) -> Any:
        """The per-ray depth factor of frames first_frame.. of colours ``wavelengths_m`` (m), or None when the
        phases do not depend on the ray's depth (:class:`holocore.trace.beams.BeamDepthTerms` for beams)."""
        return None


def register_frame_phases(cls: type[FramePhases]) -> type[FramePhases]:
    """Class decorator: register a mode under its ``name`` (a new name; the built-ins cannot be replaced)."""
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"a frame-phase mode needs a name made of letters, digits and _, got {name!r}")
    if name in _REGISTRY and type(_REGISTRY[name]) is not cls:
        raise ValueError(f"frame-phase mode {name!r} is already registered")
    _REGISTRY[name] = cls()
    return cls


_DISCOVERED: list[bool] = []


def _discover() -> None:
    """Register the modes installed packages declare (entry point group ``holocore.frame_phases``, the built-ins
    among them: holocore.plugins), once. A plug-in that is not a mode, or clashes, is left out with a warning."""
    if _DISCOVERED:
        return
    _DISCOVERED.append(True)  # first: a plug-in's import may ask for the modes again
    register_discovered(FRAME_PHASES, register_frame_phases, FramePhases, "frame-phase")


def frame_phase_modes() -> tuple[str, ...]:
    """The registered modes' names, the built-ins first."""
    _discover()
    return tuple(_REGISTRY)


def get_frame_phases(name: str) -> FramePhases:
    """The mode registered as ``name``; one-line ValueError naming the known ones otherwise."""
    _discover()
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown frame phases {name!r}: one of {', '.join(_REGISTRY)}") from None
