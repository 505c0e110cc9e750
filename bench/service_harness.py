"""A `holo serve` of its own for a benchmark: started on a temporary data dir with an admin token, scenes
uploaded as zip bundles and planned, jobs run to their end. Used by ``load_status.py`` and
``estimate_vs_measured.py``."""

from __future__ import annotations

import io
import os
import socket
import subprocess
import sys
import time
import zipfile
from pathlib import Path
from typing import Optional

import httpx

REPO = Path(__file__).resolve().parents[1]


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(data: Path, *, env: Optional[dict] = None) -> tuple[subprocess.Popen, str, str]:
    """(the server's process, its URL, an admin token) on data dir ``data``; ``env``: extra variables."""
    sys.path.insert(0, str(REPO))
    from service.auth import create_token
    from service.db import Database

    data.mkdir(parents=True, exist_ok=True)
    token = create_token(Database(data / "service.db"), scopes=["admin"], name="bench")[1]
    port = _port()
    proc = subprocess.Popen([sys.executable, "-m", "holo", "serve", "--data-dir", str(data), "--port", str(port),
                             "--log-level", "warning"], env=dict(os.environ, PYTHONPATH=str(REPO), **(env or {})),
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=open(data / "server.log", "wb"))
    url = f"http://127.0.0.1:{port}"
    for _ in range(300):
        try:
            if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                return proc, url, token
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    proc.kill()
    raise SystemExit("server did not start")


def zip_folder(folder: Path) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(folder).as_posix())
    return buf.getvalue()


def wait_job(http: httpx.Client, job_id: str, states: tuple[str, ...], timeout: float = 3600) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = http.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in states:
            return job
        time.sleep(0.5)
    raise SystemExit(f"job {job_id} never reached {states}")


def planned_scene(http: httpx.Client, bundle: bytes, *, entry: Optional[str] = None, timeout: float = 900) -> dict:
    """Upload a zip bundle and wait for its plan; the scene as the API answers it (its plan ready)."""
    r = http.post("/v1/scenes", files={"bundle": ("b.zip", bundle, "application/zip")},
                  data={"entry": entry} if entry else None)
    r.raise_for_status()
    sid = r.json()["id"]
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        sc = http.get(f"/v1/scenes/{sid}").json()
        if sc["plan_state"] == "ready":
            return sc
        if sc["plan_state"] == "failed":
            raise SystemExit(f"scene {sid}: plan failed: {sc.get('plan_error')}")
        time.sleep(0.5)
    raise SystemExit(f"scene {sid}: no plan after {timeout} s")
