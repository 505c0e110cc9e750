"""End to end: the real test stack server process, the `holo agent` process and the simulated SLM.

Checks that the frames shown are the server's stack after the configured lookup table, byte for byte, and
that corrupt downloads, a server crash during a download and a hash-consistent bad file are survived without
ever showing a wrong frame, with the agent's log saying what happened."""

from __future__ import annotations

import hashlib
import json
import signal
import subprocess
import time

import numpy as np
import pytest
from PIL import Image

from holocore.io import load_stack, phase_to_u8, save_stack
from tests.agent.helpers import (
    HOLO,
    WAVELENGTHS_M,
    StackServer,
    env,
    job,
    make_phase,
    slm_shows,
    stop_proc,
    wait_for,
)

TOKEN = "agent-token-1"
TABLES = np.stack([255 - np.arange(256), (np.arange(256) * 7) % 256, (np.arange(256) + 100) % 256]).astype(np.uint8)


def expected_levels(path) -> np.ndarray:
    """What the SLM must show: the stored phase -> docs/design.md §2 levels -> this display's table per colour."""
    lv = phase_to_u8(load_stack(path)[0])
    return np.stack([TABLES[c][lv[:, c]] for c in range(lv.shape[1])], axis=1)


def frame_digests(levels: np.ndarray) -> set[str]:
    return {hashlib.sha256(np.ascontiguousarray(levels[f, c]).tobytes()).hexdigest()
            for f in range(levels.shape[0]) for c in range(levels.shape[1])}


def assert_pngs_identical(slm_dir, job_id, levels):
    for f in range(levels.shape[0]):
        for c in range(levels.shape[1]):
            got = np.asarray(Image.open(slm_dir / f"{job_id}_c{c}_f{f:03d}.png"))
            np.testing.assert_array_equal(got, levels[f, c], err_msg=f"{job_id} f={f} c={c}")


@pytest.mark.slow
def test_agent_follows_the_service_and_recovers(tmp_path):
    srv = StackServer(tmp_path / "srv", TOKEN).start()
    lut = tmp_path / "lut.json"  # listed out of colour order: matched by wavelength
    lut.write_text(json.dumps({"luts": [{"wavelength_nm": wl, "table": TABLES[c].tolist()}
                                        for c, wl in [(2, 455.4), (0, 640.0), (1, 516.5)]]}))
    save_stack(srv.state / "j1.npz", phase=make_phase((2, 3, 24, 32), seed=31), meta={"wavelengths_m": WAVELENGTHS_M})
    srv.set_jobs([job("j1", t=1), job("other", display="lab2", t=2)])
    srv.control(mode="corrupt", count=2)  # the first two downloads arrive damaged
    slm_dir, cache, log = tmp_path / "slm", tmp_path / "cache", tmp_path / "agent.log"
    e = env()
    e.update(HOLO_AGENT_TOKEN=TOKEN, HOLO_AGENT_HEARTBEAT_INTERVAL_S="0.3", HOLO_AGENT_BACKOFF_BASE_S="0.1",
             HOLO_AGENT_BACKOFF_CAP_S="0.8")
    cmd = [*HOLO, "agent", "--server", srv.url, "--display", "lab1", "--slm", f"sim:{slm_dir}", "--cache-dir",
           str(cache), "--poll-s", "0.2", "--rate-hz", "100", "--lut", str(lut), "--log-file", str(log)]
    agent = subprocess.Popen(cmd, env=e, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    agent2 = None
    try:
        # 1. corrupt downloads are dropped; the clean one is shown exactly as the table says
        lv1 = expected_levels(srv.state / "j1.npz")
        wait_for(lambda: sum(s["stack"] == "j1" for s in slm_shows(slm_dir)) >= 6, 20, "a pass of j1 on the SLM")
        text = log.read_text()
        assert text.count("dropped the download") == 2 and "retry" in text
        assert_pngs_identical(slm_dir, "j1", lv1)
        assert {s["sha256"] for s in slm_shows(slm_dir)} <= frame_digests(lv1)
        assert not (slm_dir / "other_c0_f000.png").exists()  # another display's job is not ours

        # 2. the server crashes during a download of a newer stack and comes back: resume, then show
        save_stack(srv.state / "j2.npz", phase=make_phase((3, 3, 64, 96), seed=32),
                   meta={"wavelengths_m": WAVELENGTHS_M})
        size2 = (srv.state / "j2.npz").stat().st_size
        srv.control(mode="slow", rate_bps=150_000)
        srv.set_jobs([job("j2", t=3), job("j1", t=1)])
        part = cache / "partial" / "j2.part"
        wait_for(lambda: part.is_file() and part.stat().st_size > 30_000, 20, "a partial download of j2")
        srv.stop(signal.SIGKILL)
        n_before = len(slm_shows(slm_dir))
        time.sleep(1.0)  # outage: the agent keeps showing j1 and backs off
        during = slm_shows(slm_dir)[n_before:]
        assert during and all(s["stack"] == "j1" for s in during)
        srv.control(mode="normal")
        srv.start()
        lv2 = expected_levels(srv.state / "j2.npz")
        wait_for(lambda: sum(s["stack"] == "j2" for s in slm_shows(slm_dir)) >= 9, 20, "a pass of j2 on the SLM")
        text = log.read_text()
        assert "interrupted at" in text and "service reachable again" in text
        assert "resuming download of job j2 at byte" in text
        resumed = [r for r in srv.log() if r["path"] == "/v1/jobs/j2/stack" and r["status"] == 206]
        assert resumed and 0 < resumed[-1]["start"] < size2
        assert_pngs_identical(slm_dir, "j2", lv2)
        shows = slm_shows(slm_dir)
        good = frame_digests(lv1) | frame_digests(lv2)
        assert all(s["sha256"] in good for s in shows)  # never a corrupt or partial frame
        assert all(s["sha256"] in frame_digests(lv2) for s in shows if s["stack"] == "j2")

        # 3. heartbeats say what is shown
        wait_for(lambda: any((r.get("heartbeat") or {}).get("showing", {}) and
                             r["heartbeat"]["showing"]["job_id"] == "j2" for r in srv.log()), 10, "heartbeat j2")
        hb = [r for r in srv.log() if "heartbeat" in r]
        assert all(r["display"] == "lab1" and r["heartbeat"]["agent_version"] for r in hb)

        # 4. a hash-consistent but invalid stack is refused and j2 stays on
        (srv.state / "junk.npz").write_bytes(b"\x00" * 5000)
        srv.set_jobs([job("junk", t=4), job("j2", t=3), job("j1", t=1)])
        wait_for(lambda: "junk will not be shown" in log.read_text(), 10, "refusal of junk")
        n = len(slm_shows(slm_dir))
        wait_for(lambda: len(slm_shows(slm_dir)) > n + 9, 10, "more frames")
        assert all(s["stack"] == "j2" for s in slm_shows(slm_dir)[n:])

        # 5. a clean stop reports it
        agent.send_signal(signal.SIGTERM)
        assert agent.wait(timeout=15) == 0
        assert srv.log()[-1].get("heartbeat", {}).get("state") == "stopped"

        # 6. a restarted agent finds j2 in its cache: the server answers 304 (ETag), nothing re-downloaded
        agent2 = subprocess.Popen(cmd, env=e, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        n = len(slm_shows(slm_dir))
        wait_for(lambda: len(slm_shows(slm_dir)) > n, 20, "frames after restart")
        gets = [r for r in srv.log() if r["path"] == "/v1/jobs/j2/stack"]
        assert gets[-1]["status"] == 304
        assert "from cache" in log.read_text()
    finally:
        stop_proc(agent)
        stop_proc(agent2)
        srv.stop()
    assert agent.returncode == 0


@pytest.mark.slow
def test_agent_cli_refuses_bad_settings(tmp_path):
    r = subprocess.run([*HOLO, "agent", "--slm", "null"], env=env(), capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "needs --server" in r.stderr
    e = env()
    e["HOLO_AGENT_RATE_HZ"] = "-3"
    r = subprocess.run([*HOLO, "agent", "--server", "http://127.0.0.1:9"], env=e, capture_output=True, text=True,
                       timeout=30)
    assert r.returncode == 2 and "rate_hz" in r.stderr
    r = subprocess.run([*HOLO, "agent", "--server", "http://127.0.0.1:9", "--slm", "beamer"], env=env(),
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "slm driver must be one of" in r.stderr
