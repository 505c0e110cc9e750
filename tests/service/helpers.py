"""Helpers of the service tests: real `holo serve` processes (HTTP over a socket with httpx), uploads, waits."""

from __future__ import annotations

import io
import os
import signal
import socket
import subprocess
import sys
import time
import zipfile
from pathlib import Path
from typing import Optional

import httpx

REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def make_token(data_dir: Path, *scopes: str) -> str:
    from service.auth import create_token
    from service.db import Database

    return create_token(Database(data_dir / "service.db"), scopes=scopes, name="test")[1]


class Server:
    """One `holo serve` subprocess on a free port; restartable on the same data dir."""

    def __init__(self, data_dir: Path, *, workers: int = 1, extra: tuple[str, ...] = (),
                 pythonpath: tuple[str, ...] = ()) -> None:
        self.data_dir = data_dir
        self.pythonpath = pythonpath  # more folders to import from (a plug-in package installed there)
        self.workers = workers
        self.extra = extra
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: Optional[subprocess.Popen] = None
        data_dir.mkdir(parents=True, exist_ok=True)
        self.admin = make_token(data_dir, "admin")
        self.submit = make_token(data_dir, "submit")
        self.reader = make_token(data_dir, "read")
        self.agent = make_token(data_dir, "agent")
        self.starts = 0

    def start(self, timeout: float = 30.0) -> "Server":
        env = dict(os.environ, PYTHONPATH=os.pathsep.join((str(REPO), *self.pythonpath)))
        env.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
        self.starts += 1
        log = open(self.data_dir / f"server-{self.starts}.log", "wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "holo", "serve", "--data-dir", str(self.data_dir), "--port", str(self.port),
             "--workers", str(self.workers), "--log-level", "info", *self.extra],
            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env, cwd=REPO)
        log.close()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"holo serve exited with {self.proc.returncode}: {self.log()[-2000:]}")
            try:
                if httpx.get(f"{self.url}/readyz", timeout=1.0).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        raise RuntimeError(f"holo serve did not become ready: {self.log()[-2000:]}")

    def log(self) -> str:
        return "".join((self.data_dir / f"server-{i}.log").read_text(errors="replace")
                       for i in range(1, self.starts + 1) if (self.data_dir / f"server-{i}.log").exists())

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 20.0) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(sig)
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=10)

    def client(self, token: Optional[str] = "admin", **kw) -> httpx.Client:
        tok = getattr(self, token) if token in ("admin", "submit", "reader", "agent") else token
        headers = {"Authorization": f"Bearer {tok}"} if tok else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=kw.pop("timeout", 30.0), **kw)


def zip_dir(folder: Path, *, prefix: str = "") -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                zf.write(p, prefix + p.relative_to(folder).as_posix())
    return buf.getvalue()


def upload(client: httpx.Client, folder: Path, **data) -> httpx.Response:
    return client.post("/v1/scenes", files={"bundle": ("b.zip", zip_dir(folder), "application/zip")}, data=data)


def wait_for(predicate, *, timeout: float, interval: float = 0.1, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def wait_state(client: httpx.Client, job_id: str, states: tuple[str, ...], timeout: float = 90.0) -> dict:
    def check():
        job = client.get(f"/v1/jobs/{job_id}").json()
        return job if job["state"] in states else None

    return wait_for(check, timeout=timeout, interval=0.2, what=f"job {job_id} in {states}")


def planned_scene(server: "Server", bundle: bytes) -> dict:
    """Upload a zip bundle and wait for its plan to be ready or failed; the scene as the API answers it."""
    with server.client("submit") as c:
        r = c.post("/v1/scenes", files={"bundle": ("b.zip", bundle, "application/zip")})
        assert r.status_code in (200, 201), r.text
        sid = r.json()["id"]
        return wait_for(lambda: (lambda s: s if s["plan_state"] in ("ready", "failed") else None)(
            c.get(f"/v1/scenes/{sid}").json()), timeout=120, what=f"scene {sid}'s plan")


def finished_job(server: "Server", body: dict, *, timeout: float = 240.0) -> dict:
    """Submit ``body`` and wait for the job to succeed (an assertion with its error otherwise)."""
    with server.client("submit") as c:
        r = c.post("/v1/jobs", json=body)
        assert r.status_code == 202, r.text
        job = wait_state(c, r.json()["id"], ("succeeded", "failed", "cancelled"), timeout=timeout)
    assert job["state"] == "succeeded", job["error"]
    return job


def start_agent(server: "Server", tmp: Path, display: str, *, rate_hz: float, poll_interval_s: float,
                heartbeat_interval_s: float, max_seconds: float):
    """The real display agent for ``display`` with a simulated SLM under ``tmp``, running in a thread:
    (agent, stop event, thread); set the event and join the thread to end it."""
    import threading

    from display_agent.config import load_config
    from display_agent.daemon import Agent

    cfg = load_config(env={}, overrides=dict(server_url=server.url, token=server.agent, display=display,
                                             slm=f"sim:{tmp / 'slm'}", rate_hz=rate_hz, cache_dir=tmp / "cache",
                                             poll_interval_s=poll_interval_s,
                                             heartbeat_interval_s=heartbeat_interval_s))
    agent = Agent(cfg)
    stop = threading.Event()
    th = threading.Thread(target=agent.run, args=(stop,), kwargs={"max_seconds": max_seconds}, daemon=True)
    th.start()
    return agent, stop, th


SMALL_JOB = {"optics": {"resolution_hw": [64, 64], "seed": 7}, "preset": "fast", "frames": 2, "spp": 4,
             "encoder": "dpac"}
