"""The files a job's run is made of, typed: the job's options as stored (``jobs.spec``), ``job.json`` (what the
scheduler asks the driver to do), ``status.json`` (how the driver says the run ended) and the steps and render
stages the progress files name. Shared by the API (which stores the spec), the scheduler and the driver; light
imports only (pydantic, and holocore.options). Files written by earlier versions still read: fields added since
have defaults."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, Optional, TypedDict, Union, get_args

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from holocore.options import HologramOptions, WrpPlanes
from service.untrusted import read_job_json

__all__ = ["Step", "STEPS", "RenderStage", "RENDER_STAGES", "JobFields", "JobOptions", "JobSpec", "JobFile",
           "ArtifactInfo",
           "RunStatus", "Progress", "read_job_file", "read_run_status"]

# "evaluate" runs only for a job that asks for it (JobFields.evaluate), after the preview and pictures it pairs
# its ground truth with.
Step = Literal["render", "encode", "package", "preview", "pictures", "evaluate"]
STEPS: tuple[Step, ...] = get_args(Step)
# The stages `holo render` reports (holocore.pipeline: "analysis" once, "trace" per tile, "propagate" per frame
# chunk), in order. Ray banks and the ambient cache are built between "analysis" and the first "trace" tile
# and report nothing of their own.
RenderStage = Literal["analysis", "trace", "propagate"]
RENDER_STAGES: tuple[RenderStage, ...] = get_args(RenderStage)

class JobFields(HologramOptions):
    """What a job renders and encodes besides its optics: holocore's options (``holocore.options.HologramOptions``:
    units, limits and rules written there once) and the service's own ``evaluate``. The request
    (``service.models.JobRequest``), the stored spec and ``job.json`` inherit it; the driver hands the options to
    the CLIs as one JSON document (``service.workers.driver``), so a field added in holocore reaches every hop."""

    model_config = ConfigDict(frozen=False, extra="ignore")
    evaluate: bool = Field(
        default=False, description="Also score the hologram against Mitsuba thin-lens ground truth (holo evaluate) at "
        "the focal sweep's depths and a 3 x 3 grid of views, and, for more than one frame, the viewer-faithful score; "
        "GET /v1/jobs/{id}/evaluation. A failed evaluation is a warning, not a failed job.")

    def fields(self) -> dict[str, Any]:
        """The job fields alone (no optics, no run fields), as JSON."""
        return self.model_dump(mode="json", include=set(JobFields.model_fields))


class JobOptions(JobFields):
    """The job fields as stored and handed to the driver (a checked ``JobRequest``'s, and the service's spp cap)."""

    model_config = ConfigDict(frozen=True, extra="ignore")
    wrp_planes: WrpPlanes = 1  # jobs stored before the option rendered one plane

    def options(self) -> dict[str, Any]:
        """The options alone (no optics, no run fields)."""
        return self.model_dump(mode="json", include=set(JobOptions.model_fields))


class JobSpec(JobOptions):
    """A job's ``spec`` column (shown as its ``options``): the options and the effective optics (OpticsConfig
    as JSON)."""

    optics: dict[str, Any]


class JobFile(JobOptions):
    """``JOB_DIR/job.json``: one run (attempt) of a job, as the scheduler hands it to the driver."""

    job_id: str
    attempt: Optional[int] = None  # files from before attempts were recorded
    scene_path: str
    keep_result: bool = True
    # the kernel resource limits the driver lowers its own to first (service/workers/limits.py ProcessLimits)
    limits: Optional[dict[str, int]] = None
    # each step's predicted seconds (the job's estimate, service.cost): its progress is weighed by them
    step_seconds: Optional[dict[str, float]] = None


class ArtifactInfo(BaseModel):
    model_config = ConfigDict(frozen=True)
    sha256: str
    bytes: int


class RunStatus(BaseModel):
    """``JOB_DIR/status.json``, the driver's word on how a run ended (never trusted for integrity: the scheduler
    hashes the artifacts itself)."""

    model_config = ConfigDict(frozen=True, extra="ignore")
    ok: bool = False
    error: Optional[str] = None
    retryable: Optional[bool] = None
    stack_sha256: Optional[str] = None
    stack_bytes: Optional[int] = None
    shape_fchw: Optional[list[int]] = None
    artifacts: dict[str, ArtifactInfo] = Field(default_factory=dict)
    timings: dict[str, Union[int, float]] = Field(default_factory=dict)
    plan: Optional[dict[str, Any]] = None
    warnings: list[str] = Field(default_factory=list)
    total_s: Optional[float] = None
    uid: Optional[int] = None
    attempt: Optional[int] = None

    def to_json(self) -> dict[str, Any]:
        """The fields that were set, as JSON (what status.json holds)."""
        return self.model_dump(mode="json", exclude_unset=True)


class Progress(TypedDict):
    """A job's ``progress`` (database column, API field, SSE ``progress`` event): the step, the stage it last
    reported, its counts, and the fraction of the whole run done."""

    step: str
    stage: str
    done: int
    total: int
    fraction: float


def read_job_file(job_dir: Path) -> JobFile:
    """``job_dir/job.json`` (OSError, ValueError when missing or not a job file; read as a job's files are,
    service/untrusted.py)."""
    return JobFile.model_validate(read_job_json(job_dir, "job.json"))


def read_run_status(job_dir: Path, attempt: Optional[int] = None) -> Optional[RunStatus]:
    """``job_dir/status.json`` if it is a run status (written by run ``attempt`` when given: not by a stale
    earlier run), else None."""
    try:
        status = RunStatus.model_validate(read_job_json(job_dir, "status.json"))
    except (OSError, ValueError, ValidationError):
        return None
    if attempt is not None and status.attempt != attempt:
        return None
    return status
