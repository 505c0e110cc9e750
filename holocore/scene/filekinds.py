"""What a file in a scene bundle is, judged by its content (magic bytes), never by its name, and the sizes its
header declares (mesh faces and vertices, image pixels). Pure Python: no Mitsuba import.

A bundle may hold only what a Mitsuba scene reads: XML, meshes (PLY, Mitsuba serialized, OBJ and other text),
images (PNG, JPEG, BMP, TGA, OpenEXR, Radiance HDR, PFM, PNM), grid volumes and tensor files (measured BSDFs).
Anything else (shared objects, executables, archives, unknown binaries) is refused, so nothing in a bundle can
ever be loaded as code, whatever its name (a ``plugins/sphere.so`` in a bundle would be Mitsuba's plugin).
"""

from __future__ import annotations

import codecs
import re
import struct
from pathlib import Path

__all__ = ["FileKindError", "IMAGE_KINDS", "ALLOWED_KINDS", "sniff_kind", "image_pixels", "obj_counts", "ply_counts",
           "serialized_counts"]


class FileKindError(ValueError):
    """The file is not a kind a scene bundle may hold, or its header is malformed; the message says why."""


IMAGE_KINDS = frozenset({"png", "jpeg", "bmp", "tga", "exr", "hdr", "pfm", "pnm"})
ALLOWED_KINDS = IMAGE_KINDS | {"xml", "text", "ply", "serialized", "volume", "tensor", "empty"}
_ALLOWED_WORDS = ("XML, meshes (PLY, OBJ, Mitsuba serialized), images (PNG, JPEG, BMP, TGA, EXR, HDR, PFM, PNM), "
                  "spectra and other text, grid volumes, tensor files")
_EXECUTABLE = ((b"\x7fELF", "an ELF executable or shared library"), (b"MZ", "a Windows executable"),
               (b"\xcf\xfa\xed\xfe", "a Mach-O binary"), (b"\xfe\xed\xfa\xcf", "a Mach-O binary"),
               (b"\xca\xfe\xba\xbe", "a Mach-O or Java binary"), (b"#!", "a script"))
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _is_text(head: bytes, complete: bool) -> bool:
    if b"\0" in head:
        return False
    try:
        codecs.getincrementaldecoder("utf-8")().decode(head, final=complete)
    except UnicodeDecodeError:
        return False
    return True


def sniff_kind(path: Path, name: str) -> str:
    """The kind of ``path`` from its first bytes (one of ``ALLOWED_KINDS``); FileKindError for anything else.
    ``name`` is the bundle-relative name used in messages."""
    with path.open("rb") as fh:
        head = fh.read(65536)
        complete = len(head) < 65536
    if not head:
        return "empty"
    for magic, what in _EXECUTABLE:
        if head.startswith(magic):
            raise FileKindError(f"{name}: is {what}; a scene bundle may hold only {_ALLOWED_WORDS}")
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if head.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if head.startswith(b"v/1\x01"):
        return "exr"
    if head.startswith((b"#?RADIANCE", b"#?RGBE")):
        return "hdr"
    if re.match(rb"P[fF]\s", head):
        return "pfm"
    if re.match(rb"P[1-6]\s", head):
        return "pnm"
    if head.startswith(b"BM") and len(head) >= 26:
        return "bmp"
    if re.match(rb"ply\r?\n", head):
        return "ply"
    if head.startswith(b"\x1c\x04"):
        return "serialized"
    if head.startswith(b"VOL") and len(head) > 3 and head[3] == 3:
        return "volume"
    if head.startswith(b"tensor_file\0"):
        return "tensor"
    if _is_text(head, complete):
        stripped = head.lstrip(b"\xef\xbb\xbf \t\r\n")
        return "xml" if stripped.startswith(b"<") else "text"
    if path.suffix.lower() == ".tga" and _pillow_format(path) == "TGA":  # TGA has no magic bytes
        return "tga"
    raise FileKindError(f"{name}: unknown binary file; a scene bundle may hold only {_ALLOWED_WORDS}")


def _pillow_format(path: Path) -> str | None:
    from PIL import Image

    try:
        with Image.open(path) as im:
            return im.format
    except Exception:  # noqa: BLE001 - Pillow raises many types for files it does not read
        return None


def obj_counts(path: Path) -> tuple[int, int]:
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


def ply_counts(path: Path, name: str) -> tuple[int, int]:
    """(faces, vertices) declared in a PLY header; refuses headers whose counts need more bytes than the file
    holds (a tiny file declaring a billion faces would make the loader allocate for them)."""
    size = path.stat().st_size
    elements: list[list] = []  # [name, count, min binary bytes per item, values per item]
    fmt = None
    with path.open("rb") as fh:
        if fh.readline(64).strip() != b"ply":
            raise FileKindError(f"{name}: not a PLY file")
        for _ in range(1000):
            line = fh.readline(4096)
            if not line:
                raise FileKindError(f"{name}: PLY header has no end_header")
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
                raise FileKindError(f"{name}: malformed PLY header line {line[:60]!r}") from None
        else:
            raise FileKindError(f"{name}: PLY header too long")
    counts = {e[0]: e[1] for e in elements}
    if fmt is None:
        raise FileKindError(f"{name}: PLY header has no format line")
    # ASCII needs at least 2 bytes (digit + separator) per value, binary the property sizes.
    need = sum(e[1] * (2 * e[3] if fmt == "ascii" else e[2]) for e in elements)
    if need > size:
        raise FileKindError(f"{name}: PLY header declares {counts} elements needing at least {need} bytes, but "
                            f"the file holds {size}")
    return counts.get("face", 0), counts.get("vertex", 0)


_SERIALIZED_HEADER, _SERIALIZED_V3, _SERIALIZED_V4 = 0x041C, 3, 4
_SERIALIZED_MAX_NAME = 4096  # bytes of a mesh name Mitsuba reads before its counts (a NUL-terminated string)
_DEFLATE_MAX_RATIO = 1100  # no zlib stream inflates to more than about 1032 times its size


def _inflate_head(fh, offset: int, size: int, want: int) -> bytes:
    """The first ``want`` inflated bytes of the zlib stream at ``offset`` (or fewer when the stream ends);
    reads at most what it needs, so a bomb inside a mesh costs nothing here."""
    import zlib

    fh.seek(offset)
    d = zlib.decompressobj()
    out = b""
    left = size - offset
    while len(out) < want and left > 0 and not d.eof:
        chunk = fh.read(min(4096, left))
        if not chunk:
            break
        left -= len(chunk)
        out += d.decompress(chunk, want - len(out))
        while d.unconsumed_tail and len(out) < want:
            out += d.decompress(d.unconsumed_tail, want - len(out))
    return out[:want]


def serialized_counts(path: Path, name: str, shape_index: int) -> tuple[int, int]:
    """(faces, vertices) of mesh ``shape_index`` of a Mitsuba serialized file, as its loader finds them
    (serialized.cpp, Mitsuba 3.9): index 0 is the stream right after the file's 4-byte header, any other one is
    found through the offset table at the end of the file (the first header's version decides its layout); the
    counts are the uint64 vertex and face counts inside the zlib stream, after the flags word and (version 4)
    the mesh name. The loader allocates for those counts before reading any vertex, so they are what a mesh
    costs; counts that need more data than the compressed bytes can hold, streams that cannot be read and
    indices out of the table are refused."""
    import zlib

    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(4)
        if len(head) < 4:
            raise FileKindError(f"{name}: serialized mesh shorter than its header")
        fmt, version = struct.unpack("<HH", head)
        if fmt != _SERIALIZED_HEADER or version not in (_SERIALIZED_V3, _SERIALIZED_V4):
            raise FileKindError(f"{name}: not a Mitsuba serialized mesh of version 3 or 4")
        offset = 4
        if shape_index != 0:
            if size < 8:
                raise FileKindError(f"{name}: serialized mesh has no offset table for shape_index {shape_index}")
            fh.seek(size - 4)
            (count,) = struct.unpack("<I", fh.read(4))
            if shape_index >= count:
                raise FileKindError(f"{name}: shape_index {shape_index} is out of range (the file's table lists "
                                    f"{count} meshes)")
            width = 8 if version == _SERIALIZED_V4 else 4
            at = size - 4 - width * (count - shape_index)
            if at < 4:
                raise FileKindError(f"{name}: serialized mesh offset table is larger than the file")
            fh.seek(at)
            (start,) = struct.unpack("<Q" if width == 8 else "<I", fh.read(width))
            offset = start + 4  # the loader skips the mesh's own 4-byte header without reading it
            if offset >= size:
                raise FileKindError(f"{name}: shape_index {shape_index} points past the end of the file")
        want = 4 + (_SERIALIZED_MAX_NAME + 1 if version == _SERIALIZED_V4 else 0) + 16
        try:
            data = _inflate_head(fh, offset, size, want)
        except zlib.error:
            raise FileKindError(f"{name}: serialized mesh {shape_index}: damaged zlib stream") from None
    pos = 4
    if version == _SERIALIZED_V4:
        end = data.find(b"\0", 4)
        if end < 0:
            raise FileKindError(f"{name}: serialized mesh {shape_index}: no mesh name within "
                                f"{_SERIALIZED_MAX_NAME} bytes (or the stream ends)")
        pos = end + 1
    if len(data) < pos + 16:
        raise FileKindError(f"{name}: serialized mesh {shape_index}: the stream ends inside its header")
    flags = struct.unpack_from("<I", data, 0)[0]
    verts, faces = struct.unpack_from("<QQ", data, pos)
    scalar = 8 if flags & 0x2000 else 4
    per_vertex = 3 + 3 * bool(flags & 0x1) + 2 * bool(flags & 0x2) + 3 * bool(flags & 0x8)
    need = verts * per_vertex * scalar + faces * 12
    if need > (size - offset) * _DEFLATE_MAX_RATIO:
        raise FileKindError(f"{name}: serialized mesh {shape_index} declares {faces} faces and {verts} vertices, "
                            f"more than its {size - offset} compressed bytes can hold")
    return faces, verts


_EXR_HEADER_BYTES = 65536
_EXR_MULTIPART, _EXR_NON_IMAGE = 0x1000, 0x800  # version-field flags: several parts; deep data


def _exr_pixels(path: Path, name: str) -> int:
    """Pixels of an OpenEXR file's data window, read as OpenEXR reads its header: every attribute up to the
    header's end, where a later attribute of a name replaces an earlier one (a 1-pixel ``dataWindow`` before
    the real one hid it), so a name given twice is refused, as are a ``dataWindow`` that is not a box2i, a
    header that does not end in its first 64 KiB, and multi-part or deep files (one header is read here)."""
    with path.open("rb") as fh:
        head = fh.read(_EXR_HEADER_BYTES)
    if len(head) < 9:
        raise FileKindError(f"{name}: OpenEXR file shorter than its header")
    (version,) = struct.unpack_from("<I", head, 4)
    if version & (_EXR_MULTIPART | _EXR_NON_IMAGE):
        raise FileKindError(f"{name}: multi-part and deep OpenEXR files are not supported; save one scan-line or "
                            "tiled image")
    pos, seen, window = 8, set(), None
    while True:
        if pos >= len(head):
            raise FileKindError(f"{name}: OpenEXR header does not end within its first {_EXR_HEADER_BYTES} bytes")
        if head[pos] == 0:  # the header's end
            break
        end = head.find(b"\0", pos)
        tend = head.find(b"\0", end + 1) if end >= 0 else -1
        if tend < 0 or tend + 5 > len(head):
            raise FileKindError(f"{name}: OpenEXR header does not end within its first {_EXR_HEADER_BYTES} bytes")
        attr, kind = head[pos:end], head[end + 1:tend]
        (size,) = struct.unpack_from("<i", head, tend + 1)
        if size < 0:
            raise FileKindError(f"{name}: OpenEXR attribute {attr[:40]!r} has a bad size")
        if tend + 5 + size > len(head):
            raise FileKindError(f"{name}: OpenEXR header does not end within its first {_EXR_HEADER_BYTES} bytes")
        if attr in seen:
            raise FileKindError(f"{name}: OpenEXR header defines {attr[:40].decode('ascii', 'replace')!r} twice "
                                "(OpenEXR keeps the last)")
        seen.add(attr)
        if attr == b"dataWindow":
            if kind != b"box2i" or size != 16:
                raise FileKindError(f"{name}: OpenEXR dataWindow is not a box2i")
            window = struct.unpack_from("<4i", head, tend + 5)
        pos = tend + 5 + size
    if window is None:
        raise FileKindError(f"{name}: OpenEXR header without a readable dataWindow")
    x0, y0, x1, y1 = window
    return max(0, x1 - x0 + 1) * max(0, y1 - y0 + 1)


_HDR_HEADER_BYTES = 65536
_C_SPACE = b" \t\n\v\f\r"


def _stoull32(token: bytes) -> int | None:
    """The uint32 Mitsuba makes of a resolution token (``(uint32_t) std::stoull``: leading C whitespace, an
    optional sign, decimal digits, anything after them ignored); None where that would throw, wrap or go
    negative (a value Mitsuba would read as something else than it says)."""
    m = re.match(rb"([-+]?)(\d+)", token.lstrip(_C_SPACE))
    if m is None:
        return None
    value = int(m.group(2))
    if value >= 1 << 32 or (m.group(1) == b"-" and value != 0):
        return None
    return value


def _rgbe_size(line: bytes) -> tuple[int, int] | None | bool:
    """What Mitsuba's Radiance reader makes of one header line (Bitmap::read_rgbe, Mitsuba 3.9): a resolution
    line is one that splits on spaces and commas into exactly ``-Y H +X W``. Returns (height, width), None
    for any other line, False for a resolution line whose numbers it would not read as written."""
    if line.startswith((b"FORMAT=32-bit_rle_rgbe", b"FORMAT=32-bit_rle_xyze")):
        return None
    tokens = [t for t in re.split(rb"[ ,]", line) if t]
    if len(tokens) != 4 or tokens[0] != b"-Y" or tokens[2] != b"+X":
        return None
    h, w = _stoull32(tokens[1]), _stoull32(tokens[3])
    return False if h is None or w is None else (h, w)


def _hdr_pixels(path: Path, name: str) -> int:
    """Pixels of a Radiance HDR file, read the way Mitsuba reads its header: after the ``#?`` line, every line
    up to the first resolution line, which may come with extra spaces, commas, zero padding or ``+`` signs
    (``-Y  +09000 +X 9000``) and need not follow an empty line. A header Mitsuba could read in two ways (its file
    stream keeps carriage returns, its other streams drop them) or that this reader cannot follow is refused."""
    with path.open("rb") as fh:
        head = fh.read(_HDR_HEADER_BYTES)
    lines = head.split(b"\n")
    if not lines[0].startswith(b"#?"):
        raise FileKindError(f"{name}: Radiance HDR file without its '#?' first line")
    seen_format = False
    for line in lines[1:-1]:  # the last piece has no newline yet: it may be cut
        kept, dropped = _rgbe_size(line), _rgbe_size(line.replace(b"\r", b""))
        if kept != dropped:
            raise FileKindError(f"{name}: Radiance HDR header line {line[:60]!r} reads differently with and "
                                "without its carriage returns")
        if kept is False:
            raise FileKindError(f"{name}: Radiance HDR resolution line {line[:60]!r} holds a size that is "
                                "negative, too large or not a number")
        if kept is not None:
            if not seen_format:
                raise FileKindError(f"{name}: Radiance HDR header has no FORMAT line before its resolution")
            return kept[0] * kept[1]
        seen_format = seen_format or line.startswith((b"FORMAT=32-bit_rle_rgbe", b"FORMAT=32-bit_rle_xyze"))
    raise FileKindError(f"{name}: Radiance HDR header without a resolution line in its first "
                        f"{_HDR_HEADER_BYTES} bytes")


def _pfm_pixels(path: Path, name: str) -> int:
    with path.open("rb") as fh:
        tokens = fh.read(256).split()
    try:
        if tokens[0] not in (b"PF", b"Pf") or len(tokens[1]) > 9 or len(tokens[2]) > 9:
            raise ValueError
        return int(tokens[1]) * int(tokens[2])
    except (IndexError, ValueError):
        raise FileKindError(f"{name}: malformed PFM header") from None


def image_pixels(path: Path, name: str, kind: str, *, max_pixels: int) -> int:
    """Pixels an image of ``kind`` declares in its header (the pixels are never decoded)."""
    if kind == "exr":
        return _exr_pixels(path, name)
    if kind == "hdr":
        return _hdr_pixels(path, name)
    if kind == "pfm":
        return _pfm_pixels(path, name)
    from PIL import Image

    try:
        with Image.open(path) as im:  # parses the header only; pixels are decoded on load()
            w, h = im.size
    except Image.DecompressionBombError:
        raise FileKindError(f"{name}: image declares more than {max_pixels} pixels") from None
    except Exception:  # noqa: BLE001 - Pillow raises many types for damaged files
        raise FileKindError(f"{name}: not a readable image") from None
    return int(w) * int(h)
