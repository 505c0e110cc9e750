"""The world-to-hologram map T (paper Eq. 3, docs/design.md §3 Eq. D2), in float64.

Eye-camera coordinates (xc right, yc up, zc > 0 forward) come from the scene's perspective sensor; Mitsuba's
camera frame has +x towards the image's left, so xc = -x_camera. A point maps to hologram space as

    x = f xc / zc,   y = f yc / zc,   z = z_inf + f^2 / zc        (docs/design.md §3)

The map is projective, so straight rays stay straight: a hologram ray maps to a world ray through two points.

The formulas are written once, in :func:`camera_to_holo_xyz` and :func:`holo_to_camera_xyz`, on plain arithmetic:
the numpy methods of :class:`HologramMap` and the tracer's Dr.Jit kernel (float64 arrays) call the same two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HologramMap", "camera_to_holo_xyz", "holo_to_camera_xyz", "camera_grid"]

_FLIP_X = np.diag([-1.0, 1.0, 1.0])


def camera_to_holo_xyz(xc, yc, zc, *, f, z_inf):
    """T (docs/design.md §3, paper Eq. 3): eye-camera (xc, yc, zc > 0) -> hologram (x, y, z), metres. Works on floats,
    numpy arrays and Dr.Jit arrays alike (only +, *, /)."""
    return f * xc / zc, f * yc / zc, z_inf + f * f / zc


def holo_to_camera_xyz(x, y, z, *, f, z_inf):
    """T^-1: hologram (x, y, z > z_inf) -> eye-camera (xc, yc, zc), metres; as :func:`camera_to_holo_xyz`."""
    zc = f * f / (z - z_inf)
    return x * zc / f, y * zc / f, zc


@dataclass(frozen=True)
class HologramMap:
    """T for one sensor pose. ``cam_to_world`` is the sensor's 4x4 to_world matrix (Mitsuba convention).

    ``scene_scale`` s places the scene as if scaled by s about the eye (docs/design.md §3, "Scene scale"): eye-camera
    coordinates are s times the world's offsets from the eye, so hologram depth goes as 1 / s and the view is
    unchanged. The world (and what Mitsuba renders in it) stays as modelled: only the map knows s. A world length
    along a ray is s times as long in the eye-camera frame (:meth:`camera_length`)."""

    cam_to_world: np.ndarray
    focal_length_m: float
    z_inf_m: float
    scene_scale: float = 1.0

    def __post_init__(self) -> None:
        m = np.asarray(self.cam_to_world, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise ValueError(f"cam_to_world must be a finite 4x4 matrix, got shape {m.shape}")
        if not (np.isfinite(self.focal_length_m) and self.focal_length_m > 0):
            raise ValueError(f"focal_length_m must be finite and > 0, got {self.focal_length_m}")
        if not (np.isfinite(self.z_inf_m) and self.z_inf_m > 0):
            raise ValueError(f"z_inf_m must be finite and > 0, got {self.z_inf_m}")
        s = float(self.scene_scale)
        if not (np.isfinite(s) and s > 0):
            raise ValueError(f"scene_scale must be finite and > 0, got {self.scene_scale}")
        rot = m[:3, :3]
        # A sensor's pose is a rotation (Mitsuba refuses scaled cameras); inverted in general all the same.
        object.__setattr__(self, "cam_to_world", m)
        object.__setattr__(self, "_rot", rot @ _FLIP_X / s)  # eye-camera (xc right) -> world, linear part
        object.__setattr__(self, "_rot_inv", np.linalg.inv(rot @ _FLIP_X) * s)
        object.__setattr__(self, "_origin", m[:3, 3].copy())

    @property
    def rotation(self) -> np.ndarray:
        """Eye-camera (xc right, yc up, zc forward) -> world directions, 3x3 (a copy)."""
        return self._rot.copy()

    @property
    def rotation_inv(self) -> np.ndarray:
        """World -> eye-camera directions, 3x3 (a copy)."""
        return self._rot_inv.copy()

    @property
    def origin(self) -> np.ndarray:
        """The eye (the sensor's position) in world coordinates, m (a copy)."""
        return self._origin.copy()

    @classmethod
    def from_sensor(cls, sensor, *, focal_length_m: float, z_inf_m: float, scene_scale: float = 1.0) -> "HologramMap":
        """Build T from a Mitsuba sensor (its to_world transform)."""
        mat = np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        return cls(cam_to_world=mat, focal_length_m=focal_length_m, z_inf_m=z_inf_m, scene_scale=scene_scale)

    def camera_length(self, world_m):
        """A world length (m) as a length in the eye-camera frame: s times it (``scene_scale``)."""
        return world_m * self.scene_scale

    # ---- eye-camera frame -----------------------------------------------------------------------------
    def world_to_camera(self, p: np.ndarray) -> np.ndarray:
        """World points [..., 3] -> eye-camera (xc, yc, zc) [..., 3]."""
        return (np.asarray(p, dtype=np.float64) - self._origin) @ self._rot_inv.T

    def camera_to_world(self, c: np.ndarray) -> np.ndarray:
        return np.asarray(c, dtype=np.float64) @ self._rot.T + self._origin

    def camera_dir_to_world(self, v: np.ndarray) -> np.ndarray:
        w = np.asarray(v, dtype=np.float64) @ self._rot.T
        return w / np.linalg.norm(w, axis=-1, keepdims=True)

    # ---- T and its inverse ----------------------------------------------------------------------------
    def camera_to_holo(self, c: np.ndarray) -> np.ndarray:
        """Eye-camera points (zc > 0) -> hologram points [..., 3] (docs/design.md §3)."""
        c = np.asarray(c, dtype=np.float64)
        return np.stack(camera_to_holo_xyz(c[..., 0], c[..., 1], c[..., 2], f=self.focal_length_m, z_inf=self.z_inf_m),
                        axis=-1)

    def holo_to_camera(self, q: np.ndarray) -> np.ndarray:
        """Hologram points with z > z_inf -> eye-camera points."""
        q = np.asarray(q, dtype=np.float64)
        return np.stack(holo_to_camera_xyz(q[..., 0], q[..., 1], q[..., 2], f=self.focal_length_m, z_inf=self.z_inf_m),
                        axis=-1)

    def world_to_holo(self, p: np.ndarray) -> np.ndarray:
        return self.camera_to_holo(self.world_to_camera(p))

    def holo_depth_m(self, zc: np.ndarray | float) -> np.ndarray:
        """Hologram z of eye-camera depth zc (m)."""
        return camera_to_holo_xyz(0.0, 0.0, np.asarray(zc, dtype=np.float64), f=self.focal_length_m,
                                  z_inf=self.z_inf_m)[2]

    def holo_rays_to_camera(self, x: np.ndarray, u: np.ndarray, *, z_mid: float) -> tuple[np.ndarray, np.ndarray]:
        """Hologram rays (points x on a plane z > z_inf, unit directions u towards -z) -> eye-camera rays.

        The second point is taken where the hologram ray reaches ``z_mid`` (z_inf < z_mid < z of x); the
        camera-frame origin is T^-1 x and the direction is the unit vector to T^-1 of that second point.
        """
        x = np.asarray(x, dtype=np.float64)
        u = np.asarray(u, dtype=np.float64)
        t = (z_mid - x[..., 2]) / u[..., 2]
        c0 = self.holo_to_camera(x)
        c1 = self.holo_to_camera(x + t[..., None] * u)
        v = c1 - c0
        return c0, v / np.linalg.norm(v, axis=-1, keepdims=True)


def camera_grid(hmap: HologramMap, shape_hw: tuple[int, int], pitch_m: float, n_side: int,
                 rng: np.random.Generator) -> np.ndarray:
    """Eye-camera unit directions covering the hologram's field of view (x = f tan(angle)), jittered."""
    H, W = shape_hw
    f = hmap.focal_length_m
    tx = 1.15 * W * pitch_m / (2 * f)
    ty = 1.15 * H * pitch_m / (2 * f)
    nx = n_side
    ny = max(4, int(round(n_side * ty / tx))) if tx > 0 else n_side
    gx, gy = np.meshgrid((np.arange(nx) + rng.random(nx)) / nx, (np.arange(ny) + rng.random(ny)) / ny)
    d = np.stack([(2 * gx.ravel() - 1) * tx, (2 * gy.ravel() - 1) * ty, np.ones(gx.size)], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)
