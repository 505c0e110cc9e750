"""Scenes written by our own code (no third-party assets).

The demo scene: a textured back wall, a table, a diffuse sphere, a mirror sphere and a glass sphere between
0.3 and 1.5 m, lit by an area light. It exercises focus, mirror reflection and refraction in one small bundle.

The mirror-and-glass box (:func:`write_cbox_scene`): a Cornell-style room, 2 m on a side, its walls and its
ceiling light OBJ quads in ``meshes/``, with a mirror sphere and a glass sphere, seen from 4 m. It is the
project's own stand-in for the third-party ``cbox-mirror-glass`` bundle (same layout, shape ids and kinds of
plugins), so that the tests and the service run on a fresh clone, which has none of those bundles."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_demo_scene", "write_cbox_scene"]

_XML = ("""<scene version="3.0.0">
    <!-- A table-top scene 0.3 to 1.5 m from the eye, seen through a narrow field of view: a small SLM
         (a few hundred pixels) can only show a few degrees with depth cues larger than its depth of field. -->
    <integrator type="path"><integer name="max_depth" value="6"/></integrator>
    <sensor type="perspective" id="eye">
        <float name="fov" value="{fov}"/>
        <string name="fov_axis" value="x"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, -0.01, -1" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="256"/><integer name="height" value="192"/></film>
    </sensor>
    <bsdf type="diffuse" id="checker">
        <texture type="bitmap" name="reflectance"><string name="filename" value="textures/checker.png"/></texture>
    </bsdf>
    <bsdf type="diffuse" id="table_bsdf"><rgb name="reflectance" value="0.55, 0.5, 0.45"/></bsdf>
    <bsdf type="diffuse" id="clay"><rgb name="reflectance" value="0.75, 0.25, 0.15"/></bsdf>
    <bsdf type="conductor" id="mirror"/>
    <bsdf type="dielectric" id="glass"><float name="int_ior" value="1.5"/></bsdf>

    <shape type="rectangle" id="back_wall">
        <transform name="to_world"><scale x="0.3" y="0.2"/><translate x="0" y="0.05" z="-1.5"/></transform>
        <ref id="checker"/>
    </shape>
    <shape type="rectangle" id="table">
        <transform name="to_world"><scale x="0.5" y="1.0"/><rotate x="1" angle="-90"/>"""
        """<translate y="-0.055" z="-0.9"/></transform>
        <ref id="table_bsdf"/>
    </shape>
    <shape type="sphere" id="clay_sphere">
        <point name="center" x="-0.035" y="-0.03" z="-0.75"/><float name="radius" value="0.025"/>
        <ref id="clay"/>
    </shape>
    <shape type="sphere" id="mirror_sphere">
        <point name="center" x="0.06" y="-0.01" z="-1.1"/><float name="radius" value="0.045"/>
        <ref id="mirror"/>
    </shape>
    <shape type="sphere" id="glass_sphere">
        <point name="center" x="0.006" y="-0.014" z="-0.32"/><float name="radius" value="0.009"/>
        <ref id="glass"/>
    </shape>
    <shape type="rectangle" id="light">
        <transform name="to_world"><scale x="0.3" y="0.3"/><rotate x="1" angle="90"/>"""
        """<translate y="0.8" z="-0.6"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="12, 11.5, 11"/></emitter>
    </shape>
</scene>
""")


def _checker_png(path: Path, *, n: int = 8, size: int = 256) -> None:
    from PIL import Image

    yy, xx = np.mgrid[0:size, 0:size] * n // size
    on = (xx + yy) % 2 == 0
    img = np.where(on[..., None], np.array([230, 220, 200]), np.array([40, 70, 140])).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)


def write_demo_scene(folder: str | Path, *, fov_deg: float = 10.0) -> Path:
    """Write the demo bundle into ``folder``; returns the scene XML path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _checker_png(folder / "textures" / "checker.png")
    xml = folder / "scene.xml"
    xml.write_text(_XML.format(fov=fov_deg))
    return xml


# The room [-1, 1]^3, open towards +z (the eye). Each quad: corners counter-clockwise seen from inside, so
# the OBJ normals face into the room.
_CBOX_QUADS: dict[str, tuple[tuple[float, float, float], ...]] = {
    "floor": ((-1, -1, 1), (1, -1, 1), (1, -1, -1), (-1, -1, -1)),
    "ceiling": ((1, 1, -1), (1, 1, 1), (-1, 1, 1), (-1, 1, -1)),
    "back": ((1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, -1, -1)),
    "greenwall": ((-1, 1, -1), (-1, 1, 1), (-1, -1, 1), (-1, -1, -1)),
    "redwall": ((1, -1, 1), (1, 1, 1), (1, 1, -1), (1, -1, -1)),
    "luminaire": ((0.25, 1, -0.25), (0.25, 1, 0.25), (-0.25, 1, 0.25), (-0.25, 1, -0.25)),
}

_CBOX_XML = ("""<scene version="3.0.0">
    <!-- A Cornell-style room with a mirror sphere and a glass sphere, written by holocore.scene.demo. -->
    <integrator type="path"><integer name="max_depth" value="6"/></integrator>
    <sensor type="perspective" id="sensor">
        <string name="fov_axis" value="smaller"/>
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>
            <rfilter type="tent"/></film>
    </sensor>

    <bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.8, 0.72, 0.66"/></bsdf>
    <bsdf type="diffuse" id="green"><rgb name="reflectance" value="0.12, 0.4, 0.08"/></bsdf>
    <bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.6, 0.05, 0.05"/></bsdf>
    <bsdf type="dielectric" id="glass"><float name="int_ior" value="1.5"/></bsdf>
    <bsdf type="conductor" id="mirror"/>

    <shape type="obj" id="light">
        <string name="filename" value="meshes/cbox_luminaire.obj"/>
        <transform name="to_world"><translate y="-0.01"/></transform>
        <ref id="white"/>
        <emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter>
    </shape>
    <shape type="obj" id="floor"><string name="filename" value="meshes/cbox_floor.obj"/><ref id="white"/></shape>
    <shape type="obj" id="ceiling"><string name="filename" value="meshes/cbox_ceiling.obj"/><ref id="white"/></shape>
    <shape type="obj" id="back"><string name="filename" value="meshes/cbox_back.obj"/><ref id="white"/></shape>
    <shape type="obj" id="greenwall"><string name="filename" value="meshes/cbox_greenwall.obj"/>"""
    """<ref id="green"/></shape>
    <shape type="obj" id="redwall"><string name="filename" value="meshes/cbox_redwall.obj"/><ref id="red"/></shape>

    <shape type="sphere" id="mirrorsphere">
        <point name="center" x="-0.3" y="-0.5" z="0.2"/><float name="radius" value="0.5"/>
        <ref id="mirror"/>
    </shape>
    <shape type="sphere" id="glasssphere">
        <point name="center" x="0.5" y="-0.75" z="-0.2"/><float name="radius" value="0.25"/>
        <ref id="glass"/>
    </shape>
</scene>
""")


def write_cbox_scene(folder: str | Path, *, fov_deg: float = 39.3, res_px: int = 256,
                     radiance_rgb: tuple[float, float, float] = (17.0, 12.0, 6.0)) -> Path:
    """Write the mirror-and-glass box into ``folder`` (``cbox.xml`` and ``meshes/cbox_*.obj``); returns the
    scene XML path. ``radiance_rgb``: the ceiling light's radiance (W m^-2 sr^-1 per channel)."""
    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    for name, quad in _CBOX_QUADS.items():
        lines = [f"v {x:g} {y:g} {z:g}" for x, y, z in quad] + ["f 1 2 3 4", ""]
        (folder / "meshes" / f"cbox_{name}.obj").write_text("\n".join(lines))
    xml = folder / "cbox.xml"
    xml.write_text(_CBOX_XML.format(fov=fov_deg, res=res_px, radiance=", ".join(f"{v:g}" for v in radiance_rgb)))
    return xml
