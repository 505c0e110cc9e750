"""Hostile scene bundles, second round: what a bundle's files and XML could still slip past the bundle check
(Radiance HDR and serialized-mesh headers read otherwise than Mitsuba reads them, ``<default>`` floods, deep
or oddly encoded XML, plugins that crash Mitsuba without a file name, shared objects by name, zip central
directory floods), the planner's working directory, and jobs on scenes that crash Mitsuba. Each test builds the
attack and checks what the service does with it; the last one sends them all to a real `holo serve`."""

from __future__ import annotations

import io
import os
import signal
import struct
import subprocess
import sys
import time
import tracemalloc
import zipfile
import zlib
from pathlib import Path

import httpx
import pytest

from holocore.scene.bundle import BundleError, BundleLimits, validate_bundle
from holocore.scene.bundle_xml import Params
from holocore.scene.filekinds import FileKindError, image_pixels
from tests.service.helpers import REPO, Server, wait_for

SCENE = '<scene version="3.0.0"><sensor type="perspective"/>{body}</scene>'
BITMAP = ('<bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="{v}"/>'
          '</texture></bsdf>')
SERIALIZED = '<shape type="serialized"><string name="filename" value="{v}"/>{extra}</shape>'
HDR_HEAD = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n"


def bundle(tmp: Path, body: str, files: dict[str, bytes] | None = None, name: str = "b") -> Path:
    root = tmp / name
    root.mkdir(parents=True)
    (root / "scene.xml").write_text(SCENE.format(body=body))
    for rel, data in (files or {}).items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
    return root


def mitsuba():
    from holocore.runtime.mitsuba_env import mitsuba as mi

    return mi()


# ---- Radiance HDR: the resolution line as Mitsuba reads it ----------------------------------------------------
def test_hdr_decoy_resolution_line_no_longer_hides_the_real_one(tmp_path):
    """The old check took the first line looking like ``[-+][YX] N [-+][YX] M``: a ``+Y 1 +X 1`` decoy counted 1
    pixel while Mitsuba skipped it and read the double-spaced line after it (9000 x 9000)."""
    data = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n+Y 1 +X 1\n\n-Y  9000  +X 9000\n" + b"\0" * 64
    root = bundle(tmp_path, BITMAP.format(v="sky.hdr"), {"sky.hdr": data})
    with pytest.raises(BundleError, match="images hold more than 67108864 pixels"):
        validate_bundle(root)


@pytest.mark.parametrize("line, pixels", [
    (b"-Y 3 +X 5", 15), (b"-Y  3  +X  5", 15), (b"-Y 003 +X 0005", 15), (b"-Y +3 +X +5", 15),
    (b" -Y 3 +X 5", 15), (b"-Y,3,+X,5", 15), (b"-Y 3abc +X 5", 15), (b"-Y 3 +X 5\r", 15),
])
def test_hdr_resolution_counted_as_mitsuba_reads_it(tmp_path, line, pixels):
    """Each header is loaded by Mitsuba too: the count is what Mitsuba's Bitmap reads, not what a regex saw."""
    p = tmp_path / "t.hdr"
    p.write_bytes(HDR_HEAD + line + b"\n" + b"\x80\x80\x80\x80" * pixels)
    assert image_pixels(p, "t.hdr", "hdr", max_pixels=1 << 26) == pixels
    w, h = mitsuba().Bitmap(str(p)).size()
    assert w * h == pixels


@pytest.mark.parametrize("data, words", [
    (HDR_HEAD + b"-Y 4294967299 +X 5\n", "negative, too large"),  # Mitsuba wraps it to 3 rows
    (HDR_HEAD + b"-Y -3 +X 5\n", "negative, too large"),  # Mitsuba: 2**32 - 3 rows
    (b"#?RADIANCE\n-Y 3 +X 5\nFORMAT=32-bit_rle_rgbe\n\n", "no FORMAT line"),
    (HDR_HEAD + b"-Y 3 +X 5 \r\n", "carriage returns"),
    (HDR_HEAD + b"#" * 70000 + b"\n-Y 9000 +X 9000\n", "without a resolution line"),
])
def test_hdr_headers_mitsuba_would_misread_are_refused(tmp_path, data, words):
    p = tmp_path / "t.hdr"
    p.write_bytes(data)
    with pytest.raises(FileKindError, match=words):
        image_pixels(p, "t.hdr", "hdr", max_pixels=1 << 26)


# ---- Mitsuba serialized meshes: faces from the inflated headers -----------------------------------------------
def ser_mesh(faces: int, verts: int = 3, *, real: bool = True, name: bytes = b"m") -> bytes:
    """One version-4 mesh (header + zlib stream): float positions, ``faces`` faces (all 0 1 2)."""
    head = struct.pack("<I", 0x1000) + name + b"\0" + struct.pack("<QQ", verts, faces)
    body = struct.pack(f"<{3 * verts}f", *([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] * verts)[:3 * verts])
    body += struct.pack("<3I", 0, 1, 2) * faces if real else b""
    return struct.pack("<HH", 0x041C, 4) + zlib.compress(head + body)


def ser_file(*meshes: bytes, table: list[int] | None = None) -> bytes:
    """Meshes one after another, then the offset table Mitsuba reads for shape_index > 0."""
    out, offsets = b"", []
    for m in meshes:
        offsets.append(len(out))
        out += m
    table = offsets if table is None else table
    return out + b"".join(struct.pack("<Q", o) for o in table) + struct.pack("<I", len(table))


def test_serialized_faces_are_counted_and_capped(tmp_path):
    """The old check counted no serialized faces at all (a warning); a mesh over the cap now is refused."""
    limits = BundleLimits(max_mesh_faces=1000)
    ok = bundle(tmp_path, SERIALIZED.format(v="m.serialized", extra=""), {"m.serialized": ser_file(ser_mesh(700))})
    assert validate_bundle(ok, limits=limits).mesh_faces == 700
    big = bundle(tmp_path, SERIALIZED.format(v="m.serialized", extra=""), {"m.serialized": ser_file(ser_mesh(1001))},
                 name="big")
    with pytest.raises(BundleError, match="meshes declare more than 1000 faces"):
        validate_bundle(big, limits=limits)


def test_serialized_counts_agree_with_mitsuba(tmp_path):
    """shape_index 1 is found through the file's offset table, as Mitsuba finds it."""
    from holocore.scene.filekinds import serialized_counts

    p = tmp_path / "two.serialized"
    p.write_bytes(ser_file(ser_mesh(4), ser_mesh(9, verts=5)))
    mi = mitsuba()
    for index, faces, verts in ((0, 4, 3), (1, 9, 5)):
        assert serialized_counts(p, "two.serialized", index) == (faces, verts)
        mesh = mi.load_dict({"type": "serialized", "filename": str(p), "shape_index": index})
        assert (mesh.face_count(), mesh.vertex_count()) == (faces, verts)


def test_serialized_tricks_are_refused_or_counted(tmp_path):
    limits = BundleLimits(max_mesh_faces=1000)
    # 21 million faces declared in a few bytes: no data could hold them
    bomb = bundle(tmp_path, SERIALIZED.format(v="m.serialized", extra=""),
                  {"m.serialized": ser_file(ser_mesh(21_000_000, real=False))}, name="bomb")
    with pytest.raises(BundleError, match="more than its .* compressed bytes can hold"):
        validate_bundle(bomb)
    # one 600-face mesh, a table listing it twice, and two shapes loading index 0 and 1: two copies
    twice = SERIALIZED.format(v="m.serialized", extra="") + SERIALIZED.format(
        v="m.serialized", extra='<integer name="shape_index" value="1"/>')
    root = bundle(tmp_path, twice, {"m.serialized": ser_file(ser_mesh(600), table=[0, 0])}, name="twice")
    with pytest.raises(BundleError, match="more than 1000 faces"):
        validate_bundle(root, limits=limits)
    out_of_range = bundle(tmp_path, SERIALIZED.format(v="m.serialized", extra='<integer name="shape_index" '
                                                                              'value="5"/>'),
                          {"m.serialized": ser_file(ser_mesh(3))}, name="range")
    with pytest.raises(BundleError, match="shape_index 5 is out of range"):
        validate_bundle(out_of_range)
    long_name = bundle(tmp_path, SERIALIZED.format(v="m.serialized", extra=""),
                       {"m.serialized": ser_file(ser_mesh(3, name=b"n" * 100_000))}, name="longname")
    with pytest.raises(BundleError, match="no mesh name within 4096 bytes"):
        validate_bundle(long_name)
    damaged = bundle(tmp_path, SERIALIZED.format(v="m.serialized", extra=""),
                     {"m.serialized": struct.pack("<HH", 0x041C, 4) + b"\x78\x9c" + b"\xff" * 40}, name="damaged")
    with pytest.raises(BundleError, match="damaged zlib stream|ends inside its header"):
        validate_bundle(damaged)


def test_a_mesh_named_by_two_shapes_counts_twice(tmp_path):
    """Each shape loads its own copy: the old check counted a file once however many shapes named it."""
    ply = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
           b"element face 600\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
           + b"3 0 1 2\n" * 600)
    shape = '<shape type="ply"><string name="filename" value="m.ply"/></shape>'
    root = bundle(tmp_path, shape * 2, {"m.ply": ply})
    with pytest.raises(BundleError, match="more than 1000 faces"):
        validate_bundle(root, limits=BundleLimits(max_mesh_faces=1000))


def _count_calls(monkeypatch, owner, name: str) -> list[int]:
    """Count the calls of ``owner.name`` (a class's method or a module's function) from now on: [count]."""
    calls = [0]
    orig = getattr(owner, name)

    def counted(*args, **kwargs):
        calls[0] += 1
        return orig(*args, **kwargs)

    monkeypatch.setattr(owner, name, counted)
    return calls


# ---- <default> floods: one-pass substitution, caps --------------------------------------------------------------
def test_default_flood_is_refused_at_once(tmp_path, monkeypatch):
    """4000 defaults took the old check 91 s (every definition recompiled one regex of every name)."""
    defaults = "".join(f'<default name="p{i}" value="{i}"/>' for i in range(4000))
    uses = "".join(f'<float name="f{i}" value="$p{i % 100}"/>' for i in range(4000))
    root = bundle(tmp_path, defaults + f'<shape type="sphere">{uses}</shape>')
    defined = _count_calls(monkeypatch, Params, "define")
    with pytest.raises(BundleError, match="more than 100 <default> parameters"):
        validate_bundle(root)
    assert defined[0] == 101  # refused at the first definition past the cap, before any substitution


def test_substitution_at_the_cap_is_one_pass_and_right(tmp_path, monkeypatch):
    """At most one replacement (64 dictionary lookups at most) per ``$``: the work grows with the uses, not with
    uses x parameters as the old check's (which recompiled one regex of every name)."""
    defaults = "".join(f'<default name="p{i}" value="{i}"/>' for i in range(100))
    uses = "".join(f'<float name="f{i}" value="$p{i % 100}"/>' for i in range(20000))
    root = bundle(tmp_path, defaults + f'<shape type="sphere">{uses}</shape>')
    replaced = _count_calls(monkeypatch, Params, "_replace")
    validate_bundle(root)
    assert 0 < replaced[0] <= 20000

    params = Params(BundleLimits())
    for name, value in (("a", "A"), ("ab", "AB"), ("abc_1", "X")):
        params.define(name, value, "scene.xml")
    assert params.substitute("$ab/$a-$abc_1.$abq", "w", 1000) == "AB/A-X.ABq"  # longest name first
    # Mitsuba replaces "$bc" (longer) first and then finds "$aX": the two parsers would disagree
    params.define("aX", "Y", "scene.xml")
    params.define("bc", "X", "scene.xml")
    with pytest.raises(BundleError, match="could join it into a longer parameter name"):
        params.substitute("$a$bc", "w", 1000)


def test_one_huge_attribute_is_parsed_and_substituted_in_linear_time(tmp_path, monkeypatch):
    """7 MiB in one attribute, 2.4 million ``$a``: fed to expat in chunks, the token was rescanned per chunk, and
    each ``$`` cost a scan of every name (10 s before; well under a second now)."""
    root = bundle(tmp_path, '<default name="a" value="1"/><shape type="sphere"><string name="s" value="'
                  + "$a " * 2_400_000 + '"/></shape>')
    from defusedxml.ElementTree import XMLParser

    fed = _count_calls(monkeypatch, XMLParser, "feed")
    replaced = _count_calls(monkeypatch, Params, "_replace")
    validate_bundle(root)
    assert fed[0] == 1  # the whole file in one piece: expat scans the attribute once
    assert replaced[0] == 1  # one replacement for the one distinct segment, 2.4 million times reused


@pytest.mark.slow
def test_substitution_and_includes_cannot_blow_the_xml_up(tmp_path, monkeypatch):
    big = "1 " * 30000
    root = bundle(tmp_path, f'<default name="v" value="{big}"/>'
                  f'<shape type="sphere"><string name="s" value="{"$v" * 400}"/></shape>')
    with pytest.raises(BundleError, match="expand the scene's XML past 16777216 bytes"):
        validate_bundle(root)
    leaf = ('<scene version="3.0.0">' + '<float name="x" value="1"/>' * 8000 + "</scene>").encode()  # ~230 kB
    inc = bundle(tmp_path, '<include filename="leaf.xml"/>' * 100, {"leaf.xml": leaf}, name="inc")
    import holocore.scene.bundle as bundle_module

    parsed = _count_calls(monkeypatch, bundle_module, "parse_xml")
    with pytest.raises(BundleError, match="larger than 16777216 bytes"):
        validate_bundle(inc, entry="scene.xml")
    assert parsed[0] == 2  # the entry and the leaf once each: an include is walked again, never parsed again


# ---- XML that made the API answer 500 ------------------------------------------------------------------------------
def test_deep_nesting_and_odd_encodings_are_one_line_refusals(tmp_path):
    deep = bundle(tmp_path, '<shape type="sphere">' + "<transform name='t'>" * 1200 + "</transform>" * 1200
                  + "</shape>", name="deep")
    with pytest.raises(BundleError, match="nested deeper than 100"):
        validate_bundle(deep)
    via = bundle(tmp_path, '<include filename="i.xml"/>' * 1,
                 {"i.xml": ('<scene version="3.0.0"><shape type="sphere">' + "<transform name='t'>" * 99
                            + "</transform>" * 99 + "</shape></scene>").encode()}, name="via")
    with pytest.raises(BundleError, match="nested deeper than 100"):
        validate_bundle(via, entry="scene.xml")
    for name, decl in (("bogus", "x-bogus"), ("latin", "latin-1"), ("utf16", "UTF-16")):
        root = tmp_path / name
        root.mkdir()
        (root / "scene.xml").write_bytes(f"<?xml version='1.0' encoding='{decl}'?>".encode()
                                         + SCENE.format(body="").encode())
        with pytest.raises(BundleError, match=f"declares encoding '{decl}'; scene files must be UTF-8") as info:
            validate_bundle(root)
        assert "\n" not in str(info.value)
    long_name = bundle(tmp_path, '<shape type="obj"><string name="filename" value="%s.obj"/></shape>' % ("a" * 300),
                       name="longname")
    with pytest.raises(BundleError, match="is not a file of the bundle \\(File name too long\\)"):
        validate_bundle(long_name)  # was an OSError: a 500
    ok = tmp_path / "utf8"
    ok.mkdir()
    (ok / "scene.xml").write_bytes(b"<?xml version='1.0' encoding='UTF-8'?>" + SCENE.format(body="").encode())
    validate_bundle(ok)


# ---- plugins that crash Mitsuba --------------------------------------------------------------------------------------
@pytest.mark.parametrize("body, words", [
    ('<bsdf type="diffuse"><texture type="bitmap" name="reflectance"/></bsdf>', 'needs a <string name="filename"'),
    (BITMAP.replace('"filename"', '"filename "').format(v="t.png"), "property names may not be empty or hold spaces"),
    (BITMAP.replace('"filename"', '"Filename"').format(v="t.png"), 'needs a <string name="filename"'),
    ('<emitter type="envmap"/>', 'needs a <string name="filename"'),
    ('<shape type="ply"/>', 'needs a <string name="filename"'),
    ('<shape type="sphere"><float name=" radius" value="1"/></shape>', "property names may not"),
])
def test_plugins_that_crash_mitsuba_without_a_filename_are_refused(tmp_path, body, words):
    """The first three made Mitsuba's bitmap texture dereference a missing file name (SIGSEGV)."""
    from PIL import Image

    root = bundle(tmp_path, body)
    Image.new("RGB", (4, 4)).save(root / "t.png")
    with pytest.raises(BundleError, match=words):
        validate_bundle(root)


def _segv_module(tmp_path: Path, sig: int) -> str:
    (tmp_path / "die_now.py").write_text(f"import os\nos.kill(os.getpid(), {int(sig)})\n")
    return "die_now"


@pytest.mark.parametrize("sig, retryable", [(signal.SIGSEGV, False), (signal.SIGABRT, False),
                                            (signal.SIGKILL, True)])
def test_a_step_that_crashes_is_not_retried(tmp_path, monkeypatch, sig, retryable):
    from service.workers import driver

    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    job = tmp_path / "job"
    job.mkdir()
    with pytest.raises(driver.StepFailed) as info:
        driver._run("render", [], job, module=_segv_module(tmp_path, sig))
    assert info.value.retryable is retryable, str(info.value)


def test_jobs_queued_before_a_failed_plan_never_start(tmp_path):
    from service.db import Database
    from service.settings import ServiceSettings
    from service.workers.planner import Planner

    db = Database(tmp_path / "service.db")
    db.insert_scene({"id": "sbad", "sha256": "0" * 64, "entry": "scene.xml", "report": {}, "plan_state": "running",
                     "created_at": time.time()})
    for jid, scene in (("j1", "sbad"), ("j2", "sbad"), ("j3", "sgood")):
        db.insert_job({"id": jid, "state": "queued", "scene_id": scene, "spec": {}, "cache_key": jid,
                       "created_at": time.time()})
    Planner(ServiceSettings(data_dir=tmp_path), db)._store("sbad", None, "holo plan failed (exit -11)")
    assert [db.get_job(j)["state"] for j in ("j1", "j2", "j3")] == ["failed", "failed", "queued"]
    assert "plan failed" in db.get_job("j1")["error"]


# ---- plugins/<name>.so: by name, and never through the working directory -------------------------------------
def test_shared_object_names_are_refused_whatever_they_hold(tmp_path):
    for i, rel in enumerate(("plugins/sphere.so", "lib/libx.so.1.2", "x.DYLIB", "a.dll", "m.pyd")):
        root = bundle(tmp_path, "", {rel: b"just text\n"}, name=f"b{i}")
        with pytest.raises(BundleError, match="shared-object names"):
            validate_bundle(root)


def test_plugins_are_never_looked_up_in_the_working_directory(tmp_path):
    """The unsandboxed planner ran in the bundle's folder, and Mitsuba's default resolver starts with the working
    directory: preloading resolved ``plugins/sphere.so`` there, so the sphere plugin stayed unloaded and was
    looked up again in the scene's folder (a text one there failed the plan with "file too short"; an ELF one
    would have run). Here the folder is loaded without the bundle check, which now refuses the name."""
    scene = bundle(tmp_path, '<shape type="sphere"/>', {"plugins/sphere.so": b"not a plugin\n"}, name="scene")
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from holocore.scene.load import load_scene; "
            "print(len(load_scene(sys.argv[2], check_bundle=False).scene.shapes()))")
    env = dict(os.environ, HOLO_MI_VARIANT="scalar_rgb")
    proc = subprocess.run([sys.executable, "-c", code, str(REPO), str(scene)], capture_output=True, text=True,
                          timeout=300, cwd=scene, env=env)
    assert proc.returncode == 0 and proc.stdout.strip() == "1", proc.stderr[-1500:]


def test_the_planner_runs_in_an_empty_folder(tmp_path, monkeypatch):
    from service.settings import ServiceSettings
    from service.workers import planner as planner_mod

    seen = {}

    class FakePopen:
        def __init__(self, cmd, **kw):
            seen["cwd"] = Path(kw["cwd"])
            seen["listing"] = sorted(os.listdir(kw["cwd"]))
            self.returncode, self.pid = 0, os.getpid()
            self.stdout, self.stderr = io.BytesIO(b'{"summary": []}'), io.BytesIO(b"")

        def wait(self, timeout=None):
            return self.returncode

    class FakeDb:
        def update_scene(self, *a, **kw):
            seen["stored"] = kw

        def list_jobs(self, **kw):
            return []

    monkeypatch.setattr(planner_mod.subprocess, "Popen", FakePopen)
    settings = ServiceSettings(data_dir=tmp_path)
    (settings.scenes_dir / "s1" / "bundle").mkdir(parents=True)
    (settings.scenes_dir / "s1" / "bundle" / "scene.xml").write_text(SCENE.format(body=""))
    planner_mod.Planner(settings, FakeDb())._plan({"id": "s1", "entry": "scene.xml"})
    assert seen["listing"] == [] and seen["cwd"] != settings.scenes_dir / "s1" / "bundle", seen
    assert seen["stored"]["plan_state"] == "ready"


def test_a_plan_past_its_memory_is_stopped(tmp_path, monkeypatch):
    """The backstop for what a check misses: a plan whose resident memory outgrows its cap is killed and the
    scene's plan fails saying so (here a stand-in for `holo plan` that fills 600 MB)."""
    from service.settings import ServiceSettings
    from service.workers import planner as planner_mod

    stored = {}

    class FakeDb:
        def update_scene(self, *a, **kw):
            stored.update(kw)

        def list_jobs(self, **kw):
            return []

    settings = ServiceSettings(data_dir=tmp_path, plan_timeout_s=60)
    (settings.scenes_dir / "s1" / "bundle").mkdir(parents=True)
    p = planner_mod.Planner(settings, FakeDb())
    p.max_plan_rss_bytes = 150 * 1024 * 1024
    hog = "import time; x = bytearray(600 * 1024 * 1024); time.sleep(60)"
    monkeypatch.setattr(p, "_command", lambda entry: [sys.executable, "-c", hog])
    p._plan({"id": "s1", "entry": "scene.xml"})
    # the memory watch stopped it (the hog sleeps 60 s, the plan's timeout is 60 s: a timeout says so instead)
    assert stored["plan_state"] == "failed" and "used more than 0.2 GB of memory" in stored["plan_error"], stored


# ---- zip central-directory floods ----------------------------------------------------------------------------------
def cd_flood(entries: int, declared: int) -> bytes:
    """A zip holding only a central directory of ``entries`` one-letter members (no data), whose end record
    says ``declared``."""
    rec = struct.pack("<4s6H3I5H2I", b"PK\x01\x02", 20, 20, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0) + b"a"
    cd = rec * entries
    end = struct.pack("<4s4H2IH", b"PK\x05\x06", 0, 0, declared & 0xFFFF, declared & 0xFFFF, len(cd), 0, 0)
    return cd + end


@pytest.mark.parametrize("entries, declared, words", [
    (65000, 65000, "zip lists 65000 entries"),  # the count in the end record
    (100_000, 1, "holds more than 4000 entries"),  # a lying count: zipfile reads as many as the size covers
    (200_000, 1, "central directory is 9400000 bytes"),
])
def test_zip_central_directory_flood_is_refused_before_listing(tmp_path, entries, declared, words):
    from service.settings import UploadLimits
    from service.uploads import UploadError, unpack_zip

    data = cd_flood(entries, declared)
    tracemalloc.start()
    try:
        with pytest.raises(UploadError, match=words) as info:
            unpack_zip(io.BytesIO(data), tmp_path, limits=UploadLimits())
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert info.value.status == 413
    assert peak < len(data) + (4 << 20), peak  # the raw directory once, no object per entry


def test_zip_end_records_zipfile_chokes_on_are_one_line_refusals(tmp_path):
    from service.settings import UploadLimits
    from service.uploads import UploadError, unpack_zip

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("a", b"x")
    raw = buf.getvalue()
    at = raw.rfind(b"PK\x05\x06")  # a zip64 locator saying the archive spans two disks (BadZipFile: a 500)
    spanned = raw[:at] + struct.pack("<4sIQI", b"PK\x06\x07", 0, 0, 2) + raw[at:]
    for data in (spanned, b"PK\x05\x06" + b"\0" * 5, b""):
        with pytest.raises(UploadError, match="not a zip file"):
            unpack_zip(io.BytesIO(data), tmp_path, limits=UploadLimits())


# ---- the same attacks against a real server --------------------------------------------------------------------
def zbytes(members: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(zipfile.ZipInfo(name), data, compress_type=zipfile.ZIP_DEFLATED)
    return buf.getvalue()


def scene_zip(body: str, extra: dict[str, bytes] | None = None, head: bytes = b"") -> bytes:
    return zbytes({"scene.xml": head + SCENE.format(body=body).encode(), **(extra or {})})


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = Server(tmp_path_factory.mktemp("hostile-bundles") / "data", extra=("--max-upload-mb", "16")).start()
    yield srv
    srv.stop()


@pytest.mark.slow
def test_hostile_bundles_get_one_line_4xx_and_the_server_keeps_serving(server):
    decoy = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n+Y 1 +X 1\n\n-Y  9000  +X 9000\n" + os.urandom(256)
    cases = [
        ("hdr decoy", scene_zip(BITMAP.format(v="sky.hdr"), {"sky.hdr": decoy}), 422, "pixels"),
        ("serialized bomb", scene_zip(SERIALIZED.format(v="m.serialized", extra=""),
                                      {"m.serialized": ser_file(ser_mesh(21_000_000, real=False))}), 422,
         "compressed bytes can hold"),
        ("default flood", scene_zip("".join(f'<default name="p{i}" value="1"/>' for i in range(4000))), 422,
         "more than 100 <default> parameters"),
        ("deep nesting", scene_zip('<shape type="sphere">' + "<transform name='t'>" * 1200
                                   + "</transform>" * 1200 + "</shape>"), 422, "nested deeper than 100"),
        ("bogus encoding", scene_zip("", head=b"<?xml version='1.0' encoding='x-bogus'?>"), 422,
         "scene files must be UTF-8"),
        ("bitmap without filename", scene_zip('<bsdf type="diffuse"><texture type="bitmap" name="reflectance"/>'
                                              "</bsdf>"), 422, 'needs a <string name="filename"'),
        ("filename with a space", scene_zip(BITMAP.replace('"filename"', '"filename "').format(v="t.png")), 422,
         "property names may not"),
        ("text plugins/sphere.so", scene_zip('<shape type="sphere"/>', {"plugins/sphere.so": b"text\n"}), 422,
         "shared-object names"),
        ("central directory flood", cd_flood(100_000, 1), 413, "more than 4000 entries"),
    ]
    with server.client("submit", timeout=30.0) as c:
        for name, data, status, words in cases:  # the client's 30 s timeout bounds each answer
            r = c.post("/v1/scenes", files={"bundle": ("b.zip", data, "application/zip")})
            assert r.status_code == status, (name, r.status_code, r.text[:300])
            detail = r.json()["detail"]
            assert words in detail and "\n" not in detail and "Traceback" not in detail, (name, detail)
            assert c.get("/livez").status_code == 200, f"server down after {name}"  # same connection
    scenes = [p.name for p in (server.data_dir / "scenes").iterdir() if p.name != ".staging"]
    assert scenes == []


@pytest.mark.slow
def test_no_job_on_a_scene_whose_plan_failed(server):
    with server.client("submit", timeout=30.0) as c:
        data = scene_zip('<shape type="sphere"><float name="radius" value="abc"/></shape>')
        sid = c.post("/v1/scenes", files={"bundle": ("b.zip", data)}).json()["id"]
        wait_for(lambda: c.get(f"/v1/scenes/{sid}").json()["plan_state"] == "failed", timeout=180, what="plan")
        r = c.post("/v1/jobs", json={"scene_id": sid, "optics": {"resolution_hw": [64, 64]}, "preset": "fast",
                                     "spp": 4})
        assert r.status_code == 422 and "its plan failed" in r.json()["detail"], r.text[:300]
        assert c.get("/v1/jobs").json()["jobs"] == []
    assert httpx.get(f"{server.url}/livez", timeout=5).status_code == 200


# ---- the camera's film: bounded, since the scene's picture follows its aspect -----------------------------------
_FILM = ('<scene version="3.0.0"><default name="h" value="{h}"/><sensor type="perspective"><film type="hdrfilm">'
         '<integer name="width" value="{w}"/><integer name="height" value="$h"/></film></sensor></scene>')


@pytest.mark.parametrize("w, h, words", [
    (1, 30_000_000, "each side must be 1 to 16384 px"),
    (16384, 16384, "px in all"),
    (0, 480, "each side must be 1 to 16384 px"),
    ("1e3", 480, "must be an integer"),
])
def test_a_film_past_its_bounds_is_refused_at_upload(tmp_path, w, h, words):
    """A film of 1 x 30,000,000 px made a picture 30 M px tall and held the planner for 107 s at 2.35 GB: each
    side and the area are bounded before Mitsuba sees the scene (through <default> parameters too), in one line."""
    root = tmp_path / "b"
    root.mkdir()
    (root / "scene.xml").write_text(_FILM.format(w=w, h=h))
    with pytest.raises(BundleError, match=words) as err:
        validate_bundle(root)
    assert "\n" not in str(err.value)
    (root / "scene.xml").write_text(_FILM.format(w=640, h=480))
    validate_bundle(root)


def test_the_picture_of_a_tall_film_is_bounded_on_both_sides(tmp_path, monkeypatch):
    """A film inside the bounds but 4096 times taller than wide: the picture keeps at most 4 x 320 px of height
    (it followed the film's aspect from a width of at most 320, whatever the height came to); a film past the
    bounds, loaded without the bundle check, is refused when its size is read."""
    monkeypatch.setenv("HOLO_MI_VARIANT", "scalar_rgb")
    from holocore.evaluate.groundtruth import camera_picture
    from holocore.scene.load import load_scene

    root = tmp_path / "tall"
    root.mkdir()
    (root / "scene.xml").write_text(_FILM.format(w=4, h=16384).replace(
        "</sensor>", '</sensor><shape type="sphere"><bsdf type="diffuse"/></shape>'
                     '<emitter type="constant"/>'))
    pic = camera_picture(load_scene(root / "scene.xml"), max_width_px=320, spp=1)
    assert pic.shape[1] <= 4 * 320 and pic.shape[2] >= 1, pic.shape
    (root / "scene.xml").write_text(_FILM.format(w=1, h=20000))
    with pytest.raises(ValueError, match="each side must be 1 to 16384 px"):
        camera_picture(load_scene(root / "scene.xml", check_bundle=False), max_width_px=320, spp=1)
