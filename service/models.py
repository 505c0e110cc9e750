"""Request and response bodies of the HTTP API (pydantic; these make the OpenAPI schema at /docs), and a job's
content address. What a job may ask for is ``service.job_rules``; what it costs, ``service.cost``.

Only light imports here: ``holocore.display.optics`` is pydantic and math, nothing heavy (docs/design.md §1).
"""

from __future__ import annotations

import hashlib
import json
from typing import Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field

from holocore.display.optics import OpticsConfig
from service.jobfiles import JobFields
from service.scene_view import FieldOfViewBox

__all__ = ["NAME_PATTERN", "ID_PATTERN", "JobRequest", "Heartbeat", "Showing", "JobOut", "JobList", "SceneOut",
           "DisplayOut", "DisplayList", "Problem", "SweepRequest", "SweepCreated", "SweepJob", "SweepOut",
           "SweepList", "SWEEP_OPTIONS", "cache_key", "effective_optics"]

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$"
ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"


class JobRequest(JobFields):
    """A render job: scene, optics, the job fields (service.jobfiles.JobFields: quality, encoder, recording
    layout), and the display it is for."""

    model_config = ConfigDict(extra="forbid")

    scene_id: str = Field(pattern=ID_PATTERN, description="Id from POST /v1/scenes.")
    optics: OpticsConfig = Field(default_factory=OpticsConfig, description="The display's optics (OpticsConfig).")
    display: Optional[str] = Field(default=None, pattern=NAME_PATTERN, description="Display the job is for.")
    name: Optional[str] = Field(default=None, min_length=1, max_length=120, pattern=r"^[^\x00-\x1f\x7f]+$",
                                description="A name for people (the web page offers the uploaded file's); not "
                                            "part of the result's content address.")


SWEEP_OPTIONS = ("frames", "spp", "iterations", "optimiser", "encoder", "preset", "method", "wrp_planes",
                 "render_time_limit_s", "quality_db", "max_spp")


class SweepRequest(BaseModel):
    """One job per value of one option, every other option the job's."""

    model_config = ConfigDict(extra="forbid")
    job: JobRequest = Field(description="The job every value changes one option of (a POST /v1/jobs body).")
    option: Literal[SWEEP_OPTIONS] = Field(description="The job option the sweep varies.")
    values: list[Any] = Field(min_length=2, max_length=12, description="Its values, 2 to 12, each once.")


class SweepCreated(BaseModel):
    id: str
    option: str
    values: list[Any]
    jobs: list[str] = Field(description="The jobs' ids, in the order of the values.")
    links: dict[str, str]


class SweepJob(BaseModel):
    id: str
    value: Any
    name: Optional[str] = None
    state: Literal["queued", "running", "succeeded", "failed", "cancelled"]
    progress: Optional[dict[str, Any]] = None
    estimate_s: Optional[float] = Field(default=None, description="The estimate's seconds.")
    predicted_psnr_db: Optional[float] = Field(default=None, description="The estimate's predicted "
                                               "viewer-faithful PSNR (its quality.psnr_db).")
    predicted_uncertainty_db: Optional[float] = None
    run_s: Optional[float] = Field(default=None, description="The measured run time, once the job ran.")
    measured_psnr_db: Optional[float] = Field(default=None, description="Once evaluated: the evaluation's "
                                              "viewer-faithful mean PSNR, else its mean PSNR.")
    measured_kind: Optional[Literal["viewer", "mean"]] = None
    error: Optional[str] = None


class SweepOut(BaseModel):
    id: str
    option: str
    values: list[Any]
    created_at: str
    jobs: list[SweepJob] = Field(description="The sweep's jobs in the order of its values (a deleted job is left "
                                             "out).")


class SweepList(BaseModel):
    sweeps: list[SweepOut]


class Showing(BaseModel):
    model_config = ConfigDict(extra="forbid")
    job_id: str = Field(max_length=128)
    frame: int = Field(ge=0, le=1_000_000)


class Heartbeat(BaseModel):
    """What a display agent reports every few seconds."""

    model_config = ConfigDict(extra="forbid")
    agent_version: str = Field(max_length=64)
    showing: Optional[Showing] = None
    state: str = Field(max_length=64)
    message: str = Field(default="", max_length=2000)


class JobQuality(BaseModel):
    psnr_db: float
    source: Literal["measured", "predicted"]
    floor_db: float = Field(description="Below this viewer-faithful PSNR a result is too poor to be useful.")
    too_low: bool


class JobOut(BaseModel):
    id: str
    name: Optional[str] = None
    state: Literal["queued", "running", "succeeded", "failed", "cancelled"]
    display: Optional[str] = None
    scene_id: str
    created_at: str
    started_at: Optional[str] = None
    finished_at: Optional[str] = None
    stack_sha256: Optional[str] = None
    stack_bytes: Optional[int] = None
    options: dict[str, Any]
    progress: Optional[dict[str, Any]] = None
    timings: Optional[dict[str, Any]] = None
    plan: Optional[dict[str, Any]] = None
    error: Optional[str] = None
    attempts: int = 0
    worker_pid: Optional[int] = None
    estimate: Optional[dict[str, Any]] = None
    reused_from: Optional[str] = None
    cache_key: str
    sent_at: Optional[str] = Field(default=None, description="In GET /v1/jobs?display=NAME only: when the job was "
                                   "last sent to NAME (POST /v1/jobs/{id}/display), else its submit time; that "
                                   "list is in this order, the job the display shows next first.")
    field_of_view_box: Optional[FieldOfViewBox] = Field(
        default=None, description="In GET /v1/jobs/{id} only: where the hologram's view lies in the scene's "
                                  "picture at the job's optics (None until the scene's plan is ready).")
    sweep_id: Optional[str] = Field(default=None, description="In GET /v1/jobs/{id} only: the sweep that made "
                                    "the job (GET /v1/sweeps/{id}), else None.")
    quality: Optional[JobQuality] = Field(
        default=None, description="The job's viewer-faithful PSNR against the level below which a hologram shows "
                                  "speckle rather than the scene: measured once evaluated, else predicted; None for "
                                  "a failed or cancelled job.")
    links: dict[str, str]


class JobList(BaseModel):
    jobs: list[JobOut]


class SceneOut(BaseModel):
    id: str
    sha256: str
    entry: str
    created_at: str
    report: dict[str, Any]
    plan_state: Literal["pending", "running", "ready", "failed"]
    plan: Optional[dict[str, Any]] = None
    plan_error: Optional[str] = None
    picture_url: Optional[str] = Field(default=None, description="The scene through its camera (PNG), made with "
                                       "its plan; None while the plan is pending, or when it failed.")
    field_of_view_box: Optional[FieldOfViewBox] = Field(
        default=None, description="Where the hologram's view lies in that picture at the plan's (the default "
                                  "display's) optics; POST /v1/jobs/estimate gives it at a request's.")


class DisplayOut(BaseModel):
    name: str
    owner: Optional[str] = None
    last_seen: str
    age_s: float
    agent_version: Optional[str] = None
    showing: Optional[dict[str, Any]] = None
    state: Optional[str] = None
    message: Optional[str] = None


class DisplayList(BaseModel):
    displays: list[DisplayOut]


class Problem(BaseModel):
    """RFC 9457 problem details (media type application/problem+json)."""

    type: str = "about:blank"
    title: str
    status: int
    detail: str
    instance: Optional[str] = None


def effective_optics(req: JobRequest) -> OpticsConfig:
    """The optics the job renders with (``frames`` applied)."""
    if req.frames is None:
        return req.optics
    return req.optics.model_copy(update={"frames": req.frames})


def cache_key(req: JobRequest, *, scene_sha256: str, entry: str, code_version: str,
              max_spp: Optional[int] = None) -> str:
    """Content address of a job's result: scene content + optics + options + code version (not the display).
    ``max_spp``: the clamp on the preset's choice of spp (:func:`binding_max_spp`), when there is one."""
    # every job field (service.jobfiles.JobFields) but frames, which the effective optics hold, and the asked
    # max_spp, whose effect is the binding clamp: a field added there is part of the address without a line
    # here, so no two jobs that differ in one share a result
    fields = {k: v for k, v in req.fields().items() if k not in ("frames", "max_spp")}
    doc = {"scene": scene_sha256, "entry": entry, "optics": effective_optics(req).model_dump(mode="json"),
           "fields": fields, "code": code_version, **({"max_spp": max_spp} if max_spp is not None else {})}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()
