"""What a job submission must pass before anything is created (limits, the scene and display being the
submitter's, sane optics, memory that fits), and which earlier result a submission would reuse. One home for
both, used by ``POST /v1/jobs`` and its dry run ``POST /v1/jobs/estimate``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from service.api.context import ServiceContext
from service.api.problems import ApiError
from service.auth import Principal
from service.integrity import artifact_intact
from service.models import (JobRequest, effective_optics, job_limit_errors, memory_admission_error,
                            optics_sanity_errors)

__all__ = ["admit_job", "reusable_job"]


def admit_job(ctx: ServiceContext, req: JobRequest, principal: Principal) -> dict:
    """The job's scene row when ``principal`` may submit ``req``; else ApiError (422, or 403 for a display of
    another owner) saying what to change."""
    errs = job_limit_errors(req, ctx.settings.job_limits)
    if errs:
        raise ApiError(422, "; ".join(errs))
    scene = ctx.db.get_scene(req.scene_id)
    if scene is None or not (principal.is_admin or ctx.db.scene_owned_by(req.scene_id, principal.owner)):
        raise ApiError(422, f"scene_id: no scene {req.scene_id!r}; upload it with POST /v1/scenes first")
    if req.display is not None:
        holder = ctx.db.display_owner(req.display)
        if holder is not None and not principal.sees(holder):
            raise ApiError(403, f"display {req.display!r} is registered to another owner; jobs for it come from "
                                "that owner's tokens")
    optics_errs = optics_sanity_errors(effective_optics(req))
    if optics_errs:
        raise ApiError(422, "; ".join(optics_errs))
    too_big = memory_admission_error(req, ctx.settings.worker_memory_bytes)
    if too_big:
        raise ApiError(422, too_big)
    return scene


def reusable_job(ctx: ServiceContext, key: str) -> Optional[dict]:
    """The newest succeeded job with the content address ``key`` whose artifacts all still match their hashes."""
    for prev in ctx.db.query("SELECT * FROM jobs WHERE cache_key = ? AND state = 'succeeded' "
                             "ORDER BY finished_at DESC LIMIT 5", (key,)):
        d = Path(prev["artifact_dir"] or "")
        others = [(d / name, info.get("sha256")) for name, info in (prev["artifacts"] or {}).items()]
        if all(artifact_intact(p, sha) for p, sha in [(d / "stack.npz", prev["stack_sha256"]), *others]):
            return prev
    return None
