"""Frame-phase modes behind one interface (holocore.trace.frame_phases): the registry is what the optics accept,
each built-in gives the banks its own module defines, and a new mode is one class that the renderer and the layer
baseline take without any other change."""

from __future__ import annotations

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.trace.frame_phases import FramePhases, frame_phase_modes, get_frame_phases, register_frame_phases

LAMS = (640e-9, 516.5e-9, 455.4e-9)


def test_the_optics_accept_exactly_the_registered_modes():
    assert frame_phase_modes()[:3] == ("coded", "independent", "directional")
    for name in frame_phase_modes():
        assert OpticsConfig(frame_phases=name).frame_phase_mode() is get_frame_phases(name)
    with pytest.raises(ValueError, match="unknown frame phases 'speckle'.*coded, independent, directional"):
        OpticsConfig(frame_phases="speckle")
    with pytest.raises(ValueError, match="already registered"):
        @register_frame_phases
        class Again(FramePhases):
            name = "coded"


def test_each_built_in_mode_gives_its_own_module_bank():
    from holocore.pipeline import frame_banks
    from holocore.trace.beams import beam_gain, beam_phase_frames
    from holocore.trace.randomfield import phase_frames

    shape, F = (12, 20), 6
    want = {
        "coded": lambda lam: (1.0, phase_frames(F, shape, lam, 8e-6, seed=3, coded_frames=F)),
        "independent": lambda lam: (1.0, phase_frames(F, shape, lam, 8e-6, seed=3)),
        "directional": lambda lam: (beam_gain(lam, 8e-6, LAMS), beam_phase_frames(F, shape, lam, 8e-6,
                                                                                  wavelengths_m=LAMS)),
    }
    for name, ref in want.items():
        optics = OpticsConfig(resolution_hw=shape, frames=F, seed=3, frame_phases=name)
        banks = frame_banks(optics, shape)
        for c, lam in enumerate(LAMS):
            gain, maps = ref(lam)
            expect = gain * np.exp(1j * np.stack(list(maps)).astype(np.float32))
            assert np.allclose(banks[c].numpy(), expect, atol=1e-6), name
    # coded frames cancel the cross term of two nearby cells in the frame average, independent ones do not
    coded = frame_banks(OpticsConfig(resolution_hw=(24, 24), frames=24, frame_phases="coded"), (24, 24))[0].numpy()
    cross = np.abs((coded[:, 5, 5] * np.conj(coded[:, 5, 6])).mean())
    assert cross < 1e-5


@pytest.fixture
def scratch_registry():
    from holocore.display import phase_modes as registry

    before = dict(registry._REGISTRY)
    yield
    registry._REGISTRY.clear()
    registry._REGISTRY.update(before)


def test_a_new_mode_is_one_class(scratch_registry):
    """A mode that gives every frame the same flat phase: frames identical, the plate's field a plane wave."""

    @register_frame_phases
    class Flat(FramePhases):
        name = "flat_for_test"
        summary = "every frame phase 0"

        def lateral_phases(self, frames, shape_hw, wavelength_m, *, pitch_m, wavelengths_m, seed, first_frame=0,
                           bank_frames=None):
            return (np.zeros(shape_hw, dtype=np.float32) for _ in range(frames))

    from holocore.baselines.layers import layer_fields
    from holocore.display.profiles import PAPER
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.paper import paper_fov_x_deg
    from tests.trace.scenes import camera, emitting_plane, scene

    loaded = scene(sensor=camera(fov=paper_fov_x_deg()), plate=emitting_plane(-0.5, size=0.2))
    opt = PAPER.optics(resolution_hw=(32, 48), frames=3, z_inf_mm=4.0, frame_phases="flat_for_test")
    res = render_loaded(loaded, opt, RenderOptions(preset="balanced", spp=16, wrp_planes=1), display=PAPER)
    slm = np.asarray(res.slm_field)
    assert np.isfinite(slm).all() and np.abs(slm).max() > 0
    assert np.array_equal(slm[0], slm[1]) and np.array_equal(slm[0], slm[2])  # the same phases, the same rays
    assert res.meta["optics"]["frame_phases"] == "flat_for_test"
    _, wrp, _, _ = layer_fields(np.ones((3, 32, 48)), np.full((32, 48), 0.5), focal_length_m=0.05, z_inf_m=4e-3,
                                z_wrp_m=4e-3 + 0.05 ** 2 / 0.5 + 1e-3, pitch_m=8e-6, wavelengths_m=LAMS, frames=2,
                                planes=1, frame_phases="flat_for_test")
    core = wrp[0, 0, 12:20, 18:30]  # a flat plate, flat phases: a plane wave along the axis in the middle
    assert np.abs(np.angle(core / core.mean())).max() < 0.05
