"""Capture sequence end to end: `holo agent capture` (process) + `holo focus-sim` (process) + simulated SLM."""

from __future__ import annotations

import json
import subprocess
import threading
import time

import numpy as np
import pytest
from PIL import Image

from holocore.io import load_stack, phase_to_u8, save_stack
from tests.agent.helpers import (
    HOLO,
    WAVELENGTHS_M,
    env,
    free_port,
    make_phase,
    read_sim_log,
    slm_shows,
    start_focus_sim,
    stop_proc,
    wait_for,
)

F, C = 3, 3


@pytest.fixture()
def stack(tmp_path):
    p = tmp_path / "cap.npz"
    phase = make_phase((F, C, 16, 20), seed=11)
    save_stack(p, phase=phase, meta={"wavelengths_m": WAVELENGTHS_M})
    return p, phase


def _moves(lines):
    return [(t, int(l.split()[-1])) for t, d, l in lines if d == "RX" and " MOVE PLANE " in l]


def _settled_after(lines, t0):
    return min(t for t, d, l in lines if d == "TX" and " OK SETTLED " in l and t >= t0)


@pytest.mark.slow
def test_capture_moves_in_order_waits_for_settled_then_plays_and_triggers(tmp_path, stack):
    path, _ = stack
    sim_log = tmp_path / "sim.log"
    link = tmp_path / "ttyFOCUS"
    sim, _ = start_focus_sim(["--pty", "--link", str(link), "--move-time-s", "0.15", "--settle-s", "0.05"], sim_log)
    slm_dir, trig_dir = tmp_path / "slm", tmp_path / "trig"
    trig_dir.mkdir()
    try:
        wait_for(link.exists, 5, "pty link")
        res = subprocess.run([*HOLO, "agent", "capture", "--stack", str(path), "--slm", f"sim:{slm_dir}",
                              "--focus", str(link), "--planes", "5", "--passes", "2", "--rate-hz", "200",
                              "--trigger", f"touch {trig_dir}/plane{{plane}}_{{stack}}",
                              "--sequence-log", str(tmp_path / "seq.jsonl")],
                             env=env(), capture_output=True, text=True, timeout=60)
    finally:
        stop_proc(sim)
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout.strip().splitlines()[-1])
    assert [p["plane"] for p in summary["planes"]] == [0, 1, 2, 3, 4]
    assert [p["position"] for p in summary["planes"]] == [0, 400, 800, 1200, 1600]
    assert all(p["frames"] == 2 * F * C for p in summary["planes"])
    lines = read_sim_log(sim_log)
    moves = _moves(lines)
    assert [k for _, k in moves] == [0, 1, 2, 3, 4]  # in order, each once
    shows = slm_shows(slm_dir)
    per_plane = 2 * F * C
    assert len(shows) == 5 * per_plane
    for k, (t_move, _) in enumerate(moves):
        chunk = shows[k * per_plane:(k + 1) * per_plane]
        t_settled = _settled_after(lines, t_move)
        assert chunk[0]["t"] >= t_settled  # played only after the controller said SETTLED
        assert t_settled - t_move >= 0.15  # ... which it says only after the move time
        if k + 1 < len(moves):
            assert chunk[-1]["t"] <= moves[k + 1][0]  # and the next move waits for the playback
        trig = trig_dir / f"plane{k}_cap"
        assert trig.is_file() and trig.stat().st_mtime >= chunk[-1]["t"] - 0.01  # trigger after playback
    seq = [json.loads(l) for l in (tmp_path / "seq.jsonl").read_text().splitlines()]
    assert [e["event"] for e in seq[:6]] == ["move", "settled", "play", "played", "trigger", "move"]
    # what the SLM showed is the stored (float32) phase through the default mapping, byte for byte
    lv = phase_to_u8(load_stack(path)[0])
    for f in range(F):
        for c in range(C):
            np.testing.assert_array_equal(np.asarray(Image.open(slm_dir / f"cap_c{c}_f{f:03d}.png")), lv[f, c])


@pytest.mark.slow
def test_capture_survives_the_serial_line_vanishing(tmp_path, stack):
    path, _ = stack
    port = free_port()
    sim_log = tmp_path / "sim.log"
    args = ["--listen", f"127.0.0.1:{port}", "--move-time-s", "0.3", "--settle-s", "0", "--reset-delay-s", "0.2"]
    sim, _ = start_focus_sim(args, sim_log)
    procs = {"sim": sim}

    def saboteur():  # kill the controller while plane 2 is moving, bring it back 0.7 s later
        wait_for(lambda: sim_log.is_file() and "MOVE PLANE 2" in sim_log.read_text(), 30, "plane 2 move")
        stop_proc(procs["sim"])
        time.sleep(0.7)
        procs["sim"], _ = start_focus_sim(args, sim_log)

    th = threading.Thread(target=saboteur)
    th.start()
    try:
        res = subprocess.run([*HOLO, "agent", "capture", "--stack", str(path), "--slm", f"sim:{tmp_path / 'slm'}",
                              "--focus", f"socket://127.0.0.1:{port}", "--planes", "4", "--rate-hz", "200",
                              "--reconnect-timeout-s", "15"], env=env(), capture_output=True, text=True, timeout=60)
        th.join(timeout=30)
    finally:
        stop_proc(procs["sim"])
    assert res.returncode == 0, res.stderr
    assert "lost" in res.stderr and "reconnected" in res.stderr  # the log says what happened
    lines = read_sim_log(sim_log)
    moves = _moves(lines)
    assert [k for _, k in moves] == [0, 1, 2, 2, 3]  # plane 2 re-issued after the reconnect
    per_plane = F * C
    shows = slm_shows(tmp_path / "slm")
    assert len(shows) == 4 * per_plane
    t_reissue = moves[3][0]
    plane2 = shows[2 * per_plane:3 * per_plane]
    assert plane2[0]["t"] >= _settled_after(lines, t_reissue)  # nothing played before the new SETTLED


@pytest.mark.slow
def test_capture_cli_refuses_bad_input(tmp_path, stack):
    path, _ = stack
    bad = tmp_path / "bad.npz"
    bad.write_bytes(path.read_bytes()[:100])
    r = subprocess.run([*HOLO, "agent", "capture", "--stack", str(bad), "--slm", "null"], env=env(),
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "not a readable npz" in r.stderr
    r = subprocess.run([*HOLO, "agent", "capture", "--stack", str(path), "--slm", "null", "--focus",
                        f"socket://127.0.0.1:{free_port()}", "--reconnect-timeout-s", "0.3"], env=env(),
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "capture failed" in r.stderr and "unreachable" in r.stderr
