"""End to end over HTTP against a real `holo serve`: upload the cbox-mirror-glass bundle, submit a small job,
follow its events, download the stack (ETag, 304, Range), and check it equals the CLI's render of the same
job (same seed -> identical arrays). Then reuse, idempotency, listing, artifacts, displays, `holo submit`."""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from PIL import Image

from holocore.io import load_stack
from service.client import iter_sse
from tests.service.helpers import REPO, SMALL_JOB, upload

pytestmark = pytest.mark.scenes


@pytest.fixture(scope="module")
def rendered(server, scene_bundle, tmp_path_factory):
    """The small job, run once through the service (and followed by SSE) and once through the CLIs; the CLIs run
    in a thread meanwhile (the same seed gives the same arrays however busy the machine is)."""
    from concurrent.futures import ThreadPoolExecutor

    scene = scene_bundle("cbox-mirror-glass")
    out = tmp_path_factory.mktemp("cli")
    env = dict(os.environ, PYTHONPATH=str(REPO))
    o = SMALL_JOB["optics"]

    def cli() -> None:
        subprocess.run([sys.executable, "-m", "holo", "render", str(scene), "--out", str(out / "r.npz"), "--preset",
                        "fast", "--frames", "2", "--spp", "4", "--resolution", "x".join(map(str, o["resolution_hw"])),
                        "--seed", str(o["seed"])], check=True, env=env, capture_output=True)
        subprocess.run([sys.executable, "-m", "holo", "encode", str(out / "r.npz"), "--out", str(out / "s.npz"),
                        "--method", "dpac"], check=True, env=env, capture_output=True)

    with ThreadPoolExecutor(1) as pool:
        cli_done = pool.submit(cli)
        sc, job, events, final = _through_the_service(server, scene)
        cli_done.result()
    return {"scene": sc, "submitted": job.json(), "events": events, "job": final, "cli_stack": out / "s.npz"}


def _through_the_service(server, scene):
    with server.client("submit") as c:
        up = upload(c, scene)
        assert up.status_code == 201, up.text
        sc = up.json()
        job = c.post("/v1/jobs", json={"scene_id": sc["id"], **SMALL_JOB, "display": "lab-1"})
        assert job.status_code == 202, job.text
        assert job.headers["location"] == f"/v1/jobs/{job.json()['id']}"
        events = []
        with c.stream("GET", f"/v1/jobs/{job.json()['id']}/events", timeout=120) as resp:
            assert resp.status_code == 200 and resp.headers["content-type"].startswith("text/event-stream")
            events = list(iter_sse(resp.iter_lines()))
        final = c.get(f"/v1/jobs/{job.json()['id']}").json()
    return sc, job, events, final


@pytest.mark.slow
def test_upload_reports_the_bundle_and_plan_fills_in(server, rendered):
    sc = rendered["scene"]
    assert sc["entry"] == "cbox.xml" and sc["sha256"] and len(sc["sha256"]) == 64
    assert "meshes/cbox_floor.obj" in sc["report"]["files"] and "shape:obj" in sc["report"]["plugins"]
    assert sc["plan_state"] in ("pending", "running", "ready")
    with server.client("reader") as c:
        scene = wait_state_scene(c, sc["id"])
    assert scene["plan_state"] == "ready", scene["plan_error"]
    assert any("mirror" in line for line in scene["plan"]["summary"])
    assert scene["plan"]["analysis"]["z_wrp_m"] > 0.08


def wait_state_scene(c, scene_id, timeout=60.0):
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        s = c.get(f"/v1/scenes/{scene_id}").json()
        if s["plan_state"] in ("ready", "failed"):
            return s
        time.sleep(0.2)
    raise AssertionError("plan never finished")


@pytest.mark.slow
def test_events_show_progress_then_the_final_state(rendered):
    ev = rendered["events"]
    kinds = [e for e, _ in ev]
    assert kinds[-1] == "state" and ev[-1][1]["state"] == "succeeded"
    fractions = [d["fraction"] for e, d in ev if e == "progress"]
    assert len(fractions) >= 3 and fractions == sorted(fractions) and fractions[-1] == 1.0
    steps = {d.get("step") for e, d in ev if e == "progress"}
    assert {"render", "encode"} <= steps
    sub = rendered["submitted"]
    assert sub["state"] in ("queued", "running") and sub["estimate"]["seconds"] > 0 and sub["estimate"]["rays"] == 64 * 64 * 3 * 4


def test_stack_matches_the_cli_render_of_the_same_job(server, rendered, tmp_path):
    job = rendered["job"]
    assert job["state"] == "succeeded" and job["attempts"] == 1 and job["error"] is None
    t = job["timings"]
    assert t["render_s"] > 0 and t["encode_s"] > 0 and t["run_s"] >= t["render_s"]
    with server.client("agent") as c:
        r = c.get(f"/v1/jobs/{job['id']}/stack")
    assert r.status_code == 200
    digest = hashlib.sha256(r.content).hexdigest()
    assert digest == job["stack_sha256"] == r.headers["x-content-sha256"] and r.headers["etag"] == f'"{digest}"'
    (tmp_path / "s.npz").write_bytes(r.content)
    phase, u8, meta = load_stack(tmp_path / "s.npz")
    cli_phase, cli_u8, cli_meta = load_stack(rendered["cli_stack"])
    assert phase.shape == (2, 3, 64, 64) and u8.dtype == np.uint8
    assert np.array_equal(phase, cli_phase) and np.array_equal(u8, cli_u8)
    assert meta["encoder"]["method"] == cli_meta["encoder"]["method"] == "dpac"
    assert meta["optics"] == cli_meta["optics"] and meta["optics"]["seed"] == 7


def test_conditional_and_ranged_downloads(server, rendered):
    job = rendered["job"]
    etag = f'"{job["stack_sha256"]}"'
    with server.client("reader") as c:
        full = c.get(f"/v1/jobs/{job['id']}/stack").content
        assert c.get(f"/v1/jobs/{job['id']}/stack", headers={"If-None-Match": etag}).status_code == 304
        part = c.get(f"/v1/jobs/{job['id']}/stack", headers={"Range": "bytes=100-1099"})
        assert part.status_code == 206 and part.content == full[100:1100]
        assert part.headers["content-range"] == f"bytes 100-1099/{len(full)}"
        tail = c.get(f"/v1/jobs/{job['id']}/stack", headers={"Range": "bytes=-10"})
        assert tail.status_code == 206 and tail.content == full[-10:]
        resume = c.get(f"/v1/jobs/{job['id']}/stack", headers={"Range": "bytes=5000-", "If-Range": etag})
        assert resume.status_code == 206 and resume.content == full[5000:]
        stale = c.get(f"/v1/jobs/{job['id']}/stack", headers={"Range": "bytes=5000-", "If-Range": '"0000"'})
        assert stale.status_code == 200 and stale.content == full  # changed file: whole body, not a wrong piece
        bad = c.get(f"/v1/jobs/{job['id']}/stack", headers={"Range": f"bytes={len(full)}-"})
        assert bad.status_code == 416 and bad.headers["content-range"] == f"bytes */{len(full)}"


def test_frames_zip_and_preview(server, rendered, tmp_path):
    job = rendered["job"]
    with server.client("reader") as c:
        z = c.get(f"/v1/jobs/{job['id']}/frames.zip")
        p = c.get(f"/v1/jobs/{job['id']}/preview.png")
    assert z.status_code == 200 and p.status_code == 200 and p.headers["content-type"] == "image/png"
    cli_u8 = load_stack(rendered["cli_stack"])[1]
    with zipfile.ZipFile(io.BytesIO(z.content)) as zf:
        names = sorted(zf.namelist())
        assert names == sorted(f"f{f:03d}_c{c}.png" for f in range(2) for c in range(3))
        img = np.asarray(Image.open(io.BytesIO(zf.read("f001_c2.png"))))
    assert img.dtype == np.uint8 and np.array_equal(img, cli_u8[1, 2])
    prev = np.asarray(Image.open(io.BytesIO(p.content)).convert("RGB"), dtype=np.float64)
    assert prev.shape[:2] == (64, 64) and np.isfinite(prev).all() and prev.std() > 1.0  # an image, not flat


def test_identical_job_reuses_the_result_and_idempotency_keys(server, rendered):
    sc, job = rendered["scene"], rendered["job"]
    body = {"scene_id": sc["id"], **SMALL_JOB, "display": "lab-2"}
    with server.client("submit") as c:
        again = c.post("/v1/jobs", json=body)
        assert again.status_code == 202
        j = again.json()
        assert j["state"] == "succeeded" and j["reused_from"] == job["id"] and j["stack_sha256"] == job["stack_sha256"]
        assert j["cache_key"] == job["cache_key"] and j["display"] == "lab-2"
        other = {**body, "optics": {**SMALL_JOB["optics"], "seed": 8}}
        k1 = c.post("/v1/jobs", json=other, headers={"Idempotency-Key": "k-1"})
        k2 = c.post("/v1/jobs", json=other, headers={"Idempotency-Key": "k-1"})
        assert k1.status_code == k2.status_code == 202 and k1.json()["id"] == k2.json()["id"]
        assert k2.headers.get("idempotent-replayed") == "true" and k1.json()["cache_key"] != job["cache_key"]
        clash = c.post("/v1/jobs", json={**other, "frames": 3}, headers={"Idempotency-Key": "k-1"})
        assert clash.status_code == 422 and "different request" in clash.json()["detail"]
        gone = c.delete(f"/v1/jobs/{k1.json()['id']}")  # do not spend the test's time rendering it
        assert gone.status_code in (202, 409)


def test_listing_filters_newest_first(server, rendered):
    with server.client("agent") as c:
        lab1 = c.get("/v1/jobs", params={"display": "lab-1", "state": "succeeded", "limit": 5}).json()["jobs"]
        assert [j["id"] for j in lab1] == [rendered["job"]["id"]]
        everything = c.get("/v1/jobs", params={"scene_id": rendered["scene"]["id"]}).json()["jobs"]
        created = [j["created_at"] for j in everything]
        assert len(everything) >= 2 and created == sorted(created, reverse=True)
        assert len(c.get("/v1/jobs", params={"limit": 1}).json()["jobs"]) == 1


def test_heartbeats_and_displays(server):
    with server.client("agent") as c:
        r = c.post("/v1/displays/lab-1/heartbeat", json={"agent_version": "1.0", "showing": {"job_id": "j1", "frame": 3},
                                                           "state": "playing", "message": "ok"})
        assert r.status_code == 204
    with server.client("submit") as c:
        assert c.post("/v1/displays/lab-1/heartbeat", json={"agent_version": "1", "showing": None, "state": "idle",
                                                             "message": ""}).status_code == 403
    with server.client("reader") as c:
        ds = c.get("/v1/displays").json()["displays"]
    d = next(d for d in ds if d["name"] == "lab-1")
    assert d["showing"] == {"job_id": "j1", "frame": 3} and d["state"] == "playing" and 0 <= d["age_s"] < 60


def test_health_metrics_and_openapi(server, rendered):
    import httpx

    assert httpx.get(f"{server.url}/livez").json() == {"status": "ok"}
    ready = httpx.get(f"{server.url}/readyz").json()
    assert ready["status"] == "ready" and all(ready["checks"].values())
    assert httpx.get(f"{server.url}/metrics").status_code == 401  # metrics need a token (scope read)
    m = httpx.get(f"{server.url}/metrics", headers={"Authorization": f"Bearer {server.admin}"}).text
    assert 'holo_jobs{state="succeeded"}' in m and "holo_http_request_duration_seconds_bucket" in m
    assert 'route="/v1/jobs/{job_id}/stack"' in m
    mine = httpx.get(f"{server.url}/metrics", headers={"Authorization": f"Bearer {server.reader}"}).text
    assert 'holo_jobs{state="succeeded"}' in mine and "holo_http_request" not in mine  # its owner's alone
    paths = httpx.get(f"{server.url}/openapi.json").json()["paths"]
    for p in ("/v1/scenes", "/v1/scenes/{scene_id}", "/v1/jobs", "/v1/jobs/{job_id}", "/v1/jobs/{job_id}/events",
              "/v1/jobs/{job_id}/stack", "/v1/jobs/{job_id}/frames.zip", "/v1/jobs/{job_id}/preview.png"):
        assert p in paths
    assert "delete" in paths["/v1/jobs/{job_id}"]
    assert httpx.get(f"{server.url}/docs").status_code == 200


@pytest.mark.slow
def test_holo_submit_cli_uploads_follows_and_downloads(server, rendered, scene_bundle, tmp_path):
    """`holo submit` of the same job: the service reuses the result; the downloaded stack is byte-identical."""
    out = tmp_path / "stack.npz"
    r = subprocess.run([sys.executable, "-m", "holo", "submit", str(scene_bundle("cbox-mirror-glass")),
                        "--server", server.url, "--token", server.submit, "--resolution", "64x64", "--seed", "7",
                        "--frames", "2", "--spp", "4", "--preset", "fast", "--encoder", "dpac", "--out", str(out)],
                       capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=120)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout.strip().splitlines()[-1])
    assert doc["stack_sha256"] == rendered["job"]["stack_sha256"]
    assert hashlib.sha256(out.read_bytes()).hexdigest() == doc["stack_sha256"]
    bad = subprocess.run([sys.executable, "-m", "holo", "submit", str(scene_bundle("cbox-mirror-glass")),
                          "--server", server.url, "--token", "hpt_nope_nope"], capture_output=True, text=True,
                         env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=60)
    assert bad.returncode == 1 and "401" in bad.stderr and "invalid or revoked token" in bad.stderr


def test_files_upload_gives_the_same_content_address(server, rendered, scene_bundle):
    scene = scene_bundle("cbox-mirror-glass")
    files = [("files", (p.relative_to(scene).as_posix(), p.read_bytes(), "application/octet-stream"))
             for p in sorted(scene.rglob("*")) if p.is_file()]
    with server.client("submit") as c:
        r = c.post("/v1/scenes", files=files)
    assert r.status_code == 200, r.text  # already there: same files, same entry -> same id
    assert r.json()["id"] == rendered["scene"]["id"] and r.json()["sha256"] == rendered["scene"]["sha256"]


@pytest.mark.slow
def test_a_time_limited_job_renders_until_its_limit(server, rendered, tmp_path):
    """A job with render_time_limit_s: the worker's `holo render` traces passes of rays until the limit (at most
    the job's spp); the stack's meta says how many."""
    body = {"scene_id": rendered["scene"]["id"], **SMALL_JOB, "spp": 512, "render_time_limit_s": 4.0}
    with server.client("submit") as c:
        job = c.post("/v1/jobs", json=body)
        assert job.status_code == 202, job.text
        jid = job.json()["id"]
        assert job.json()["options"]["render_time_limit_s"] == 4.0 and job.json()["options"]["spp"] == 512
        with c.stream("GET", f"/v1/jobs/{jid}/events", timeout=120) as resp:
            list(iter_sse(resp.iter_lines()))
        final = c.get(f"/v1/jobs/{jid}").json()
        assert final["state"] == "succeeded", final
        (tmp_path / "s.npz").write_bytes(c.get(f"/v1/jobs/{jid}/stack").content)
    _, _, meta = load_stack(tmp_path / "s.npz")
    sm = meta["sampling"]
    assert sm["time_limit_s"] == 4.0 and 16 <= sm["spp"] <= 512 and sm["passes"][0]["spp"] == 16
    assert meta["plan"]["spp"] == sm["spp"]
