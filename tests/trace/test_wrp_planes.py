"""Several wave recording planes (holocore.plan.wrp_planes): placement, the slabs, and the physics
(the same field as one plane, with Monte Carlo noise that falls as the squared distance to the plane)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions, render_loaded
from holocore.plan.wrp_planes import WrpPlanes, choose_planes, place_planes
from tests.trace.optics_probe import fov_deg
from tests.trace.scenes import T, camera, scene

MARGIN = 1.0e-3
Z_WRP = 0.092


def _slab_of(planes: WrpPlanes, z: float) -> list[int]:
    return [k for k in range(planes.count) if planes.slab(k)[0] < z <= planes.slab(k)[1]]


def test_planes_sit_one_margin_in_front_of_each_cluster_and_slabs_partition():
    depths = [0.0905] * 5 + [0.086] * 20 + [0.0815] * 40
    planes = place_planes(depths, z_wrp_m=Z_WRP, margin_m=MARGIN, count=3)
    assert planes.z_m[0] == Z_WRP
    assert planes.z_m[1:] == pytest.approx((0.087, 0.0825))
    for z in np.linspace(0.07, Z_WRP, 400):  # every depth is recorded by exactly one plane
        assert len(_slab_of(planes, float(z))) == 1
    for z in set(depths):  # ... the one just in front of it, at least one margin away
        (k,) = _slab_of(planes, z)
        assert planes.z_m[k] - z == pytest.approx(min(p - z for p in planes.z_m if p - z >= MARGIN * 0.999))
    assert planes.farthest_distance_m(depths) == pytest.approx(0.0015)  # the front cluster on the WRP


def test_more_planes_never_cost_more_and_extra_planes_are_dropped():
    depths = [0.0905] * 5 + [0.086] * 20 + [0.0815] * 40
    e = [sum(place_planes(depths, z_wrp_m=Z_WRP, margin_m=MARGIN, count=k).noise_energy(depths))
         for k in (1, 2, 3)]
    assert e[0] > e[1] > e[2]
    # the WRP and one plane a margin in front of each of the three depths; no more
    assert place_planes(depths, z_wrp_m=Z_WRP, margin_m=MARGIN, count=8).count == 4
    assert place_planes([], z_wrp_m=Z_WRP, margin_m=MARGIN, count=4).count == 1  # a black scene


def test_auto_takes_planes_for_depth_and_one_for_a_flat_scene():
    kw = dict(z_wrp_m=Z_WRP, margin_m=MARGIN)
    deep = choose_planes([0.0905] * 5 + [0.086] * 20 + [0.0815] * 40, **kw)
    flat = choose_planes([Z_WRP - MARGIN] * 30, **kw)
    assert deep.count >= 3 and flat.count == 1


def test_bad_plane_options_are_refused():
    with pytest.raises(ValueError, match="wrp_planes"):
        RenderOptions(wrp_planes=0)
    with pytest.raises(ValueError, match="wrp_planes"):
        RenderOptions(wrp_planes="three")
    with pytest.raises(ValueError, match="direct"):
        RenderOptions(method="direct", wrp_planes=3)
    with pytest.raises(ValueError, match="front to back"):
        WrpPlanes((0.08, 0.09), MARGIN)


# ---- physics: a glowing textured card far behind a near one -----------------------------------------
LAM = 516.5e-9
P = 8e-6
F_M = 0.05
H = W = 48


def _card(zc: float, x: float) -> dict:
    """An emitting card at depth zc covering the left (x = -1) or right (+1) half of the view (the random-phase
    bank makes it a rough surface)."""
    half = 0.25 * zc * W * P / F_M
    return {"type": "rectangle", "to_world": T().translate([x * half, 0, -zc]).scale([half, 2 * half, 1]),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}}


@pytest.fixture(scope="module")
def two_depths():
    # In hologram space (f = 50 mm) the near card lies 6.25 mm beyond z_inf, the far one 5 mm behind it.
    zc_near = 0.4
    zc_far = F_M * F_M / (F_M * F_M / zc_near - 5e-3)
    return scene(sensor=camera(fov=fov_deg(W, P, F_M)), near=_card(zc_near, -1), far=_card(zc_far, +1))


def _optics():
    return OpticsConfig(resolution_hw=(H, W), wavelengths_nm=(LAM * 1e9,), pitch_um=P * 1e6, frames=2,
                        focal_length_mm=F_M * 1e3)


def _two_estimates(sc, planes: int, spp: int):
    # The recording planes' own estimates: the cone equaliser (holocore.optics.cone_equaliser) filters each
    # plane afterwards, differently with one plane and several (pixel averages), and is tested on its own.
    out = [render_loaded(sc, _optics(), RenderOptions(preset="fast", spp=spp, wrp_planes=planes, ray_seed=s,
                                                      cone_equaliser=False))
           for s in (1, 2)]
    return [r.wrp_field.astype(np.complex128) for r in out], out[0].meta


@pytest.mark.slow
def test_two_planes_estimate_the_same_field_with_far_less_noise(two_depths):
    """Noise energy per ray grows as r^2 (docs/design.md §4): recording the far card 1 mm instead of 6 mm from its
    plane cuts its noise about 36x; the means of the one- and two-plane estimates are the same field."""
    (a1, b1), m1 = _two_estimates(two_depths, 1, 256)
    (a2, b2), m2 = _two_estimates(two_depths, 2, 256)
    assert len(m1["wrp_planes_m"]) == 1 and len(m2["wrp_planes_m"]) == 2
    assert m2["wrp_planes_m"][1] < m2["z_wrp_m"] - 3e-3  # a plane in front of the far card
    noise1 = np.sum(np.abs(a1 - b1) ** 2) / 2
    noise2 = np.sum(np.abs(a2 - b2) ** 2) / 2
    s1 = np.real(np.vdot(a1, b1))
    s2 = np.real(np.vdot(a2, b2))
    # The same rays (one trace from the WRP feeds both planes): the far card's noise falls by (6 / 1)^2, the
    # near card's stays (both halves of the view hold the same light), so the total falls well over 8x.
    assert m2["stats"]["rays"] == m1["stats"]["rays"]
    assert noise2 < noise1 / 8, (noise1, noise2)
    assert s2 == pytest.approx(s1, rel=0.25)  # the same signal energy
    # the same field: the correlation of the two means, corrected for their remaining noise
    m1_, m2_ = (a1 + b1) / 2, (a2 + b2) / 2
    corr = np.real(np.vdot(m1_, m2_)) / math.sqrt(s1 * s2)
    assert corr > 0.85, corr
    assert np.all(np.isfinite(a2)) and np.all(np.isfinite(b2))
