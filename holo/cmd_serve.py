"""`holo serve`: the rendering service (HTTP API, SQLite job store, one worker process per job)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

import typer

from holo.common import fail


def register(app: typer.Typer) -> None:
    app.command("serve")(serve)


def serve(
    data_dir: Optional[Path] = typer.Option(None, "--data-dir", help="Folder for the database, scenes and job "
                                                                     "artifacts (default: HOLO_DATA_DIR)."),
    host: Optional[str] = typer.Option(None, help="Address to bind (default: HOLO_HOST, else 127.0.0.1: this "
                                                  "machine only)."),
    port: Optional[int] = typer.Option(None, help="TCP port (0..65535; default: HOLO_PORT, else 8080)."),
    workers: Optional[int] = typer.Option(None, help="Jobs run at the same time (1..256; default: HOLO_WORKERS, "
                                                     "else 1)."),
    engine: Optional[str] = typer.Option(None, help="local (subprocesses) | ray (default: ray when --ray-address "
                                                    "or HOLO_RAY_ADDRESS is set)."),
    ray_address: Optional[str] = typer.Option(
        None, "--ray-address", help="Ray cluster address, e.g. ray://head:10001 or auto; its workers must share "
                                    "--data-dir."),
    ray_gpus: Optional[float] = typer.Option(None, "--ray-gpus", help="GPUs each job asks Ray for (0..64)."),
    max_attempts: Optional[int] = typer.Option(None, "--max-attempts", help="Runs of a job before a crash fails it "
                                                                            "(1..100; default: HOLO_MAX_ATTEMPTS, "
                                                                            "else 3)."),
    max_upload_mb: Optional[float] = typer.Option(None, "--max-upload-mb", help="Largest upload and unpacked "
                                                                                "bundle, MiB (default 256)."),
    sandbox: Optional[str] = typer.Option(None, "--sandbox", help="Privilege separation: run scene planning and "
                                                                  "jobs as unprivileged uids. auto (default: on "
                                                                  "when root and possible), on (mandatory), off, "
                                                                  "or UIDBASE (on; planner uid, jobs UIDBASE+1..; "
                                                                  "default 61000). Env HOLO_SANDBOX."),
    trusted_proxies: Optional[str] = typer.Option(None, "--trusted-proxies", help="Comma-separated addresses or "
                                                                               "networks of reverse proxies whose "
                                                                               "X-Forwarded-For names the client "
                                                                               "(default: none; env "
                                                                               "HOLO_TRUSTED_PROXIES)."),
    log_level: str = typer.Option("info", "--log-level", help="debug | info | warning | error"),
) -> None:
    """Run the rendering service (REST API on /v1, OpenAPI at /docs)."""
    from pydantic import ValidationError

    from service.settings import ServiceSettings

    if max_upload_mb is not None and not 0 < max_upload_mb <= 1 << 20:
        fail(f"--max-upload-mb must be in (0, 1048576], got {max_upload_mb}")
    if log_level not in ("debug", "info", "warning", "error"):
        fail(f"--log-level must be debug, info, warning or error, got {log_level!r}")
    if data_dir is None and not os.environ.get("HOLO_DATA_DIR"):
        fail("give the service's data folder: --data-dir DIR or HOLO_DATA_DIR")
    try:
        settings = ServiceSettings.from_env(data_dir=data_dir, host=host, port=port, workers=workers, engine=engine,
                                            ray_address=ray_address, ray_gpus_per_job=ray_gpus,
                                            max_attempts=max_attempts, max_upload_mb=max_upload_mb,
                                            sandbox=sandbox, trusted_proxies=trusted_proxies)
    except ValidationError as exc:
        fail("; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors()))
    from service.api.context import DataDirBusy
    from service.server import serve as run
    from service.workers.engine import SandboxUnavailable
    from service.workers.ray_engine import RayUnavailable

    try:
        run(settings, log_level=log_level)
    except (DataDirBusy, SandboxUnavailable, RayUnavailable) as exc:
        fail(str(exc), code=1)
