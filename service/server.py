"""Run the service: uvicorn with the app, its scheduler and planner in this process (`holo serve`)."""

from __future__ import annotations

import logging
import os

from service.settings import ServiceSettings
from service.workers.engine import resolve_sandbox
from service.workers.ray_engine import RayEngine

__all__ = ["serve", "close_data_dir"]

log = logging.getLogger("holo.service")


def close_data_dir(settings: ServiceSettings) -> None:
    """Without the sandbox: the data dir, its database files and its top folders owner-only (0700 / 0600), also
    when an earlier start or `holo token create` made them under a laxer umask."""
    d = settings.data_dir
    for p, mode in ((d, 0o700), (settings.scenes_dir, 0o700), (settings.jobs_dir, 0o700)):
        try:
            if p.is_dir() and p.stat().st_uid == os.geteuid():
                os.chmod(p, mode)
        except OSError:
            pass
    for p in d.glob("service.db*"):
        try:
            if p.is_file() and p.stat().st_uid == os.geteuid():
                os.chmod(p, 0o600)
        except OSError:
            pass


def serve(settings: ServiceSettings, *, log_level: str = "info") -> None:
    """Serve until SIGINT/SIGTERM; on the way out running jobs are stopped and put back in the queue."""
    import uvicorn

    from service.api.app import create_app

    logging.basicConfig(level=getattr(logging, log_level.upper(), logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from service.http_timeouts import header_timeout_protocol
    # What the server creates is its own (the database, scenes, artifacts); folders sandbox users enter are
    # opened explicitly. Without the sandbox nobody else needs to read any of it either.
    os.umask(0o077)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    if resolve_sandbox(settings) is None:  # raises SandboxUnavailable when --sandbox on cannot be honoured
        close_data_dir(settings)
        if os.geteuid() == 0:
            log.warning("running as root without privilege separation (--sandbox off): uploaded scenes are "
                        "parsed and rendered by root processes; use --sandbox on unless something else confines "
                        "this service")
    engine = None
    if settings.engine == "ray":  # connected before serving, so an unreachable cluster is a one-line error

        engine = RayEngine(settings)
    app = create_app(settings, engine=engine)
    config = uvicorn.Config(app, host=settings.host, port=settings.port, log_level=log_level,
                            timeout_graceful_shutdown=3, proxy_headers=False, server_header=False,
                            http=header_timeout_protocol(settings.header_timeout_s),
                            timeout_keep_alive=settings.keepalive_timeout_s)
    uvicorn.Server(config).run()
