"""Frame-phase modes: how the F frames give each image point its phase (``OpticsConfig.frame_phases``).

One interface, :class:`FramePhases`, and a registry, as Mitsuba registers integrators: a mode is a subclass with a
``name``, registered by :func:`register_frame_phases`; ``OpticsConfig.frame_phases`` accepts exactly the registry's
keys, the renderer (:mod:`holocore.pipeline`) and the baselines ask the mode object for what differs:

* :meth:`FramePhases.lateral_phases`: the bank, one float32 [H, W] phase map per frame on the cell lattice (each
  image point takes the value of its cell; docs/design.md §4), with :meth:`FramePhases.gain` its amplitude per colour;
* :meth:`FramePhases.depth_terms`: a per-ray factor that depends on the ray's depth (directional frames' Eq. B1),
  None for phases that are the same at any depth;
* what the cone equaliser may assume (:attr:`FramePhases.noise_aware`, :attr:`FramePhases.rim_ripple`) and which
  phases the light-field stereogram keeps (:attr:`FramePhases.stereogram_coded`).

The built-in modes: ``coded`` (the default; :mod:`holocore.trace.randomfield`, docs/physics.md "Coded frame
phases"), ``independent`` (the paper's Eq. 4) and ``directional`` (:mod:`holocore.trace.beams`). A mode
from another package is found by its entry point (group ``holocore.frame_phases``: holocore.plugins), the
built-ins are declared the same way. This module imports nothing heavy and no holocore module but the plug-in
finder at import time (the optics config validates against its keys), so every implementation imports what it
needs inside its methods, and a plug-in mode imports only this module at import time.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any, ClassVar, Iterator, Optional, Sequence

from holocore.plugins import FRAME_PHASES, discovered

if TYPE_CHECKING:  # numpy only in annotations: the API process and the agent import this module for its names
    import numpy as np

__all__ = ["FramePhases", "register_frame_phases", "frame_phase_modes", "get_frame_phases", "CodedPhases",
           "IndependentPhases", "DirectionalPhases"]

_REGISTRY: dict[str, "FramePhases"] = {}


class FramePhases:
    """A frame-phase mode. Subclasses set ``name`` and ``summary`` and implement :meth:`lateral_phases`."""

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""  # one line for the CLI's help and the docs
    noise_aware: ClassVar[bool] = True  # the cone equaliser may use Eq. C4 (its gain divided by the noise) over C3
    rim_ripple: ClassVar[bool] = True  # False: the rays carry their points' ideal spectrum, the equaliser only B
    stereogram_coded: ClassVar[bool] = True  # the light-field stereogram's per-plane-wave phases: coded, else independent

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
    for name, cls in discovered(FRAME_PHASES):
        try:
            if not (isinstance(cls, type) and issubclass(cls, FramePhases)):
                raise TypeError(f"{cls!r} is not a FramePhases subclass")
            register_frame_phases(cls)
        except (TypeError, ValueError) as exc:
            warnings.warn(f"frame-phase plug-in {name!r} left out: {exc}", RuntimeWarning, stacklevel=2)


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


@register_frame_phases
class CodedPhases(FramePhases):
    name = "coded"
    summary = ("one random field plus a per-cell code ramp, so that the cross terms of nearby image cells cancel "
               "in the frame average: less speckle (holocore.trace.randomfield)")

    def lateral_phases(self, frames, shape_hw, wavelength_m, *, pitch_m, wavelengths_m, seed, first_frame=0,
                       bank_frames=None):
        from holocore.trace.randomfield import phase_frames

        F = int(bank_frames if bank_frames is not None else frames)
        return phase_frames(frames, shape_hw, wavelength_m, pitch_m, seed=seed, first_frame=first_frame,
                            coded_frames=F)


@register_frame_phases
class IndependentPhases(FramePhases):
    name = "independent"
    summary = "one random field per frame (the paper's Eq. 4)"
    stereogram_coded = False

    def lateral_phases(self, frames, shape_hw, wavelength_m, *, pitch_m, wavelengths_m, seed, first_frame=0,
                       bank_frames=None):
        from holocore.trace.randomfield import phase_frames

        return phase_frames(frames, shape_hw, wavelength_m, pitch_m, seed=seed, first_frame=first_frame,
                            coded_frames=None)


@register_frame_phases
class DirectionalPhases(FramePhases):
    name = "directional"
    summary = ("frame m a plane wave towards one of F eye positions spread over the common cone: no speckle, the "
               "defocus blur sampled by the frames a pupil holds (holocore.trace.beams)")
    noise_aware = False  # C4 fits a random-phase sheet's flat spectrum to frame 0, here one beam
    rim_ripple = False  # each ray carries (B2)'s 1 / K_rel of its own depth and frame
    stereogram_coded = True  # a stereogram's phases are per plane wave, not per image point: it keeps coded ones

    def gain(self, wavelength_m, *, pitch_m, wavelengths_m):
        from holocore.trace.beams import beam_gain

        return beam_gain(float(wavelength_m), float(pitch_m), wavelengths_m)

    def lateral_phases(self, frames, shape_hw, wavelength_m, *, pitch_m, wavelengths_m, seed, first_frame=0,
                       bank_frames=None):
        from holocore.trace.beams import beam_phase_frames

        return beam_phase_frames(frames, shape_hw, float(wavelength_m), float(pitch_m), wavelengths_m=wavelengths_m,
                                 first_frame=first_frame, bank_frames=bank_frames)

    def depth_terms(self, *, frames, first_frame, bank_frames, wavelengths_m, all_wavelengths_m, pitch_m):
        from holocore.trace.beams import BeamDepthTerms

        return BeamDepthTerms.make(frames=frames, first_frame=first_frame, bank_frames=bank_frames,
                                   wavelengths_m=wavelengths_m, all_wavelengths_m=all_wavelengths_m, pitch_m=pitch_m)
