"""What every request handler reaches through ``request.app.state.ctx``: settings, database, workers."""

from __future__ import annotations

import fcntl
import os
from dataclasses import dataclass, field
from typing import Any, Optional

from service.auth import AuthFailures
from service.db import Database
from service.metrics import Metrics
from service.settings import ServiceSettings

__all__ = ["ServiceContext", "DataDirBusy"]


class DataDirBusy(RuntimeError):
    """Another server holds this data dir (one server per data dir)."""


@dataclass
class ServiceContext:
    settings: ServiceSettings
    db: Database
    metrics: Metrics
    code_version: str
    scheduler: Any = None  # service.workers.scheduler.Scheduler when workers run in this process
    planner: Any = None
    auth_failures: AuthFailures = field(default_factory=AuthFailures)  # per app: failed authentications
    uploads_in_flight: dict = field(default_factory=dict)  # owner -> uploads being received or unpacked now
    streams_open: dict = field(default_factory=dict)  # owner -> job event streams open now
    _lock_fd: Optional[int] = field(default=None, repr=False)

    def lock_data_dir(self) -> None:
        path = self.settings.data_dir / "server.lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise DataDirBusy(f"another holo serve uses {self.settings.data_dir} (lock {path})") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._lock_fd = fd

    def unlock_data_dir(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def wake_scheduler(self) -> None:
        if self.scheduler is not None:
            self.scheduler.wake()

    def wake_planner(self) -> None:
        if self.planner is not None:
            self.planner.wake()
