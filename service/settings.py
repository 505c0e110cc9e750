"""Service settings: one validated model, filled from `holo serve` options and ``HOLO_*`` environment variables.

Everything lives under ``data_dir``: ``service.db`` (SQLite, WAL), ``scenes/<id>/bundle/``, ``jobs/<id>/``
(one folder per job: its inputs, logs and artifacts) and ``server.lock`` (one server per data dir).
"""

from __future__ import annotations

import ipaddress
import os
from functools import cached_property
from pathlib import Path
from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, field_validator

__all__ = ["JobLimits", "UploadLimits", "ServiceSettings"]


class JobLimits(BaseModel):
    """Caps on what one job may ask for (requests beyond them get 422)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_side_px: int = Field(default=4096, ge=1, description="Largest SLM side, pixels.")
    max_pixels: int = Field(default=4096 * 2304, ge=1, description="Largest SLM area H*W, pixels.")
    max_frames: int = Field(default=64, ge=1, description="Most time-multiplexed frames.")
    max_spp: int = Field(default=4096, ge=1, description="Most rays per WRP pixel.")
    max_wavelengths: int = Field(default=3, ge=1, description="Most colors.")
    max_iterations: int = Field(default=5000, ge=0, description="Most encoder iterations.")
    max_render_time_s: float = Field(default=4 * 3600.0, gt=0, description="Longest render time limit, s.")
    max_ray_budget: float = Field(default=4e10, gt=0, description="Most rays in a job: H*W*C*spp.")
    max_wrp_distance_mm: float = Field(default=1000.0, gt=0, description="Largest optics.max_wrp_distance_mm: "
                                       "how far in front of z_inf a job's WRP, and so behind it its deeper "
                                       "recording planes, may lie (their grids widen with that depth).")


class UploadLimits(BaseModel):
    """Caps on scene uploads (bytes are checked while streaming, before anything is unpacked)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_body_bytes: int = Field(default=256 * 1024 * 1024, ge=1, description="Largest request body.")
    max_total_bytes: int = Field(default=256 * 1024 * 1024, ge=1, description="Largest unpacked bundle.")
    max_files: int = Field(default=2000, ge=1, description="Most files in a bundle.")
    max_ratio: float = Field(default=200.0, gt=1, description="Largest zip compression ratio of one member.")
    max_mesh_faces: int = Field(default=20_000_000, ge=1)
    max_image_pixels: int = Field(default=64 * 1024 * 1024, ge=1)


class ServiceSettings(BaseModel):
    """How `holo serve` runs. Environment: ``HOLO_DATA_DIR``, ``HOLO_HOST``, ``HOLO_PORT``, ``HOLO_WORKERS``,
    ``HOLO_ENGINE`` (local | ray), ``HOLO_RAY_ADDRESS``, ``HOLO_RAY_GPUS`` (GPUs per job on Ray),
    ``HOLO_MAX_ATTEMPTS``, ``HOLO_MAX_UPLOAD_MB`` (largest upload and unpacked bundle), ``HOLO_TRUSTED_PROXIES``
    (comma-separated), ``HOLO_BODY_TIMEOUT_S``, ``HOLO_MAX_QUEUED_JOBS_PER_OWNER``, ``HOLO_MAX_SCENES_PER_OWNER``,
    ``HOLO_MAX_UPLOADS_PER_OWNER``, ``HOLO_MAX_STORED_GB_PER_OWNER``, ``HOLO_MAX_STREAMS_PER_OWNER``,
    ``HOLO_OPEN_DISPLAY_OWNERS`` (comma-separated)."""

    model_config = ConfigDict(extra="forbid")

    data_dir: Path
    host: str = "127.0.0.1"
    port: int = Field(default=8080, ge=0, le=65535)
    workers: int = Field(default=1, ge=1, le=256, description="Jobs run at the same time.")
    engine: Literal["local", "ray"] = "local"
    ray_address: Optional[str] = None
    ray_gpus_per_job: float = Field(default=0.0, ge=0.0, le=64.0)
    max_attempts: int = Field(default=3, ge=1, le=100, description="Runs of a job before a crash fails it.")
    job_timeout_s: float = Field(default=6 * 3600.0, gt=0, description="Wall-clock cap of one job run.")
    plan_timeout_s: float = Field(default=300.0, gt=0, description="Wall-clock cap of `holo plan` on upload.")
    kill_grace_s: float = Field(default=3.0, ge=0, description="SIGTERM to SIGKILL delay when stopping a job.")
    tick_s: float = Field(default=0.2, gt=0, le=5, description="Scheduler poll period.")
    keep_result: bool = Field(default=True, description="Keep RESULT.npz (complex fields) after encoding.")
    job_limits: JobLimits = JobLimits()
    upload_limits: UploadLimits = UploadLimits()
    # Privilege separation (service/workers/sandbox.py, docs/service.md "Privilege separation").
    sandbox: str = Field(default="auto", pattern=r"^(auto|on|off|[0-9]{1,10})$",
                         description="Run scene planning and jobs as unprivileged uids: auto (when root and "
                                     "possible), on (mandatory), off, or a uid base (on, with that base).")
    sandbox_uid_base: int = Field(default=61000, ge=1, le=2 ** 31 - 300, description="Planner uid; job slot k "
                                                                                       "runs as base + 1 + k.")
    # Connections and authentication.
    header_timeout_s: float = Field(default=10.0, gt=0, le=600, description="Time a client has to send a request's "
                                                                            "headers; slower connections are closed.")
    keepalive_timeout_s: float = Field(default=5.0, gt=0, le=600, description="Idle keep-alive connections close "
                                                                             "after this.")
    auth_failures_per_minute: int = Field(default=60, ge=1, description="Failed authentications a client address "
                                                                       "may make per minute before its failures "
                                                                       "get 429 (a valid token always passes).")
    trusted_proxies: list[str] = Field(default_factory=list, description="Addresses or networks (CIDR) of reverse "
                                       "proxies whose X-Forwarded-For names the client; from any other peer the "
                                       "header is ignored.")
    body_timeout_s: float = Field(default=300.0, gt=0, le=86400, description="Time a client has to send a "
                                  "request's whole body; slower requests get 408 and the connection is closed.")
    metrics_public: bool = Field(default=False, description="Serve /metrics without a token (else: scope read).")
    # Fairness between owners: what one owner may hold at once (the scheduler also takes owners in turn).
    max_queued_jobs_per_owner: int = Field(default=100, ge=1, description="Queued and running jobs one owner may "
                                                                         "have; more get 429.")
    max_scenes_per_owner: int = Field(default=1000, ge=1, description="Scenes one owner may store; more get 403.")
    max_uploads_per_owner: int = Field(default=2, ge=1, description="Uploads of one owner in progress at once; "
                                                                   "more get 429 before their body is read.")
    max_streams_per_owner: int = Field(default=50, ge=1, description="Job event streams (SSE) one owner may hold "
                                       "open at once; more get 429 (each polls the database four times a second "
                                       "until its job ends).")
    max_stored_gb_per_owner: Optional[float] = Field(default=None, gt=0, description="Bytes (GB) of scenes and "
                                                     "job results one owner may store, counting what its queued "
                                                     "jobs will write; uploads and submits past it get 403 "
                                                     "(default: half the data dir's file system).")
    open_display_owners: list[str] = Field(default_factory=lambda: ["default"], description="Owners whose agents "
                                           "register a display name with their first heartbeat; any other "
                                           "owner's displays are registered by an admin (PUT /v1/displays/NAME).")
    # Memory admission.
    worker_memory_mb: Optional[float] = Field(default=None, gt=0, description="Memory the workers may use together, "
                                                                             "MB (default: the machine's, less "
                                                                             "10% or 1 GiB, whichever is more).")

    @field_validator("data_dir")
    @classmethod
    def _absolute(cls, v: Path) -> Path:
        return Path(v).expanduser().resolve()

    @field_validator("trusted_proxies", mode="before")
    @classmethod
    def _networks(cls, v):
        items = [x.strip() for x in v.split(",")] if isinstance(v, str) else list(v or [])
        out = []
        for x in items:
            if not x:
                continue
            try:
                out.append(str(ipaddress.ip_network(x, strict=False)))
            except ValueError:
                raise ValueError(f"not an IP address or network: {x[:60]!r}") from None
        return out

    @field_validator("open_display_owners", mode="before")
    @classmethod
    def _owners(cls, v):
        return [x.strip() for x in v.split(",") if x.strip()] if isinstance(v, str) else v

    @cached_property
    def trusted_proxy_networks(self) -> tuple:
        return tuple(ipaddress.ip_network(x) for x in self.trusted_proxies)

    @property
    def db_path(self) -> Path:
        return self.data_dir / "service.db"

    @property
    def scenes_dir(self) -> Path:
        return self.data_dir / "scenes"

    @property
    def jobs_dir(self) -> Path:
        return self.data_dir / "jobs"

    @property
    def worker_memory_bytes(self) -> int:
        """What the workers may hold at once: ``worker_memory_mb``, else physical memory less a margin."""
        if self.worker_memory_mb is not None:
            return int(self.worker_memory_mb * 1e6)
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        return int(total - max(0.1 * total, 2**30))

    @property
    def stored_bytes_per_owner(self) -> int:
        """What one owner may store: ``max_stored_gb_per_owner``, else half the data dir's file system."""
        if self.max_stored_gb_per_owner is not None:
            return int(self.max_stored_gb_per_owner * 1e9)
        st = os.statvfs(self.data_dir if self.data_dir.exists() else self.data_dir.parent)
        return int(st.f_frsize * st.f_blocks // 2)

    @property
    def sandbox_dir(self) -> Path:
        """Folders of sandboxed scene planning (``plan-<scene>/``)."""
        return self.data_dir / "sandbox"

    @classmethod
    def from_env(cls, **overrides) -> "ServiceSettings":
        """Settings from ``HOLO_*`` variables, then explicit overrides (None = keep)."""
        env = os.environ
        data: dict = {}
        for key, var in (("data_dir", "HOLO_DATA_DIR"), ("host", "HOLO_HOST"), ("port", "HOLO_PORT"),
                         ("workers", "HOLO_WORKERS"), ("engine", "HOLO_ENGINE"), ("ray_address", "HOLO_RAY_ADDRESS"),
                         ("ray_gpus_per_job", "HOLO_RAY_GPUS"), ("max_attempts", "HOLO_MAX_ATTEMPTS"),
                         ("sandbox", "HOLO_SANDBOX"),
                         ("header_timeout_s", "HOLO_HEADER_TIMEOUT_S"),
                         ("auth_failures_per_minute", "HOLO_AUTH_FAILURES_PER_MINUTE"),
                         ("metrics_public", "HOLO_METRICS_PUBLIC"), ("worker_memory_mb", "HOLO_WORKER_MEMORY_MB"),
                         ("trusted_proxies", "HOLO_TRUSTED_PROXIES"), ("body_timeout_s", "HOLO_BODY_TIMEOUT_S"),
                         ("max_queued_jobs_per_owner", "HOLO_MAX_QUEUED_JOBS_PER_OWNER"),
                         ("max_scenes_per_owner", "HOLO_MAX_SCENES_PER_OWNER"),
                         ("max_uploads_per_owner", "HOLO_MAX_UPLOADS_PER_OWNER"),
                         ("max_stored_gb_per_owner", "HOLO_MAX_STORED_GB_PER_OWNER"),
                         ("max_streams_per_owner", "HOLO_MAX_STREAMS_PER_OWNER"),
                         ("open_display_owners", "HOLO_OPEN_DISPLAY_OWNERS")):
            if env.get(var):
                data[key] = env[var]
        upload_mb = overrides.pop("max_upload_mb", None) or env.get("HOLO_MAX_UPLOAD_MB")
        if upload_mb:
            n = int(float(upload_mb) * 1024 * 1024)
            data["upload_limits"] = UploadLimits(max_body_bytes=n, max_total_bytes=n)
        data.update({k: v for k, v in overrides.items() if v is not None})
        if data.get("ray_address") and "engine" not in data:
            data["engine"] = "ray"
        return cls(**data)
