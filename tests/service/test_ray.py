"""The distributed engine against a real Ray cluster on this machine: a head started by the test (`ray start
--head`, loopback only, its own temp dir and ports), and real `holo serve` processes that connect to it by
address like a deployment does: one configured on the command line (``--engine ray --ray-address HOST:PORT``),
one by environment only (``HOLO_RAY_ADDRESS=ray://...`` through the Ray Client, ``HOLO_RAY_GPUS=1``,
``HOLO_MAX_ATTEMPTS``). A small job runs through Ray into the shared data dir and its stack equals the CLI's
(= the local engine's, see test_e2e.py); cancelling a running job stops its driver's whole process group; a
Ray worker killed mid-job means a retry on a fresh task, then a failure once the attempts are spent."""

from __future__ import annotations

import hashlib
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ray")

from holocore.io import load_stack  # noqa: E402
from service.workers.engine import group_alive  # noqa: E402
from tests.service.helpers import REPO, SMALL_JOB, Server, upload, wait_for, wait_state  # noqa: E402
from tests.service.test_robustness import SLOW, group_members  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.scenes, pytest.mark.timeout(240)]  # slow: a Ray cluster per test; tests/service/test_units.py covers the engine choice

_MARK = "HOLO_TEST_RAY_CLUSTER"  # in the environment of the jobs' drivers and CLIs (own sessions: see _cluster_pids)
# Ray on loopback only: with this, Ray takes 127.0.0.1 as the node address instead of probing for a routable one
_RAY_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_USAGE_STATS_ENABLED": "0"}


def _stat(pid: int) -> tuple[bytes, int]:
    """(state, session id) of ``pid``."""
    raw = Path(f"/proc/{pid}/stat").read_bytes()
    rest = raw[raw.rfind(b")") + 2:].split()
    return rest[0], int(rest[3])


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie counts as gone)."""
    try:
        return _stat(pid)[0] != b"Z"
    except (OSError, IndexError, ValueError):
        return False


def _cluster_pids(sid: int, token: str) -> list[int]:
    """Live processes of the test's cluster: the session `ray start` ran in (its daemons and Ray workers stay in
    it), and whatever carries the cluster's marker in its environment (job drivers start their own sessions)."""
    needle = f"{_MARK}={token}".encode()
    pids = []
    for p in Path("/proc").iterdir():
        if not p.name.isdigit() or int(p.name) == os.getpid():
            continue
        try:
            state, psid = _stat(int(p.name))
            if state != b"Z" and (psid == sid or needle in (p / "environ").read_bytes().split(b"\0")):
                pids.append(int(p.name))
        except (OSError, IndexError, ValueError):
            continue
    return pids


def _ports(n: int) -> list[int]:
    """``n`` distinct free ports for the cluster, outside the kernel's ephemeral range (32768+: where the ports
    that Ray and everything else bind as 0 land) and Ray's own ranges (workers 10002-19999, Ray Client servers
    23000-23999), so that none is taken between now and `ray start`."""
    rng, ports = random.Random(), []
    for port in rng.sample(range(24000, 32000), 200):
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        ports.append(port)
        if len(ports) == n:
            return ports
    raise RuntimeError("no free ports for the Ray cluster")


def _environ(pid: int) -> dict[str, str]:
    raw = Path(f"/proc/{pid}/environ").read_bytes().decode(errors="replace")
    return dict(kv.split("=", 1) for kv in raw.split("\0") if "=" in kv)


@pytest.fixture(scope="module")
def ray_cluster():
    """A Ray head on 127.0.0.1 (2 CPUs, 1 logical GPU), stopped (every process of it) at the end."""
    token = uuid.uuid4().hex
    temp = Path(tempfile.mkdtemp(prefix="holo-ray-", dir="/tmp"))  # short: Ray's socket paths live under it
    port, client_port, nowhere_port, *more = _ports(8)
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    env.update(_RAY_ENV, PYTHONPATH=str(REPO), **{_MARK: token})
    # Nothing leaves this machine: even with usage stats off, Ray's head probes cloud metadata servers
    # (169.254.169.254, metadata.google.internal) and posts a "disabled" note to usage-stats.ray.io, all with
    # `requests`; send those to a closed loopback port (gRPC and Ray's own HTTP to 127.0.0.1 go direct).
    nowhere = f"http://127.0.0.1:{nowhere_port}"
    for var in ("http_proxy", "https_proxy", "HTTP_PROXY", "HTTPS_PROXY"):
        env[var] = nowhere
    env["no_proxy"] = env["NO_PROXY"] = "127.0.0.1,localhost"
    env["RAY_USAGE_STATS_REPORT_URL"] = f"{nowhere}/"
    cmd = [sys.executable, "-m", "ray.scripts.scripts", "start", "--head", "--node-ip-address=127.0.0.1",
           f"--port={port}", f"--ray-client-server-port={client_port}", "--num-cpus=2", "--num-gpus=1",
           "--object-store-memory=100000000", "--include-dashboard=false", f"--dashboard-port={more[0]}",
           f"--dashboard-agent-listen-port={more[1]}", f"--dashboard-agent-grpc-port={more[2]}",
           f"--runtime-env-agent-port={more[3]}", f"--metrics-export-port={more[4]}",
           f"--temp-dir={temp}", "--disable-usage-stats"]
    mp = pytest.MonkeyPatch()
    for k, v in _RAY_ENV.items():  # for the `holo serve` processes (their Ray drivers), which copy our env
        mp.setenv(k, v)
    mp.delenv("RAY_ADDRESS", raising=False)
    head = subprocess.Popen(cmd, env=env, cwd=temp, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, start_new_session=True)  # its own session: see _cluster_pids
    assert head.pid != os.getsid(0)
    try:
        try:
            out, _ = head.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            head.kill()
            out, _ = head.communicate()
        assert head.returncode == 0, f"ray start failed ({head.returncode}): {out.decode(errors='replace')[-3000:]}"

        def client_server_up() -> bool:
            with socket.socket() as s:
                s.settimeout(1.0)
                return s.connect_ex(("127.0.0.1", client_port)) == 0

        wait_for(client_server_up, timeout=30, interval=0.2, what="the Ray Client server")
        yield {"address": f"127.0.0.1:{port}", "client": f"ray://127.0.0.1:{client_port}", "token": token}
    finally:
        mp.undo()
        deadline = time.monotonic() + 20
        while (pids := _cluster_pids(head.pid, token)) and time.monotonic() < deadline:  # `ray stop --force`,
            for pid in pids:                                                            # this cluster only
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            time.sleep(0.2)
        shutil.rmtree(temp, ignore_errors=True)
        assert not _cluster_pids(head.pid, token), "processes of the test's Ray cluster outlived it"


@pytest.fixture(scope="module")
def ray_server(ray_cluster, tmp_path_factory):
    """`holo serve --engine ray --ray-address 127.0.0.1:PORT` (CPU jobs)."""
    s = Server(tmp_path_factory.mktemp("ray-cli") / "data",
               extra=("--engine", "ray", "--ray-address", ray_cluster["address"])).start(timeout=90)
    yield s
    s.stop()


@pytest.fixture(scope="module")
def env_server(ray_cluster, tmp_path_factory):
    """`holo serve` configured by environment only: Ray Client address, 1 GPU per job, 2 attempts."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HOLO_RAY_ADDRESS", ray_cluster["client"])
        mp.setenv("HOLO_RAY_GPUS", "1")
        mp.setenv("HOLO_MAX_ATTEMPTS", "2")
        mp.delenv("HOLO_ENGINE", raising=False)
        s = Server(tmp_path_factory.mktemp("ray-env") / "data").start(timeout=90)
    yield s
    s.stop()


def _driver_rendering(server: Server, job_id: str, timeout: float = 90.0) -> tuple[int, int]:
    """Wait until the job's driver (started by a Ray worker: its pid is in ray_driver.pid) runs `holo render`;
    returns (driver pid = its process group, render pid)."""
    pid_file = server.data_dir / "jobs" / job_id / "ray_driver.pid"

    def check():
        try:
            pid = int(pid_file.read_text())
        except (OSError, ValueError):
            return None
        renders = [p for p, cmd in group_members(pid) if "-m holo render" in cmd]
        return (pid, renders[0]) if renders else None

    return wait_for(check, timeout=timeout, interval=0.05, what=f"job {job_id} rendering on ray")


def _ray_worker_of(driver_pid: int) -> int:
    """The Ray worker that started the driver (``--parent-pid``), checked to be one."""
    args = Path(f"/proc/{driver_pid}/cmdline").read_bytes().decode().split("\0")
    worker = int(args[args.index("--parent-pid") + 1])
    assert Path(f"/proc/{worker}/cmdline").read_bytes().startswith(b"ray::"), "the driver's parent is no Ray worker"
    return worker


def test_a_job_runs_on_ray_into_the_shared_data_dir_and_matches_the_cli(ray_server, ray_cluster, scene_bundle,
                                                                         tmp_path):
    scene = scene_bundle("cbox-mirror-glass")
    assert f"ray engine: connected to {ray_cluster['address']}" in ray_server.log()
    with ray_server.client("submit") as c:
        up = upload(c, scene)
        assert up.status_code == 201, up.text
        job = c.post("/v1/jobs", json={"scene_id": up.json()["id"], **SMALL_JOB})
        assert job.status_code == 202, job.text
        # meanwhile, the same job through the CLIs (what the local engine runs; test_e2e checks that they agree)
        o, env = SMALL_JOB["optics"], dict(os.environ, PYTHONPATH=str(REPO))
        cli = subprocess.Popen([sys.executable, "-m", "holo", "render", str(scene), "--out", str(tmp_path / "r.npz"),
                                "--preset", "fast", "--frames", "2", "--spp", "4", "--resolution",
                                "x".join(map(str, o["resolution_hw"])), "--seed", str(o["seed"])],
                               env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        done = wait_state(c, job.json()["id"], ("succeeded", "failed"), timeout=150)
        assert done["state"] == "succeeded", (done["error"], ray_server.log()[-3000:])
        r = c.get(f"/v1/jobs/{done['id']}/stack")
    assert done["attempts"] == 1 and done["worker_pid"] is None and done["error"] is None
    t = done["timings"]
    assert t["engine"] == "ray" and t["render_s"] > 0 and t["encode_s"] > 0 and t["run_s"] >= t["render_s"]
    job_dir = ray_server.data_dir / "jobs" / done["id"]
    assert int((job_dir / "ray_driver.pid").read_text()) > 0  # written by the Ray task, in the shared data dir
    assert r.status_code == 200
    digest = hashlib.sha256(r.content).hexdigest()
    assert digest == done["stack_sha256"] == r.headers["x-content-sha256"] and r.headers["etag"] == f'"{digest}"'
    assert (job_dir / "stack.npz").read_bytes() == r.content
    (tmp_path / "s.npz").write_bytes(r.content)
    phase, u8, meta = load_stack(tmp_path / "s.npz")
    assert phase.shape == (2, 3, 64, 64) and u8.shape == (2, 3, 64, 64) and u8.dtype == np.uint8
    assert cli.wait(timeout=120) == 0, cli.stderr.read().decode(errors="replace")[-2000:]
    subprocess.run([sys.executable, "-m", "holo", "encode", str(tmp_path / "r.npz"), "--out", str(tmp_path / "c.npz"),
                    "--method", "dpac"], check=True, env=env, capture_output=True, timeout=120)
    cli_phase, cli_u8, cli_meta = load_stack(tmp_path / "c.npz")
    assert np.array_equal(phase, cli_phase) and np.array_equal(u8, cli_u8)
    assert meta["optics"] == cli_meta["optics"] and meta["encoder"]["method"] == "dpac"


def test_cancel_stops_the_ray_jobs_process_group_and_gpu_jobs_get_a_gpu(env_server, ray_cluster, scene_bundle):
    log = env_server.log()
    assert f"ray engine: connected to {ray_cluster['client']} (1.0 GPUs per job)" in log and "engine ray" in log
    with env_server.client("submit") as c:
        sid = upload(c, scene_bundle("cbox-mirror-glass")).json()["id"]
        slow = c.post("/v1/jobs", json={"scene_id": sid, **SLOW}).json()
        pgid, render_pid = _driver_rendering(env_server, slow["id"])
        _ray_worker_of(pgid)
        assert _environ(render_pid).get("CUDA_VISIBLE_DEVICES") == "0"  # Ray gave the job the cluster's GPU
        assert _environ(render_pid).get(_MARK) == ray_cluster["token"]  # it runs under the test's cluster
        r = c.delete(f"/v1/jobs/{slow['id']}")
        assert r.status_code == 202 and r.json()["state"] == "cancelled"
        wait_for(lambda: not group_alive(pgid), timeout=15, what="the cancelled job's process group to exit")
        assert not _alive(render_pid)
        time.sleep(1.0)
        s = c.get(f"/v1/jobs/{slow['id']}").json()
    assert s["state"] == "cancelled" and s["stack_sha256"] is None and s["attempts"] == 1


def test_a_killed_ray_worker_means_a_retry_then_a_failure(env_server, scene_bundle):
    with env_server.client("submit") as c:
        sid = upload(c, scene_bundle("cbox-mirror-glass")).json()["id"]
        job = c.post("/v1/jobs", json={"scene_id": sid, **SLOW, "optics": {**SLOW["optics"], "seed": 2}}).json()
        seen = []
        for attempt in (1, 2):  # HOLO_MAX_ATTEMPTS=2: the second crash is the last
            wait_for(lambda: c.get(f"/v1/jobs/{job['id']}").json()["attempts"] >= attempt, timeout=60,
                     what=f"attempt {attempt}")
            pgid, render_pid = _driver_rendering(env_server, job["id"])
            assert pgid not in seen
            seen.append(pgid)
            os.kill(_ray_worker_of(pgid), signal.SIGKILL)  # the node's worker dies: the driver must go with it
            wait_for(lambda: not group_alive(pgid), timeout=15, what="the dead worker's job to stop")
            assert not _alive(render_pid)
        done = wait_state(c, job["id"], ("succeeded", "failed"), timeout=60)
    assert done["state"] == "failed" and done["attempts"] == 2, done
    assert "killed by signal 9" in done["error"] and "2 attempts" in done["error"]
    assert "requeued" in env_server.log() and "ray task ended with" in env_server.log()
