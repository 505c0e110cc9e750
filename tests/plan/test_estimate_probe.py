"""The probe-based estimate (holocore.plan.estimate_probe): its arithmetic, and a real probe of a project scene."""

from __future__ import annotations

import pytest

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions
from holocore.calibration import probe_scene
from holocore.plan.estimate_probe import Probe, estimate_with_probe, process_age_s


def test_prediction_adds_start_up_compile_and_the_scenes_own_ray_cost():
    optics = OpticsConfig(resolution_hw=(100, 200), frames=1)
    opts = RenderOptions(preset="fast", spp=8)
    slow = estimate_with_probe(optics, opts, Probe(startup_s=3.0, compile_s=2.0, ray_color_s=1e-6, probe_s=1.0),
                               scene_primitives=10, subhologram_radius_px=5.0)
    fast = estimate_with_probe(optics, opts, Probe(startup_s=3.0, compile_s=2.0, ray_color_s=5e-7, probe_s=1.0),
                               scene_primitives=10, subhologram_radius_px=5.0)
    rays_colors = 100 * 200 * 8 * 3
    assert slow["trace"] - fast["trace"] == pytest.approx(5e-7 * rays_colors, rel=1e-9)
    assert slow["startup"] == 3.0 and slow["compile"] == 2.0
    parts = sum(v for k, v in slow.items() if k != "total")
    assert slow["total"] == pytest.approx(parts, rel=1e-12) and slow["total"] > 5.0 + 1e-6 * rays_colors
    double = estimate_with_probe(optics.model_copy(update={"resolution_hw": (200, 200)}), opts,
                                 Probe(startup_s=3.0, compile_s=2.0, ray_color_s=1e-6, probe_s=1.0),
                                 scene_primitives=10, subhologram_radius_px=5.0)
    assert double["trace"] > 1.9 * slow["trace"] - 1.0  # twice the rays (up to the per-tile term)


@pytest.mark.slow
def test_a_real_probe_measures_positive_costs(tmp_path):
    from holocore.scene.demo import write_demo_scene
    from holocore.scene.load import load_scene

    write_demo_scene(tmp_path / "scene")
    loaded = load_scene(tmp_path / "scene")
    probe = probe_scene(loaded, OpticsConfig(frames=4), RenderOptions(preset="fast", spp=4),
                        startup_s=process_age_s())
    assert probe.ray_color_s > 0 and probe.compile_s >= 0 and probe.startup_s > 0 and probe.probe_s > 0
    # on a machine busy with other work the probe's seconds are brought back to an idle machine's: the estimate
    # multiplies by the load once, at submit
    import os
    import time

    from holocore.plan import estimate

    try:
        estimate._SAMPLED.update(at=time.monotonic() + 3600, value=4.0 * (os.cpu_count() or 1))  # 5x slower
        loaded_probe = probe_scene(loaded, OpticsConfig(frames=4), RenderOptions(preset="fast", spp=4), startup_s=5.0)
    finally:
        estimate._SAMPLED.clear()
    assert loaded_probe.load_slowdown == 5.0 and loaded_probe.startup_s == 1.0
    assert 0 < loaded_probe.ray_color_s and loaded_probe.probe_s > 0
