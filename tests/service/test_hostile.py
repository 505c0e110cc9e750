"""A hostile-input corpus against a real `holo serve`: every request is refused with a 4xx problem+json and a
clear message, the server keeps serving, nothing refused is stored, and no file outside the bundle is read
(the escape targets are FIFOs: opening one would block the request until the client times out)."""

from __future__ import annotations

import io
import json
import os
import struct
import zipfile
import zlib
from pathlib import Path

import httpx
import pytest

from service.auth import revoke_token
from service.db import Database
from tests.service.helpers import Server, make_token, wait_for

SCENE = '<scene version="3.0.0"><sensor type="perspective"/>{body}</scene>'


def zbytes(members: dict[str, bytes], *, method=zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", method) as zf:
        for name, data in members.items():
            zf.writestr(zipfile.ZipInfo(name), data, compress_type=method)
    return buf.getvalue()


def scene_zip(body: str, extra: dict[str, bytes] | None = None) -> bytes:
    return zbytes({"scene.xml": SCENE.format(body=body).encode(), **(extra or {})})


def symlink_zip() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("scene.xml", SCENE.format(body=""))
        info = zipfile.ZipInfo("mesh.obj")
        info.external_attr = (0o120777 << 16)
        zf.writestr(info, "/etc/passwd")
    return buf.getvalue()


def lying_zip() -> bytes:
    """A member whose headers declare 100 bytes but whose data inflates to 2 MiB."""
    raw = bytearray(zbytes({"scene.xml": SCENE.format(body="").encode(), "big.bin": b"\0" * (2 << 20)}))
    for sig, off in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        i = 0
        while (i := raw.find(sig, i)) >= 0:
            name_len = struct.unpack_from("<H", raw, i + (26 if sig == b"PK\x03\x04" else 28))[0]
            name_at = i + (30 if sig == b"PK\x03\x04" else 46)
            if raw[name_at:name_at + name_len] == b"big.bin":
                struct.pack_into("<I", raw, i + off, 100)
            i += 4
    return bytes(raw)


def png_header(w: int, h: int) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    root = tmp_path_factory.mktemp("hostile")
    for name in ("canary.fifo", "canary.xml"):
        os.mkfifo(root / name)  # anything that opens these blocks
    srv = Server(root / "data", extra=("--max-upload-mb", "8")).start()
    yield srv, root
    srv.stop()


def uploads(root: Path) -> list[tuple[str, dict, int, str]]:
    fifo = str(root / "canary.fifo")
    up = "../../../../canary.fifo"  # data/scenes/.staging/<tmp>/ -> root: the relative escape hits the FIFO
    ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n" \
          b"property float z\nelement face 1000000000\nproperty list uchar int vertex_indices\nend_header\n" + b"\0" * 64
    shape = '<shape type="{k}"><string name="filename" value="{v}"/></shape>'
    bitmap = '<bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="{v}"/>' \
             '</texture></bsdf>'
    B = lambda data: {"files": {"bundle": ("b.zip", data, "application/zip")}}  # noqa: E731
    return [
        ("zip member with ..", B(zbytes({"../evil.xml": b"<scene/>"})), 422, "'..' would leave the bundle"),
        ("zip member absolute", B(zbytes({"/etc/cron.d/x": b"x"})), 422, "absolute paths are not allowed"),
        ("zip member drive letter", B(zbytes({"C:\\Windows\\x.xml": b"x"})), 422, "absolute paths"),
        ("zip symlink member", B(symlink_zip()), 422, "symbolic link"),
        ("zip bomb (ratio)", B(zbytes({"scene.xml": b"<scene/>", "z.bin": b"\0" * (4 << 20)})), 413, "zip bomb"),
        ("zip declares too much", B(zbytes({f"z{i}.bin": b"\0" * 1_000_000 for i in range(9)})), 413,
         "declares more than"),
        # zipfile stops at the declared size and the CRC no longer matches (our byte count would stop it too)
        ("zip lies about sizes", B(lying_zip()), 422, "cannot unpack 'big.bin'"),
        ("zip with too many files", B(zbytes({f"f{i}": b"" for i in range(2001)})), 413, "more than 2000"),
        ("not a zip", B(b"hello, not a zip"), 422, "not a zip file"),
        ("entity bomb", B(zbytes({"scene.xml": b'<?xml version="1.0"?><!DOCTYPE s [<!ENTITY a "aaaaaaaaaa">'
                                                b'<!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;"><!ENTITY c "&b;&b;&b;'
                                                b'&b;&b;&b;&b;&b;&b;&b;">]><scene>&c;</scene>'})), 422, "DTDs"),
        ("external entity", B(zbytes({"scene.xml": f'<?xml version="1.0"?><!DOCTYPE s [<!ENTITY x SYSTEM '
                                                   f'"file://{fifo}">]><scene>&x;</scene>'.encode()})), 422,
         "DTDs, entities and external references are not allowed"),
        ("include leaving the bundle", B(scene_zip(f'<include filename="{up[:-4]}xml"/>')), 422,
         "leaves the scene bundle"),
        ("include absolute", B(scene_zip(f'<include filename="{root / "canary.xml"}"/>')), 422, "absolute path"),
        ("path element", B(scene_zip('<path value="/"/>')), 422, "<path> elements"),
        ("mesh absolute", B(scene_zip(shape.format(k="obj", v=fifo))), 422, "absolute path"),
        ("mesh relative escape", B(scene_zip(shape.format(k="obj", v=up))), 422, "leaves the scene bundle"),
        ("mesh via $default escape", B(scene_zip('<default name="d" value="../../../.."/>'
                                                 + shape.format(k="obj", v="$d/canary.fifo"))), 422, "leaves"),
        ("unknown plugin", B(scene_zip('<bsdf type="evil"/>')), 422, "disallowed bsdf plugin 'evil'"),
        ("unknown element", B(scene_zip('<exec cmd="rm -rf /"/>')), 422, "unknown XML element <exec>"),
        ("huge declared mesh", B(scene_zip(shape.format(k="ply", v="m.ply"), {"m.ply": ply})), 422,
         "declares"),
        ("huge image header", B(scene_zip(bitmap.format(v="t.png"), {"t.png": png_header(60000, 60000)})), 422,
         "pixels"),
        ("no scene xml", B(zbytes({"readme.txt": b"hi"})), 422, "0 XML files"),
        ("two xml, no entry", B(zbytes({"a.xml": SCENE.format(body="").encode(),
                                        "b.xml": SCENE.format(body="").encode()})), 422, "name the scene file"),
        ("entry outside", {**B(scene_zip("")), "data": {"entry": "../canary.xml"}}, 422, "leaves the scene bundle"),
        ("files name with ..", {"files": [("files", ("../../x.xml", SCENE.format(body=""), "text/xml"))]}, 422,
         "'..' would leave the bundle"),
        ("files name absolute", {"files": [("files", ("/tmp/x.xml", SCENE.format(body=""), "text/xml"))]}, 422,
         "absolute paths"),
        ("bundle and files", {"files": [("bundle", ("b.zip", scene_zip(""), "application/zip")),
                                        ("files", ("a.xml", b"<scene/>", "text/xml"))]}, 422, "not both"),
        ("empty form", {"data": {"entry": "scene.xml"}}, 422, "no scene"),
        ("body over the cap", B(os.urandom(9 << 20)), 413, "larger than the limit"),
    ]


@pytest.mark.slow
def test_hostile_uploads_are_refused_and_nothing_is_stored(hostile):
    srv, root = hostile
    with srv.client("submit", timeout=20.0) as c:
        for name, kw, status, words in uploads(root):
            r = c.post("/v1/scenes", **kw)
            assert r.status_code == status, (name, r.status_code, r.text[:300])
            assert r.headers["content-type"].startswith("application/problem+json"), name
            body = r.json()
            assert body["status"] == status and words in body["detail"], (name, body["detail"])
            assert httpx.get(f"{srv.url}/livez", timeout=5).status_code == 200, f"server down after {name}"
    scenes = [p.name for p in (srv.data_dir / "scenes").iterdir() if p.name != ".staging"]
    assert scenes == [] and list((srv.data_dir / "scenes" / ".staging").iterdir()) == []


def raw_job(c: httpx.Client, text: str) -> httpx.Response:
    return c.post("/v1/jobs", content=text.encode(), headers={"content-type": "application/json"})


@pytest.mark.slow
def test_hostile_jobs_are_refused(hostile, scene_bundle):
    srv, _ = hostile
    with srv.client("submit") as c:
        buf = io.BytesIO()
        folder = scene_bundle("cbox-mirror-glass")
        with zipfile.ZipFile(buf, "w") as zf:
            for p in folder.rglob("*"):
                if p.is_file():
                    zf.write(p, p.relative_to(folder).as_posix())
        sid = c.post("/v1/scenes", files={"bundle": ("b.zip", buf.getvalue())}).json()["id"]
        good = {"scene_id": sid, "optics": {"resolution_hw": [64, 64]}, "preset": "fast", "spp": 4}
        cases = [
            ('{"scene_id": "%s", "optics": {"pitch_um": NaN}}' % sid, "optics.pitch_um: Input should be a finite"),
            ('{"scene_id": "%s", "optics": {"wavelengths_nm": [Infinity]}}' % sid, "finite number"),
            ('{"scene_id": "%s", "optics": {"pitch_um": -8}}' % sid, "greater than 0"),
            ('{"scene_id": "%s", "optics": {"z_inf_mm": -1e308}}' % sid, "greater than 0"),
            (json.dumps({**good, "optics": {"resolution_hw": [100000, 5]}}), "must be in 1..16384"),
            (json.dumps({**good, "optics": {"resolution_hw": [4097, 16]}}), "at most 4096 px"),
            (json.dumps({**good, "frames": 0}), "greater than or equal to 1"),
            (json.dumps({**good, "frames": 100}), "frames: must be in 1..64"),
            (json.dumps({**good, "spp": 10**9}), "less than or equal to 1000000"),
            (json.dumps({**good, "spp": 5000}), "spp: must be in 1..4096"),
            (json.dumps({**good, "optics": {"resolution_hw": [4096, 2304]}, "spp": 4096}), "rays"),
            (json.dumps({**good, "encoder": "rm -rf"}), "encoder"),
            (json.dumps({**good, "evil": 1}), "Extra inputs are not permitted"),
            (json.dumps({**good, "display": "../../etc"}), "display"),
            (json.dumps({**good, "scene_id": "snope"}), "no scene 'snope'"),
            (json.dumps({**good, "scene_id": "../../x"}), "scene_id"),
            (json.dumps({**good, "optics": {"pitch_um": 1e-300}}), "optics.pitch_um: must be in"),
            (json.dumps({**good, "optics": {"fov_x_deg": 1e-300}}), "optics.fov_x_deg: must be in"),
            ("{not json", "JSON decode error"),
            ("[]", "Input should be a valid dictionary"),
        ]
        for text, words in cases:
            r = raw_job(c, text)
            assert r.status_code == 422, (text, r.status_code, r.text[:300])
            assert r.headers["content-type"].startswith("application/problem+json")
            assert words in r.json()["detail"], (text, r.json()["detail"])
        assert c.get("/v1/jobs").json()["jobs"] == []  # none of them was queued
        r = c.post("/v1/jobs", json=good, headers={"Idempotency-Key": "a" * 300})
        assert r.status_code == 422 and "Idempotency-Key" in r.json()["detail"]
    assert httpx.get(f"{srv.url}/livez").status_code == 200


def test_auth_failures(hostile):
    srv, _ = hostile
    url = srv.url
    r = httpx.get(f"{url}/v1/jobs")
    assert r.status_code == 401 and r.headers["www-authenticate"].startswith("Bearer")
    assert "authentication required" in r.json()["detail"]
    for header, words in (("Bearer hpt_0000_wrong", "invalid or revoked token"), ("Bearer nonsense", "invalid"),
                          ("Basic dXNlcjpwYXNz", "malformed Authorization header"), ("Bearer " + "x" * 5000, "invalid")):
        r = httpx.get(f"{url}/v1/jobs", headers={"Authorization": header})
        assert r.status_code == 401 and words in r.json()["detail"], (header, r.text)
    with srv.client("reader") as c:
        r = c.post("/v1/jobs", json={"scene_id": "sx"})
        assert r.status_code == 403 and "lacks the 'submit' scope" in r.json()["detail"]
        assert c.delete("/v1/jobs/jx").status_code == 403
    with srv.client("agent") as c:
        assert c.post("/v1/scenes", files={"bundle": ("b.zip", b"x")}).status_code == 403
        assert c.get("/v1/jobs").status_code == 200
    with srv.client("submit") as c:
        r = c.post("/v1/displays/lab/heartbeat", json={"agent_version": "1", "state": "idle", "message": ""})
        assert r.status_code == 403 and "'agent' scope" in r.json()["detail"]
    tok = make_token(srv.data_dir, "read")
    with srv.client(tok) as c:
        assert c.get("/v1/jobs").status_code == 200
        revoke_token(Database(srv.data_dir / "service.db"), tok.split("_")[1])
        assert c.get("/v1/jobs").status_code == 401


def test_odd_paths_and_methods(hostile):
    srv, _ = hostile
    with srv.client("admin") as c:
        for path in ("/v1/jobs/..%2F..%2Fetc%2Fpasswd", "/v1/jobs/%00", "/v1/scenes/" + "a" * 100):
            r = c.get(path)
            assert r.status_code in (404, 422) and r.json()["detail"], path
        r = c.get("/v1/jobs/jdoesnotexist")
        assert r.status_code == 404 and "no job 'jdoesnotexist'" in r.json()["detail"]
        assert c.get("/v1/jobs/jdoesnotexist/stack").status_code == 404
        r = c.put("/v1/jobs")
        assert r.status_code == 405 and "not allowed" in r.json()["detail"]
        r = c.get("/v1/nothing-here")
        assert r.status_code == 404 and r.headers["content-type"].startswith("application/problem+json")
        r = c.get("/v1/jobs", params={"limit": 100000, "state": "exploded"})
        assert r.status_code == 422 and "limit" in r.json()["detail"]
        r = c.post("/v1/displays/lab/heartbeat", json={"agent_version": "1", "state": "x" * 100, "message": ""})
        assert r.status_code == 422
    assert httpx.get(f"{srv.url}/readyz").status_code == 200


# ---- code, leaks, integrity, tenancy, malformed input, connections --------------------------------

SECRET_LINE = "root:x:0:0"  # the first line of /etc/passwd: it must never appear anywhere


def _evil_so(tmp: Path, marker: Path) -> bytes:
    """A shared object whose constructor writes ``marker`` (what a planted Mitsuba plugin would run)."""
    import shutil
    import subprocess

    if shutil.which("gcc") is None:
        return b"\x7fELF\x02\x01\x01\x00" + b"\0" * 56  # still an ELF header: the check refuses it by content
    src = tmp / "evil.c"
    src.write_text('#include <stdio.h>\n__attribute__((constructor)) static void hit(void) '
                   f'{{ FILE *f = fopen("{marker}", "w"); if (f) {{ fputs("ran", f); fclose(f); }} }}\n')
    subprocess.run(["gcc", "-shared", "-fPIC", "-o", str(tmp / "evil.so"), str(src)], check=True)
    return (tmp / "evil.so").read_bytes()


def _everything_stored(srv: Server) -> str:
    """Every byte the server stored or logged, as text (database, logs, status files, plans)."""
    chunks = [srv.log()]
    for p in srv.data_dir.rglob("*"):
        if p.is_file() and p.suffix not in (".npz", ".zip", ".png"):
            chunks.append(p.read_bytes().decode("latin-1"))
    return "".join(chunks)


@pytest.mark.slow
def test_uploaded_code_never_runs_and_no_outside_byte_leaks(hostile, tmp_path):
    srv, root = hostile
    marker = tmp_path / "MARKER"
    so = _evil_so(tmp_path, marker)
    sphere = '<shape type="sphere"/>'
    deep = "d/" * 6
    cases = [
        ("plugin shared object", scene_zip(sphere, {"plugins/sphere.so": so}), 422, "plugins/sphere.so: is an ELF"),
        ("shared object named like a mesh", scene_zip('<shape type="ply"><string name="filename" '
                                                      'value="m.ply"/></shape>', {"m.ply": so}), 422, "is an ELF"),
        ("duplicate defaults", scene_zip('<default name="f" value="/etc/passwd"/><default name="f" value="m.obj"/>'
                                         '<shape type="obj"><string name="filename" value="$f"/></shape>',
                                         {"m.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"}), 422, "defined twice"),
        ("duplicate default plugin type", scene_zip('<default name="t" value="sphere"/><default name="t" value="evil"/>'
                                                    '<shape type="$t"/>'), 422, "defined twice"),
        ("include in subfolders escaping", scene_zip(f'<include filename="{deep}inc.xml"/>', {
            f"{deep}inc.xml": ('<scene version="3.0.0"><shape type="obj"><string name="filename" value="'
                               + "../" * 20 + 'etc/passwd"/></shape></scene>').encode()}), 422, "leaves the scene"),
        ("image by content, not name", scene_zip('<bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
                                                 '<string name="filename" value="t.dat"/></texture></bsdf>',
                                                 {"t.dat": png_header(10000, 10000)}), 422, "images hold more than"),
    ]
    with srv.client("submit") as c:
        for name, data, status, words in cases:
            r = c.post("/v1/scenes", files={"bundle": ("b.zip", data, "application/zip")})
            assert r.status_code == status and words in r.json()["detail"], (name, r.status_code, r.text[:300])
            assert SECRET_LINE not in r.text
        # the CLI loads scenes the same way: a folder with a planted plugin is refused in one line
        import subprocess
        import sys

        folder = tmp_path / "planted"
        (folder / "plugins").mkdir(parents=True)
        (folder / "scene.xml").write_text(SCENE.format(body=sphere))
        (folder / "plugins" / "sphere.so").write_bytes(so)
        cli = subprocess.run([sys.executable, "-m", "holo", "plan", str(folder)], capture_output=True, text=True,
                             timeout=120, cwd=tmp_path)
        assert cli.returncode != 0 and "is an ELF" in cli.stderr and "Traceback" not in cli.stderr, cli.stderr
    assert not marker.exists(), "uploaded code ran"
    assert SECRET_LINE not in _everything_stored(srv)


@pytest.mark.slow
def test_plan_errors_name_the_users_file_not_the_server(hostile):
    srv, _ = hostile
    with srv.client("submit") as c:
        data = zbytes({"scene.xml": ('<scene version="3.0.0">\n<sensor type="perspective"/>\n'
                                     '<shape type="sphere"><float name="radius" value="abc"/></shape>\n'
                                     '</scene>').encode()})
        sid = c.post("/v1/scenes", files={"bundle": ("b.zip", data)}).json()["id"]
        scene = wait_for(lambda: (lambda s: s if s["plan_state"] in ("ready", "failed") else None)(
            c.get(f"/v1/scenes/{sid}").json()), timeout=120, what="plan")
    err = scene["plan_error"]
    assert scene["plan_state"] == "failed" and "scene.xml (line 3" in err, err
    assert str(srv.data_dir) not in err and "/tmp/" not in err and ".cpp" not in err, err


def _small_job(c: httpx.Client, folder: Path, **over) -> dict:
    from tests.service.helpers import SMALL_JOB, upload

    sid = upload(c, folder).json()["id"]
    r = c.post("/v1/jobs", json={"scene_id": sid, **SMALL_JOB, **over})
    assert r.status_code == 202, r.text
    return r.json()


@pytest.mark.slow
def test_stored_artifacts_are_checked_before_serving_or_reuse(hostile, scene_bundle):
    from tests.service.helpers import wait_state

    srv, _ = hostile
    with srv.client("submit") as c:
        job = wait_state(c, _small_job(c, scene_bundle("cbox-mirror-glass"))["id"], ("succeeded", "failed"),
                         timeout=300)
        assert job["state"] == "succeeded", job["error"]
        url = f"/v1/jobs/{job['id']}/stack"
        r = c.get(url, headers={"Range": "bytes=0-" + "9" * 5000})
        assert r.status_code == 206, r.status_code
        r = c.get(url, headers={"Range": "bytes=" + "9" * 5000 + "-"})
        assert r.status_code == 416
        etag = c.get(url).headers["etag"]
        stack = srv.data_dir / "jobs" / job["id"] / "stack.npz"
        with open(stack, "r+b") as fh:
            fh.truncate(1000)
        for headers in ({}, {"If-None-Match": etag}, {"Range": "bytes=0-10"}):
            r = c.get(url, headers=headers)
            assert r.status_code == 409 and "integrity check" in r.json()["detail"], (headers, r.status_code)
        again = _small_job(c, scene_bundle("cbox-mirror-glass"))
        # recomputed, not the corrupt one (the scheduler may have started it already)
        assert again["reused_from"] is None and again["state"] in ("queued", "running"), again
        c.delete(f"/v1/jobs/{again['id']}")


def test_tenancy_owners_see_only_their_own(hostile, scene_bundle):
    from service.auth import create_token
    from tests.service.helpers import SMALL_JOB, upload

    srv, _ = hostile
    db = Database(srv.data_dir / "service.db")
    tok = {f"{o}-{s}": create_token(db, scopes=[s], owner=o, name=f"{o}-{s}")[1]
           for o in ("alice", "bob") for s in ("submit", "agent")}
    folder = scene_bundle("cbox-mirror-glass")
    with srv.client(tok["alice-submit"]) as alice, srv.client(tok["bob-submit"]) as bob, \
            srv.client(tok["alice-agent"]) as alice_agent, srv.client(tok["bob-agent"]) as bob_agent:
        hb = {"agent_version": "1", "state": "idle", "message": "<script>x</script>\x07"}
        r = alice_agent.post("/v1/displays/alice-lab/heartbeat", json=hb)
        assert r.status_code == 403 and "an admin registers displays" in r.json()["detail"]  # not hers yet
        with srv.client("admin") as admin:
            assert admin.put("/v1/displays/alice-lab", json={"owner": "alice"}).status_code == 204
        assert alice_agent.post("/v1/displays/alice-lab/heartbeat", json=hb).status_code == 204
        r = bob_agent.post("/v1/displays/alice-lab/heartbeat", json=hb)
        assert r.status_code == 403 and "not registered to this agent" in r.json()["detail"]
        sid = upload(alice, folder).json()["id"]
        assert bob.get(f"/v1/scenes/{sid}").status_code == 404
        r = bob.post("/v1/jobs", json={"scene_id": sid, **SMALL_JOB})
        assert r.status_code == 422 and "no scene" in r.json()["detail"]
        job = alice.post("/v1/jobs", json={"scene_id": sid, **SMALL_JOB, "display": "alice-lab"}).json()
        for call in (bob.get(f"/v1/jobs/{job['id']}"), bob.delete(f"/v1/jobs/{job['id']}"),
                     bob.get(f"/v1/jobs/{job['id']}/events"), bob.get(f"/v1/jobs/{job['id']}/stack")):
            assert call.status_code == 404, call.request.url
        assert job["id"] not in [j["id"] for j in bob.get("/v1/jobs").json()["jobs"]]
        assert bob_agent.get("/v1/jobs", params={"display": "alice-lab"}).json()["jobs"] == []
        assert [j["id"] for j in alice_agent.get("/v1/jobs", params={"display": "alice-lab"}).json()["jobs"]] \
            == [job["id"]]
        r = upload(bob, folder)  # bob brings the same files: a scene of his own, nothing of alice's shows
        assert r.status_code == 201 and r.json()["id"] != sid, r.text
        r = bob.post("/v1/jobs", json={"scene_id": sid, **SMALL_JOB})
        assert r.status_code == 422 and "no scene" in r.json()["detail"]
        bobs = bob.post("/v1/jobs", json={"scene_id": upload(bob, folder).json()["id"], **SMALL_JOB,
                                          "display": "alice-lab"})
        assert bobs.status_code == 202 and bobs.json()["reused_from"] is None  # aimed at alice's display, but
        assert [j["id"] for j in alice_agent.get("/v1/jobs", params={"display": "alice-lab"}).json()["jobs"]] \
            == [job["id"]]  # only alice's jobs reach her agents
        bob.delete(f"/v1/jobs/{bobs.json()['id']}")
        shown = [d for d in alice.get("/v1/displays").json()["displays"] if d["name"] == "alice-lab"]
        assert shown and "\x07" not in shown[0]["message"] and bob.get("/v1/displays").json()["displays"] == []
        with srv.client("admin") as admin:
            assert admin.get(f"/v1/jobs/{job['id']}").status_code == 200
            assert admin.delete(f"/v1/jobs/{job['id']}").status_code in (202, 409)


def _chunks(total: int):
    """A multipart upload of ``total`` bytes, streamed (chunked transfer encoding: no Content-Length)."""
    yield b'--XyZ\r\nContent-Disposition: form-data; name="bundle"; filename="b.zip"\r\n\r\n'
    block = b"x" * (1 << 20)
    sent = 0
    while sent < total:
        yield block
        sent += len(block)
    yield b"\r\n--XyZ--\r\n"


def test_malformed_input_answers_4xx_and_keeps_serving(hostile):
    srv, _ = hostile
    with srv.client("submit") as c:
        cases = [
            ("1000-character name", {"files": {"bundle": ("b.zip", zbytes({"a" * 1000 + ".xml": b"<scene/>"}))}},
             422, "longer than 255 bytes"),
            ("file then folder", {"files": {"bundle": ("b.zip", zbytes({"d": b"x", "d/e.txt": b"y"}))}}, 422,
             "is a file and a folder"),
            ("folder then file", {"files": {"bundle": ("b.zip", zbytes({"d/e.txt": b"y", "d": b"x"}))}}, 422,
             "is a file and a folder"),
        ]
        for name, kw, status, words in cases:
            r = c.post("/v1/scenes", **kw)
            assert r.status_code == status and words in r.json()["detail"], (name, r.status_code, r.text[:200])
            assert c.get("/v1/jobs").status_code == 200, f"connection lost after {name}"
        r = c.post("/v1/scenes", content=_chunks(9 << 20), headers={"content-type": "multipart/form-data; boundary=XyZ"})
        assert r.status_code == 413 and "larger than the limit" in r.json()["detail"]
        assert c.get("/v1/jobs").status_code == 200


@pytest.mark.slow
def test_slow_and_idle_connections_are_closed(server_factory):
    import socket
    import time

    srv = server_factory("slow")
    os.environ["HOLO_HEADER_TIMEOUT_S"] = "1"
    try:
        srv.start()
    finally:
        del os.environ["HOLO_HEADER_TIMEOUT_S"]
    for trickle in (False, True):
        s = socket.create_connection(("127.0.0.1", srv.port), timeout=10)
        t0 = time.monotonic()
        s.settimeout(0.3)
        if trickle:
            s.sendall(b"GET /livez HTTP/1.1\r\nHost: x\r\n")
        closed = False
        while time.monotonic() - t0 < 20:
            try:
                if trickle:
                    s.sendall(b"X-Slow: 1\r\n")
                if s.recv(100) == b"":
                    closed = True
                    break
            except socket.timeout:
                continue
            except OSError:
                closed = True
                break
        s.close()
        assert closed, f"connection (trickle={trickle}) stayed open 20 s (header timeout 1 s)"
    assert httpx.get(f"{srv.url}/livez").status_code == 200


@pytest.mark.slow
def test_token_expiry_rate_limit_and_metrics(server_factory):
    import time

    from service.auth import create_token

    srv = server_factory("auth")
    os.environ["HOLO_AUTH_FAILURES_PER_MINUTE"] = "5"
    try:
        srv.start()
    finally:
        del os.environ["HOLO_AUTH_FAILURES_PER_MINUTE"]
    assert httpx.get(f"{srv.url}/metrics").status_code == 401
    assert httpx.get(f"{srv.url}/metrics", headers={"Authorization": f"Bearer {srv.reader}"}).status_code == 200
    short = create_token(Database(srv.data_dir / "service.db"), scopes=["read"], expires_in_s=1.0)[1]
    with srv.client(short) as c:
        assert c.get("/v1/jobs").status_code == 200
        time.sleep(1.2)
        r = c.get("/v1/jobs")
        assert r.status_code == 401 and "expired" in r.json()["detail"]
    for _ in range(3):  # with /metrics without a token and the expired token's: 5 failures in this minute
        assert httpx.get(f"{srv.url}/v1/jobs", headers={"Authorization": "Bearer hpt_x_wrong"}).status_code == 401
    r = httpx.get(f"{srv.url}/v1/jobs", headers={"Authorization": "Bearer hpt_x_wrong"})
    assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1 and "too many" in r.json()["detail"]
    r = httpx.get(f"{srv.url}/v1/jobs", headers={"Authorization": f"Bearer {srv.reader}"})
    assert r.status_code == 200  # failures are turned away, a valid token never is


@pytest.mark.slow
def test_a_job_too_big_for_the_workers_is_refused_at_submit(server_factory, scene_bundle):
    from tests.service.helpers import SMALL_JOB, upload

    srv = server_factory("memory")
    os.environ["HOLO_WORKER_MEMORY_MB"] = "4000"
    try:
        srv.start()
    finally:
        del os.environ["HOLO_WORKER_MEMORY_MB"]
    with srv.client("submit") as c:
        sid = upload(c, scene_bundle("cbox-mirror-glass")).json()["id"]
        r = c.post("/v1/jobs", json={"scene_id": sid, "optics": {"resolution_hw": [1080, 1920]}, "frames": 24,
                                     "encoder": "dpac"})
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        from holocore.plan.memory_estimate import estimate_memory

        need = estimate_memory(height_px=1080, width_px=1920, colors=3, frames=24).peak_bytes / 1e9
        assert f"needs about {need:.1f} GB" in detail and "workers have 4.0 GB" in detail and "lower" in detail, detail
        assert c.get("/v1/jobs").json()["jobs"] == []
        r = c.post("/v1/jobs", json={"scene_id": sid, **SMALL_JOB})
        assert r.status_code == 202 and r.json()["estimate"]["memory"]["peak_bytes"] < 4e9
        c.delete(f"/v1/jobs/{r.json()['id']}")
