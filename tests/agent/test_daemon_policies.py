"""Daemon playback policies with real processes around it (test stack server, focus simulator)."""

from __future__ import annotations

import json
import threading

import pytest

from display_agent.config import load_config
from display_agent.daemon import Agent
from holocore.io import save_stack
from tests.agent.helpers import (
    WAVELENGTHS_M,
    StackServer,
    free_port,
    job,
    make_phase,
    read_sim_log,
    slm_shows,
    start_focus_sim,
    stop_proc,
    wait_for,
)

TOKEN = "tok"
F, C = 2, 3


@pytest.fixture()
def server(tmp_path):
    srv = StackServer(tmp_path / "srv", TOKEN).start()
    save_stack(srv.state / "j1.npz", phase=make_phase((F, C, 8, 12), seed=41), meta={"wavelengths_m": WAVELENGTHS_M})
    srv.set_jobs([job("j1")])
    yield srv
    srv.stop()


def _run(agent: Agent):
    stop = threading.Event()
    th = threading.Thread(target=agent.run, args=(stop,), kwargs={"max_seconds": 30}, daemon=True)
    th.start()
    return stop, th


def test_policy_once_plays_one_pass_then_blanks(server, tmp_path):
    cfg = load_config(env={}, overrides=dict(server_url=server.url, token=TOKEN, display="lab1",
                                             slm=f"sim:{tmp_path / 'slm'}",
                                             policy="once", rate_hz=200, cache_dir=tmp_path / "cache",
                                             poll_interval_s=0.1, heartbeat_interval_s=0.2))
    stop, th = _run(Agent(cfg))
    try:
        wait_for(lambda: "blank" in (tmp_path / "slm" / "slm.log").read_text()
                 if (tmp_path / "slm" / "slm.log").is_file() else False, 15, "blank after one pass")
        wait_for(lambda: any((r.get("heartbeat") or {}).get("state") == "idle" for r in server.log()), 5, "idle hb")
    finally:
        stop.set()
        th.join(timeout=10)
    shows = slm_shows(tmp_path / "slm")
    assert [(s["f"], s["c"]) for s in shows] == [(f, c) for f in range(F) for c in range(C)]  # exactly one pass


@pytest.mark.slow
def test_policy_capture_runs_the_sequence_for_a_new_stack(server, tmp_path):
    port = free_port()
    sim_log = tmp_path / "sim.log"
    sim, _ = start_focus_sim(["--listen", f"127.0.0.1:{port}", "--move-time-s", "0.1", "--settle-s", "0",
                              "--reset-delay-s", "0.1"], sim_log)
    cfg = load_config(env={}, overrides=dict(server_url=server.url, token=TOKEN, display="lab1",
                                             slm=f"sim:{tmp_path / 'slm'}",
                                             policy="capture", planes=3, passes_per_plane=2, rate_hz=300,
                                             focus_url=f"socket://127.0.0.1:{port}", cache_dir=tmp_path / "cache",
                                             poll_interval_s=0.1))
    stop, th = _run(Agent(cfg))
    seq = tmp_path / "cache" / "capture.jsonl"
    try:
        wait_for(lambda: seq.is_file() and seq.read_text().count('"played"') == 3, 20, "three planes captured")
    finally:
        stop.set()
        th.join(timeout=10)
        stop_proc(sim)
    moves = [l.split()[-1] for _, d, l in read_sim_log(sim_log) if d == "RX" and "MOVE PLANE" in l]
    assert moves == ["0", "1", "2"]
    assert len(slm_shows(tmp_path / "slm")) == 3 * 2 * F * C
    events = [json.loads(l)["event"] for l in seq.read_text().splitlines()]
    assert events == ["move", "settled", "play", "played"] * 3
