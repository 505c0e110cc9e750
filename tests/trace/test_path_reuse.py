"""Path reuse across frames (paper Sec. 4.3, docs/design.md §4): frames share every traced quantity but the
random phase, have equal mean intensity, uncorrelated random parts, and the same seed gives the same result."""

from __future__ import annotations

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions, render_loaded
from tests.trace.scenes import T, camera, scene

OPT = OpticsConfig(resolution_hw=(40, 40), wavelengths_nm=(516.5,), focal_length_mm=20.0, frames=6, seed=3)


def _scene():
    light = {"type": "rectangle", "to_world": T().translate([0, 1, -0.5]).rotate([1, 0, 0], 90).scale(0.5),
             "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 5.0}}}
    wall = {"type": "rectangle", "to_world": T().translate([0, 0, -0.6]).scale(0.5),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.8}}}
    return scene(sensor=camera(fov=3), wall=wall, light=light)


@pytest.fixture(scope="module")
def result():
    return render_loaded(_scene(), OPT, RenderOptions(preset="balanced", spp=16))


@pytest.mark.slow
def test_frames_have_equal_mean_intensity(result):
    inten = (np.abs(result.wrp_field[:, 0]) ** 2).mean(axis=(1, 2))
    assert np.all(inten > 0)
    assert inten.std() / inten.mean() < 0.1, inten


def test_frames_are_uncorrelated(result):
    u = result.wrp_field[:, 0].reshape(OPT.frames, -1)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    corr = np.abs(u.conj() @ u.T)
    off = corr[~np.eye(OPT.frames, dtype=bool)]
    # |<u_a, u_b>| for independent random phasors over N effective cells is ~1/sqrt(N)
    assert off.max() < 0.15, off.max()


def test_same_seed_same_result(result):
    again = render_loaded(_scene(), OPT, RenderOptions(preset="balanced", spp=16))
    np.testing.assert_array_equal(again.wrp_field, result.wrp_field)
    other = render_loaded(_scene(), OPT.model_copy(update={"seed": 4}), RenderOptions(preset="balanced", spp=16))
    assert not np.array_equal(other.wrp_field, result.wrp_field)


def test_frames_share_the_traced_paths():
    """Feed a bank whose frame m is frame 0 times exp(i m alpha): if every frame reuses the same paths and only
    the random phase differs, U_m = U_0 exp(i m alpha) exactly."""
    import math

    import torch

    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.trace.hologram_rays import RecordingGrid, TraceSettings, trace_field
    from holocore.trace.mapping import HologramMap

    loaded = _scene()
    H, W = OPT.resolution_hw
    hmap = HologramMap.from_sensor(loaded.sensor, focal_length_m=0.02, z_inf_m=0.08)
    rng = np.random.default_rng(0)
    base = np.exp(2j * np.pi * rng.random((H, W)))
    alpha = 0.7
    bank = torch.from_numpy(np.stack([base * np.exp(1j * m * alpha) for m in range(4)]).astype(np.complex64))
    z_wrp = float(hmap.holo_depth_m(0.4))
    grid = RecordingGrid(wavelengths_m=(516.5e-9,), pitch_m=8e-6, shape_hw=(H, W), plane_z_m=z_wrp, z_wrp_m=z_wrp)
    u = trace_field(loaded.scene, hmap, grid, frames=4, settings=TraceSettings(spp=8), integrator=mitsuba().load_dict(
                        {"type": "path", "max_depth": 2}), seed=1, bank_phasors=[bank])
    assert np.abs(u[0]).max() > 0
    for m in range(1, 4):
        np.testing.assert_allclose(u[m], u[0] * np.exp(1j * m * alpha), rtol=0, atol=2e-5 * np.abs(u[0]).max())
    assert math.isfinite(float(np.abs(u).sum()))
