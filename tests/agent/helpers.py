"""Process helpers for the display agent tests: real processes (stack server, focus simulator, agent)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable
HOLO = [PY, "-m", "holo"]
WAVELENGTHS_M = [640e-9, 516.5e-9, 455.4e-9]


def env() -> dict[str, str]:
    e = {k: v for k, v in os.environ.items() if not k.startswith("HOLO_AGENT_")}
    e["PYTHONPATH"] = str(ROOT) + os.pathsep + e.get("PYTHONPATH", "")
    e["SDL_VIDEODRIVER"] = "dummy"
    return e


def wait_for(cond: Callable[[], object], timeout_s: float, what: str, interval_s: float = 0.05) -> object:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        v = cond()
        if v:
            return v
        time.sleep(interval_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def make_phase(shape: tuple[int, int, int, int], seed: int) -> np.ndarray:
    """A synthetic phase stack in [0, 2pi) with the hard values included (0, just under 2pi, half levels)."""
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0, 2 * np.pi, shape)
    flat = ph.reshape(-1)
    specials = [0.0, 2 * np.pi * (1 - 1e-9), 2 * np.pi * 255.5 / 256, 2 * np.pi * 0.5 / 256, np.pi]
    flat[: len(specials)] = specials
    return ph


def stop_proc(p: Optional[subprocess.Popen], sig: int = signal.SIGTERM, timeout_s: float = 5.0) -> None:
    if p is None or p.poll() is not None:
        return
    p.send_signal(sig)
    try:
        p.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait(timeout=5)


class StackServer:
    """tests/agent/stack_server.py as a process on a fixed port (so it can be restarted there)."""

    def __init__(self, state: Path, token: str, port: int = 0) -> None:
        self.state, self.token, self.port = state, token, port
        self.proc: Optional[subprocess.Popen] = None
        state.mkdir(parents=True, exist_ok=True)

    def start(self) -> "StackServer":
        (self.state / "port").unlink(missing_ok=True)
        self.proc = subprocess.Popen([PY, str(Path(__file__).with_name("stack_server.py")), "--state",
                                      str(self.state), "--port", str(self.port), "--token", self.token],
                                     env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        self.port = int(wait_for(lambda: (self.state / "port").is_file() and (self.state / "port").read_text(),
                                 10, "stack server port"))
        return self

    def stop(self, sig: int = signal.SIGTERM) -> None:
        stop_proc(self.proc, sig)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def set_jobs(self, jobs: list[dict]) -> None:
        tmp = self.state / "jobs.json.tmp"
        tmp.write_text(json.dumps(jobs))
        tmp.replace(self.state / "jobs.json")

    def control(self, **ctl: object) -> None:
        tmp = self.state / "control.json.tmp"
        tmp.write_text(json.dumps(ctl))
        tmp.replace(self.state / "control.json")

    def log(self) -> list[dict]:
        p = self.state / "server.log"
        if not p.is_file():
            return []
        out = []
        for line in p.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:  # a line being written right now
                pass
        return out


def job(job_id: str, display: str = "lab1", t: float = 0.0) -> dict:
    iso = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(1_700_000_000 + t))
    return {"id": job_id, "state": "succeeded", "display": display, "created_at": iso, "finished_at": iso}


def start_focus_sim(args: list[str], log: Path) -> tuple[subprocess.Popen, str]:
    """Start `holo focus-sim ARGS --log LOG`; returns (process, its first stdout line)."""
    p = subprocess.Popen([*HOLO, "focus-sim", *args, "--log", str(log)], env=env(), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    line = p.stdout.readline().strip() if p.stdout else ""
    if not line:
        err = p.stderr.read() if p.stderr else ""
        raise AssertionError(f"focus-sim did not start: {err}")
    return p, line


def read_sim_log(log: Path) -> list[tuple[float, str, str]]:
    out = []
    for line in log.read_text().splitlines():
        try:
            t, d, rest = line.split(" ", 2)
            out.append((float(t), d, rest))
        except ValueError:  # a line being written right now
            pass
    return out


def slm_shows(slm_dir: Path) -> list[dict]:
    """Parsed 'show' lines of a SimSLM log."""
    p = slm_dir / "slm.log"
    out = []
    if not p.is_file():
        return out
    for line in p.read_text().splitlines():
        parts = line.split()
        if len(parts) >= 3 and parts[1] == "show":
            try:
                kv = dict(x.split("=", 1) for x in parts[3:])
                rec = {"t": float(parts[0]), "stack": parts[2], "c": int(kv["c"]), "f": int(kv["f"]),
                       "sha256": kv["sha256"]}
            except (ValueError, KeyError):  # a line being written right now
                continue
            if len(rec["sha256"]) == 64:
                out.append(rec)
    return out
