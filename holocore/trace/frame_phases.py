"""The project's frame-phase modes (the interface and registry: :mod:`holocore.display.phase_modes`, which
finds these by their entry points in pyproject.toml, as it finds a lab's): ``coded`` (the default;
:mod:`holocore.trace.randomfield`, docs/physics.md "Coded frame phases"), ``independent`` (the paper's Eq. 4) and
``directional`` (:mod:`holocore.trace.beams`). Each imports its numerics inside its methods, so that finding the
modes (the API process validates optics against their names) stays light.
"""

from __future__ import annotations

from holocore.display.phase_modes import FramePhases, frame_phase_modes, get_frame_phases, register_frame_phases

__all__ = ["FramePhases", "register_frame_phases", "frame_phase_modes", "get_frame_phases", "CodedPhases",
           "IndependentPhases", "DirectionalPhases"]


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
