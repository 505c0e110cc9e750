"""Scene bundles: a folder holding a Mitsuba 3 XML scene and every file it references, checked before Mitsuba
parses anything (issue 3 item 1, issue 5 item 6; the service runs it on every upload).

Rules (the *bundle-confinement rule*): every referenced file (``filename`` attributes and strings,
``<include>``) must resolve to a regular file inside the bundle; absolute paths, ``~``, ``..`` escapes,
symbolic links leaving the bundle and ``<path>`` elements (extra search paths) are refused. The XML is read
with defusedxml (no DTDs, no entities, no external references), element names and plugins must be on
allow-lists, and caps bound bytes, files, includes, mesh faces/vertices (read from OBJ lines or PLY headers,
with declared counts checked against the file size) and image pixels (headers only: Pillow for PNG/JPEG/...,
hand-read headers for EXR, HDR and PFM). Pure Python: no Mitsuba import.
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
import struct
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Optional

__all__ = ["BundleError", "BundleLimits", "BundleReport", "validate_bundle", "ALLOWED_PLUGINS", "ALLOWED_TAGS"]


class BundleError(ValueError):
    """The bundle is refused; the message says why."""


@dataclass(frozen=True)
class BundleLimits:
    """Caps on what a bundle may hold (bytes, counts, pixels)."""

    max_total_bytes: int = 512 * 1024 * 1024
    max_files: int = 2000
    max_mesh_faces: int = 20_000_000
    max_mesh_vertices: int = 20_000_000
    max_image_pixels: int = 64 * 1024 * 1024
    max_xml_bytes: int = 8 * 1024 * 1024
    max_include_depth: int = 8
    max_includes: int = 256

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"BundleLimits.{name} must be a positive integer, got {value!r}")


@dataclass
class BundleReport:
    """What a valid bundle holds. ``entry`` is the absolute path of the scene XML; ``files`` are relative
    POSIX paths; ``sha256`` hashes sorted (relative path, bytes) pairs, so it names the content."""

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
# Every other element Mitsuba 3's XML parser knows (values, transforms, references). Anything else is refused.
ALLOWED_TAGS = set(ALLOWED_PLUGINS) | {
    "scene", "default", "include", "ref", "alias", "boolean", "integer", "float", "string", "point", "vector",
    "rgb", "color", "transform", "translate", "rotate", "scale", "matrix", "lookat",
}
_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".bmp", ".tga", ".exr", ".hdr", ".rgbe", ".pfm", ".ppm", ".pgm"}
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _rel(root: Path, p: Path) -> str:
    return p.relative_to(root).as_posix()


def _inside(root: Path, target: Path) -> bool:
    try:
        target.relative_to(root)
        return True
    except ValueError:
        return False


def _check_reference(root: Path, base: Path, value: str, what: str) -> Path:
    """Resolve a reference made from a file in folder ``base`` (inside root); refuse escapes and misses."""
    if not value or "\x00" in value or len(value) > 4096:
        raise BundleError(f"{what}: empty or invalid file reference")
    norm = value.replace("\\", "/")
    pure = PurePosixPath(norm)
    if pure.is_absolute() or re.match(r"^[A-Za-z]:", value) or value.startswith("~") or "://" in value:
        raise BundleError(f"{what}: absolute path {value!r} is not allowed; paths must be relative to the bundle")
    if "$" in norm:
        raise BundleError(f"{what}: {value!r} uses an undefined $parameter")
    candidates = [(base / Path(*pure.parts)).resolve(), (root / Path(*pure.parts)).resolve()]
    if not _inside(root, candidates[0]):
        raise BundleError(f"{what}: {value!r} leaves the scene bundle")
    for cand in candidates:
        # Mitsuba resolves relative to the including file's folder, then to the entry's; both must stay inside.
        if _inside(root, cand) and cand.is_file():
            return cand
    raise BundleError(f"{what}: {value!r} is referenced but not in the bundle")


def _parse(path: Path, limits: BundleLimits, name: str):
    from xml.etree.ElementTree import ParseError

    from defusedxml import DefusedXmlException
    from defusedxml.ElementTree import parse

    if path.stat().st_size > limits.max_xml_bytes:
        raise BundleError(f"{name}: XML larger than {limits.max_xml_bytes} bytes")
    try:
        return parse(str(path), forbid_dtd=True, forbid_entities=True, forbid_external=True).getroot()
    except DefusedXmlException as exc:
        raise BundleError(f"{name}: refused XML construct ({type(exc).__name__}): DTDs, entities and external "
                          "references are not allowed") from None
    except (ParseError, UnicodeError, ValueError) as exc:
        raise BundleError(f"{name}: not well-formed XML: {exc}") from None


def _defaults(root_el) -> dict[str, str]:
    return {d.get("name", ""): d.get("value", "") for d in root_el.iter("default")}


def _subst(value: str, defaults: dict[str, str]) -> str:
    return re.sub(r"\$(\w+)", lambda m: defaults.get(m.group(1), m.group(0)), value)


def _obj_counts(path: Path) -> tuple[int, int]:
    """(triangles, vertices) of a Wavefront OBJ, streaming its lines (polygons count as fans)."""
    faces = verts = 0
    with path.open("rb") as fh:
        for line in fh:
            s = line.lstrip()
            if s[:2] in (b"f ", b"f\t"):
                faces += max(1, len(s.split()) - 3)
            elif s[:2] in (b"v ", b"v\t"):
                verts += 1
    return faces, verts


def _ply_counts(path: Path, name: str) -> tuple[int, int]:
    """(faces, vertices) declared in a PLY header; refuses headers whose counts need more bytes than the file
    holds (a tiny file declaring a billion faces would make the loader allocate for them)."""
    size = path.stat().st_size
    elements: list[list] = []  # [name, count, min binary bytes per item, values per item]
    fmt = None
    with path.open("rb") as fh:
        first = fh.readline(64).strip()
        if first != b"ply":
            raise BundleError(f"{name}: not a PLY file")
        for _ in range(1000):
            line = fh.readline(4096)
            if not line:
                raise BundleError(f"{name}: PLY header has no end_header")
            parts = line.split()
            if not parts or parts[0] in (b"comment", b"obj_info"):
                continue
            if parts[0] == b"end_header":
                break
            try:
                if parts[0] == b"format":
                    fmt = parts[1].decode()
                elif parts[0] == b"element":
                    n = int(parts[2])
                    if n < 0:
                        raise ValueError
                    elements.append([parts[1].decode(errors="replace"), n, 0, 0])
                elif parts[0] == b"property" and elements:
                    if parts[1] == b"list":  # count type, item type: at least the count plus 3 indices
                        elements[-1][2] += _PLY_SIZES[parts[2].decode()] + 3 * _PLY_SIZES[parts[3].decode()]
                        elements[-1][3] += 4
                    else:
                        elements[-1][2] += _PLY_SIZES[parts[1].decode()]
                        elements[-1][3] += 1
            except (IndexError, ValueError, KeyError, UnicodeError):
                raise BundleError(f"{name}: malformed PLY header line {line[:60]!r}") from None
        else:
            raise BundleError(f"{name}: PLY header too long")
    counts = {e[0]: e[1] for e in elements}
    if fmt is None:
        raise BundleError(f"{name}: PLY header has no format line")
    # ASCII needs at least 2 bytes (digit + separator) per value, binary the property sizes.
    need = sum(e[1] * (2 * e[3] if fmt == "ascii" else e[2]) for e in elements)
    if need > size:
        raise BundleError(f"{name}: PLY header declares {counts} elements needing at least {need} bytes, but the "
                          f"file holds {size}")
    return counts.get("face", 0), counts.get("vertex", 0)


def _exr_pixels(path: Path, name: str) -> int:
    with path.open("rb") as fh:
        head = fh.read(65536)
    if head[:4] != b"\x76\x2f\x31\x01":
        raise BundleError(f"{name}: not an OpenEXR file")
    pos = 8
    while pos < len(head):
        end = head.find(b"\0", pos)
        if end < 0 or end == pos:
            break
        attr = head[pos:end]
        tend = head.find(b"\0", end + 1)
        if tend < 0 or tend + 5 > len(head):
            break
        (size,) = struct.unpack("<i", head[tend + 1:tend + 5])
        value = head[tend + 5:tend + 5 + size]
        if attr == b"dataWindow" and len(value) == 16:
            x0, y0, x1, y1 = struct.unpack("<4i", value)
            return max(0, x1 - x0 + 1) * max(0, y1 - y0 + 1)
        pos = tend + 5 + max(size, 0)
    raise BundleError(f"{name}: OpenEXR header without a readable dataWindow")


def _hdr_pixels(path: Path, name: str) -> int:
    with path.open("rb") as fh:
        for _ in range(200):
            line = fh.readline(4096)
            if not line:
                break
            m = re.match(rb"^([-+])([YX]) (\d+) ([-+])([YX]) (\d+)\s*$", line)
            if m:
                return int(m.group(3)) * int(m.group(6))
    raise BundleError(f"{name}: Radiance HDR header without a resolution line")


def _pfm_pixels(path: Path, name: str) -> int:
    with path.open("rb") as fh:
        tokens = fh.read(256).split()
    try:
        if tokens[0] not in (b"PF", b"Pf"):
            raise ValueError
        return int(tokens[1]) * int(tokens[2])
    except (IndexError, ValueError):
        raise BundleError(f"{name}: malformed PFM header") from None


def _image_pixels(path: Path, name: str, limits: BundleLimits) -> int:
    ext = path.suffix.lower()
    if ext == ".exr":
        return _exr_pixels(path, name)
    if ext in (".hdr", ".rgbe"):
        return _hdr_pixels(path, name)
    if ext == ".pfm":
        return _pfm_pixels(path, name)
    from PIL import Image

    try:
        with Image.open(path) as im:  # parses the header only; pixels are decoded on load()
            w, h = im.size
    except Image.DecompressionBombError:
        raise BundleError(f"{name}: image declares more than {limits.max_image_pixels} pixels") from None
    except Exception:  # noqa: BLE001 - Pillow raises many types for damaged files
        raise BundleError(f"{name}: not a readable image") from None
    return int(w) * int(h)


def _is_file_reference(node) -> Optional[str]:
    """The file path an element names, if any: a ``filename`` attribute, or a string property whose name
    says it is a file (``filename``, ``*_filename``, ``*file``)."""
    if node.get("filename") is not None:
        return node.get("filename")
    if node.tag == "string":
        pname = (node.get("name") or "").lower()
        if pname == "filename" or pname.endswith("filename") or pname.endswith("file"):
            return node.get("value", "")
    return None


def _list_files(root: Path, limits: BundleLimits) -> tuple[list[Path], int]:
    files: list[Path] = []
    total = 0
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        d = Path(dirpath)
        for name in list(dirnames):
            p = d / name
            if p.is_symlink():
                if not _inside(root, p.resolve()):
                    raise BundleError(f"{_rel(root, p)}: symbolic link leaves the bundle")
        for name in filenames:
            p = d / name
            rel = _rel(root, p)
            if p.is_symlink() and not _inside(root, p.resolve()):
                raise BundleError(f"{rel}: symbolic link leaves the bundle")
            try:
                st = p.stat()
            except OSError:
                raise BundleError(f"{rel}: dangling symbolic link or unreadable file") from None
            if not stat.S_ISREG(st.st_mode):
                raise BundleError(f"{rel}: not a regular file (devices, FIFOs and sockets are refused)")
            files.append(p)
            total += st.st_size
            if len(files) > limits.max_files:
                raise BundleError(f"bundle holds more than {limits.max_files} files")
            if total > limits.max_total_bytes:
                raise BundleError(f"bundle is larger than {limits.max_total_bytes} bytes")
    return files, total


def validate_bundle(root: str | Path, *, entry: Optional[str] = None, limits: BundleLimits = BundleLimits()
                    ) -> BundleReport:
    """Check a scene folder (``entry``: the scene XML relative to it, needed when the root holds several XML
    files); returns what it holds or raises :class:`BundleError` saying why not."""
    if not isinstance(limits, BundleLimits):
        raise ValueError(f"limits must be a BundleLimits, got {type(limits).__name__}")
    root_in = Path(root)
    if not root_in.is_dir():
        raise BundleError(f"scene bundle {root_in} is not a folder")
    root = root_in.resolve()
    files, total = _list_files(root, limits)

    if entry is None:
        xmls = sorted(p for p in root.glob("*.xml") if p.is_file())
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
    counted: set[Path] = set()
    totals = {"faces": 0, "verts": 0, "pixels": 0, "includes": 0}
    stack: list[Path] = []

    def account(ref: Path, rel: str) -> None:
        if ref in counted:  # a mesh or image used twice is loaded once
            return
        counted.add(ref)
        ext = ref.suffix.lower()
        if ext == ".obj":
            f, v = _obj_counts(ref)
        elif ext == ".ply":
            f, v = _ply_counts(ref, rel)
        elif ext == ".serialized":
            f = v = 0
            warnings.append(f"{rel}: face count of .serialized meshes is not checked before loading (bytes are)")
        elif ext in _IMAGE_EXT:
            totals["pixels"] += _image_pixels(ref, rel, limits)
            f = v = 0
        else:
            f = v = 0
        totals["faces"] += f
        totals["verts"] += v
        if totals["faces"] > limits.max_mesh_faces:
            raise BundleError(f"meshes declare more than {limits.max_mesh_faces} faces ({rel})")
        if totals["verts"] > limits.max_mesh_vertices:
            raise BundleError(f"meshes declare more than {limits.max_mesh_vertices} vertices ({rel})")
        if totals["pixels"] > limits.max_image_pixels:
            raise BundleError(f"images hold more than {limits.max_image_pixels} pixels ({rel})")

    def visit(xml: Path, inherited: dict[str, str]) -> None:
        name = _rel(root, xml)
        if xml in stack:
            raise BundleError(f"{name}: includes itself (include cycle)")
        if len(stack) >= limits.max_include_depth:
            raise BundleError(f"{name}: includes nested deeper than {limits.max_include_depth}")
        stack.append(xml)
        el = _parse(xml, limits, name)
        if el.tag != "scene":
            raise BundleError(f"{name}: root element is <{el.tag}>, expected <scene>")
        defaults = {**_defaults(el), **inherited}
        base = xml.parent
        for node in el.iter():
            tag = node.tag
            if not isinstance(tag, str):
                continue  # comments and processing instructions
            if tag == "path":
                raise BundleError(f"{name}: <path> elements (extra search paths) are not allowed")
            if tag not in ALLOWED_TAGS:
                raise BundleError(f"{name}: unknown XML element <{tag[:40]}>")
            if tag == "include":
                totals["includes"] += 1
                if totals["includes"] > limits.max_includes:
                    raise BundleError(f"scene has more than {limits.max_includes} includes")
                inc = _check_reference(root, base, _subst(node.get("filename", ""), defaults), "include")
                if inc.suffix.lower() != ".xml":
                    raise BundleError(f"include: {_rel(root, inc)} is not an .xml file")
                referenced.add(inc)
                visit(inc, defaults)
                continue
            if tag in ALLOWED_PLUGINS and node.get("type") is not None:
                kind = _subst(node.get("type", ""), defaults)
                if kind not in ALLOWED_PLUGINS[tag]:
                    raise BundleError(f"{name}: unknown or disallowed {tag} plugin {kind[:40]!r}")
                plugins.add(f"{tag}:{kind}")
            value = _is_file_reference(node)
            if value is not None:
                ref = _check_reference(root, base, _subst(value, defaults), f"{name}: filename")
                referenced.add(ref)
                account(ref, _rel(root, ref))
        stack.pop()

    visit(entry_path, {})
    unused = [p for p in files if p not in referenced and p != entry_path and p.suffix.lower() != ".xml"]
    if unused:
        warnings.append(f"{len(unused)} file(s) not referenced by the scene, e.g. {_rel(root, unused[0])}")
    h = hashlib.sha256()
    for p in sorted(files, key=lambda q: _rel(root, q)):
        h.update(_rel(root, p).encode("utf-8", "surrogateescape") + b"\0")
        with p.open("rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
        h.update(b"\0")
    return BundleReport(entry=entry_path, files=sorted(_rel(root, p) for p in files), total_bytes=total,
                        sha256=h.hexdigest(), plugins=sorted(plugins), warnings=warnings,
                        mesh_faces=totals["faces"], image_pixels=totals["pixels"])
