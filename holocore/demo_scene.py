"""The embedded demo scene, written by our own code (no third-party assets): a textured back wall, a table,
a diffuse sphere, a mirror sphere and a glass sphere between 0.3 and 1.5 m, lit by an area light. It exercises
focus, mirror reflection and refraction in one small bundle."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_demo_scene"]

_XML = """<scene version="3.0.0">
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
        <transform name="to_world"><scale x="0.5" y="1.0"/><rotate x="1" angle="-90"/><translate y="-0.055" z="-0.9"/></transform>
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
        <transform name="to_world"><scale x="0.3" y="0.3"/><rotate x="1" angle="90"/><translate y="0.8" z="-0.6"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="12, 11.5, 11"/></emitter>
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


def write_demo_scene(folder: str | Path, *, fov_deg: float = 10.0) -> Path:
    """Write the demo bundle into ``folder``; returns the scene XML path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _checker_png(folder / "textures" / "checker.png")
    xml = folder / "scene.xml"
    xml.write_text(_XML.format(fov=fov_deg))
    return xml
