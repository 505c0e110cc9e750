"""The embedded demo scene, written by our own code (no third-party assets): a textured back wall, a floor,
a diffuse sphere, a mirror sphere and a glass sphere at different depths, lit by an area light. It exercises
focus, mirror reflection and refraction in one small bundle."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_demo_scene"]

_XML = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="6"/></integrator>
    <sensor type="perspective" id="eye">
        <float name="fov" value="{fov}"/>
        <string name="fov_axis" value="x"/>
        <transform name="to_world"><lookat origin="0, 0.35, 2.2" target="0, 0.2, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="256"/><integer name="height" value="256"/></film>
    </sensor>
    <bsdf type="diffuse" id="checker">
        <texture type="bitmap" name="reflectance"><string name="filename" value="textures/checker.png"/></texture>
    </bsdf>
    <bsdf type="diffuse" id="floor_bsdf"><rgb name="reflectance" value="0.6, 0.6, 0.55"/></bsdf>
    <bsdf type="diffuse" id="clay"><rgb name="reflectance" value="0.75, 0.25, 0.15"/></bsdf>
    <bsdf type="conductor" id="mirror"/>
    <bsdf type="dielectric" id="glass"><float name="int_ior" value="1.5"/></bsdf>

    <shape type="rectangle" id="back_wall">
        <transform name="to_world"><scale x="1.6" y="1.2"/><translate x="0" y="0.7" z="-1.2"/></transform>
        <ref id="checker"/>
    </shape>
    <shape type="rectangle" id="floor">
        <transform name="to_world"><scale x="1.6" y="1.6"/><rotate x="1" angle="-90"/><translate y="-0.5" z="-0.2"/></transform>
        <ref id="floor_bsdf"/>
    </shape>
    <shape type="sphere" id="clay_sphere">
        <point name="center" x="-0.55" y="-0.2" z="-0.5"/><float name="radius" value="0.3"/>
        <ref id="clay"/>
    </shape>
    <shape type="sphere" id="mirror_sphere">
        <point name="center" x="0.5" y="-0.15" z="-0.8"/><float name="radius" value="0.35"/>
        <ref id="mirror"/>
    </shape>
    <shape type="sphere" id="glass_sphere">
        <point name="center" x="0.05" y="-0.25" z="0.2"/><float name="radius" value="0.25"/>
        <ref id="glass"/>
    </shape>
    <shape type="rectangle" id="light">
        <transform name="to_world"><scale x="0.5" y="0.5"/><rotate x="1" angle="90"/><translate y="1.6" z="0.2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="9, 8.5, 8"/></emitter>
    </shape>
</scene>
"""


def _checker_png(path: Path, *, n: int = 8, size: int = 256) -> None:
    from PIL import Image

    yy, xx = np.mgrid[0:size, 0:size] * n // size
    on = (xx + yy) % 2 == 0
    img = np.where(on[..., None], np.array([230, 220, 200]), np.array([40, 70, 140])).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)


def write_demo_scene(folder: str | Path, *, fov_deg: float = 40.0) -> Path:
    """Write the demo bundle into ``folder``; returns the scene XML path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _checker_png(folder / "textures" / "checker.png")
    xml = folder / "scene.xml"
    xml.write_text(_XML.format(fov=fov_deg))
    return xml
