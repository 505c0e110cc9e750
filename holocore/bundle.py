"""Scene bundles: a folder holding a Mitsuba 3 XML scene and every file it references, checked before Mitsuba
parses anything (issue 3, item 1; the service reuses it for uploads).

Every referenced file (``filename`` strings, ``<include>``) must resolve inside the bundle: absolute paths,
``..`` escapes, symbolic links leaving the bundle and ``<path>`` elements (search paths) are refused. The XML
is read with defusedxml (no DTDs, no entity expansion), plugins must be on an allow-list, and caps bound
bytes, files, mesh faces and image pixels. Pure Python: no Mitsuba import.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Optional

__all__ = ["BundleError", "BundleLimits", "BundleReport", "validate_bundle", "ALLOWED_PLUGINS"]


class BundleError(ValueError):
    """The bundle is refused; the message says why."""


@dataclass(frozen=True)
class BundleLimits:
    max_total_bytes: int = 512 * 1024 * 1024
    max_files: int = 2000
    max_mesh_faces: int = 20_000_000
    max_image_pixels: int = 64 * 1024 * 1024
    max_xml_bytes: int = 8 * 1024 * 1024
    max_include_depth: int = 8


@dataclass
class BundleReport:
    entry: Path
    files: list[str]
    total_bytes: int
    sha256: str
    plugins: list[str]
    warnings: list[str] = field(default_factory=list)
    mesh_faces: int = 0
    image_pixels: int = 0


# Mitsuba 3 plugins a scene may use (rendering plugins only; nothing that writes files or runs code).
ALLOWED_PLUGINS = {
    "bsdf": {"diffuse", "dielectric", "thindielectric", "roughdielectric", "conductor", "roughconductor",
             "plastic", "roughplastic", "bumpmap", "normalmap", "blendbsdf", "mask", "twosided", "null",
             "principled", "principledthin", "hair", "measured", "pplastic", "polarizer", "retarder",
             "circular"},
    "shape": {"obj", "ply", "serialized", "sphere", "rectangle", "disk", "cylinder", "cube", "shapegroup",
              "instance", "bsplinecurve", "linearcurve", "sdfgrid", "ellipsoids", "ellipsoidsmesh"},
    "emitter": {"area", "point", "spot", "directional", "constant", "envmap", "projector", "directionalarea"},
    "texture": {"bitmap", "checkerboard", "mesh_attribute", "volume"},
    "sensor": {"perspective", "thinlens", "orthographic", "radiancemeter", "irradiancemeter", "batch"},
    "film": {"hdrfilm", "specfilm"},
    "rfilter": {"box", "tent", "gaussian", "mitchell", "catmullrom", "lanczos"},
    "sampler": {"independent", "stratified", "multijitter", "orthogonal", "ldsampler"},
    "integrator": {"path", "direct", "aov", "volpath", "volpathmis", "depth", "moment", "stokes", "ptracer",
                   "prb", "direct_projective", "prb_projective"},
    "medium": {"homogeneous", "heterogeneous"},
    "phase": {"isotropic", "hg", "rayleigh", "blendphase", "tabphase", "sggx"},
    "volume": {"constvolume", "gridvolume"},
    "spectrum": {"uniform", "regular", "irregular", "blackbody", "d65", "srgb"},
}
_FILE_EXT_MESH = {".obj", ".ply", ".serialized"}
_FILE_EXT_IMAGE = {".png", ".jpg", ".jpeg", ".bmp", ".tga", ".exr", ".hdr", ".pfm", ".ppm"}


def _rel(root: Path, p: Path) -> str:
    return p.relative_to(root).as_posix()


def _inside(root: Path, target: Path) -> bool:
    try:
        target.relative_to(root)
        return True
    except ValueError:
        return False


def _check_reference(root: Path, base: Path, value: str, what: str) -> Path:
    """Resolve a reference made from the file at ``base`` (a folder inside root); refuse escapes."""
    if not value or "\x00" in value:
        raise BundleError(f"{what}: empty or invalid file reference")
    pure = PurePosixPath(value.replace("\\", "/"))
    if pure.is_absolute() or re.match(r"^[A-Za-z]:", value) or value.startswith("~"):
        raise BundleError(f"{what}: absolute path {value!r} is not allowed; paths must be relative to the bundle")
    candidate = (base / Path(*pure.parts)).resolve()
    if not _inside(root, candidate):
        raise BundleError(f"{what}: {value!r} leaves the scene bundle")
    if not candidate.is_file():
        # Mitsuba also resolves relative to the entry's folder; accept that too if it exists inside.
        alt = (root / Path(*pure.parts)).resolve()
        if _inside(root, alt) and alt.is_file():
            return alt
        raise BundleError(f"{what}: {value!r} is referenced but not in the bundle")
    return candidate


def _parse(path: Path, limits: BundleLimits):
    from defusedxml import DefusedXmlException
    from defusedxml.ElementTree import parse

    if path.stat().st_size > limits.max_xml_bytes:
        raise BundleError(f"{path.name}: XML larger than {limits.max_xml_bytes} bytes")
    try:
        return parse(str(path), forbid_dtd=True, forbid_entities=True, forbid_external=True).getroot()
    except DefusedXmlException as exc:
        raise BundleError(f"{path.name}: refused XML construct ({type(exc).__name__}): DTDs and entities are "
                          "not allowed") from None
    except Exception as exc:  # noqa: BLE001 - ParseError and friends
        raise BundleError(f"{path.name}: not well-formed XML: {exc}") from None


def _defaults(root_el) -> dict[str, str]:
    return {d.get("name", ""): d.get("value", "") for d in root_el.iter("default")}


def _subst(value: str, defaults: dict[str, str]) -> str:
    return re.sub(r"\$(\w+)", lambda m: defaults.get(m.group(1), m.group(0)), value)


def _obj_faces(path: Path) -> int:
    n = 0
    with path.open("rb") as fh:
        for line in fh:
            if line.startswith(b"f "):
                n += max(1, len(line.split()) - 3)
    return n


def _ply_faces(path: Path) -> int:
    with path.open("rb") as fh:
        for _ in range(200):
            line = fh.readline()
            if not line or line.strip() == b"end_header":
                break
            parts = line.split()
            if len(parts) == 3 and parts[0] == b"element" and parts[1] == b"face":
                try:
                    return int(parts[2])
                except ValueError:
                    raise BundleError(f"{path.name}: malformed PLY header") from None
    return 0


def _image_pixels(path: Path, warnings: list[str]) -> int:
    if path.suffix.lower() in {".exr", ".hdr", ".pfm"}:
        warnings.append(f"{path.name}: pixel count of {path.suffix} images not checked before loading")
        return 0
    from PIL import Image

    try:
        with Image.open(path) as im:  # reads the header only
            w, h = im.size
    except Exception:  # noqa: BLE001
        raise BundleError(f"{path.name}: not a readable image") from None
    return int(w) * int(h)


def validate_bundle(root: str | Path, *, entry: Optional[str] = None, limits: BundleLimits = BundleLimits()
                    ) -> BundleReport:
    """Check a scene folder; returns what it holds or raises :class:`BundleError` saying why not."""
    root_in = Path(root)
    if not root_in.is_dir():
        raise BundleError(f"scene bundle {root_in} is not a folder")
    root = root_in.resolve()
    files: list[Path] = []
    total = 0
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        d = Path(dirpath)
        for name in list(dirnames):
            p = d / name
            if p.is_symlink() and not _inside(root, p.resolve()):
                raise BundleError(f"{_rel(root, p)}: symbolic link leaves the bundle")
        for name in filenames:
            p = d / name
            if p.is_symlink() and not _inside(root, p.resolve()):
                raise BundleError(f"{_rel(root, p)}: symbolic link leaves the bundle")
            if name.startswith(".") and name != ".":
                continue
            files.append(p)
            total += p.stat().st_size
            if len(files) > limits.max_files:
                raise BundleError(f"bundle holds more than {limits.max_files} files")
            if total > limits.max_total_bytes:
                raise BundleError(f"bundle is larger than {limits.max_total_bytes} bytes")

    if entry is None:
        xmls = sorted(p for p in root.glob("*.xml"))
        if len(xmls) != 1:
            raise BundleError(f"bundle has {len(xmls)} XML files at its root; name the scene file (entry)")
        entry_path = xmls[0]
    else:
        entry_path = _check_reference(root, root, entry, "entry")
        if entry_path.suffix.lower() != ".xml":
            raise BundleError(f"entry {entry!r} is not an .xml file")

    plugins: set[str] = set()
    warnings: list[str] = []
    referenced: set[Path] = set()
    faces = 0
    pixels = 0

    def visit(xml: Path, depth: int, inherited: dict[str, str]) -> None:
        nonlocal faces, pixels
        if depth > limits.max_include_depth:
            raise BundleError(f"{_rel(root, xml)}: includes nested deeper than {limits.max_include_depth}")
        el = _parse(xml, limits)
        if el.tag != "scene":
            raise BundleError(f"{_rel(root, xml)}: root element is <{el.tag}>, expected <scene>")
        defaults = {**_defaults(el), **inherited}
        base = xml.parent
        for node in el.iter():
            tag = node.tag
            if tag == "path":
                raise BundleError(f"{_rel(root, xml)}: <path> elements (extra search paths) are not allowed")
            if tag == "include":
                inc = _check_reference(root, base, _subst(node.get("filename", ""), defaults), "include")
                referenced.add(inc)
                if inc.suffix.lower() == ".xml":
                    visit(inc, depth + 1, defaults)
                continue
            if tag in ALLOWED_PLUGINS:
                kind = _subst(node.get("type", ""), defaults)
                if tag == "spectrum" and not kind:
                    continue
                if kind not in ALLOWED_PLUGINS[tag]:
                    raise BundleError(f"{_rel(root, xml)}: unknown or disallowed {tag} plugin {kind!r}")
                plugins.add(f"{tag}:{kind}")
            if tag == "string" and node.get("name") == "filename":
                ref = _check_reference(root, base, _subst(node.get("value", ""), defaults), "filename")
                referenced.add(ref)
                ext = ref.suffix.lower()
                if ext == ".obj":
                    faces += _obj_faces(ref)
                elif ext == ".ply":
                    faces += _ply_faces(ref)
                elif ext in _FILE_EXT_IMAGE:
                    pixels += _image_pixels(ref, warnings)
                if faces > limits.max_mesh_faces:
                    raise BundleError(f"meshes declare more than {limits.max_mesh_faces} faces")
                if pixels > limits.max_image_pixels:
                    raise BundleError(f"images hold more than {limits.max_image_pixels} pixels")

    visit(entry_path, 0, {})
    unused = [p for p in files if p not in referenced and p != entry_path and p.suffix.lower() != ".xml"]
    if unused:
        warnings.append(f"{len(unused)} file(s) not referenced by the scene, e.g. {_rel(root, unused[0])}")
    h = hashlib.sha256()
    for p in sorted(files, key=lambda q: _rel(root, q)):
        h.update(_rel(root, p).encode() + b"\0")
        with p.open("rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
        h.update(b"\0")
    return BundleReport(entry=entry_path, files=sorted(_rel(root, p) for p in files), total_bytes=total,
                        sha256=h.hexdigest(), plugins=sorted(plugins), warnings=warnings, mesh_faces=faces,
                        image_pixels=pixels)
