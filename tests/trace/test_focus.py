"""Focus and brightness: traced fields reconstruct where T says (docs/design.md §3-4).

Dot-textured emitting planes (each dot focuses like a point) with one frame and no random phase: the
reconstruction is speckle-free and its sharpness (intensity concentration) peaks at the focus depth.
"""

from __future__ import annotations

import pytest

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions, render_loaded
from tests.trace.optics_probe import (
    best_focus,
    depth_of_field,
    dot_texture,
    fov_deg,
    intensity,
)
from tests.trace.scenes import T, camera, emitting_plane, scene

LAM = 516.5e-9
P = 4e-6
F_M = 0.025
H = W = 64


def optics(frames=1, **kw):
    return OpticsConfig(resolution_hw=(H, W), wavelengths_nm=(LAM * 1e9,), pitch_um=P * 1e6, frames=frames,
                        focal_length_mm=F_M * 1e3, **kw)


def cam():
    return camera(fov=fov_deg(W, P, F_M))


def z_holo(zc):
    return 0.08 + F_M * F_M / zc


def focus_of(res, z_expect, region=None):
    m = res.meta
    dof = depth_of_field(LAM, P)
    z, _ = best_focus(res.wrp_field, z_wrp=m["z_wrp_m"], z_center=z_expect, span=3 * dof, n=25, region=region,
                      wavelength_m=LAM, pitch_m=P, focal_length_m=F_M)
    return z, dof


@pytest.fixture(scope="module")
def dots(tmp_path_factory):
    return dot_texture(tmp_path_factory.mktemp("tex") / "dots.png")


@pytest.mark.slow
def test_plane_focuses_at_predicted_depth(dots):
    zc = 0.5
    res = render_loaded(scene(sensor=cam(), plane=emitting_plane(-zc, size=0.005, texture=dots)), optics(),
                        RenderOptions(preset="fast", spp=96))
    z, dof = focus_of(res, z_holo(zc))
    assert abs(z - z_holo(zc)) < 0.5 * dof, (z, z_holo(zc), dof)


@pytest.mark.slow
@pytest.mark.parametrize("wrp_planes", [1, 3])
def test_two_planes_focus_at_their_own_depths(dots, wrp_planes):
    near = emitting_plane(-0.4, size=0.004, texture=dots, x=-0.004)
    far = emitting_plane(-1.0, size=0.01, texture=dots, x=+0.01)
    res = render_loaded(scene(sensor=cam(), near=near, far=far), optics(),
                        RenderOptions(preset="fast", spp=256, wrp_planes=wrp_planes))
    assert len(res.meta["wrp_planes_m"]) == min(wrp_planes, 2)  # two depths: one plane in front of each
    left = (slice(8, H - 8), slice(4, W // 2 - 4))
    right = (slice(8, H - 8), slice(W // 2 + 4, W - 4))
    z_near, dof = focus_of(res, z_holo(0.4), region=left)
    z_far, _ = focus_of(res, z_holo(1.0), region=right)
    assert abs(z_near - z_holo(0.4)) < 0.5 * dof
    assert abs(z_far - z_holo(1.0)) < 0.5 * dof


# Brightness needs a converged estimate: the Monte Carlo noise power relative to the signal is about
# pi rho^2 / N (rho: sub-hologram radius in pixels, docs/physics.md), and image points need rho >= 3-4 px
# (the default 4-pixel WRP margin) for the random-phase correlation area to fit in their sub-hologram. At
# 8 um pitch, planes 1.0 and 1.5 mm below the WRP have rho = 4 and 6 px; N = 2048 keeps both biases < 6 %.
P_B = 8e-6
HB = WB = 32


def _bright_optics(frames=8, frame_phases="coded"):
    return OpticsConfig(resolution_hw=(HB, WB), wavelengths_nm=(LAM * 1e9,), pitch_um=P_B * 1e6, frames=frames,
                        focal_length_mm=F_M * 1e3, frame_phases=frame_phases)


def _mean_in(res, region, z):
    m = res.meta
    img = intensity(res.wrp_field, z_wrp=m["z_wrp_m"], z_focus=z, wavelength_m=LAM, pitch_m=P_B,
                    focal_length_m=F_M)
    return float(img[region].mean())


def _half_plane(zc: float, side: int, radiance: float = 1.0) -> dict:
    """An emitting plane at depth zc filling the left (side=-1) or right (+1) half of the view."""
    half = 0.01 * zc
    return {"type": "rectangle", "to_world": T().translate([side * half, 0, -zc]).scale([half, 2 * half, 1]),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": radiance}}}


LEFT = (slice(6, HB - 6), slice(4, WB // 2 - 4))
RIGHT = (slice(6, HB - 6), slice(WB // 2 + 4, WB - 4))


@pytest.mark.slow
@pytest.mark.parametrize("frame_phases", ["coded", "independent", "directional"])
@pytest.mark.parametrize("wrp_planes", [1, 3])
def test_equal_radiance_at_two_depths_is_equally_bright(wrp_planes, frame_phases):
    """Two half planes 0.5 mm apart, one plane in front of each with 3 planes: with directional frames each beam
    samples its points' spectrum 1-2 Fresnel zones from their plane at one frequency, where a hard rim rings
    (31 % apart before the rim taper and Eq. B2's per-ray factor)."""
    zc_far = F_M * F_M / (z_holo(0.5) - 0.08 - 0.5e-3)  # 0.5 mm farther in hologram space
    near = _half_plane(0.5, -1)
    far = _half_plane(zc_far, +1)
    res = render_loaded(scene(sensor=camera(fov=fov_deg(WB, P_B, F_M)), near=near, far=far),
                        _bright_optics(frame_phases=frame_phases),
                        RenderOptions(preset="fast", spp=2048, wrp_planes=wrp_planes))
    assert len(res.meta["wrp_planes_m"]) == min(wrp_planes, 2)  # two depths: one plane in front of each
    a = _mean_in(res, LEFT, z_holo(0.5))
    b = _mean_in(res, RIGHT, z_holo(zc_far))
    assert abs(a / b - 1) < 0.10, (a, b)


@pytest.mark.slow
def test_twice_the_radiance_gives_twice_the_intensity():
    dim = _half_plane(0.5, -1, radiance=1.0)
    bright = _half_plane(0.5, +1, radiance=2.0)
    res = render_loaded(scene(sensor=camera(fov=fov_deg(WB, P_B, F_M)), dim=dim, bright=bright), _bright_optics(),
                        RenderOptions(preset="fast", spp=512))
    a = _mean_in(res, LEFT, z_holo(0.5))
    b = _mean_in(res, RIGHT, z_holo(0.5))
    assert abs(b / a - 2) < 0.2, (a, b)
