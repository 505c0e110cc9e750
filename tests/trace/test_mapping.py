"""The world-to-hologram map T (docs/design.md §3, paper Eq. 3; holocore.trace.mapping): the worked example of docs/design.md §3,
straight rays stay straight, T^-1 T = identity, Mitsuba's mirrored camera x, and the Dr.Jit kernel's use of the
same formulas."""

from __future__ import annotations

import numpy as np
import pytest

from holocore.trace.mapping import HologramMap, camera_to_holo_xyz, holo_to_camera_xyz

F, Z_INF = 0.05, 0.08


def _look_at(origin, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Mitsuba's look_at to_world: camera +z towards the target, +y up, +x = up x forward (the image's left)."""
    o, t, u = (np.asarray(v, dtype=np.float64) for v in (origin, target, up))
    d = (t - o) / np.linalg.norm(t - o)
    left = np.cross(u, d)
    left /= np.linalg.norm(left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, np.cross(d, left), d, o
    return m


@pytest.fixture
def hmap() -> HologramMap:
    return HologramMap(cam_to_world=_look_at((0.3, -0.2, 1.0), (0.5, 0.1, -3.0)), focal_length_m=F, z_inf_m=Z_INF)


def test_design_worked_example_depths():
    # f = 50 mm: 10 m at z_inf + 0.25 mm, 0.9 m at + 2.78 mm, 0.5 m at + 5 mm (docs/design.md §3)
    for zc, dz in ((10.0, 0.25e-3), (0.9, 2.0 / 0.9 * 1.25e-3), (0.5, 5e-3)):
        x, y, z = camera_to_holo_xyz(0.0, 0.0, zc, f=F, z_inf=Z_INF)
        assert (x, y) == (0.0, 0.0) and z == pytest.approx(Z_INF + dz, rel=1e-12)
    # laterally linear in the tangent of the view angle: 1 degree right at any depth is f tan(1 deg)
    t = np.tan(np.radians(1.0))
    for zc in (0.5, 2.0, 10.0):
        assert camera_to_holo_xyz(t * zc, 0.0, zc, f=F, z_inf=Z_INF)[0] == pytest.approx(F * t, rel=1e-12)


def test_inverse_is_exact(hmap):
    rng = np.random.default_rng(0)
    c = np.stack([rng.uniform(-1, 1, 500), rng.uniform(-1, 1, 500), rng.uniform(0.1, 50.0, 500)], axis=1)
    np.testing.assert_allclose(hmap.holo_to_camera(hmap.camera_to_holo(c)), c, rtol=1e-12, atol=1e-14)
    p = hmap.camera_to_world(c)
    np.testing.assert_allclose(hmap.world_to_camera(p), c, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(hmap.world_to_holo(p), hmap.camera_to_holo(c), rtol=1e-12, atol=1e-15)


def test_straight_rays_stay_straight(hmap):
    # three points on a world line in front of the eye map to three collinear hologram points, and a hologram
    # ray maps back (holo_rays_to_camera) to the camera ray through them
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(0.3, 1.0)])
        b = a + np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(0.5, 5.0)])
        pts = np.stack([a, 0.3 * a + 0.7 * b, b])
        q = hmap.camera_to_holo(pts)
        cross = np.cross(q[1] - q[0], q[2] - q[0])
        assert np.linalg.norm(cross) < 1e-12 * np.linalg.norm(q[1] - q[0]) * np.linalg.norm(q[2] - q[0]) + 1e-22
        u = (q[2] - q[0]) / np.linalg.norm(q[2] - q[0])
        c0, v = hmap.holo_rays_to_camera(q[:1], u[None], z_mid=0.5 * (q[0, 2] + Z_INF))
        np.testing.assert_allclose(c0[0], a, rtol=1e-10)
        np.testing.assert_allclose(v[0], (b - a) / np.linalg.norm(b - a), atol=1e-9)


def test_camera_x_is_mirrored_from_mitsubas():
    # Mitsuba's camera +x points to the image's left; xc (and hologram x) to its right (docs/design.md §3)
    hm = HologramMap(cam_to_world=_look_at((0, 0, 0), (0, 0, -1)), focal_length_m=F, z_inf_m=Z_INF)
    right_of_view = np.array([[0.1, 0.0, -1.0]])  # world +x, seen from a camera looking down -z
    assert hm.world_to_holo(right_of_view)[0, 0] > 0
    np.testing.assert_allclose(hm.rotation @ hm.rotation_inv, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(hm.origin, 0.0)


def test_the_kernel_uses_the_same_formulas():
    # the tracer evaluates T on Dr.Jit float64 arrays through the same two functions
    from holocore.runtime.mitsuba_env import mitsuba

    mi = mitsuba()
    zc = np.array([0.2, 0.9, 10.0, 1e4])
    xc, yc = 0.1 * zc, -0.05 * zc
    got = camera_to_holo_xyz(mi.Float64(xc), mi.Float64(yc), mi.Float64(zc), f=F, z_inf=Z_INF)
    want = camera_to_holo_xyz(xc, yc, zc, f=F, z_inf=Z_INF)
    for g, w in zip(got, want):
        np.testing.assert_allclose(np.asarray(g), w, rtol=1e-15)
    back = holo_to_camera_xyz(*got, f=F, z_inf=Z_INF)
    np.testing.assert_allclose(np.asarray(back[2]), zc, rtol=1e-9)
