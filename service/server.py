"""Run the service: uvicorn with the app, its scheduler and planner in this process (`holo serve`)."""

from __future__ import annotations

import logging
import os

from service.settings import ServiceSettings

__all__ = ["serve"]


def serve(settings: ServiceSettings, *, log_level: str = "info") -> None:
    """Serve until SIGINT/SIGTERM; on the way out running jobs are stopped and put back in the queue."""
    import uvicorn

    from service.api.app import create_app

    logging.basicConfig(level=getattr(logging, log_level.upper(), logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from service.http_timeouts import header_timeout_protocol
    from service.workers.engine import resolve_sandbox

    settings.data_dir.mkdir(parents=True, exist_ok=True)
    if resolve_sandbox(settings) is not None:  # raises SandboxUnavailable when --sandbox on cannot be honoured
        os.umask(0o077)  # what the server creates is its own; folders sandbox users enter are opened explicitly
    engine = None
    if settings.engine == "ray":  # connected before serving, so an unreachable cluster is a one-line error
        from service.workers.ray_engine import RayEngine

        engine = RayEngine(settings)
    app = create_app(settings, engine=engine)
    config = uvicorn.Config(app, host=settings.host, port=settings.port, log_level=log_level,
                            timeout_graceful_shutdown=3, proxy_headers=False, server_header=False,
                            http=header_timeout_protocol(settings.header_timeout_s),
                            timeout_keep_alive=settings.keepalive_timeout_s)
    uvicorn.Server(config).run()
