"""The near-smooth lobe's spread on the recording plane (holocore.plan.effects.lobe_spread_px) and the plan's noise
estimate that uses it; its agreement with measured glow is tests/trace/test_far_image_parallax.py's."""

from __future__ import annotations

import math

import pytest

from holocore.plan.effects import SceneInventory, lobe_spread_px, make_plan, noise_factor

KW = dict(focal_length_m=0.05, pitch_m=8e-6)


def test_spread_is_the_tilt_magnified_over_the_depth_between_surface_and_image():
    """2 alpha f (1 - z_s / z_i) / p: a plate 0.5 m away showing a point 1.5 m away, at f 50 mm and 8 um pitch,
    spreads by 8333 alpha px; linear in alpha, bounded by 2 alpha f / p for a point at infinity, and zero without
    a near-smooth surface, without depths, or with the image in front of the surface."""
    assert lobe_spread_px([0.001], zc_surface_m=0.5, zc_image_m=1.5, **KW) == pytest.approx(8.333, rel=1e-3)
    assert lobe_spread_px([0.003, 0.001], zc_surface_m=0.5, zc_image_m=1.5, **KW) == pytest.approx(25.0, rel=1e-3)
    assert lobe_spread_px([0.001], zc_surface_m=0.5, zc_image_m=1e9, **KW) == pytest.approx(12.5, rel=1e-6)
    for alphas, zs, zi in (([], 0.5, 1.5), ([0.01], None, 1.5), ([0.01], 0.5, None), ([0.01], 1.5, 0.5)):
        assert lobe_spread_px(alphas, zc_surface_m=zs, zc_image_m=zi, **KW) == 0.0


def test_the_plan_noise_uses_the_widened_sub_hologram():
    """noise = k(theta) (rho^2 + spread^2) / N, and the auto ray count grows with it up to the preset's cap."""
    inv = SceneInventory(shapes=1, primitives=1, near_smooth={"plate": 0.001})
    smooth = make_plan(inv, preset="balanced", frames=1, n_colors=3, spp=256, subhologram_radius_px=5.6,
                       theta_max=0.04)
    rough = make_plan(inv, preset="balanced", frames=1, n_colors=3, spp=256, subhologram_radius_px=5.6,
                      theta_max=0.04, lobe_spread_px=8.33)
    assert smooth.noise_to_signal == pytest.approx(noise_factor(0.04) * 5.6 ** 2 / 256)
    assert rough.noise_to_signal == pytest.approx(noise_factor(0.04) * (5.6 ** 2 + 8.33 ** 2) / 256)
    assert any("with the near-smooth lobes' spread" in w for w in rough.summary)
    auto = [make_plan(inv, preset="balanced", frames=1, n_colors=3, subhologram_radius_px=5.6, theta_max=0.04,
                      lobe_spread_px=s).spp for s in (0.0, 8.33, 1e4)]
    assert auto[0] < auto[1] < auto[2] == 512 and math.isfinite(rough.noise_to_signal)
