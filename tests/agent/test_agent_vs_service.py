"""End to end with the real service: `holo serve` renders a small scene for a display, `holo agent` picks the
stack up, shows it on the simulated SLM through a lookup table, and reports back in GET /v1/displays."""

from __future__ import annotations

import importlib.util
import subprocess

import httpx
import numpy as np
import pytest

from holocore.io import load_stack
from tests.agent.helpers import HOLO, env, free_port, slm_shows, stop_proc, wait_for
from tests.agent.test_agent_e2e import TABLES, assert_pngs_identical, expected_levels

pytestmark = [pytest.mark.slow, pytest.mark.scenes]


def _have_service() -> bool:
    return all(importlib.util.find_spec(m) is not None
               for m in ("holo.cmd_serve", "holo.cmd_token", "holo.cmd_submit", "service.server", "mitsuba"))


@pytest.mark.skipif(not _have_service(), reason="holo serve / token / submit or Mitsuba not installed")
def test_agent_shows_what_the_service_rendered(tmp_path, scene_bundle):
    scene = scene_bundle("cbox-mirror-glass")  # the project's own box
    data = tmp_path / "svc"
    tok = subprocess.run([*HOLO, "token", "create", "--data-dir", str(data), "--scope", "submit", "--scope", "read",
                          "--scope", "agent"], env=env(), capture_output=True, text=True, timeout=60)
    assert tok.returncode == 0, tok.stderr
    token = tok.stdout.strip().splitlines()[-1].strip()
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    serve = subprocess.Popen([*HOLO, "serve", "--data-dir", str(data), "--port", str(port)], env=env(),
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    agent = None
    headers = {"Authorization": f"Bearer {token}"}
    try:
        wait_for(lambda: _get(f"{url}/livez", headers) == 200, 60, "holo serve up")
        lut = tmp_path / "lut.npy"
        np.save(lut, TABLES)
        slm_dir = tmp_path / "slm"
        agent = subprocess.Popen([*HOLO, "agent", "--server", url, "--token", token, "--display", "benchE2E", "--slm",
                                  f"sim:{slm_dir}", "--cache-dir", str(tmp_path / "cache"), "--poll-s", "0.3",
                                  "--rate-hz", "60", "--lut", str(lut), "--log-file", str(tmp_path / "agent.log")],
                                 env={**env(), "HOLO_AGENT_HEARTBEAT_INTERVAL_S": "0.5"},
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        out = tmp_path / "STACK.npz"
        sub = subprocess.run([*HOLO, "submit", str(scene), "--server", url, "--token", token, "--preset", "fast",
                              "--frames", "2", "--resolution", "32x32", "--iterations", "20", "--to-display", "benchE2E",
                              "--out", str(out)], env=env(), capture_output=True, text=True, timeout=240)
        assert sub.returncode == 0, sub.stderr
        job_id = [l for l in sub.stdout.splitlines() if l.startswith("{")][-1].split('"job_id": "')[1].split('"')[0]
        phase, _, _ = load_stack(out)
        assert phase.shape == (2, 3, 32, 32)
        wait_for(lambda: sum(s["stack"] == job_id for s in slm_shows(slm_dir)) >= 6, 30, "a pass on the SLM")
        assert_pngs_identical(slm_dir, job_id, expected_levels(out))

        def showing() -> bool:
            r = httpx.get(f"{url}/v1/displays", headers=headers, timeout=5)
            d = [x for x in r.json()["displays"] if x["name"] == "benchE2E"]
            return bool(d) and (d[0].get("showing") or {}).get("job_id") == job_id

        wait_for(showing, 15, "the service's display list to say what the agent shows")
    finally:
        stop_proc(agent)
        stop_proc(serve, timeout_s=15)


def _get(url: str, headers: dict) -> int:
    try:
        return httpx.get(url, headers=headers, timeout=2).status_code
    except httpx.TransportError:
        return 0
