"""Run the service: uvicorn with the app, its scheduler and planner in this process (`holo serve`)."""

from __future__ import annotations

import logging

from service.settings import ServiceSettings

__all__ = ["serve"]


def serve(settings: ServiceSettings, *, log_level: str = "info") -> None:
    """Serve until SIGINT/SIGTERM; on the way out running jobs are stopped and put back in the queue."""
    import uvicorn

    from service.api.app import create_app

    logging.basicConfig(level=getattr(logging, log_level.upper(), logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    app = create_app(settings)
    config = uvicorn.Config(app, host=settings.host, port=settings.port, log_level=log_level,
                            timeout_graceful_shutdown=3, proxy_headers=False, server_header=False)
    uvicorn.Server(config).run()
