"""Scenes the tracer tests build with Mitsuba's own shapes (no files needed)."""

from __future__ import annotations

from typing import Any


def T():
    from holocore.runtime.mitsuba_env import mitsuba

    return mitsuba().ScalarTransform4f()


def camera(fov: float = 10.0, origin=(0, 0, 0), target=(0, 0, -1), up=(0, 1, 0)) -> dict:
    return {"type": "perspective", "fov": fov, "fov_axis": "x",
            "to_world": T().look_at(origin=list(origin), target=list(target), up=list(up))}


def emitting_plane(z: float, *, size: float = 5.0, radiance: float = 1.0, texture: str | None = None,
                   x: float = 0.0, rotate_y_deg: float = 0.0) -> dict:
    """A rectangle facing the camera (+z normal) at depth z, turned ``rotate_y_deg`` about y, glowing with the
    given radiance (a Lambertian emitter)."""
    em: dict[str, Any] = {"type": "area", "radiance": {"type": "rgb", "value": radiance}}
    if texture is not None:
        em["radiance"] = {"type": "bitmap", "filename": texture}
    return {"type": "rectangle", "to_world": T().translate([x, 0, z]).rotate([0, 1, 0], rotate_y_deg).scale(size),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}}, "emitter": em}


def scene(**shapes) -> Any:
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.scene.load import from_mitsuba_scene

    mi = mitsuba()
    d = {"type": "scene", "sensor": shapes.pop("sensor", camera())}
    d.update(shapes)
    return from_mitsuba_scene(mi.load_dict(d))
