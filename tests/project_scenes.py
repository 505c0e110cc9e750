"""The scenes the tests run on: the project's own, written by project code into a session folder with the layout
of the third-party bundles in ``../shared/scenes``, and those bundles themselves for the tests whose id says
``shared`` (they skip, saying so, when ``../shared`` is absent). A test id runs the same data on a fresh clone and
in CI. ``HOLO_NO_SHARED=1`` pretends that ``../shared`` is absent (to check just that).

=====================  ==============================================  ==========================================
shared bundle          what the tests use it for                       the project's stand-in
=====================  ==============================================  ==========================================
cbox-mirror-glass      mirror and glass spheres in a diffuse room, OBJ  :func:`holocore.scene.demo.write_cbox_scene`
                       meshes, one area light                          (same layout, ids and plugin kinds)
veach-bidir            glass (id "Glass"), a glossy metal, diffuse,     :func:`write_glossy_glass_room`
                       two area lights
veach-mis              rough plastic plates (alpha 0.005 to 0.1), five  :func:`write_glossy_plates`
                       sphere lights, no delta surface
=====================  ==============================================  ==========================================
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Callable

__all__ = ["SHARED_SCENES", "NO_SHARED_ENV", "ENTRIES", "shared_available", "SCENE_SOURCES", "SceneBundles",
           "write_project_scene", "write_glossy_glass_room", "write_glossy_plates"]

SHARED_SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"
NO_SHARED_ENV = "HOLO_NO_SHARED"
# bundle name -> its scene file (the same for the shared bundle and the project's stand-in)
ENTRIES = {"cbox-mirror-glass": "cbox.xml", "veach-bidir": "scene.xml", "veach-mis": "integrator_direct_both.xml"}


def shared_available() -> bool:
    """Whether ``../shared/scenes`` is there and not hidden by ``HOLO_NO_SHARED=1``."""
    if os.environ.get(NO_SHARED_ENV, "").strip() not in ("", "0"):
        return False
    return all((SHARED_SCENES / name / entry).is_file() for name, entry in ENTRIES.items())


# The sources a test parametrised over both runs on (by the ``bundles_of`` fixture of tests/conftest.py): the
# project's scenes, and ../shared's, whose case skips saying so when ../shared is absent; the id names the data.
SCENE_SOURCES: list[str] = ["project", "shared"]

_ROOM = """
    <bsdf type="diffuse" id="wall"><rgb name="reflectance" value="0.7, 0.68, 0.62"/></bsdf>
    <shape type="rectangle" id="floor">
        <transform name="to_world"><scale x="3" y="3"/><rotate x="1" angle="-90"/><translate y="-1"/></transform>
        <ref id="wall"/>
    </shape>
    <shape type="rectangle" id="backwall">
        <transform name="to_world"><scale x="3" y="2"/><translate y="1" z="-2"/></transform>
        <ref id="wall"/>
    </shape>"""


def _sensor(fov_deg: float, origin: str, target: str, width_px: int, height_px: int) -> str:
    return f"""
    <sensor type="perspective" id="sensor">
        <float name="fov" value="{fov_deg}"/><string name="fov_axis" value="x"/>
        <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 1, 0"/></transform>
        <film type="hdrfilm">
            <integer name="width" value="{width_px}"/><integer name="height" value="{height_px}"/>
        </film>
    </sensor>"""


def write_glossy_glass_room(folder: Path) -> Path:
    """A room with a glass egg (id "Glass", the only dielectric), a rough metal lamp shade, a diffuse floor and
    wall, lit by two area lights; the stand-in for veach-bidir. Returns the scene XML path."""
    folder.mkdir(parents=True, exist_ok=True)
    xml = folder / ENTRIES["veach-bidir"]
    sensor = _sensor(40.0, "0, 0.2, 4", "0, -0.2, 0", 96, 64)
    xml.write_text(f"""<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="6"/></integrator>{sensor}{_ROOM}
    <shape type="sphere" id="Glass">
        <point name="center" x="0" y="-0.3" z="0"/><float name="radius" value="0.45"/>
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>
    </shape>
    <shape type="sphere" id="Lamp">
        <point name="center" x="0.8" y="-0.6" z="-0.8"/><float name="radius" value="0.4"/>
        <bsdf type="roughconductor"><string name="material" value="Al"/><float name="alpha" value="0.2"/></bsdf>
    </shape>
    <shape type="rectangle" id="light-ceiling">
        <transform name="to_world"><scale x="0.5" y="0.5"/><rotate x="1" angle="90"/><translate y="2" z="-0.5"/></transform>
        <emitter type="area"><rgb name="radiance" value="8, 7, 6"/></emitter>
    </shape>
    <shape type="rectangle" id="light-side">
        <transform name="to_world"><scale x="0.3" y="0.3"/><rotate y="1" angle="-90"/><translate x="2.5" y="0.5"/></transform>
        <emitter type="area"><rgb name="radiance" value="6, 6, 8"/></emitter>
    </shape>
</scene>
""")
    return xml


def write_glossy_plates(folder: Path) -> Path:
    """Four rough plastic plates (alpha 0.005, 0.02, 0.05, 0.1) in front of a diffuse wall, lit by five sphere
    lights of growing size: glossy, view-dependent, no delta surface; the stand-in for veach-mis."""
    folder.mkdir(parents=True, exist_ok=True)
    plates = []
    for i, alpha in enumerate((0.005, 0.02, 0.05, 0.1)):
        y = -0.6 + 0.4 * i
        plates.append(f"""
    <shape type="rectangle" id="plate{i + 1}">
        <transform name="to_world"><scale x="1.2" y="0.15"/><rotate x="1" angle="{-60 + 12 * i}"/>
            <translate y="{y:g}" z="-0.5"/></transform>
        <bsdf type="roughplastic"><float name="alpha" value="{alpha}"/>
            <rgb name="diffuse_reflectance" value="0.07, 0.09, 0.13"/></bsdf>
    </shape>""")
    lights = []
    for i, (radius, value) in enumerate(((0.02, 400), (0.05, 70), (0.1, 18), (0.2, 4), (0.4, 1))):
        x = -1.2 + 0.6 * i
        lights.append(f"""
    <shape type="sphere" id="light{i + 1}">
        <point name="center" x="{x:g}" y="1.2" z="-1.4"/><float name="radius" value="{radius}"/>
        <emitter type="area"><rgb name="radiance" value="{value}"/></emitter>
    </shape>""")
    xml = folder / ENTRIES["veach-mis"]
    sensor = _sensor(40.0, "0, 0.6, 4", "0, -0.2, 0", 96, 64)
    xml.write_text(f"""<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>{sensor}{_ROOM}{"".join(plates)}{"".join(lights)}
</scene>
""")
    return xml


_WRITERS: dict[str, Callable[[Path], Path]] = {
    "veach-bidir": write_glossy_glass_room,
    "veach-mis": write_glossy_plates,
}


def write_project_scene(name: str, folder: Path) -> Path:
    """Write the project's stand-in for the shared bundle ``name`` into ``folder``; returns its scene XML."""
    if name == "cbox-mirror-glass":
        from holocore.scene.demo import write_cbox_scene

        return write_cbox_scene(folder)
    if name not in _WRITERS:
        raise KeyError(f"no project scene stands in for {name!r}; known: {sorted(ENTRIES)}")
    return _WRITERS[name](folder)


class SceneBundles:
    """Scene bundles by their shared name, from one source: ``"shared"`` (../shared/scenes) or ``"project"``
    (written on first use under ``root``)."""

    def __init__(self, source: str, root: Path) -> None:
        if source not in ("shared", "project"):
            raise ValueError(f"source must be 'shared' or 'project', got {source!r}")
        self.source = source
        self.root = SHARED_SCENES if source == "shared" else root

    def folder(self, name: str) -> Path:
        """The bundle folder of ``name`` (what `holo render`, `holo submit` and an upload take)."""
        return self.entry(name).parent

    def entry(self, name: str) -> Path:
        """The scene XML of ``name``."""
        if name not in ENTRIES:
            raise KeyError(f"unknown scene bundle {name!r}; known: {sorted(ENTRIES)}")
        xml = self.root / name / ENTRIES[name]
        if self.source == "project" and not xml.is_file():
            tmp = self.root / f".{name}.partial"
            shutil.rmtree(tmp, ignore_errors=True)
            write_project_scene(name, tmp)
            tmp.rename(self.root / name)
        return xml
