"""``lab_repeat``: every frame shows frame 0's independent random phases, so all frames of a render are the
same field (a mode no built-in gives, which a test can see)."""

from __future__ import annotations

from holocore.trace.frame_phases import FramePhases, IndependentPhases


class RepeatedPhases(FramePhases):
    name = "lab_repeat"
    summary = "frame 0's random phases in every frame (a lab's plug-in)"
    stereogram_coded = False

    def lateral_phases(self, frames, shape_hw, wavelength_m, *, pitch_m, wavelengths_m, seed, first_frame=0,
                       bank_frames=None):
        first = next(iter(IndependentPhases().lateral_phases(1, shape_hw, wavelength_m, pitch_m=pitch_m,
                                                             wavelengths_m=wavelengths_m, seed=seed)))
        for _ in range(frames):
            yield first.copy()
