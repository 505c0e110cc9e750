"""Load test of the service's status endpoint: N concurrent clients polling ``GET /v1/jobs/{id}``.

Starts its own `holo serve` on a temporary data dir (or uses ``--server URL --token T --job-id J``), uploads a
small synthetic scene, and measures two phases: the server idle (the job finished), and the server busy (a
render of the job running in the worker at the same time). Prints p50/p90/p99 latency and throughput and, with
``--out``, writes a Markdown report. Not part of CI:

    .venv/bin/python bench/load_status.py --clients 50 --seconds 10 --out bench/results/service_load.md
"""

from __future__ import annotations

import argparse
import asyncio
import io
import os
import platform
import statistics
import tempfile
import time
import zipfile
from pathlib import Path

import httpx
from service_harness import start_server, wait_job

SCENE = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="30"/>
    <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="64"/></film></sensor>
  <emitter type="constant"/>
  <shape type="sphere"><bsdf type="diffuse"/></shape>
</scene>"""


async def _client(http: httpx.AsyncClient, path: str, until: float, lat: list[float], errors: list[int]) -> None:
    while time.perf_counter() < until:
        t0 = time.perf_counter()
        try:
            r = await http.get(path)
            if r.status_code != 200:
                errors.append(r.status_code)
        except httpx.HTTPError:
            errors.append(-1)
        lat.append(time.perf_counter() - t0)


async def phase(url: str, token: str, job_id: str, clients: int, seconds: float) -> dict:
    lat: list[float] = []
    errors: list[int] = []
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(base_url=url, headers={"Authorization": f"Bearer {token}"}, limits=limits,
                                 timeout=30.0) as http:
        await http.get(f"/v1/jobs/{job_id}")  # warm up
        until = time.perf_counter() + seconds
        t0 = time.perf_counter()
        await asyncio.gather(*(_client(http, f"/v1/jobs/{job_id}", until, lat, errors) for _ in range(clients)))
        wall = time.perf_counter() - t0
    q = statistics.quantiles(lat, n=100)
    return {"requests": len(lat), "errors": len(errors), "rps": len(lat) / wall, "p50_ms": q[49] * 1e3,
            "p90_ms": q[89] * 1e3, "p99_ms": q[98] * 1e3, "max_ms": max(lat) * 1e3}


def _submit(http: httpx.Client, scene_id: str, *, resolution: int, spp: int, seed: int) -> str:
    body = {"scene_id": scene_id, "optics": {"resolution_hw": [resolution, resolution], "seed": seed},
            "preset": "fast", "frames": 2, "spp": spp, "encoder": "dpac"}
    r = http.post("/v1/jobs", json=body)
    r.raise_for_status()
    return r.json()["id"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--server", default=None, help="Use a running server (with --token and --job-id).")
    ap.add_argument("--token", default=None)
    ap.add_argument("--job-id", default=None)
    ap.add_argument("--out", type=Path, default=None, help="Write a Markdown report here.")
    args = ap.parse_args()
    if not 1 <= args.clients <= 1000 or not 0 < args.seconds <= 600:
        raise SystemExit("--clients must be in 1..1000 and --seconds in (0, 600]")
    results: dict[str, dict] = {}
    if args.server:
        if not (args.token and args.job_id):
            raise SystemExit("--server needs --token and --job-id")
        results["given job"] = asyncio.run(phase(args.server, args.token, args.job_id, args.clients, args.seconds))
    else:
        with tempfile.TemporaryDirectory(prefix="holo-load-") as tmp:
            proc, url, token = start_server(Path(tmp) / "data")
            try:
                with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=60) as http:
                    buf = io.BytesIO()
                    with zipfile.ZipFile(buf, "w") as zf:
                        zf.writestr("scene.xml", SCENE)
                    sid = http.post("/v1/scenes", files={"bundle": ("b.zip", buf.getvalue())}).json()["id"]
                    done = _submit(http, sid, resolution=32, spp=2, seed=1)
                    wait_job(http, done, ("succeeded", "failed"), timeout=300)
                    results["idle server (finished job)"] = asyncio.run(
                        phase(url, token, done, args.clients, args.seconds))
                    busy = _submit(http, sid, resolution=384, spp=64, seed=2)
                    wait_job(http, busy, ("running",), timeout=300)
                    time.sleep(3.0)  # let the render itself start
                    results["busy server (render running)"] = asyncio.run(
                        phase(url, token, busy, args.clients, args.seconds))
                    still = http.get(f"/v1/jobs/{busy}").json()["state"]
                    results["busy server (render running)"]["job_state_after"] = still
                    if still in ("queued", "running"):
                        http.delete(f"/v1/jobs/{busy}")
            finally:
                proc.terminate()
                proc.wait(timeout=30)
    lines = [f"{name}: {r['requests']} requests, {r['errors']} errors, {r['rps']:.0f} req/s, p50 {r['p50_ms']:.1f} ms, "
             f"p90 {r['p90_ms']:.1f} ms, p99 {r['p99_ms']:.1f} ms, max {r['max_ms']:.1f} ms"
             for name, r in results.items()]
    print("\n".join(lines))
    if args.out:
        rows = "\n".join(f"| {name} | {r['requests']} | {r['errors']} | {r['rps']:.0f} | {r['p50_ms']:.1f} | "
                         f"{r['p90_ms']:.1f} | {r['p99_ms']:.1f} | {r['max_ms']:.1f} |" for name, r in results.items())
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(
            f"# Service load: {args.clients} concurrent clients polling job status\n\n"
            f"`bench/load_status.py --clients {args.clients} --seconds {args.seconds:g}` on {platform.node() or 'host'} "
            f"({os.cpu_count()} CPU cores, {platform.python_implementation()} {platform.python_version()}), "
            f"{time.strftime('%Y-%m-%d')}. One `holo serve` (uvicorn, one process, SQLite WAL), the clients "
            "(httpx, asyncio, one process) on the same machine: both share the cores, so these numbers include "
            "the load generator's own CPU use.\n\n"
            "| phase | requests | errors | req/s | p50 ms | p90 ms | p99 ms | max ms |\n|---|---|---|---|---|---|---|---|\n"
            f"{rows}\n")


if __name__ == "__main__":
    main()
