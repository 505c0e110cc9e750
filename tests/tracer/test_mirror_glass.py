"""Depth through mirrors and glass (issue 3; DESIGN.md §4, docs/physics.md): images focus at the virtual
image depth, not at the delta surface, and not at the unfolded optical path."""

from __future__ import annotations

import pytest

from holocore.pipeline import RenderOptions, render_loaded
from tests.tracer.optics_probe import dot_texture
from tests.tracer.scenes import T, emitting_plane, scene
from tests.tracer.test_focus import cam, focus_of, optics, z_holo


@pytest.fixture(scope="module")
def dots(tmp_path_factory):
    return dot_texture(tmp_path_factory.mktemp("tex") / "dots.png")


def _emitter(texture: str, to_world) -> dict:
    return {"type": "rectangle", "to_world": to_world,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
            "emitter": {"type": "area", "radiance": {"type": "bitmap", "filename": texture}}}


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
