"""Loading a scene bundle into Mitsuba, after the bundle check (files confined to the bundle), and reading
its perspective sensor."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from holocore.mitsuba_env import mitsuba

__all__ = ["LoadedScene", "load_scene", "resolve_entry"]


@dataclass
class LoadedScene:
    scene: Any  # mi.Scene
    entry: Path  # the scene XML
    sensor: Any
    fov_x_deg: float
    bundle: Any  # holocore.bundle.BundleReport or None when loaded from a dict

    @property
    def name(self) -> str:
        return self.entry.parent.name if self.entry.name in ("scene.xml", "cbox.xml") else self.entry.stem


def resolve_entry(path: str | Path) -> tuple[Path, str | None]:
    """(bundle root, entry name) for a scene folder or an XML file."""
    p = Path(path).expanduser()
    if not p.exists():
        raise FileNotFoundError(f"scene not found: {p}")
    if p.is_dir():
        return p.resolve(), None
    if p.suffix.lower() != ".xml":
        raise ValueError(f"a scene is a folder or a Mitsuba .xml file, got {p}")
    return p.resolve().parent, p.name


def _sensor_fov_x_deg(sensor) -> float:
    mi = mitsuba()
    params = mi.traverse(sensor)
    if "x_fov" not in params:
        raise ValueError(
            f"the scene's sensor is a {sensor.class_name()}; wave path tracing needs a perspective sensor "
            "(DESIGN.md §3 maps its eye-camera frame to hologram space)"
        )
    fov = float(params["x_fov"][0]) if hasattr(params["x_fov"], "__len__") else float(params["x_fov"])
    if not (0.0 < fov < 180.0) or math.isnan(fov):
        raise ValueError(f"sensor field of view {fov} deg is not usable")
    return fov


def load_scene(path: str | Path, *, check_bundle: bool = True) -> LoadedScene:
    """Check the bundle (every file inside it, no escapes) and load it with Mitsuba."""
    root, entry_name = resolve_entry(path)
    report = None
    if check_bundle:
        from holocore.bundle import validate_bundle

        report = validate_bundle(root, entry=entry_name)
        entry = Path(report.entry)
        if not entry.is_absolute():
            entry = root / entry
    else:
        if entry_name is None:
            xmls = sorted(root.glob("*.xml"))
            if len(xmls) != 1:
                raise ValueError(f"{root} holds {len(xmls)} XML files; name the scene file")
            entry_name = xmls[0].name
        entry = root / entry_name
    mi = mitsuba()
    scene = mi.load_file(str(entry))
    sensors = scene.sensors()
    if not sensors:
        raise ValueError(f"{entry} has no sensor: the hologram needs the scene's camera")
    return LoadedScene(scene=scene, entry=entry, sensor=sensors[0], fov_x_deg=_sensor_fov_x_deg(sensors[0]),
                       bundle=report)


def from_mitsuba_scene(scene, *, name: str = "scene") -> LoadedScene:
    """Wrap a scene made with mi.load_dict (tests, demos)."""
    sensor = scene.sensors()[0]
    return LoadedScene(scene=scene, entry=Path(f"{name}.xml"), sensor=sensor, fov_x_deg=_sensor_fov_x_deg(sensor),
                       bundle=None)
