"""Hostile corpus, the service's side: limits, lockouts, bodies, cross-tenant facts, integrity, fairness and
deployment defaults that a hostile client or job could walk past. Most tests drive the app in process (no
workers, no renders: scenes and finished jobs are rows and files written here); the ones about sockets (slow
bodies, unread bodies) start a real `holo serve`."""

from __future__ import annotations

import hashlib
import os
import socket
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Optional

import pytest
import warnings

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

from service.auth import create_token
from service.settings import ServiceSettings

SCENE_SHA = "ab" * 32


class App:
    """The service app in this process (no scheduler, no planner) with a token maker and row writers."""

    def __init__(self, data_dir: Path, **settings) -> None:
        from service.api.app import create_app

        self.settings = ServiceSettings(data_dir=data_dir, **settings)
        self.app = create_app(self.settings, start_workers=False)
        self.ctx = self.app.state.ctx
        self.db = self.ctx.db

    def token(self, *scopes: str, owner: str = "default") -> str:
        return create_token(self.db, scopes=scopes or ("submit",), owner=owner, name=f"{owner}-test")[1]

    @contextmanager
    def client(self, token: Optional[str] = None, *, address: str = "10.0.0.1") -> Iterator[TestClient]:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        with TestClient(self.app, headers=headers, client=(address, 40000), raise_server_exceptions=False) as c:
            yield c

    def scene(self, owner: str, *, scene_id: str = "stest", plan: Optional[dict] = None) -> str:
        """A scene row (ready plan by default) owned by ``owner``, with an empty bundle folder."""
        (self.settings.scenes_dir / scene_id / "bundle").mkdir(parents=True, exist_ok=True)
        self.db.insert_scene({"id": scene_id, "sha256": SCENE_SHA, "entry": "scene.xml", "report": {},
                              "plan_state": "ready", "plan": plan or {"summary": []}, "created_at": time.time()})
        self.db.add_scene_owner(scene_id, owner)
        return scene_id

    def finish(self, job_id: str, data: bytes = b"stack bytes") -> Path:
        """Mark a queued job succeeded with a stack file of ``data`` (what a worker would leave)."""
        row = self.db.get_job(job_id)
        d = Path(row["artifact_dir"])
        d.mkdir(parents=True, exist_ok=True)
        (d / "stack.npz").write_bytes(data)
        sha = hashlib.sha256(data).hexdigest()
        self.db.update_job(job_id, state="succeeded", finished_at=time.time(), stack_sha256=sha,
                           stack_bytes=len(data), artifacts={"stack.npz": {"sha256": sha, "bytes": len(data)}})
        return d / "stack.npz"


@pytest.fixture
def svc(tmp_path) -> App:
    return App(tmp_path / "data")


def small(scene_id: str, **over) -> dict:
    return {"scene_id": scene_id, "optics": {"resolution_hw": [64, 64]}, "preset": "fast", "spp": 4,
            "encoder": "dpac", **over}


# ---- the preset's most rays are counted and clamped ------------------------------------------------------------

def test_a_preset_without_spp_is_admitted_by_its_most_rays_and_clamped_to_max_spp(svc):
    """``preset: reference`` without spp may choose up to 8192 rays per pixel from the scene depth; admission
    counted a typical 1024, so 2304x4096x3 (2.9e10 typical, 2.3e11 at most) was admitted past the 4e10 budget,
    and the render could trace 8192 per pixel past max_spp 4096."""
    from holocore.plan.effects import choose_spp
    from service.jobfiles import JobFile

    sid = svc.scene("default")
    with svc.client(svc.token("submit")) as c:
        big = {"scene_id": sid, "optics": {"resolution_hw": [2304, 4096]}, "preset": "reference",
               "encoder": "dpac", "frames": 1}
        for path in ("/v1/jobs", "/v1/jobs/estimate"):
            r = c.post(path, json=big)
            assert r.status_code == 422, (path, r.status_code, r.text)
            assert "rays" in r.json()["detail"] and "4096 rays per pixel" in r.json()["detail"], r.text
        r = c.post("/v1/jobs", json={**big, "optics": {"resolution_hw": [256, 256]}})
        assert r.status_code == 202, r.text
        job = r.json()
    assert job["options"]["max_spp"] == 4096  # the render is told the clamp
    assert job["estimate"]["spp_assumed"] is None or job["estimate"]["spp_assumed"] <= 4096
    spec = JobFile(**{k: v for k, v in job["options"].items() if k != "optics"}, job_id=job["id"],
                   scene_path="/x/scene.xml")
    assert spec.hologram_options().max_spp == 4096 and spec.hologram_options().spp is None  # what the render reads
    # the renderer's choice for a deep scene: 8192 unclamped, 4096 with the service's cap
    assert choose_spp("reference", 1e4, 0.05) == 8192 and choose_spp("reference", 1e4, 0.05, 4096) == 4096
    from holocore.plan.effects import SceneInventory, make_plan

    plan = make_plan(SceneInventory(shapes=1, primitives=1), preset="reference", frames=1, n_colors=1,
                     subhologram_radius_px=1e4,
                     max_spp=4096)
    assert plan.spp == 4096
    # the fast preset's own bound is below max_spp: nothing to clamp, the spec and cache key are as before
    with svc.client(svc.token("submit")) as c:
        fast = c.post("/v1/jobs", json=small(sid, spp=None)).json()
    assert fast["options"]["max_spp"] is None


def test_the_render_cli_takes_the_clamp():
    from holocore.pipeline import RenderOptions

    assert RenderOptions(preset="reference", max_spp=4096).max_spp == 4096
    with pytest.raises(ValueError, match="max_spp must be in"):
        RenderOptions(max_spp=0)


# ---- failed authentications lock out failures only, counted per real client ------------------------------------

def test_wrong_tokens_from_one_address_never_lock_out_a_valid_token(tmp_path):
    """60 wrong tokens from 127.0.0.1 made a valid token answer 429 for 60 s: behind a proxy or Docker NAT that
    is everyone."""
    svc = App(tmp_path / "data", auth_failures_per_minute=5)
    good = svc.token("read")
    with svc.client(address="172.17.0.1") as anon:
        for _ in range(5):
            assert anon.get("/v1/jobs", headers={"Authorization": "Bearer hpt_x_wrong"}).status_code == 401
        r = anon.get("/v1/jobs", headers={"Authorization": "Bearer hpt_x_wrong"})
        assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1 and "too many" in r.json()["detail"]
        assert anon.get("/v1/jobs").status_code == 429  # no token at all is a failure too
        r = anon.get("/v1/jobs", headers={"Authorization": f"Bearer {good}"})
        assert r.status_code == 200, r.text  # the same address, a real token: served
        r = anon.post("/v1/jobs", json={"scene_id": "snope"}, headers={"Authorization": f"Bearer {good}"})
        assert r.status_code == 403 and "submit" in r.json()["detail"]  # authenticated, only short of a scope


def test_x_forwarded_for_counts_only_from_a_configured_proxy(tmp_path):
    """The address failures are counted by: a proxy's X-Forwarded-For names the client, anyone else's header is
    ignored (a client naming a new address per request would escape the count, or frame another address)."""
    from service.api.deps import client_address

    nets = ServiceSettings(data_dir=tmp_path, trusted_proxies="10.0.0.2, 172.16.0.0/12").trusted_proxy_networks

    def scope(peer, xff=None):
        return {"client": (peer, 1), "headers": [(b"x-forwarded-for", xff.encode())] if xff else []}

    assert client_address(scope("10.0.0.2", "203.0.113.7")) == "10.0.0.2"  # no proxy configured
    assert client_address(scope("10.0.0.2", "203.0.113.7"), nets) == "203.0.113.7"
    assert client_address(scope("10.0.0.2", "6.6.6.6, 203.0.113.7, 172.20.0.3"), nets) == "203.0.113.7"
    assert client_address(scope("198.51.100.9", "203.0.113.7"), nets) == "198.51.100.9"  # not a proxy
    assert client_address(scope("10.0.0.2", "not-an-ip"), nets) == "10.0.0.2"
    svc = App(tmp_path / "data", auth_failures_per_minute=2, trusted_proxies=["10.0.0.2"])
    bad = {"Authorization": "Bearer hpt_x_wrong"}
    with svc.client(address="10.0.0.2") as proxy, svc.client(address="198.51.100.9") as direct:
        for _ in range(2):
            assert proxy.get("/v1/jobs", headers={**bad, "X-Forwarded-For": "203.0.113.7"}).status_code == 401
        assert proxy.get("/v1/jobs", headers={**bad, "X-Forwarded-For": "203.0.113.7"}).status_code == 429
        assert proxy.get("/v1/jobs", headers={**bad, "X-Forwarded-For": "203.0.113.8"}).status_code == 401
        for i in range(2):  # a direct client's own header changes nothing: still its own address
            assert direct.get("/v1/jobs", headers={**bad, "X-Forwarded-For": f"1.2.3.{i}"}).status_code == 401
        assert direct.get("/v1/jobs", headers={**bad, "X-Forwarded-For": "1.2.3.9"}).status_code == 429
    with pytest.raises(ValueError, match="not an IP address"):
        ServiceSettings(data_dir=tmp_path, trusted_proxies="proxy.example")


def test_an_ipv6_host_cannot_dodge_the_count_by_changing_address(tmp_path):
    """A host is commonly given a whole IPv6 /64: counted per address, each of its 2^64 addresses had fresh
    failures to spend."""
    svc = App(tmp_path / "data", auth_failures_per_minute=3)
    bad = {"Authorization": "Bearer hpt_x_wrong"}
    for i in range(3):
        with svc.client(address=f"2001:db8:0:1::{i + 1:x}") as c:
            assert c.get("/v1/jobs", headers=bad).status_code == 401
    with svc.client(address="2001:db8:0:1:ffff::9") as c:  # the same /64
        assert c.get("/v1/jobs", headers=bad).status_code == 429
        assert c.get("/v1/jobs", headers={"Authorization": f"Bearer {svc.token('read')}"}).status_code == 200
    with svc.client(address="2001:db8:0:2::1") as c:  # the next /64 is another host
        assert c.get("/v1/jobs", headers=bad).status_code == 401
    with svc.client(address="::ffff:192.0.2.7") as c6, svc.client(address="192.0.2.7") as c4:
        for _ in range(3):  # an IPv4 client seen through a mapped address is that client
            assert c6.get("/v1/jobs", headers=bad).status_code == 401
        assert c4.get("/v1/jobs", headers=bad).status_code == 429


# ---- no body is read before authentication; a body has a deadline --------------------------------------------

@pytest.fixture(scope="module")
def live(tmp_path_factory):
    from tests.service.helpers import Server

    srv = Server(tmp_path_factory.mktemp("live") / "data")
    os.environ["HOLO_BODY_TIMEOUT_S"] = "2"
    try:
        srv.start()
    finally:
        del os.environ["HOLO_BODY_TIMEOUT_S"]
    yield srv
    srv.stop()


def _raw(srv, head: bytes, body: bytes = b"") -> socket.socket:
    s = socket.create_connection(("127.0.0.1", srv.port), timeout=10)
    s.sendall(head + body)
    return s


def _answer(s: socket.socket, timeout: float) -> bytes:
    s.settimeout(timeout)
    out = b""
    try:
        while b"\r\n\r\n" not in out or not out.rstrip().endswith(b"}"):
            chunk = s.recv(65536)
            if not chunk:
                break
            out += chunk
    except OSError:  # a timeout, or a reset after the answer
        pass
    return out


@pytest.mark.slow
def test_an_unauthenticated_body_is_refused_before_it_is_read(live):
    """A 100 MB multipart with no token was spooled to disk before the 401. Now the 401 comes from the headers
    alone, with the body unsent, and the connection is closed."""
    reader, agent = (f"Authorization: Bearer {t}\r\n".encode() for t in (live.reader, live.agent))
    for auth, status in ((b"", b"401"), (b"Authorization: Bearer hpt_x_wrong\r\n", b"401"),
                         (reader, b"403"), (agent, b"403")):  # a valid token without submit: refused unread too
        head = (b"POST /v1/scenes HTTP/1.1\r\nHost: x\r\n" + auth
                + b"Content-Type: multipart/form-data; boundary=XyZ\r\nContent-Length: 100000000\r\n\r\n")
        s = _raw(live, head, b'--XyZ\r\nContent-Disposition: form-data; name="bundle"; filename="b.zip"\r\n\r\n')
        answer = _answer(s, 5.0)  # the body is never sent: a server waiting for it answers nothing in 5 s
        s.close()
        assert answer.startswith(b"HTTP/1.1 " + status), answer[:200]
        assert b"connection: close" in answer.lower()
        if status == b"403":
            assert b"lacks the 'submit' scope" in answer, answer[-300:]
    staging = live.data_dir / "scenes" / ".staging"
    assert not staging.exists() or list(staging.iterdir()) == []


def test_a_json_body_is_small_whatever_the_upload_limit(svc):
    """Every route but the upload took bodies up to the upload limit (256 MiB) and FastAPI parsed them whole
    before any check: a 40 MB JSON array held 200 MB, so a few submits of any token could take gigabytes."""
    from service.api.app import JSON_BODY_BYTES

    junk = b'{"scene_id": "sx", "junk": [' + b"0," * JSON_BODY_BYTES + b'0]}'
    json_type = {"content-type": "application/json"}
    with svc.client(svc.token("submit")) as c, svc.client(svc.token("agent")) as agent:
        for client, path in ((c, "/v1/jobs"), (c, "/v1/jobs/estimate"), (agent, "/v1/displays/d1/heartbeat")):
            r = client.post(path, content=junk, headers=json_type)  # declared length
            assert r.status_code == 413 and f"limit of {JSON_BODY_BYTES} bytes" in r.json()["detail"], (path, r.text)
            streamed = client.post(path, content=iter([junk[:1000], junk[1000:]]), headers=json_type)  # chunked
            assert streamed.status_code == 413, (path, streamed.status_code, streamed.text[:200])
        r = c.post("/v1/jobs", json={"scene_id": "snope", "optics": {"resolution_hw": [64, 64]}})
        assert r.status_code == 422 and "no scene" in r.json()["detail"]  # a real job's body passes as before
        # an upload may still be as large as the upload limit
        big = {"bundle": ("b.zip", _zip({"scene.xml": SCENE_XML, "notes.txt": os.urandom(JSON_BODY_BYTES).hex()
                                         .encode()}), "application/zip")}
        r = c.post("/v1/scenes", files=big)
        assert r.status_code == 201, r.text


@pytest.mark.slow
def test_a_body_trickled_at_one_byte_a_second_times_out(live):
    """Bodies at 1 byte/s never timed out: a handful of clients could hold every request slot."""
    import threading

    body = b'{"scene_id": "' + b"s" * 40 + b'"}'
    head = (b"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " + live.submit.encode()
            + b"\r\nContent-Type: application/json\r\nContent-Length: " + str(len(body)).encode() + b"\r\n\r\n")

    s = _raw(live, head)
    stop = threading.Event()

    def trickle():  # a byte a second, until the server answers or closes
        for byte in body:
            if stop.wait(1.0):
                return
            try:
                s.sendall(bytes([byte]))
            except OSError:
                return

    sender = threading.Thread(target=trickle, daemon=True)
    sender.start()
    answer = b""
    s.settimeout(10.0)
    try:
        while not answer.rstrip().endswith(b"}"):
            chunk = s.recv(65536)
            if not chunk:
                break
            answer += chunk
    except OSError:
        pass
    stop.set()
    sender.join(timeout=5)
    s.close()
    assert answer.startswith(b"HTTP/1.1 408"), answer[:300]
    # the whole body would take ~55 s at a byte a second, past the 10 s the reader waits: an answer at all is early
    assert b"did not arrive within 2 s" in answer
    import httpx

    with live.client("submit") as c:  # a whole body in time is served as before
        r = c.post("/v1/jobs", json={"scene_id": "snope"})
        assert r.status_code == 422 and "no scene" in r.json()["detail"]
    assert httpx.get(f"{live.url}/livez").status_code == 200


# ---- nothing of one owner reaches another: reuse, uploads, metrics, displays, the stack's meta -----------------

SCENE_XML = (b'<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="30"/></sensor>'
             b'<shape type="sphere"><bsdf type="diffuse"/></shape><emitter type="constant"/></scene>')


def _zip(files: dict[str, bytes]) -> bytes:
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in files.items():
            zf.writestr(name, data)
    return buf.getvalue()


def test_an_identical_job_of_another_owner_is_not_reused(svc):
    """Bob's job identical to Alice's came back at once with ``reused_from`` naming Alice's job."""
    alice, bob = svc.token("submit", owner="alice"), svc.token("submit", owner="bob")
    for owner in ("alice", "bob"):
        svc.db.add_scene_owner(svc.scene(owner), owner)
    with svc.client(alice) as a, svc.client(bob) as b:
        first = a.post("/v1/jobs", json=small("stest")).json()
        svc.finish(first["id"])
        est = b.post("/v1/jobs/estimate", json=small("stest")).json()
        assert est["reuses"] is None
        theirs = b.post("/v1/jobs", json=small("stest")).json()
        assert theirs["state"] == "queued" and theirs["reused_from"] is None, theirs
        assert a.post("/v1/jobs/estimate", json=small("stest")).json()["reuses"] == first["id"]
        again = a.post("/v1/jobs", json=small("stest")).json()  # the owner's own result is reused as before
        assert again["state"] == "succeeded" and again["reused_from"] == first["id"]


def test_an_identical_upload_tells_nothing_of_another_owners(svc):
    """Bob uploading Alice's files got Alice's scene: her created_at, her ready plan, 200 instead of 201."""
    alice, bob = svc.token("submit", owner="alice"), svc.token("submit", owner="bob")
    files = {"bundle": ("b.zip", _zip({"scene.xml": SCENE_XML}), "application/zip")}
    with svc.client(alice) as a, svc.client(bob) as b:
        r = a.post("/v1/scenes", files=files)
        assert r.status_code == 201, r.text
        hers = r.json()
        svc.db.update_scene(hers["id"], plan_state="ready", plan={"summary": ["planned"]})
        time.sleep(0.01)
        r = b.post("/v1/scenes", files=files)
        assert r.status_code == 201, r.text
        his = r.json()
        assert his["id"] != hers["id"] and his["plan_state"] == "pending" and his["plan"] is None
        assert his["created_at"] > hers["created_at"] and his["sha256"] == hers["sha256"]
        assert b.get(f"/v1/scenes/{hers['id']}").status_code == 404
        assert b.post("/v1/scenes", files=files).status_code == 200  # his own again: the same scene
    with svc.client(svc.token("submit")) as d:  # the default owner keeps the single-tenant ids
        from service.api.scenes import scene_id_for

        mine = d.post("/v1/scenes", files=files).json()
        assert mine["id"] == scene_id_for("default", hers["sha256"], "scene.xml")
        assert mine["id"] == "s" + hashlib.sha256(f"{hers['sha256']}\0scene.xml".encode()).hexdigest()[:24]


def test_metrics_of_a_non_admin_token_are_its_owners_alone(svc):
    """/metrics gave any read token the service's global counts (everyone's jobs, uploads, requests)."""
    svc.scene("alice", scene_id="salice")
    with svc.client(svc.token("submit", owner="alice")) as a:
        for i in range(3):
            r = a.post("/v1/jobs", json=small("salice", optics={"resolution_hw": [64, 64], "seed": i}))
            assert r.status_code == 202, r.text
    with svc.client(svc.token("read", owner="bob")) as b:
        text = b.get("/metrics").text
        assert 'holo_jobs{state="queued"} 0.0' in text and "holo_http_requests" not in text, text
        assert "holo_scenes 0.0" in text
    with svc.client(svc.token("read", owner="alice")) as a:
        text = a.get("/metrics").text
        assert 'holo_jobs{state="queued"} 3.0' in text and "holo_scenes 1.0" in text
    with svc.client(svc.token("admin")) as admin:
        text = admin.get("/metrics").text
        assert 'holo_jobs{state="queued"} 3.0' in text and "holo_http_requests" in text


def test_a_display_of_another_owner_and_a_free_name_get_the_same_answer(svc):
    """/v1/jobs/estimate answered 403 for display names other owners hold and 200 for free ones: a probe."""
    svc.scene("bob", scene_id="sbob")
    svc.db.claim_display("alice-lab", "alice", "t")
    with svc.client(svc.token("submit", owner="bob")) as b:
        for path in ("/v1/jobs/estimate", "/v1/jobs"):
            held = b.post(path, json=small("sbob", display="alice-lab"))
            free = b.post(path, json=small("sbob", display="nobodys-lab"))
            assert held.status_code == free.status_code, (path, held.text, free.text)
            assert held.status_code in (200, 202) and set(held.json()) == set(free.json())
    with svc.client(svc.token("agent", owner="alice")) as agent:  # and bob's job reaches no agent of alice's
        assert agent.get("/v1/jobs", params={"display": "alice-lab"}).json()["jobs"] == []


@pytest.mark.slow
def test_the_stack_names_its_scene_relative_to_the_bundle(tmp_path, scene_bundle):
    """STACK.npz meta.scene held the server's absolute path of the bundle."""
    import shutil

    from holocore.display.optics import OpticsConfig
    from holocore.pipeline import RenderOptions, render

    folder = tmp_path / "secret-server-path" / "bundle"
    shutil.copytree(scene_bundle("cbox-mirror-glass"), folder)
    entry = next(folder.glob("*.xml"))
    res = render(entry, OpticsConfig(resolution_hw=(16, 16), frames=1, wavelengths_nm=(520.0,)),
                 RenderOptions(preset="fast", spp=1, wrp_planes=1))
    assert res.meta["scene"] == entry.name and "secret-server-path" not in str(res.meta), res.meta["scene"]


# ---- the integrity cache cannot be fooled by an overwrite with its mtime set back ------------------------------

def _overwrite_keeping_mtime(path: Path, data: bytes) -> None:
    st = path.stat()
    time.sleep(0.02)  # past the kernel's coarse clock tick: the overwrite gets a ctime of its own
    with open(path, "r+b") as fh:  # in place: same inode, same size
        fh.write(data)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    after = path.stat()
    assert (after.st_size, after.st_mtime_ns, after.st_ino) == (st.st_size, st.st_mtime_ns, st.st_ino)


def test_an_overwrite_with_mtime_restored_is_not_served_or_reused(svc):
    """Hashes were cached by (size, mtime_ns, inode): an in-place overwrite with its mtime set back was served
    under the old ETag and reused into another job."""
    from service.integrity import artifact_intact, current_sha256

    svc.scene("default")
    good = b"A" * 4096
    with svc.client(svc.token("submit")) as c:
        job = c.post("/v1/jobs", json=small("stest")).json()
        stack = svc.finish(job["id"], good)
        r = c.get(f"/v1/jobs/{job['id']}/stack")
        assert r.status_code == 200 and r.content == good  # hashed once, now cached
        _overwrite_keeping_mtime(stack, b"B" * 4096)
        r = c.get(f"/v1/jobs/{job['id']}/stack")
        assert r.status_code == 409 and "integrity check" in r.json()["detail"], r.status_code
        again = c.post("/v1/jobs", json=small("stest")).json()
        assert again["reused_from"] is None and again["state"] == "queued", again
    # reuse hashes afresh even when the cache would say nothing changed
    other = svc.settings.data_dir / "f.bin"
    other.write_bytes(good)
    sha = hashlib.sha256(good).hexdigest()
    assert current_sha256(other) == sha
    from service import integrity

    integrity._known[str(other)] = (integrity._known[str(other)][0], "0" * 64)  # a stale entry
    assert not artifact_intact(other, sha) and artifact_intact(other, sha, fresh=True)


# ---- memory admission counts the deeper recording planes' grids ------------------------------------------------

def _plan(z_near_zc: float = 0.3, z_far_zc: float = 3.0, f: float = 0.05, z_inf: float = 0.08) -> dict:
    """A scene plan as `holo plan --json` stores it (the parts memory admission reads), made at f, z_inf."""
    return {"summary": [], "focal_length_m": f, "optics": {"z_inf_mm": z_inf * 1e3},
            "field_of_view": {"camera_fov_x_deg": 30.0},
            "analysis": {"z_near_holo_m": z_inf + f * f / z_near_zc, "z_far_holo_m": z_inf + f * f / z_far_zc}}


DEEP = {"optics": {"resolution_hw": [32, 48], "wavelengths_nm": [520], "focal_length_mm": 300.0, "frames": 1},
        "preset": "fast", "spp": 4, "encoder": "dpac", "wrp_planes": 2}


def test_deeper_planes_grids_count_at_admission(tmp_path):
    """wrp_planes 2 at f = 300 mm on a 32x48 SLM measured 2.18 GB against 0.63 GB estimated and was admitted:
    the deeper plane's grid is wider by (z_0 - z_k) tan(theta) / p on each side, and that depth grows with f^2."""
    from holocore.plan.memory_estimate import estimate_memory, plane_chain_bytes
    from holocore.plan.wrp_planes import WrpPlanes

    svc = App(tmp_path / "data", worker_memory_mb=1000)
    sid = svc.scene("default", plan=_plan())
    with svc.client(svc.token("submit")) as c:
        r = c.post("/v1/jobs", json={"scene_id": sid, **DEEP})
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert "workers have 1.0 GB" in detail and "deeper recording planes" in detail and "px wider" in detail
        one = c.post("/v1/jobs", json={"scene_id": sid, **DEEP, "wrp_planes": 1})
        assert one.status_code == 202, one.text  # the same job on one plane fits
        assert one.json()["estimate"]["memory"]["plane_border_px"] == 0
        near = c.post("/v1/jobs", json={"scene_id": sid, **DEEP, "optics": {**DEEP["optics"], "focal_length_mm": 50}})
        assert near.status_code == 202, near.text  # f = 50 mm: 36 times shallower, a narrow border
        border = near.json()["estimate"]["memory"]["plane_border_px"]
        assert 0 < border < 50
        r = c.post("/v1/jobs", json={"scene_id": sid, **DEEP, "optics": {**DEEP["optics"], "max_wrp_distance_mm": 1e9}})
        assert r.status_code == 422 and "optics.max_wrp_distance_mm: at most 1000 mm" in r.json()["detail"]
    # the border the estimate counts is the one the renderer gives the deepest possible plane
    depth = 36 * (0.05 ** 2) * (1 / 0.3 - 1 / 3.0)
    planes = WrpPlanes((0.5, 0.5 - depth), 1e-6)
    import math

    theta = math.asin(520e-9 / (2 * 8e-6))
    b = planes.border_px(1, pitch_m=8e-6, theta_max=theta)
    m = estimate_memory(height_px=32, width_px=48, colors=1, frames=1, plane_border_px=b)
    assert m.render_bytes - estimate_memory(height_px=32, width_px=48, colors=1, frames=1).render_bytes \
        == plane_chain_bytes(32, 48, b) > 0.5e9


def test_a_job_submitted_before_its_scene_is_planned_is_checked_before_it_runs(tmp_path):
    """A pending plan says nothing of the scene's depth: the job is queued, and the scheduler counts its planes'
    grids once the plan is ready (waiting until then), refusing it if the workers cannot hold it."""
    from service.workers.scheduler import Scheduler

    svc = App(tmp_path / "data", worker_memory_mb=1000)
    sid = svc.scene("default", plan=_plan())
    svc.db.update_scene(sid, plan_state="pending", plan=None)
    with svc.client(svc.token("submit")) as c:
        r = c.post("/v1/jobs", json={"scene_id": sid, **DEEP})
        assert r.status_code == 202, r.text
        job = r.json()
    assert job["estimate"]["memory"]["plane_border_px"] is None
    sched = Scheduler(svc.settings, svc.db, engine=None)
    row = svc.db.get_job(job["id"])
    assert sched._memory_need(row) is None  # waits for the plan
    svc.db.update_scene(sid, plan_state="ready", plan=_plan())
    assert sched._memory_need(row) == -1
    failed = svc.db.get_job(job["id"])
    assert failed["state"] == "failed" and "refused before it ran" in failed["error"] and "px wider" in failed["error"]


# ---- owners share the service fairly ----------------------------------------------------------------------------

def test_owners_are_scheduled_in_turn_not_first_come(svc):
    """One FIFO queue: an owner who queued 50 jobs first made everyone else wait for all 50."""
    for owner in ("alice", "bob", "carol"):
        svc.scene(owner, scene_id=f"s{owner}")
    with svc.client(svc.token("submit", owner="alice")) as a:
        alices = [a.post("/v1/jobs", json=small("salice", optics={"resolution_hw": [64, 64], "seed": i})).json()["id"]
                  for i in range(5)]
    with svc.client(svc.token("submit", owner="bob")) as b:
        bobs = [b.post("/v1/jobs", json=small("sbob", optics={"resolution_hw": [64, 64], "seed": i})).json()["id"]
                for i in range(2)]
    with svc.client(svc.token("submit", owner="carol")) as c:
        carol = c.post("/v1/jobs", json=small("scarol")).json()["id"]
    order = [j["id"] for j in svc.db.queued_jobs_fair(limit=10)]
    assert order == [alices[0], bobs[0], carol, alices[1], bobs[1], *alices[2:]], order
    assert svc.db.claim_next_job(alices[0])["id"] == alices[0]  # alice has one running: the others go first
    assert [j["id"] for j in svc.db.queued_jobs_fair(limit=3)] == [bobs[0], carol, bobs[1]]
    assert svc.db.next_queued_job()["id"] == bobs[0]
    svc.db.update_job(alices[0], state="succeeded")  # one worker: alice's finished, the others still go first
    assert [j["id"] for j in svc.db.queued_jobs_fair(limit=3)] == [bobs[0], carol, alices[1]]
    for expect in (bobs[0], carol, alices[1], bobs[1], alices[2]):  # one worker, each run to the end in turn
        got = svc.db.claim_next_job(svc.db.next_queued_job()["id"])
        assert got["id"] == expect, (got["id"], expect)
        time.sleep(0.002)  # started_at apart
        svc.db.update_job(got["id"], state="succeeded")


def test_per_owner_caps_on_queued_jobs_scenes_and_uploads(tmp_path):
    """Nothing stopped one owner from queueing, storing or uploading without end."""
    svc = App(tmp_path / "data", max_queued_jobs_per_owner=2, max_scenes_per_owner=1, max_uploads_per_owner=1)
    svc.scene("alice", scene_id="salice")
    alice, bob = svc.token("submit", owner="alice"), svc.token("submit", owner="bob")
    with svc.client(alice) as a:
        for i in range(2):
            assert a.post("/v1/jobs", json=small("salice", optics={"resolution_hw": [64, 64], "seed": i})
                          ).status_code == 202
        r = a.post("/v1/jobs", json=small("salice", optics={"resolution_hw": [64, 64], "seed": 9}))
        assert r.status_code == 429 and "2 jobs queued or running" in r.json()["detail"], r.text
        files = {"bundle": ("b.zip", _zip({"scene.xml": SCENE_XML}), "application/zip")}
        r = a.post("/v1/scenes", files=files)
        assert r.status_code == 403 and "stores 1 scenes" in r.json()["detail"], r.text
        svc.ctx.uploads_in_flight["alice"] = 1  # one of hers is being received
        r = a.post("/v1/scenes", files=files)
        assert r.status_code == 429 and "uploads in progress" in r.json()["detail"], r.text
        del svc.ctx.uploads_in_flight["alice"]
    with svc.client(bob) as b:  # another owner is not held back by her
        assert b.post("/v1/scenes", files=files).status_code == 201
        assert svc.ctx.uploads_in_flight == {}


def test_display_names_go_only_to_agents_they_are_registered_to(tmp_path):
    """Display names went to the first agent that heartbeat them: any owner could take a name another lab had
    not switched on yet."""
    svc = App(tmp_path / "data")
    hb = {"agent_version": "1", "state": "idle", "message": ""}
    bob_agent, bob_other = svc.token("agent", owner="bob"), svc.token("agent", owner="bob")
    with svc.client(svc.token("agent", owner="alice")) as alice, svc.client(bob_agent) as bob, \
            svc.client(bob_other) as bob2, svc.client(svc.token("admin")) as admin:
        squat = alice.post("/v1/displays/bob-lab/heartbeat", json=hb)
        assert squat.status_code == 403 and "an admin registers displays" in squat.json()["detail"]
        assert bob.get("/v1/displays").json()["displays"] == []  # not registered to alice either
        bob_id = next(t["id"] for t in svc.db.list_tokens() if t["owner"] == "bob")
        assert admin.put("/v1/displays/bob-lab", json={"owner": "bob", "agent_token_id": bob_id}).status_code == 204
        assert bob.post("/v1/displays/bob-lab/heartbeat", json=hb).status_code == 204
        r = bob2.post("/v1/displays/bob-lab/heartbeat", json=hb)  # bob's, but not the token it was registered to
        assert r.status_code == 403 and r.json()["detail"] == squat.json()["detail"]
        foreign = alice.post("/v1/displays/bob-lab/heartbeat", json=hb)
        assert foreign.status_code == 403 and foreign.json()["detail"] == squat.json()["detail"]  # no probe
    with svc.client(svc.token("agent")) as single_tenant:  # the default owner still registers by heartbeat
        assert single_tenant.post("/v1/displays/lab-1/heartbeat", json=hb).status_code == 204


# ---- deployment defaults: no CDN, private files, a loud unsandboxed root, a closed environment ---------------

def test_docs_load_nothing_from_another_origin(svc):
    """/docs loaded swagger-ui from a CDN without SRI: a third party's script on a page that asks for tokens."""
    with svc.client() as c:
        docs = c.get("/docs")
        assert docs.status_code == 200 and docs.headers["content-type"].startswith("text/html")
        assert "<script" not in docs.text and "http" not in docs.text.replace('href="/openapi.json"', "")
        assert "/v1/jobs/{job_id}/stack" in docs.text and docs.headers["content-security-policy"].startswith(
            "default-src 'none'")
        assert c.get("/redoc").status_code == 404
        assert c.get("/openapi.json").status_code == 200


@pytest.mark.slow
def test_unsandboxed_server_keeps_its_files_private_and_says_so(server_factory):
    """--sandbox off as root logged nothing, /readyz never showed the sandbox state, and service.db and the
    artifacts were 0644 in 0755 folders."""
    import stat

    import httpx

    srv = server_factory("plain", extra=("--sandbox", "off"))
    os.chmod(srv.data_dir / "service.db", 0o644)  # as a laxer umask left it
    srv.start()
    ready = httpx.get(f"{srv.url}/readyz").json()
    assert ready["sandbox"] == {"state": "off", "root": os.geteuid() == 0, "jobs": False, "private_tmp": False}, ready
    with srv.client("submit") as c:
        r = c.post("/v1/scenes", files={"bundle": ("b.zip", _zip({"scene.xml": SCENE_XML}), "application/zip")})
        assert r.status_code == 201, r.text
    for p in [srv.data_dir / "service.db", *(srv.data_dir / "scenes").rglob("*")]:
        mode = stat.S_IMODE(p.stat().st_mode)
        assert mode & 0o077 == 0, (p, oct(mode))
    assert stat.S_IMODE(srv.data_dir.stat().st_mode) & 0o077 == 0
    if os.geteuid() == 0:
        assert "running as root without privilege separation" in srv.log()


def test_a_token_made_before_the_first_serve_leaves_nothing_readable(tmp_path):
    """`holo token create` on a new data dir made it 0755 and service.db 0644 (the user's umask) until the first
    `holo serve` closed them: every job, scene and token hash readable by anyone on the host meanwhile."""
    import stat
    import subprocess
    import sys

    data = tmp_path / "fresh" / "data"
    r = subprocess.run([sys.executable, "-m", "holo", "token", "create", "--data-dir", str(data), "--scope", "read"],
                       capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2], timeout=60,
                       preexec_fn=lambda: os.umask(0o022))
    assert r.returncode == 0, r.stderr
    assert stat.S_IMODE(data.stat().st_mode) == 0o700
    files = [p for p in data.iterdir() if p.name.startswith("service.db")]
    assert files and all(stat.S_IMODE(p.stat().st_mode) == 0o600 for p in files), \
        [(p.name, oct(p.stat().st_mode)) for p in files]
    from service.db import Database

    old = os.umask(0o022)
    try:
        db = Database(tmp_path / "other" / "service.db")  # any maker: the service, a test, a script
        db.insert_token(token_id="t", token_hash="h", name="", scopes=["read"], created_at=0.0, owner="default",
                        expires_at=None)
    finally:
        os.umask(old)
    made = [p for p in (tmp_path / "other").iterdir()]
    assert {p.name for p in made} >= {"service.db", "service.db-wal"}
    assert all(stat.S_IMODE(p.stat().st_mode) == 0o600 for p in made), [(p.name, oct(p.stat().st_mode)) for p in made]


def test_sandboxed_processes_get_an_allow_listed_environment(tmp_path, monkeypatch):
    """The sandbox's environment was the server's less a deny-list of secret-looking names: a proxy URL with a
    password, a cloud session or the data dir's location passed through."""
    from service.workers.engine import sandbox_env

    monkeypatch.setenv("HTTPS_PROXY", "http://user:hunter2@proxy:3128")
    monkeypatch.setenv("AWS_SESSION_TOKEN", "x")
    monkeypatch.setenv("HOLO_DATA_DIR", "/srv/holo")
    monkeypatch.setenv("HOLO_DEVICE", "cpu")
    monkeypatch.setenv("LC_ALL", "C.UTF-8")
    env = sandbox_env(tmp_path)
    assert not {"HTTPS_PROXY", "AWS_SESSION_TOKEN", "HOLO_DATA_DIR", "USER", "LOGNAME"} & set(env), sorted(env)
    assert env["HOLO_DEVICE"] == "cpu" and env["LC_ALL"] == "C.UTF-8" and "PATH" in env
    assert env["HOME"] == str(tmp_path / "home") and env["TMPDIR"] == str(tmp_path / "tmp")
    assert env["PYTHONSAFEPATH"] == "1"


def test_scene_plans_are_claimed_in_turn_by_owner(svc):
    """One planner, one FIFO: an owner's hundred uploads held every other owner's plans back."""
    for i in range(4):
        svc.scene("alice", scene_id=f"salice{i}")
    svc.scene("bob", scene_id="sbob")
    for sid in [f"salice{i}" for i in range(4)] + ["sbob"]:
        svc.db.update_scene(sid, plan_state="pending", plan=None)
    claimed = [svc.db.claim_next_plan()["id"] for _ in range(3)]
    assert claimed == ["salice0", "sbob", "salice1"], claimed


@pytest.mark.skipif(os.geteuid() != 0, reason="making files of another uid needs root")
def test_what_a_sandbox_uid_leaves_in_shared_temporary_folders_is_removed_with_its_processes(tmp_path):
    """Slot uids share /tmp, /var/tmp and /dev/shm, and the files a run left there stayed: the uid's next run
    (another owner's job) could read them, and files in /dev/shm held memory until a reboot."""
    import ctypes
    import ctypes.util

    from service.workers.engine import kill_uids, remove_leftovers

    uid, other = 61_901, 61_902  # not the sandbox tests' uids
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o1777)
    os.chmod(shared, 0o1777)
    world = shared / "made-0777-by-another"
    world.mkdir()
    os.chmod(world, 0o777)
    closed = shared / "root-only"
    closed.mkdir(mode=0o700)

    def made_by(who: int, path: Path, *, folder: bool = False) -> Path:
        if folder:
            path.mkdir()
            (path / "inside").write_bytes(b"x")
            os.chown(path / "inside", who, who)
        else:
            path.write_bytes(b"secret of the last run")
        os.chown(path, who, who)
        return path

    mine = [made_by(uid, shared / "f"), made_by(uid, shared / "d", folder=True), made_by(uid, world / "g")]
    os.symlink("/etc/passwd", shared / "link")
    os.lchown(shared / "link", uid, uid)
    mine.append(shared / "link")
    kept = [made_by(other, shared / "theirs"), made_by(uid, closed / "unreachable-to-it"), Path("/etc/passwd")]
    elsewhere = tmp_path / "elsewhere"  # another running uid's link to a folder: never followed
    elsewhere.mkdir()
    kept.append(made_by(uid, elsewhere / "not-in-a-shared-folder"))
    os.symlink(elsewhere, shared / "swapped")
    os.lchown(shared / "swapped", other, other)
    kept.append(shared / "swapped")
    gone = remove_leftovers({uid}, roots=(str(shared),))
    assert sorted(gone) == sorted(map(str, mine)), gone
    assert not any(os.path.lexists(p) for p in mine) and all(os.path.lexists(p) for p in kept)
    # System V shared memory outlives its processes too
    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: become the sandbox uid, make a segment, leave
        try:
            os.setgroups([])
            os.setgid(uid)
            os.setuid(uid)
            os.write(w, str(libc.shmget(0, 1 << 20, 0o1600)).encode())  # IPC_PRIVATE, IPC_CREAT | 0600
        finally:
            os._exit(0)
    os.close(w)
    shmid = int(os.read(r, 100) or b"-1")
    os.close(r)
    os.waitpid(pid, 0)
    assert shmid >= 0
    assert kill_uids({uid}, timeout_s=2.0)  # no processes left: the sweep of the real shared folders runs
    assert libc.shmctl(ctypes.c_int(shmid), ctypes.c_int(0), None) != 0  # already removed


def test_what_one_owner_stores_is_capped_in_bytes(tmp_path):
    """The caps counted scenes and queued jobs, not bytes: 1000 scenes of 256 MiB, or finished jobs without
    end (a 4096x2304 job with 64 frames and 3 colours leaves 40 GB), were one owner's to fill the disk with."""
    from service.api.submission import output_bytes, owner_stored_bytes

    svc = App(tmp_path / "data", max_stored_gb_per_owner=0.015)  # 15 MB an owner
    svc.scene("alice", scene_id="salice")
    svc.scene("bob", scene_id="sbob")
    alice, bob = svc.token("submit", owner="alice"), svc.token("submit", owner="bob")
    job = {"optics": {"resolution_hw": [256, 256], "wavelengths_nm": [520]}, "frames": 4}
    one = output_bytes({"resolution_hw": [256, 256], "wavelengths_nm": [520], "frames": 4}, keep_result=True)
    assert 10e6 < one < 11e6  # 256 x 256 x 4 samples, 22 bytes each, and the small files
    with svc.client(alice) as a, svc.client(bob) as b:
        first = a.post("/v1/jobs", json=small("salice", **job))
        assert first.status_code == 202, first.text
        r = a.post("/v1/jobs", json=small("salice", frames=4, optics={**job["optics"], "seed": 2}))
        assert r.status_code == 403 and "max_stored_gb_per_owner" in r.json()["detail"], r.text
        assert "0.015 GB one owner may store" in r.json()["detail"]
        assert b.post("/v1/jobs", json=small("sbob", **job)).status_code == 202  # another owner's room is its own
        # a finished job counts what its folder holds, not the prediction
        svc.finish(first.json()["id"], b"x" * 1000)
        assert owner_stored_bytes(svc.ctx, "alice") < 10_000
        again = a.post("/v1/jobs", json=small("salice", frames=4, optics={**job["optics"], "seed": 2}))
        assert again.status_code == 202, again.text
        reused = a.post("/v1/jobs", json=small("salice", **job))  # a reused result adds nothing
        assert reused.status_code == 202 and reused.json()["reused_from"] == first.json()["id"]
        # an upload counts its unpacked bytes
        files = {"bundle": ("b.zip", _zip({"scene.xml": SCENE_XML, "big.txt": b"0123456789" * 600_000}),
                 "application/zip")}
        r = a.post("/v1/scenes", files=files)
        assert r.status_code == 403 and "this scene adds up to 0.01 GB" in r.json()["detail"], r.text
    assert ServiceSettings(data_dir=tmp_path).stored_bytes_per_owner > 0  # default: half the file system


def test_reuse_then_delete_never_lowers_what_an_owner_is_charged_below_its_disk_use(tmp_path):
    """A reused result was charged only to the job that computed it; deleting that job kept the folder (the
    reusing job holds it) and charged it to nobody: compute, resubmit, delete, again, and the owner stored
    gigabytes counted as nothing. Every job that holds a folder charges it, once per owner."""
    from service.api.submission import owner_stored_bytes

    svc = App(tmp_path / "data", max_stored_gb_per_owner=0.005)  # 5 MB an owner; a new job's prediction is 4.2
    svc.scene("alice", scene_id="salice")
    alice = svc.token("submit", owner="alice")
    job = {"optics": {"resolution_hw": [8, 8], "wavelengths_nm": [520]}, "frames": 1}
    with svc.client(alice) as a:
        on_disk = 0
        for seed in range(1, 5):
            body = small("salice", frames=1, optics={**job["optics"], "seed": seed})
            first = a.post("/v1/jobs", json=body)
            if seed == 4:  # 3 x 300 kB held and 4.2 MB predicted: past 5 MB
                assert first.status_code == 403 and "max_stored_gb_per_owner" in first.json()["detail"], first.text
                break
            assert first.status_code == 202, first.text
            svc.finish(first.json()["id"], bytes([seed]) * 300_000)
            on_disk += 300_000
            reused = a.post("/v1/jobs", json=body)
            assert reused.status_code == 202 and reused.json()["reused_from"] == first.json()["id"], reused.text
            assert a.post(f"/v1/jobs/{first.json()['id']}/delete").status_code == 204
            assert (Path(svc.db.get_job(reused.json()["id"])["artifact_dir"]) / "stack.npz").is_file()
            assert owner_stored_bytes(svc.ctx, "alice") >= on_disk
        # the last holder deleted: the folder goes, and so does the charge
        last = reused.json()["id"]
        folder = Path(svc.db.get_job(last)["artifact_dir"])
        assert a.post(f"/v1/jobs/{last}/delete").status_code == 204
        assert not folder.exists() and owner_stored_bytes(svc.ctx, "alice") == on_disk - 300_000


def test_a_jobs_plane_scratch_counts_against_its_owners_storage(tmp_path):
    """A deeper recording plane is held in a scratch file of [frames, colours] on its wider grid while the job
    renders: at f = 300 mm on a 32x48 SLM a few MB of output came with tens of MB of scratch per frame, which
    only the memory check (one frame of one colour) counted."""
    from service.api.submission import output_bytes

    svc = App(tmp_path / "data", worker_memory_mb=4000, max_stored_gb_per_owner=0.09)
    sid = svc.scene("default", plan=_plan())
    with svc.client(svc.token("submit")) as c:
        one = c.post("/v1/jobs", json={"scene_id": sid, **DEEP, "optics": {**DEEP["optics"], "seed": 1}})
        assert one.status_code == 202, one.text
        border = one.json()["estimate"]["memory"]["plane_border_px"]
        assert border > 500
        opt = {"resolution_hw": [32, 48], "wavelengths_nm": [520], "frames": 1}
        scratch = output_bytes(opt, keep_result=True, wrp_planes=2, plane_border=border) - \
            output_bytes(opt, keep_result=True, wrp_planes=1)
        assert scratch == (32 + 2 * border) * (48 + 2 * border) * 8 > 35e6  # 40 MB a frame, output 4 MB
        four = c.post("/v1/jobs", json={"scene_id": sid, **DEEP, "frames": 4})  # 4 frames of scratch
        assert four.status_code == 403 and "max_stored_gb_per_owner" in four.json()["detail"], four.text
        flat = c.post("/v1/jobs", json={"scene_id": sid, **DEEP, "frames": 4, "wrp_planes": 1})
        assert flat.status_code == 202, flat.text  # one plane: no scratch
        # a queued job's scratch is not on the disk yet (at most the workers' running jobs hold theirs); a
        # running one's is
        again = {"scene_id": sid, **DEEP, "optics": {**DEEP["optics"], "seed": 3}}
        assert c.post("/v1/jobs", json=again).status_code == 202
        svc.db.claim_next_job(one.json()["id"])
        r = c.post("/v1/jobs", json={**again, "optics": {**again["optics"], "seed": 4}})
        assert r.status_code == 403, r.text


@pytest.mark.skipif(os.geteuid() != 0, reason="a mount namespace and another uid need root")
def test_a_sandboxed_job_gets_temporary_folders_of_its_own(tmp_path):
    """Slot uids shared /tmp, /var/tmp and /dev/shm while their runs overlapped: what one run put there another
    could find, and /dev/shm is memory. The job starter gives each run a namespace where they are its own folder
    (where the platform grants CAP_SYS_ADMIN; else they stay shared and its leftovers are swept)."""
    import subprocess
    import sys

    from service.workers.private_tmp import private_targets

    uid = 61_903
    own = tmp_path / "jobtmp"
    own.mkdir()
    os.chown(own, uid, uid)
    tag = f"probe-{os.getpid()}-{time.monotonic_ns()}"
    script = (f"id -u; ls -A /tmp /var/tmp /dev/shm | grep -c . ; echo a > /tmp/{tag}.t; echo b > /dev/shm/{tag}.s; "
              f"echo c > /var/tmp/{tag}.v; ipcs -m | grep -c '^0x' || true")
    r = subprocess.run([sys.executable, "-m", "service.workers.private_tmp", str(own), str(uid), str(uid), "--",
                        "/bin/sh", "-c", script], cwd="/", capture_output=True, text=True, timeout=60,
                       env={"PATH": os.environ["PATH"], "PYTHONPATH": str(Path(__file__).resolve().parents[2]),
                            "PYTHONSAFEPATH": "1"})
    assert r.returncode == 0, r.stderr
    if "no namespace of its own" in r.stderr:
        pytest.skip(f"this platform gives no mount namespace: {r.stderr.strip()}")
    # the folders the starter may replace: all three, unless the code itself lives under one (a clone in /tmp)
    repo = str(Path(__file__).resolve().parents[2])
    private = private_targets([repo, sys.executable, os.path.realpath(sys.executable), sys.prefix, sys.base_prefix])
    assert "/var/tmp" in private and "/dev/shm" in private
    assert f"private {', '.join(private)} and System V IPC" in r.stderr, r.stderr
    letter = {"/tmp": "t", "/var/tmp": "v", "/dev/shm": "s"}
    Path("/tmp", f"{tag}.t").unlink(missing_ok=True)  # written to the host's /tmp when that stays shared
    lines = r.stdout.split()
    assert lines[0] == str(uid)
    if len(private) == 3:
        assert lines[1] == "3"  # the three listings' headers only: nothing of the host's folders is seen
    assert lines[2] == "0"  # no System V segment of anyone else's
    assert sorted(p.name for p in own.iterdir()) == sorted(f"{tag}.{letter[d]}" for d in private)
    assert all(p.stat().st_uid == uid and p.stat().st_mode & 0o077 == 0 for p in own.iterdir())
    assert not any(Path(d, f"{tag}.{letter[d]}").exists() for d in private)
    # a folder that holds what the job reaches by absolute path is not mounted over (a data dir under /tmp)
    assert private_targets(["/tmp/x/data/jobs/j1", "/usr/bin/python3"]) == ["/var/tmp", "/dev/shm"]
    assert private_targets(["/srv/holo/jobs/j1"]) == ["/tmp", "/var/tmp", "/dev/shm"]
    # refused: not dropping to an unprivileged uid
    bad = subprocess.run([sys.executable, "-m", "service.workers.private_tmp", str(own), "0", "0", "--", "true"],
                         capture_output=True, text=True, env={"PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    assert bad.returncode == 2 and "non-root" in bad.stderr


def test_a_jobs_log_swapped_for_a_link_a_fifo_or_a_hard_link_is_not_read(svc, tmp_path):
    """While a sandboxed run goes on its folder is its uid's and the server reads its logs as root: a log
    swapped for a link to the database (or /etc/shadow) after the route's is_symlink check was read and served,
    and a fifo held a server thread in open() for good."""
    from service.api.jobs import _log_text

    svc.scene("default")
    with svc.client(svc.token("submit")) as c:
        job = c.post("/v1/jobs", json=small("stest")).json()
        folder = svc.finish(job["id"]).parent
        (folder / "render.log").write_text("traced 4 rays\n")
        assert c.get(f"/v1/jobs/{job['id']}/logs/render").text == "traced 4 rays\n"
        secret = tmp_path / "secret.db"
        secret.write_text("another owner's rows\n")
        (folder / "render.log").unlink()
        os.symlink(secret, folder / "render.log")
        r = c.get(f"/v1/jobs/{job['id']}/logs/render")
        assert r.status_code == 404 and "another owner" not in r.text
    # what the route's own check cannot stop: the swap after it, as the open sees it
    for name, make in (("link", lambda p: os.symlink(secret, p)), ("fifo", os.mkfifo),
                       ("hard", lambda p: os.link(secret, p))):
        p = folder / f"{name}.log"
        make(p)
        with pytest.raises(OSError):
            _log_text(p, [str(folder)])  # the fifo: refused at once, not a thread blocked in open()


def test_one_owner_holds_a_bounded_number_of_event_streams(tmp_path):
    """Every open event stream polls the database four times a second (through the shared thread pool) until
    its job ends, and one owner could open them without end: a few thousand held every tenant's requests up."""
    import asyncio

    svc = App(tmp_path / "data", max_streams_per_owner=2)
    svc.scene("alice", scene_id="salice")
    alice, bob = svc.token("submit", owner="alice"), svc.token("read", owner="bob")
    with svc.client(alice) as c:
        job = c.post("/v1/jobs", json=small("salice")).json()["id"]  # queued: its stream stays open

    async def scenario():
        async def open_stream(token: str, jid: str = job):
            sent, gone = [], asyncio.Event()
            scope = {"type": "http", "method": "GET", "path": f"/v1/jobs/{jid}/events", "raw_path": b"",
                     "query_string": b"", "root_path": "", "scheme": "http", "http_version": "1.1",
                     "server": ("test", 80), "client": ("10.0.0.1", 1),
                     "headers": [(b"authorization", f"Bearer {token}".encode()), (b"host", b"test")]}

            async def receive():
                await gone.wait()
                return {"type": "http.disconnect"}

            async def send(message):
                sent.append(message)

            task = asyncio.create_task(svc.app(scope, receive, send))
            while not (sent and (len(sent) > 1 or sent[0]["status"] != 200)) and not task.done():
                await asyncio.sleep(0.01)
            return sent[0]["status"], gone, task

        async with svc.app.router.lifespan_context(svc.app):
            first, second = await open_stream(alice), await open_stream(alice)
            assert first[0] == second[0] == 200
            third = await open_stream(alice)
            assert third[0] == 429, third
            with svc.client(bob) as b:  # another owner's streams are its own (its job: 404, not 429)
                assert b.get(f"/v1/jobs/{job}/events").status_code == 404
            first[1].set()  # the client goes: its stream ends and its place is free
            await asyncio.wait_for(first[2], 5)
            fourth = await open_stream(alice)
            assert fourth[0] == 200
            for _status, gone, task in (second, fourth):
                gone.set()
                await asyncio.wait_for(task, 5)
        assert svc.ctx.streams_open == {}

    asyncio.run(scenario())


# ---- an evaluation against ground truth is part of the job's memory and storage ------------------------------
def test_an_evaluated_job_is_admitted_with_its_evaluation(tmp_path):
    """``evaluate: true`` left the estimate as it was (0.71 GB at 540x960) while the evaluate step peaked at
    1.4 GB there (bench/results/evaluation_memory.md), about 2 KB an SLM pixel: the estimate now counts it, so a
    4096x2304 evaluation is refused by memory where the hologram alone fits; and its folder (a PNG pair per cell)
    counts in what the owner stores."""
    svc = App(tmp_path / "data", worker_memory_mb=16000, max_stored_gb_per_owner=0.2)
    svc.scene("alice", scene_id="salice")
    tok = svc.token("submit", owner="alice")
    job = small("salice", optics={"resolution_hw": [540, 960]}, frames=1)
    with svc.client(tok) as c:
        plain = c.post("/v1/jobs/estimate", json=job).json()["estimate"]["memory"]
        evaluated = c.post("/v1/jobs/estimate", json={**job, "evaluate": True}).json()["estimate"]["memory"]
        assert plain["peak_bytes"] < 1.0e9 and "evaluate_bytes" not in plain, plain
        assert evaluated["peak_stage"] == "evaluate" and evaluated["peak_bytes"] >= 1.44e9, evaluated
        big = {**job, "optics": {"resolution_hw": [2304, 4096]}}
        assert c.post("/v1/jobs/estimate", json=big).status_code == 200
        r = c.post("/v1/jobs/estimate", json={**big, "evaluate": True})
        assert r.status_code == 422 and "(evaluate;" in r.json()["detail"], r.text
        assert "its evaluation against ground truth grows with the SLM's pixels" in r.json()["detail"]
        # storage: a queued job counts its folder's most, with its evaluation's (about 53 MB at 540x960 beside
        # 42 MB): 0.2 GB holds two such jobs where it held four without
        admitted = [c.post("/v1/jobs", json={**job, "optics": {"resolution_hw": [540, 960], "seed": i},
                                             "evaluate": True}).status_code for i in range(5)]
        assert admitted == [202, 202, 403, 403, 403], admitted
