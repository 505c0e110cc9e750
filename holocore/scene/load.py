"""Loading a scene bundle into Mitsuba, after the bundle check (files confined to the bundle), and reading
its perspective sensor.

Mitsuba resolves a plugin ``<type>`` to ``plugins/<type>.so`` through its file resolver, which normally
searches the scene's folder first: a bundle could bring its own shared object. So, before any scene
is parsed, every plugin of Mitsuba's own installation is loaded once (the plugin manager keeps them, and never
looks a loaded name up again), with a resolver holding only Mitsuba's own folder (not the working directory);
the bundle check refuses any file that is not scene data by its content, and shared-object names; and scenes
are parsed from the checked entry text (its integrator stripped) with a resolver holding only the entry's
folder. Errors come back as :class:`SceneLoadError` in the user's terms
(bundle-relative paths, no server paths)."""

from __future__ import annotations

import math
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from holocore.runtime.mitsuba_env import mitsuba
from holocore.scene.bundle import entry_source, validate_bundle
from holocore.scene.bundle import film_size_error
from holocore.scene.errors import scrub_message
from holocore.scene.features import shape_name

__all__ = ["LoadedScene", "SceneLoadError", "load_scene", "resolve_entry", "preload_plugins", "unsupported_reason",
           "sensor_film_hw"]

_PRELOAD_LOCK = threading.Lock()
_PRELOADED: list[str] = []


class SceneLoadError(ValueError):
    """Mitsuba could not load a checked bundle; the message names the file and line, relative to the bundle."""


# Mitsuba's load optimisation merges the meshes that share a BSDF into one shape without an id: the plan could
# then neither count a scene's mirrors and glass per shape nor name them by their ids, so the shapes are kept.
_MERGE_SHAPES = False


def preload_plugins() -> list[str]:
    """Load every plugin of Mitsuba's installation (once per process) so that no plugin name is ever resolved
    through a search path that holds a scene's folder; returns their names. The plugins are looked up with a
    resolver holding only Mitsuba's own folder: Mitsuba's default one starts with the working directory, which
    may be a scene's folder (a ``plugins/sphere.so`` there would be loaded as the sphere plugin)."""
    with _PRELOAD_LOCK:
        if not _PRELOADED:
            mi = mitsuba()
            own = Path(mi.__file__).parent
            pm = mi.PluginManager.instance()
            names = sorted(p.name[:-3] for p in (own / "plugins").iterdir() if p.name.endswith(".so"))
            with _resolver_holding(own):
                for name in names:
                    try:
                        pm.plugin_type(name)
                    except Exception:  # noqa: BLE001 - a plugin this variant cannot use stays unloaded (never resolved)
                        pass
            _PRELOADED.extend(names)
        return list(_PRELOADED)


@contextmanager
def _resolver_holding(*folders: Path) -> Iterator[None]:
    """The thread's file resolver holds only ``folders`` inside the block (restored afterwards)."""
    mi = mitsuba()
    fr = mi.file_resolver()
    saved = [str(p) for p in fr]
    fr.clear()
    for folder in folders:
        fr.append(str(folder))
    try:
        yield
    finally:
        fr.clear()
        for p in saved:
            fr.append(p)


def _resolver_for(entry_dir: Path):
    """While a scene loads, the file resolver holds the entry's folder and then Mitsuba's own: every asset comes
    from the bundle (the bundle check has confined each reference to it), Mitsuba's built-in data (the measured
    IOR tables a named conductor reads, data/ior/*.spd; the sRGB coefficients) from its installation, and every
    plugin is loaded already, so no plugin name is resolved through either."""
    return _resolver_holding(entry_dir, Path(mitsuba().__file__).parent)


@dataclass
class LoadedScene:
    scene: Any  # mi.Scene
    entry: Path  # the scene XML
    sensor: Any
    fov_x_deg: float
    bundle: Any  # holocore.scene.bundle.BundleReport or None when loaded from a dict

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
            "(docs/design.md §3 maps its eye-camera frame to hologram space)"
        )
    fov = float(params["x_fov"][0]) if hasattr(params["x_fov"], "__len__") else float(params["x_fov"])
    if not (0.0 < fov < 180.0) or math.isnan(fov):
        raise ValueError(f"sensor field of view {fov} deg is not usable")
    return fov


def sensor_film_hw(sensor) -> tuple[int, int]:
    """The sensor's film size (rows, columns) in pixels: with its field of view, the camera's image. ValueError
    past the bound a bundle's film is held to (holocore.scene.bundle.film_size_error): a scene loaded without
    the bundle check, or stored before the bound, is held to it too."""
    w, h = (int(v) for v in sensor.film().size())
    why = film_size_error(h, w)
    if why is not None:
        raise ValueError(why)
    return h, w


_PERSPECTIVE = {"perspective", "thinlens"}


def unsupported_reason(plugins: list[str]) -> str | None:
    """Why a scene using ``plugins`` ("tag:type", as the bundle report lists them) cannot become a hologram, in
    one line that says what to change; None when it can. Checked before Mitsuba parses the scene."""
    hetero = sorted(p.split(":")[1] for p in plugins if p.startswith("medium:") and p != "medium:homogeneous")
    if hetero:
        return (f"<medium type={hetero[0]!r}>: wave path tracing simulates participating media only when "
                "homogeneous and absorbing (albedo 0): use a homogeneous medium or remove it")
    ellipsoids = sorted(p for p in plugins if p in ("shape:ellipsoids", "shape:ellipsoidsmesh"))
    if ellipsoids:
        return (f"Gaussian ellipsoid primitives (<shape type={ellipsoids[0].split(':')[1]!r}>) need Mitsuba's "
                "volumetric-primitive integrators; wave path tracing does not trace them: use meshes")
    other = sorted(p.split(":")[1] for p in plugins if p.startswith("sensor:") and p.split(":")[1] not in _PERSPECTIVE)
    if other:
        return (f"<sensor type={other[0]!r}>: wave path tracing needs a perspective sensor (the eye's camera; "
                "perspective or thinlens) and no other: remove or replace it")
    tables = sorted(p.split(":")[1] for p in plugins if p in ("spectrum:blackbody", "spectrum:regular",
                                                               "spectrum:irregular"))
    if tables:
        return (f"<spectrum type={tables[0]!r}> needs a spectral Mitsuba variant, and holograms render in RGB at the "
                "display's laser lines: give that emitter or material an <rgb> value (spectral files given as "
                "<spectrum filename=...> are converted and work)")
    return None


def _scatters(medium) -> bool:
    """Whether a homogeneous medium scatters anywhere: sigma_s = albedo sigma_t > 0 in some colour. Raises
    RuntimeError when Mitsuba cannot evaluate its coefficients (a phase function given the wrong volume)."""
    mi = mitsuba()
    import drjit as dr

    mei = dr.zeros(mi.MediumInteraction3f, 1)
    sigma_s, _sigma_n, _sigma_t = medium.get_scattering_coefficients(mei, True)
    return any(float(dr.max(sigma_s[c])[0]) > 0 for c in range(3))


def media_reason(scene) -> str | None:
    """Why the scene's media cannot become a hologram, in one line naming the medium and the shape (or
    sensor) holding it; None when every medium is homogeneous and absorbing (albedo 0), which the tracer
    simulates as Beer-Lambert attenuation. A scattering medium would need volumetric light transport
    (in-scattered radiance along each segment), which the wave path's image point model does not hold."""
    holders = [(f"sensor {sensor.id() or '#' + str(i)!r}", sensor.get_medium())
               for i, sensor in enumerate(scene.sensors())]
    for i, sh in enumerate(scene.shapes()):
        name = shape_name(sh, i)
        holders += [(f"shape {name!r} (interior)", sh.interior_medium()),
                    (f"shape {name!r} (exterior)", sh.exterior_medium())]
    for where, medium in holders:
        if medium is None:
            continue
        what = f"medium {medium.id()!r} of {where}" if medium.id() else f"the medium of {where}"
        if not medium.is_homogeneous():
            return (f"{what} is not homogeneous: wave path tracing simulates participating media only when "
                    "homogeneous and absorbing; use a homogeneous medium")
        try:
            scatters = _scatters(medium)
        except RuntimeError as e:
            return f"{what} cannot be evaluated by Mitsuba ({str(e).strip().splitlines()[0]}): fix or remove it"
        if scatters:
            return (f"{what} scatters (albedo > 0): wave path tracing simulates participating media only "
                    "when absorbing (Beer-Lambert); set its albedo to 0 or remove the medium")
    return None


def _rel_name(root: Path, entry: Path) -> str:
    try:
        return entry.relative_to(root).as_posix()
    except ValueError:
        return entry.name


def load_scene(path: str | Path, *, check_bundle: bool = True) -> LoadedScene:
    """Check the bundle (every file inside it, no escapes, only scene data) and load it with Mitsuba.
    ``check_bundle=False`` is for trusted folders only (tests): Mitsuba then reads the files as it likes."""
    root, entry_name = resolve_entry(path)
    report = None
    mi = mitsuba()
    preload_plugins()
    if check_bundle:
        report = validate_bundle(root, entry=entry_name)
        entry = Path(report.entry)
        why = unsupported_reason(report.plugins)
        if why is not None:
            raise SceneLoadError(f"{_rel_name(root, entry)}: {why}")
        try:
            with _resolver_for(entry.parent):
                scene = mi.load_string(entry_source(report), optimize=_MERGE_SHAPES)
        except RuntimeError as exc:
            raise SceneLoadError(scrub_message(f"Mitsuba could not load the scene: {exc}", roots=[entry.parent],
                                               entry_name=_rel_name(root, entry))) from None
    else:
        if entry_name is None:
            xmls = sorted(root.glob("*.xml"))
            if len(xmls) != 1:
                raise ValueError(f"{root} holds {len(xmls)} XML files; name the scene file")
            entry_name = xmls[0].name
        entry = root / entry_name
        scene = mi.load_file(str(entry), optimize=_MERGE_SHAPES)
    sensors = scene.sensors()
    if not sensors:
        raise ValueError(f"{entry} has no sensor: the hologram needs the scene's camera")
    why = media_reason(scene)
    if why is not None:
        raise SceneLoadError(f"{entry.name}: {why}")
    return LoadedScene(scene=scene, entry=entry, sensor=sensors[0], fov_x_deg=_sensor_fov_x_deg(sensors[0]),
                       bundle=report)


def from_mitsuba_scene(scene, *, name: str = "scene") -> LoadedScene:
    """Wrap a scene made with mi.load_dict (tests, demos)."""
    why = media_reason(scene)
    if why is not None:
        raise SceneLoadError(f"{name}: {why}")
    sensor = scene.sensors()[0]
    return LoadedScene(scene=scene, entry=Path(f"{name}.xml"), sensor=sensor, fov_x_deg=_sensor_fov_x_deg(sensor),
                       bundle=None)
