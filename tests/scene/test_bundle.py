"""Scene-bundle safety beyond confinement: declared mesh and image sizes read from headers,
include cycles, unknown elements, non-regular files, references hidden in other attributes."""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import pytest

from holocore.scene.bundle import BundleError, BundleLimits, validate_bundle

SCENE = '<scene version="3.0.0"><sensor type="perspective"/>{body}</scene>'


def make(tmp_path: Path, body: str, files: dict[str, bytes] | None = None, name: str = "b") -> Path:
    root = tmp_path / name
    root.mkdir()
    (root / "scene.xml").write_text(SCENE.format(body=body))
    for rel, data in (files or {}).items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    return root


def ply(n_vert: int, n_face: int, *, binary: bool = True, body: bytes = b"") -> bytes:
    fmt = "binary_little_endian 1.0" if binary else "ascii 1.0"
    return (f"ply\nformat {fmt}\nelement vertex {n_vert}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {n_face}\nproperty list uchar int vertex_indices\nend_header\n").encode() + body


def png_header(w: int, h: int) -> bytes:
    """A well-formed PNG declaring w x h pixels with (almost) no pixel data."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b"")


def exr_header(w: int, h: int) -> bytes:
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    return (b"\x76\x2f\x31\x01" + b"\x02\0\0\0" + b"channels\0chlist\0" + struct.pack("<i", 1) + b"\0"
            + b"dataWindow\0box2i\0" + struct.pack("<i", 16) + box + b"\0")


def shape(fname: str, kind: str = "ply") -> str:
    return f'<shape type="{kind}"><string name="filename" value="{fname}"/></shape>'


def bitmap(fname: str) -> str:
    return f'<bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" ' \
           f'value="{fname}"/></texture></bsdf>'


def test_small_binary_ply_passes_and_counts_faces(tmp_path):
    body = struct.pack("<9f", *range(9)) + b"\x03" + struct.pack("<3i", 0, 1, 2)
    rep = validate_bundle(make(tmp_path, shape("m.ply"), {"m.ply": ply(3, 1, body=body)}))
    assert rep.mesh_faces == 1 and rep.plugins == ["sensor:perspective", "shape:ply"]


@pytest.mark.parametrize("n_vert, n_face, binary", [(3, 10**9, True), (10**12, 1, True), (10**8, 10, False)])
def test_ply_declaring_more_than_the_file_holds_is_refused(tmp_path, n_vert, n_face, binary):
    root = make(tmp_path, shape("m.ply"), {"m.ply": ply(n_vert, n_face, binary=binary, body=b"\0" * 64)})
    with pytest.raises(BundleError, match="declares .* needing at least"):
        validate_bundle(root)


def test_ply_over_the_face_cap_is_refused_even_when_consistent(tmp_path):
    body = b"\0" * (3 * 12 + 5 * 13)
    root = make(tmp_path, shape("m.ply"), {"m.ply": ply(3, 5, body=body)})
    assert validate_bundle(root).mesh_faces == 5
    with pytest.raises(BundleError, match="more than 4 faces"):
        validate_bundle(root, limits=BundleLimits(max_mesh_faces=4))


def test_malformed_ply_headers_are_refused(tmp_path):
    root = make(tmp_path, shape("m.ply"), {"m.ply": b"ply\nformat ascii 1.0\nelement face -3\nend_header\n"})
    with pytest.raises(BundleError, match="malformed PLY header"):
        validate_bundle(root)
    root2 = make(tmp_path, shape("m.ply"), {"m.ply": b"ply\nformat ascii 1.0\n" + b"comment x\n" * 2000},
                 name="c")
    with pytest.raises(BundleError, match="PLY header too long"):
        validate_bundle(root2)


@pytest.mark.parametrize("fname, data", [
    ("t.png", png_header(100_000, 100_000)),
    ("t.exr", exr_header(20_000, 20_000)),
    ("t.hdr", b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 30000 +X 30000\n"),
    ("t.pfm", b"PF\n30000 30000\n-1.0\n"),
])
def test_images_declaring_huge_sizes_are_refused_from_their_headers(tmp_path, fname, data):
    root = make(tmp_path, bitmap(fname), {fname: data})
    with pytest.raises(BundleError, match="pixels"):
        validate_bundle(root)


def test_real_small_image_is_counted(tmp_path):
    from PIL import Image

    root = make(tmp_path, bitmap("t.png"))
    Image.new("RGB", (7, 5)).save(root / "t.png")
    assert validate_bundle(root).image_pixels == 35
    (root / "t.png").write_bytes(b"not an image")
    with pytest.raises(BundleError, match="needs a readable image"):
        validate_bundle(root)


def test_include_cycles_and_include_floods_are_refused(tmp_path):
    root = make(tmp_path, '<include filename="a.xml"/>',
                {"a.xml": b'<scene version="3.0.0"><include filename="scene.xml"/></scene>'})
    with pytest.raises(BundleError, match="include cycle"):
        validate_bundle(root, entry="scene.xml")
    flood = "".join('<include filename="leaf.xml"/>' for _ in range(300))
    root2 = make(tmp_path, flood, {"inc/leaf.xml": b'<scene version="3.0.0"/>'}, name="flood")
    (root2 / "leaf.xml").write_bytes(b'<scene version="3.0.0"/>')
    with pytest.raises(BundleError, match="more than 256 includes"):
        validate_bundle(root2, entry="scene.xml")


@pytest.mark.parametrize("body, words", [
    ('<spectrum name="eta" filename="../../etc/hosts"/>', "leaves the scene bundle"),
    ('<bsdf type="measured"><string name="filename" value="/etc/passwd"/></bsdf>', "absolute path"),
    ('<shape type="obj"><string name="filename" value="$undefined/x.obj"/></shape>', "undefined"),
    ('<shape type="obj"><string name="filename" value="file:///etc/passwd"/></shape>', "absolute path"),
    ('<default name="d" value="../.."/><shape type="obj"><string name="filename" value="$d/x.obj"/></shape>',
     "leaves the scene bundle"),
    ('<script type="python">import os</script>', "unknown XML element <script>"),
    ('<default name="i" value="python"/><bsdf type="$i"/>', "disallowed bsdf plugin 'python'"),
    ('<bsdf type="$i"/><default name="i" value="diffuse"/>', "undefined"),  # Mitsuba: defaults come first
])
def test_references_and_elements_outside_the_rules_are_refused(tmp_path, body, words):
    with pytest.raises(BundleError, match=words):
        validate_bundle(make(tmp_path, body))


def test_fifo_and_dangling_links_are_refused(tmp_path):
    root = make(tmp_path, "")
    os.mkfifo(root / "pipe")
    with pytest.raises(BundleError, match="not a regular file"):
        validate_bundle(root)
    root2 = make(tmp_path, "", name="c")
    os.symlink(root2 / "nowhere", root2 / "dangling")
    with pytest.raises(BundleError, match="dangling"):
        validate_bundle(root2)


def test_symlink_inside_the_bundle_is_fine_and_hash_follows_content(tmp_path):
    obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    root = make(tmp_path, shape("link.obj", "obj"), {"real/a.obj": obj})
    os.symlink(root / "real" / "a.obj", root / "link.obj")
    rep = validate_bundle(root)
    assert rep.mesh_faces == 1 and "link.obj" in rep.files
    other = make(tmp_path, shape("link.obj", "obj"), {"real/a.obj": obj, "link.obj": obj}, name="copy")
    assert validate_bundle(other).sha256 == rep.sha256  # same relative paths and bytes -> same hash


def test_bad_limits_and_missing_folder(tmp_path):
    with pytest.raises(ValueError, match="max_files"):
        BundleLimits(max_files=0)
    with pytest.raises(BundleError, match="not a folder"):
        validate_bundle(tmp_path / "nope")
    root = make(tmp_path, "")
    (root / "second.xml").write_text(SCENE.format(body=""))
    with pytest.raises(BundleError, match="name the scene file"):
        validate_bundle(root)
    assert validate_bundle(root, entry="second.xml").entry.name == "second.xml"
