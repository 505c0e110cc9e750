"""Depth through mirrors and glass (docs/design.md §4, docs/physics.md): images focus at the virtual
image depth, not at the delta surface, and not at the unfolded optical path."""

from __future__ import annotations

import pytest

from holocore.pipeline import RenderOptions, render_loaded
from tests.trace.optics_probe import dot_texture
from tests.trace.scenes import T, emitting_plane, scene
from tests.trace.test_focus import cam, focus_of, optics, z_holo


@pytest.fixture(scope="module")
def dots(tmp_path_factory):
    return dot_texture(tmp_path_factory.mktemp("tex") / "dots.png")


def _emitter(texture: str, to_world) -> dict:
    return {"type": "rectangle", "to_world": to_world,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
            "emitter": {"type": "area", "radiance": {"type": "bitmap", "filename": texture}}}


@pytest.mark.slow
def test_flat_mirror_focuses_at_the_virtual_image(dots):
    # Mirror 0.4 m ahead turned 45 deg: the view goes to +x, where a dot plane faces it 0.1 m away.
    mirror = {"type": "rectangle", "to_world": T().translate([0, 0, -0.4]).rotate([0, 1, 0], 45).scale(0.05),
              "bsdf": {"type": "conductor"}}
    plane = _emitter(dots, T().translate([0.1, 0, -0.4]).rotate([0, 1, 0], -90).scale(0.005))
    res = render_loaded(scene(sensor=cam(), mirror=mirror, plane=plane), optics(),
                        RenderOptions(preset="fast", spp=256))
    assert res.meta["plan"]["coherent_delta"]
    z, dof = focus_of(res, z_holo(0.5))
    assert abs(z - z_holo(0.5)) < 0.5 * dof, (z, z_holo(0.5), dof)
    assert abs(z - z_holo(0.4)) > 1.5 * dof  # not at the mirror


@pytest.mark.slow
def test_convex_mirror_sphere_obeys_the_mirror_equation(dots):
    # Sphere radius 0.2 m centred 0.5 m ahead (vertex at 0.3 m); dot plane 0.5 m behind the eye facing it.
    radius, vertex, d_obj = 0.2, 0.3, 0.8
    f_mirror = -radius / 2
    d_img = 1.0 / (1.0 / f_mirror - 1.0 / d_obj)  # negative: virtual, behind the mirror
    zc_image = vertex - d_img
    sphere = {"type": "sphere", "center": [0, 0, -0.5], "radius": radius, "bsdf": {"type": "conductor"}}
    plane = _emitter(dots, T().translate([0, 0, 0.5]).rotate([0, 1, 0], 180).scale(0.036))
    res = render_loaded(scene(sensor=cam(), sphere=sphere, plane=plane), optics(),
                        RenderOptions(preset="fast", spp=128))
    z, dof = focus_of(res, z_holo(zc_image))
    assert abs(z - z_holo(zc_image)) < 0.5 * dof, (z, z_holo(zc_image), dof)
    assert abs(z - z_holo(vertex + d_obj)) > 2 * dof  # not at the unfolded path length


@pytest.mark.slow
def test_glass_slab_brings_the_image_closer(dots):
    t, n, zc = 0.15, 1.5, 0.5
    slab = {"type": "cube", "to_world": T().translate([0, 0, -0.375]).scale([0.05, 0.05, t / 2]),
            "bsdf": {"type": "dielectric", "int_ior": n, "ext_ior": 1.0}}
    plane = emitting_plane(-zc, size=0.005, texture=dots)
    res = render_loaded(scene(sensor=cam(), slab=slab, plane=plane), optics(), RenderOptions(preset="fast", spp=256))
    expect = z_holo(zc - t * (1 - 1 / n))
    z, dof = focus_of(res, expect)
    assert abs(z - expect) < 0.5 * dof, (z, expect, dof)
    # the shift t(1 - 1/n) is 1.1 depths of field here: the image is measurably closer than without the slab
    assert z - z_holo(zc) > 0.5 * dof


def _signal_and_noise(loaded, optics_, spp: int):
    """(signal, noise) power of the WRP field from two independent ray seeds: Re<U1, U2> is an unbiased
    estimate of |E U|^2, and |U1 - U2|^2 / 2 of the Monte Carlo noise."""
    import numpy as np

    f = [render_loaded(loaded, optics_, RenderOptions(preset="balanced", spp=spp, wrp_planes=1, ray_seed=seed))
         .wrp_field.astype(np.complex128) for seed in (11, 12)]
    return float(np.real(np.vdot(f[0], f[1]))), float(np.sum(np.abs(f[0] - f[1]) ** 2) / 2)


@pytest.mark.slow
def test_rays_through_a_glass_ball_add_up_coherently(tmp_path):
    # The paper's glass scene (a ball imaging a dotted card into the air in front of it, 0.72 m) at the paper
    # display with virtual infinity at 4 mm. The rays of one card point reach the WRP through different parts
    # of the ball, where their apparent distances differ by ~0.4 % (a piston of tens of radians in k r): unless
    # each point keeps one depth, its sub-hologram decorrelates. Measured before the fix: noise 157x the
    # signal, against the plan's ~1x; after it, 0.5x, as for a card seen directly.
    from holocore.display.profiles import PAPER
    from holocore.scene.load import load_scene
    from holocore.scene.paper import write_paper_scene

    loaded = load_scene(write_paper_scene("glass", tmp_path / "glass"))
    opt = PAPER.optics(resolution_hw=(64, 96), frames=2, z_inf_mm=4.0)
    signal, noise = _signal_and_noise(loaded, opt, 256)
    plan = render_loaded(loaded, opt, RenderOptions(preset="balanced", spp=256, wrp_planes=1)).meta["plan"]
    assert plan["coherent_delta"]
    assert signal > 0 and noise / signal < 2.0 * max(1.0, plan["noise_to_signal"]), (noise / signal, plan)
