"""The bundle check sees what Mitsuba does: defaults, substitution, includes and paths follow
Mitsuba's own rules; files are judged by content; the content id is unambiguous; and, traced with strace, a
process that checks and loads many generated tricky bundles never opens a file outside them."""

from __future__ import annotations

import os
import random
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

from holocore.scene.bundle import (
    BundleError,
    content_sha256,
    entry_source,
    validate_bundle,
)

REPO = Path(__file__).resolve().parents[2]
SENSOR = '<sensor type="perspective"><float name="fov" value="40"/></sensor>'
TRI = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"


def scene(root: Path, body: str, name: str = "scene.xml", files: dict[str, bytes] | None = None) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    (root / name).write_text(f'<scene version="3.0.0">{SENSOR}{body}</scene>')
    for rel, data in (files or {}).items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
    return root


def obj(value: str) -> str:
    return f'<shape type="obj"><string name="filename" value="{value}"/></shape>'


def png(w: int, h: int) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


def test_duplicate_defaults_are_refused_first_one_would_win(tmp_path):
    # Mitsuba keeps the first definition; an older check kept the last, so "/etc/passwd" slipped through.
    root = scene(tmp_path, '<default name="f" value="/etc/passwd"/><default name="f" value="m.obj"/>' + obj("$f"),
                 files={"m.obj": TRI})
    with pytest.raises(BundleError, match="defined twice"):
        validate_bundle(root)


def test_substitution_is_longest_name_first_and_everywhere(tmp_path):
    root = scene(tmp_path, '<default name="m" value="nope"/><default name="mesh" value="m.obj"/>'
                           '<default name="t" value="obj"/>'
                           '<shape type="$t"><string name="filename" value="$mesh"/></shape>', files={"m.obj": TRI})
    report = validate_bundle(root)
    assert "shape:obj" in report.plugins and report.mesh_faces == 1
    root2 = scene(tmp_path / "b", '<default name="t" value="evil"/><shape type="$t"/>')
    with pytest.raises(BundleError, match="disallowed shape plugin 'evil'"):
        validate_bundle(root2)
    root3 = scene(tmp_path / "c", '<default name="a" value="$b"/><default name="b" value="x"/>')
    with pytest.raises(BundleError, match="values are not expanded"):
        validate_bundle(root3)


def test_references_in_includes_resolve_against_the_entry_folder(tmp_path):
    # Mitsuba resolves a file named inside sub/inc.xml against the entry's folder, not sub/.
    inc = f'<scene version="3.0.0">{obj("m.obj")}</scene>'.encode()
    root = scene(tmp_path, '<include filename="sub/inc.xml"/>', files={"sub/inc.xml": inc, "sub/m.obj": TRI})
    with pytest.raises(BundleError, match="not in the bundle .*relative to the scene file's folder"):
        validate_bundle(root)
    (root / "m.obj").write_bytes(TRI)
    assert validate_bundle(root).mesh_faces == 1
    deep = "d/" * 6
    bad = f'<scene version="3.0.0">{obj("../" * 20 + "etc/passwd")}</scene>'.encode()
    root2 = scene(tmp_path / "x", f'<include filename="{deep}inc.xml"/>', files={f"{deep}inc.xml": bad})
    with pytest.raises(BundleError, match="leaves the scene bundle"):
        validate_bundle(root2)


def test_files_are_judged_by_content(tmp_path):
    root = scene(tmp_path, "", files={"plugins/sphere.so": b"\x7fELF\x02\x01\x01" + b"\0" * 100})
    with pytest.raises(BundleError, match="plugins/sphere.so: is an ELF executable"):
        validate_bundle(root)
    root2 = scene(tmp_path / "b", "", files={"notes.bin": os.urandom(64) + b"\0"})
    with pytest.raises(BundleError, match="unknown binary file"):
        validate_bundle(root2)
    bitmap = ('<bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" '
              'value="t.dat"/></texture></bsdf>')
    root3 = scene(tmp_path / "c", bitmap, files={"t.dat": png(10000, 10000)})
    with pytest.raises(BundleError, match="images hold more than"):
        validate_bundle(root3)


def test_content_id_is_unambiguous(tmp_path):
    a = tmp_path / "a"
    b = tmp_path / "b"
    for d, files in ((a, {"x": b"1\0y\0" + b"2"}), (b, {"x": b"1", "y": b"2"})):
        d.mkdir()
        for k, v in files.items():
            (d / k).write_bytes(v)
    # the old hash joined name\0content\0: both gave the same bytes "x\01\0y\02\0"
    assert content_sha256(a, sorted(a.iterdir())) != content_sha256(b, sorted(b.iterdir()))


def test_integrator_is_stripped_keeping_lines(tmp_path):
    root = tmp_path
    (root / "scene.xml").write_text('<scene version="3.0.0">\n<integrator type="path_guiding_integrator">\n'
                                    '  <integer name="max_depth" value="5"/>\n</integrator>\n' + SENSOR +
                                    '\n<shape type="sphere"/>\n</scene>\n')
    report = validate_bundle(root)
    assert any("path_guiding_integrator" in s for s in report.ignored)
    text = entry_source(report)
    assert "integrator" not in text and text.count("\n") == (root / "scene.xml").read_text().count("\n")
    from holocore.scene.load import load_scene

    loaded = load_scene(root)
    assert loaded.scene.integrator() is None and len(loaded.scene.shapes()) == 1


def test_mitsuba_errors_name_the_users_file_and_line(tmp_path):
    from holocore.scene.load import SceneLoadError, load_scene

    root = tmp_path / "bundle"
    root.mkdir()
    (root / "scene.xml").write_text(f'<scene version="3.0.0">\n{SENSOR}\n<shape type="sphere">'
                                    '<float name="radius" value="abc"/></shape></scene>')
    with pytest.raises(SceneLoadError) as err:
        load_scene(root)
    msg = str(err.value)
    assert "scene.xml (line 3" in msg and str(tmp_path) not in msg and "parser.cpp" not in msg


# ---- the traced property test ------------------------------------------------------------------------------

def _tricky_bundle(rng: random.Random, root: Path, outside: Path) -> None:
    """A bundle mixing the tricks that broke the old check: duplicate or late defaults, includes in
    subfolders with relative and escaping references, links to the outside, absolute paths, odd kinds."""
    targets = [f"{outside}/secret.obj", "../" * rng.randint(1, 12) + f"{outside.name}/secret.obj",
               "m.obj", "sub/m.obj", "sub/../m.obj", "./m.obj", "link.obj", "~/secret.obj", "sub\\m.obj",
               "$f", "$f.obj", "$dir/secret.obj", "file:///etc/passwd", "t.dat", "plugins/sphere.so"]
    defaults = []
    for _ in range(rng.randint(0, 3)):
        defaults.append((rng.choice(["f", "f", "dir", "t", "ff"]),
                         rng.choice(["m", "m.obj", str(outside), "../" * 5 + outside.name, "/etc/passwd", "sphere",
                                     "$f"])))
    body = "".join(f'<default name="{n}" value="{v}"/>' for n, v in defaults)
    if rng.random() < 0.3:
        body += obj("$f")
    body += "".join(obj(rng.choice(targets)) for _ in range(rng.randint(1, 3)))
    if rng.random() < 0.3:
        body += f'<shape type="{rng.choice(["$t", "sphere", "obj"])}"/>'
    files = {"m.obj": TRI, "sub/m.obj": TRI}
    if rng.random() < 0.5:
        depth = "d/" * rng.randint(1, 5)
        inc_target = rng.choice(targets)
        files[f"{depth}inc.xml"] = f'<scene version="3.0.0">{obj(inc_target)}</scene>'.encode()
        body = f'<include filename="{rng.choice([depth + "inc.xml", "inc.xml", "../inc.xml"])}"/>' + body
    if rng.random() < 0.3:
        files["t.dat"] = png(8, 8)
        body += ('<bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" '
                 'value="t.dat"/></texture></bsdf>')
    if rng.random() < 0.2:
        files["plugins/sphere.so"] = b"\x7fELF" + b"\0" * 60
    scene(root, body, files=files)
    if rng.random() < 0.3:
        os.symlink(outside / "secret.obj", root / "link.obj")


_TRACED = r"""
import os, sys
sys.path.insert(0, sys.argv[1])
from holocore.scene.load import load_scene
load_scene(sys.argv[2])  # warm-up: imports, plugins, kernels
for b in sys.argv[3:]:
    print("BEGIN", b, flush=True)
    try:
        load_scene(b)
        print("LOADED", b, flush=True)
    except Exception as exc:
        print("REFUSED", b, type(exc).__name__, str(exc)[:200], flush=True)
"""


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed (scripts/setup.sh installs it)")
def test_traced_loads_never_open_a_file_outside_their_bundle(tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.obj").write_bytes(b"v 9 9 9\nv 8 8 8\nv 7 7 7\nf 1 2 3\n")
    warm = scene(tmp_path / "warm", obj("m.obj") + '<bsdf type="diffuse"/>', files={"m.obj": TRI})
    rng = random.Random(20261201)
    bundles = []
    for i in range(60):
        b = tmp_path / "bundles" / f"b{i:02d}"
        _tricky_bundle(rng, b, outside)
        bundles.append(b)
    trace = tmp_path / "trace.txt"
    proc = subprocess.run(["strace", "-f", "-qq", "-e", "trace=open,openat,openat2,creat,execve", "-o", str(trace),
                           sys.executable, "-c", _TRACED, str(REPO), str(warm), *map(str, bundles)],
                          capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    outcomes = [ln.split(" ", 2)[0] for ln in proc.stdout.splitlines() if ln.startswith(("LOADED", "REFUSED"))]
    assert len(outcomes) == len(bundles)
    assert 0 < outcomes.count("LOADED") < len(bundles), "the generator should make both kinds"
    lines = trace.read_text(errors="replace").splitlines()
    opened = [ln.split('"')[1] for ln in lines if '"' in ln and ("open" in ln or "creat" in ln)]
    # nothing outside the bundles: the secret, /etc, or the bundles' parent are never opened
    assert not [p for p in opened if str(outside) in p or p.startswith("/etc/passwd")], \
        [p for p in opened if str(outside) in p][:5]
    assert not [ln for ln in lines if "execve(" in ln and sys.executable not in ln and "strace" not in ln]
    roots = [str(b) for b in bundles] + [str(warm)]
    after_warm = opened[next(i for i, p in enumerate(opened) if p.startswith(str(tmp_path / "bundles"))):]
    allowed = (str(tmp_path / "bundles"), "/proc/", "/sys/", "/dev/", sys.prefix, sys.base_prefix, "/usr/lib",
               "/lib", str(REPO))
    stray = [p for p in after_warm if not p.startswith(allowed) and not any(p.startswith(r) for r in roots)]
    assert not stray, stray[:10]


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc is needed to build the planted plugin")
def test_preloaded_plugins_never_resolve_through_a_scene_folder(tmp_path):
    """Defence in depth: even a folder loaded without the bundle check (``check_bundle=False``, trusted folders
    only) cannot make Mitsuba run a planted ``plugins/sphere.so``, once every plugin is preloaded."""
    marker = tmp_path / "MARKER"
    root = scene(tmp_path / "b", '<shape type="sphere"/>')
    (root / "plugins").mkdir()
    (tmp_path / "evil.c").write_text('#include <stdio.h>\n__attribute__((constructor)) static void hit(void) '
                                     f'{{ FILE *f = fopen("{marker}", "w"); if (f) fclose(f); }}\n')
    subprocess.run(["gcc", "-shared", "-fPIC", "-o", str(root / "plugins" / "sphere.so"), str(tmp_path / "evil.c")],
                   check=True)
    ours = ("import sys; sys.path.insert(0, sys.argv[1]); from holocore.scene.load import load_scene; "
            "load_scene(sys.argv[2], check_bundle=False)")
    proc = subprocess.run([sys.executable, "-c", ours, str(REPO), str(root)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-1000:]
    assert not marker.exists()
    # the control: Mitsuba's own load_file, without the preloading, runs the planted code (the attack is real)
    bare = ("import sys; sys.path.insert(0, sys.argv[1]); from holocore.runtime.mitsuba_env import mitsuba; "
            "mitsuba().load_file(sys.argv[2] + '/scene.xml')")
    subprocess.run([sys.executable, "-c", bare, str(REPO), str(root)], capture_output=True, text=True, timeout=300)
    assert marker.exists()
