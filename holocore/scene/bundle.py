"""Scene bundles: a folder holding a Mitsuba 3 XML scene and every file it references, checked before Mitsuba
parses anything (the service runs it on every upload; `holo` runs it before every load).

The check sees what Mitsuba will do, with Mitsuba's own rules, probed against Mitsuba 3.9:
- ``<default>`` parameters form one ordered namespace over the entry and its includes, the first definition
  wins; we refuse a name defined twice, and a value holding ``$``. ``$name`` is substituted in every attribute
  of every element (types, names, values, file names), the longest name first, in one pass
  (``holocore.scene.bundle_xml.Params``);
  anything left with a ``$`` is refused (Mitsuba would call it an undefined parameter), and so is an attribute
  Mitsuba's replace-in-turn could read otherwise.
- Every relative reference (``filename`` attributes and strings, ``<include>``, in the entry or in an include)
  resolves against the entry's folder, never the including file's; it must name a regular file inside the
  bundle. Absolute paths, ``~``, URLs, ``..`` components and backslashes are refused, as are ``<path>``
  elements (extra search paths) and symbolic links leaving the bundle.
- Every file in the bundle is of a kind a scene reads, judged by its content (``holocore.scene.filekinds``): no
  shared object or executable can be in a bundle under any name, and no file may be named like a shared object.
- The XML is read with defusedxml (no DTDs, entities or external references); element names and plugin types
  must be on allow-lists; caps bound bytes, files, includes, ``<default>`` parameters, element depth, the XML
  walked in all (each include every time), mesh faces/vertices and image pixels (read from headers as Mitsuba
  reads them, by content: a PNG named ``t.dat`` counts as an image; every use of a file counts). Only UTF-8 XML
  is read; every parser error is a BundleError. Plugins that read a file must name it (``_NEEDS_FILENAME``),
  plugins Mitsuba crashes on without a property need it (``_NEEDS_PROPERTY``), a sampler's ``sample_count`` is
  bounded, a film's size is bounded (:func:`film_size_error`), and property names hold no whitespace.
- The scene's ``<integrator>`` is ignored: the hologram brings its own. ``entry_source`` gives the entry XML
  with its top-level integrators blanked (line and column numbers kept), and the report says what was ignored.
Pure Python: no Mitsuba import.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from holocore.scene.bundle_files import check_reference, content_sha256, file_reference, list_files, rel_name
from holocore.scene.bundle_xml import Params, parse_xml
from holocore.scene.errors import BundleError
from holocore.scene.filekinds import (
    IMAGE_KINDS,
    FileKindError,
    image_pixels,
    obj_counts,
    ply_counts,
    serialized_counts,
)

__all__ = ["BundleError", "BundleLimits", "BundleReport", "validate_bundle", "entry_source", "content_sha256",
           "ALLOWED_PLUGINS", "ALLOWED_TAGS", "IGNORED_PLUGIN_TAGS"]


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
    # every XML byte walked (an include counts each time it is included) plus what substitution adds
    max_xml_total_bytes: int = 16 * 1024 * 1024
    max_defaults: int = 100
    max_xml_depth: int = 100  # element nesting, through includes (Mitsuba's parser recurses per level)

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"BundleLimits.{name} must be a positive integer, got {value!r}")


@dataclass
class BundleReport:
    """What a valid bundle holds. ``entry`` is the absolute path of the scene XML; ``files`` are relative
    POSIX paths; ``sha256`` names the content unambiguously (see ``content_sha256``); ``kinds`` maps each file
    to its kind by content; ``ignored`` lists scene elements the hologram renderer does not use."""

    entry: Path
    files: list[str]
    total_bytes: int
    sha256: str
    plugins: list[str]
    warnings: list[str] = field(default_factory=list)
    mesh_faces: int = 0
    image_pixels: int = 0
    kinds: dict[str, str] = field(default_factory=dict)
    ignored: list[str] = field(default_factory=list)


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
# Plugin elements the hologram renderer ignores: stripped from the entry before Mitsuba parses it, so their
# type is never instantiated (any type is accepted there).
IGNORED_PLUGIN_TAGS = ("integrator",)
# What a plugin's file must be, by content.
_EXPECTED_KINDS = {"shape:obj": ({"text"}, "an OBJ mesh"), "shape:ply": ({"ply"}, "a PLY mesh"),
                   "shape:serialized": ({"serialized"}, "a Mitsuba serialized mesh"),
                   "texture:bitmap": (IMAGE_KINDS, "a readable image"), "emitter:envmap": (IMAGE_KINDS,
                                                                                         "a readable image")}
# Plugins that read a file named by their ``filename`` string property. Mitsuba's bitmap texture dereferences
# a missing one (SIGSEGV); the others fail later with a less clear message, so all of them must name it.
_NEEDS_FILENAME = {"texture:bitmap", "emitter:envmap", "shape:obj", "shape:ply", "shape:serialized",
                   "shape:bsplinecurve", "shape:linearcurve", "bsdf:measured", "volume:gridvolume"}
# Properties without which Mitsuba 3.9 crashes loading the plugin (``<bsdf type="blendbsdf"/>`` alone: SIGSEGV).
_NEEDS_PROPERTY = {"bsdf:blendbsdf": ("weight",)}
# A sampler's sample_count Mitsuba 3.9 survives: 0 divides by zero in multijitter (SIGFPE), and near 2**32
# stratified, orthogonal and ldsampler never finish their constructor. The renderer brings its own sampler, so
# the scene's is only instantiated.
_MAX_SAMPLE_COUNT = 1 << 16
# A film's size: nothing renders at it (the hologram has its own resolution), but it gives the camera's aspect, and
# the scene's picture (holocore.evaluate.groundtruth.camera_picture) follows that aspect: a film of 1 x 30,000,000
# px made a picture 30 M px tall and held the planner for minutes. Each side and the area are bounded here, at
# upload, and again when a scene is loaded (holocore.scene.load.sensor_film_hw), by this one rule.
MAX_FILM_SIDE_PX = 16384
MAX_FILM_PIXELS = 1 << 26
_DEFAULT_FILM_HW = (576, 768)  # Mitsuba's film without a width or height


def film_size_error(height_px: int, width_px: int) -> Optional[str]:
    """Why a film of ``height_px`` x ``width_px`` pixels is refused (None when it is not), in one line."""
    if not (1 <= height_px <= MAX_FILM_SIDE_PX and 1 <= width_px <= MAX_FILM_SIDE_PX):
        return (f"the camera's film is {width_px} x {height_px} px: each side must be 1 to {MAX_FILM_SIDE_PX} px "
                "(the film gives the camera's aspect; the hologram has its own resolution)")
    if height_px * width_px > MAX_FILM_PIXELS:
        return (f"the camera's film is {width_px} x {height_px} px: at most {MAX_FILM_PIXELS} px in all "
                "(the film gives the camera's aspect; the hologram has its own resolution)")
    return None
class _Walker:
    """One pass over the entry and its includes in document order, as Mitsuba's parser reads them."""

    def __init__(self, root: Path, entry: Path, limits: BundleLimits, kinds: dict[str, str]) -> None:
        self.root, self.base, self.limits, self.kinds = root, entry.parent, limits, kinds
        self.entry = entry
        self.params = Params(limits)
        self.xml_bytes = 0  # charged against limits.max_xml_total_bytes
        self.parsed: dict[Path, object] = {}  # each XML file is parsed once, however often it is included
        self.plugins: set[str] = set()
        self.ignored: list[str] = []
        self.warnings: list[str] = []
        self.referenced: set[Path] = set()
        self.faces = self.verts = self.pixels = self.includes = 0
        self.stack: list[Path] = []
        self.shape_index = 0  # of the serialized shape being walked

    def account(self, ref: Path, plugin: Optional[str], shape_index: int = 0) -> None:
        """Count what loading ``ref`` for ``plugin`` costs. Every use counts: each plugin element loads its own
        copy of its file (two shapes naming one mesh hold it twice)."""
        rel = rel_name(self.root, ref)
        kind = self.kinds.get(rel, "")
        expected = _EXPECTED_KINDS.get(plugin or "")
        if expected is not None and kind not in expected[0]:
            raise BundleError(f"{rel}: {plugin} needs {expected[1]}, but the file is not one (by its content: "
                              f"{kind})")
        try:
            if kind in IMAGE_KINDS:
                self.pixels += image_pixels(ref, rel, kind, max_pixels=self.limits.max_image_pixels)
            elif kind == "ply":
                f, v = ply_counts(ref, rel)
                self.faces, self.verts = self.faces + f, self.verts + v
            elif kind == "serialized" and plugin == "shape:serialized":
                f, v = serialized_counts(ref, rel, shape_index)
                self.faces, self.verts = self.faces + f, self.verts + v
            elif kind == "text" and plugin == "shape:obj":
                f, v = obj_counts(ref)
                self.faces, self.verts = self.faces + f, self.verts + v
        except FileKindError as exc:
            raise BundleError(str(exc)) from None
        if self.faces > self.limits.max_mesh_faces:
            raise BundleError(f"meshes declare more than {self.limits.max_mesh_faces} faces ({rel})")
        if self.verts > self.limits.max_mesh_vertices:
            raise BundleError(f"meshes declare more than {self.limits.max_mesh_vertices} vertices ({rel})")
        if self.pixels > self.limits.max_image_pixels:
            raise BundleError(f"images hold more than {self.limits.max_image_pixels} pixels ({rel})")

    def charge(self, n: int) -> None:
        self.xml_bytes += n
        if self.xml_bytes > self.limits.max_xml_total_bytes:
            raise BundleError(f"the scene's XML (entry and includes, each time it is included, and what $parameters "
                              f"add) is larger than {self.limits.max_xml_total_bytes} bytes")

    def visit(self, xml: Path, depth: int = 0) -> None:
        name = rel_name(self.root, xml)
        if xml in self.stack:
            raise BundleError(f"{name}: includes itself (include cycle)")
        if len(self.stack) >= self.limits.max_include_depth:
            raise BundleError(f"{name}: includes nested deeper than {self.limits.max_include_depth}")
        if self.kinds.get(name) != "xml":
            raise BundleError(f"{name}: is not an XML file (by its content)")
        self.stack.append(xml)
        self.charge(xml.stat().st_size)
        el = self.parsed.get(xml)
        if el is None:
            el = self.parsed[xml] = parse_xml(xml, self.limits, name)
        if el.tag != "scene":
            raise BundleError(f"{name}: root element is <{str(el.tag)[:40]}>, expected <scene>")
        self.element(el, name, parent=None, top=True, depth=depth + 1)
        self.stack.pop()

    def element(self, node, name: str, *, parent: Optional[str], top: bool, depth: int) -> dict[str, str]:
        """Walk ``node``'s children; returns the property names they define (name -> element tag)."""
        if depth > self.limits.max_xml_depth:  # through includes: each file alone is capped while parsing
            raise BundleError(f"{name}: XML elements nested deeper than {self.limits.max_xml_depth} (through "
                              "includes)")
        props: dict[str, str] = {}
        for child in node:
            tag = child.tag
            if not isinstance(tag, str):
                continue  # comments and processing instructions
            if tag == "path":
                raise BundleError(f"{name}: <path> elements (extra search paths) are not allowed")
            if tag not in ALLOWED_TAGS:
                raise BundleError(f"{name}: unknown XML element <{tag[:40]}>")
            where = f"{name}: <{tag}>"
            if tag == "default":
                self.params.define(child.get("name", ""), child.get("value", ""), name)
                continue
            attrs = {}
            for k, v in child.attrib.items():
                attrs[k] = out = self.params.substitute(v, where, self.limits.max_xml_total_bytes - self.xml_bytes)
                if out is not v:
                    self.charge(max(0, len(out) - len(v)))
            pname = attrs.get("name")
            if pname is not None:
                if not pname or any(ch.isspace() or ord(ch) < 32 or ord(ch) == 127 for ch in pname):
                    raise BundleError(f"{where}: name {pname[:60]!r}: property names may not be empty or hold "
                                      "spaces or control characters")
                props[pname] = tag
                if tag == "integer" and pname == "sample_count" and (parent or "").startswith("sampler:"):
                    _check_sample_count(attrs.get("value", ""), where)
            if tag in IGNORED_PLUGIN_TAGS and top and len(self.stack) == 1:
                self.ignored.append(f"the scene's <{tag} type={attrs.get('type', '')[:40]!r}> (the hologram "
                                    "renderer brings its own)")
                continue
            if tag == "include":
                self.includes += 1
                if self.includes > self.limits.max_includes:
                    raise BundleError(f"scene has more than {self.limits.max_includes} includes")
                inc = check_reference(self.root, self.base, attrs.get("filename", ""), f"{name}: include")
                self.referenced.add(inc)
                self.visit(inc, depth)
                continue
            kind = attrs.get("type")
            if tag in ALLOWED_PLUGINS and kind is not None:
                if kind not in ALLOWED_PLUGINS[tag]:
                    raise BundleError(f"{name}: unknown or disallowed {tag} plugin {kind[:40]!r}")
                self.plugins.add(f"{tag}:{kind}")
            plugin = f"{tag}:{kind}" if tag in ALLOWED_PLUGINS else None
            if plugin == "shape:serialized":  # read before its filename, in whatever order the two come
                self.shape_index = _shape_index(child, self.params, where)
            value = file_reference(tag, attrs)
            if value is not None:
                ref = check_reference(self.root, self.base, value, f"{name}: filename")
                self.referenced.add(ref)
                user = parent if tag == "string" else plugin
                self.account(ref, user, self.shape_index if user == "shape:serialized" else 0)
            inner = self.element(child, name, parent=plugin, top=False, depth=depth + 1)
            if tag == "film":
                _check_film(child, self.params, where)
            if plugin in _NEEDS_FILENAME and inner.get("filename") != "string":
                raise BundleError(f"{where} type={kind!r}: needs a <string name=\"filename\" value=\"...\"/> "
                                  "naming its file (exactly that name, lower case)")
            for needed in _NEEDS_PROPERTY.get(plugin or "", ()):
                if needed not in inner:
                    raise BundleError(f"{where} type={kind!r}: needs its {needed!r} property (Mitsuba crashes "
                                      "without it)")
        return props


def _check_sample_count(text: str, where: str) -> None:
    """A sampler's ``sample_count``: an integer from 1 to ``_MAX_SAMPLE_COUNT``, written plainly."""
    m = re.fullmatch(r"\s*\+?([0-9]{1,9})\s*", text)
    if m is None or not 1 <= int(m.group(1)) <= _MAX_SAMPLE_COUNT:
        raise BundleError(f"{where}: sample_count {text[:40]!r} must be an integer from 1 to {_MAX_SAMPLE_COUNT} "
                          "(the hologram renderer chooses its own rays per pixel)")


def _check_film(node, params: Params, where: str) -> None:
    """A film's width and height (Mitsuba's defaults where it gives none), by :func:`film_size_error`."""
    size = {"height": _DEFAULT_FILM_HW[0], "width": _DEFAULT_FILM_HW[1]}
    for child in node:
        if child.tag == "integer" and child.get("name") in size:
            text = params.substitute(child.get("value", ""), where, 1 << 10)
            if not re.fullmatch(r"\s*\+?[0-9]{1,9}\s*", text):
                raise BundleError(f"{where}: film {child.get('name')} {text[:40]!r} must be an integer from 1 to "
                                  f"{MAX_FILM_SIDE_PX}")
            size[child.get("name")] = int(text)
    why = film_size_error(size["height"], size["width"])
    if why is not None:
        raise BundleError(f"{where}: {why}")


def _shape_index(node, params: Params, where: str) -> int:
    """A serialized shape's ``shape_index`` (default 0), as Mitsuba reads the integer."""
    for child in node:
        if child.tag == "integer" and child.get("name") == "shape_index":
            text = params.substitute(child.get("value", ""), where, 1 << 10)
            if not re.fullmatch(r"\s*\+?[0-9]{1,9}", text):
                raise BundleError(f"{where}: shape_index {text[:40]!r} is not a non-negative integer")
            return int(text)
    return 0


def validate_bundle(root: str | Path, *, entry: Optional[str] = None, limits: BundleLimits = BundleLimits()
                    ) -> BundleReport:
    """Check a scene folder (``entry``: the scene XML relative to it, needed when the root holds several XML
    files); returns what it holds or raises :class:`BundleError` saying why not."""
    if not isinstance(limits, BundleLimits):
        raise ValueError(f"limits must be a BundleLimits, got {type(limits).__name__}")
    root_in = Path(root)
    if not root_in.is_dir():
        raise BundleError(f"scene bundle {root_in.name or root_in} is not a folder")
    root = root_in.resolve()
    files, total, kinds = list_files(root, limits)
    if entry is None:
        xmls = sorted(p for p in root.glob("*.xml") if p.is_file())
        if len(xmls) != 1:
            raise BundleError(f"bundle has {len(xmls)} XML files at its root; name the scene file (entry)")
        entry_path = xmls[0]
    else:
        entry_path = check_reference(root, root, entry, "entry")
        if entry_path.suffix.lower() != ".xml":
            raise BundleError(f"entry {entry[:120]!r} is not an .xml file")
    w = _Walker(root, entry_path, limits, kinds)
    w.visit(entry_path)
    unused = [p for p in files if p not in w.referenced and p != entry_path and kinds[rel_name(root, p)] != "xml"]
    warnings = list(w.warnings)
    if unused:
        warnings.append(f"{len(unused)} file(s) not referenced by the scene, e.g. {rel_name(root, unused[0])}")
    return BundleReport(entry=entry_path, files=sorted(rel_name(root, p) for p in files), total_bytes=total,
                        sha256=content_sha256(root, files), plugins=sorted(w.plugins), warnings=warnings,
                        mesh_faces=w.faces, image_pixels=w.pixels, kinds=kinds, ignored=w.ignored)


def entry_source(report: BundleReport) -> str:
    """The entry XML as Mitsuba should parse it: its top-level ``IGNORED_PLUGIN_TAGS`` elements blanked with
    spaces (newlines kept, so Mitsuba's line and column numbers still point into the user's file)."""
    import xml.parsers.expat

    raw = Path(report.entry).read_bytes()
    spans: list[list[int]] = []
    depth = [0]
    pending: list[list[int]] = []  # spans waiting for the byte index where they end

    def close_pending() -> None:
        while pending:
            pending.pop()[1] = p.CurrentByteIndex

    def start(tag, attrs):  # noqa: ARG001
        close_pending()
        depth[0] += 1
        if depth[0] == 2 and tag in IGNORED_PLUGIN_TAGS:
            spans.append([p.CurrentByteIndex, -1, depth[0]])

    def end(tag):  # noqa: ARG001
        close_pending()
        if spans and spans[-1][1] == -1 and spans[-1][2] == depth[0]:
            pending.append(spans[-1])
        depth[0] -= 1

    def other(*_):
        close_pending()

    p = xml.parsers.expat.ParserCreate()
    p.StartElementHandler, p.EndElementHandler = start, end
    p.CharacterDataHandler = p.CommentHandler = p.ProcessingInstructionHandler = p.DefaultHandler = other
    p.Parse(raw, True)
    out = bytearray(raw)
    for a, b, _ in spans:
        for i in range(a, b):
            if out[i] not in (10, 13):
                out[i] = 32
    return out.decode("utf-8")
