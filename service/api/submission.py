"""The service's job logic, apart from HTTP: what a submission must pass before anything is created (limits,
the scene and display being the submitter's, sane optics, memory that fits), which earlier result it would
reuse, and the submission itself (idempotency keys, content-addressed reuse, the new job row). Used by
``POST /v1/jobs`` and its dry run ``POST /v1/jobs/estimate``; the SQL is service/db.py's."""

from __future__ import annotations

import hashlib
import os
import re
import secrets
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from service.api.context import ServiceContext
from service.api.problems import ApiError
from service.auth import Principal
from service.db import FINAL_STATES
from service.integrity import artifact_intact
from service.jobfiles import JobSpec
from service.cost import (
    calibration_or_none,
    estimate_cost,
    hologram_seconds,
    memory_admission_error,
    output_bytes,
    plane_border_px,
)
from service.job_rules import binding_max_spp, job_limit_errors, optics_sanity_errors, spp_cap
from service.models import JobRequest, cache_key, effective_optics
from service.settings import JobLimits
from service.quality import resolve_quality_target

__all__ = ["admit_job", "busy_threads", "resolve_target", "reusable_job", "scene_plane_border", "job_spec",
           "submit_job", "Submitted",
           "IDEMPOTENCY_KEY", "output_bytes", "owner_stored_bytes", "storage_error"]

IDEMPOTENCY_KEY = re.compile(r"^[\x21-\x7e]{1,200}$")


@dataclass(frozen=True)
class Submitted:
    """The outcome of a submit: the job's row, and whether it is an earlier submit's (same idempotency key)."""

    job: dict[str, Any]
    replayed: bool = False


def admit_job(ctx: ServiceContext, req: JobRequest, principal: Principal) -> dict:
    """The job's scene row when ``principal`` may submit ``req``; else ApiError (422) saying what to change."""
    errs = job_limit_errors(req, ctx.settings.job_limits)
    if errs:
        raise ApiError(422, "; ".join(errs))
    scene = ctx.db.get_scene(req.scene_id)
    if scene is None or not (principal.is_admin or ctx.db.scene_owned_by(req.scene_id, principal.owner)):
        raise ApiError(422, f"scene_id: no scene {req.scene_id!r}; upload it with POST /v1/scenes first")
    if scene["plan_state"] == "failed":  # Mitsuba could not load it (or crashed): a job would fail the same way
        raise ApiError(422, f"scene_id: scene {req.scene_id!r} cannot be rendered, its plan failed: "
                            f"{scene['plan_error'] or 'no message'}; fix the scene and upload it again")
    # A job's display is not checked against the displays' owners: whether a name is another owner's or free
    # gets the same answer (no probing for other owners' displays), and a job reaches only its own owner's
    # agents (GET /v1/jobs lists an owner's jobs), so naming a foreign display shows it nowhere.
    optics_errs = optics_sanity_errors(effective_optics(req))
    if optics_errs:
        raise ApiError(422, "; ".join(optics_errs))
    too_big = memory_admission_error(req, ctx.settings.worker_memory_bytes,
                                     plane_border=scene_plane_border(ctx, req, scene))
    if too_big:
        raise ApiError(422, too_big)
    return scene


def busy_threads(ctx: ServiceContext) -> float:
    """The machine's load that this service's own running jobs make (each job's steps keep every core busy):
    a new job queues behind them rather than running beside them, so an estimate leaves it out."""
    return float(ctx.db.count_jobs()["running"] * (os.cpu_count() or 1))


def resolve_target(ctx: ServiceContext, req: JobRequest, principal: Principal) -> tuple[JobRequest, Optional[float]]:
    """(the request with its ``quality_db`` resolved into frames, spp and iterations within the service's limits
    (service/quality.py), the target); the request itself and None without a target. The scene's plan informs
    the choice where the principal may read it; admission then checks the resolved request as any other."""
    if req.quality_db is None:
        return req, None

    scene = ctx.db.get_scene(req.scene_id)
    mine = scene is not None and (principal.is_admin or ctx.db.scene_owned_by(req.scene_id, principal.owner))
    plan = scene["plan"] if mine and scene["plan_state"] == "ready" else None
    limits = ctx.settings.job_limits

    def allowed(r: JobRequest) -> bool:
        return not job_limit_errors(r, limits) and memory_admission_error(r, ctx.settings.worker_memory_bytes) is None

    max_spp = binding_max_spp(req, limits)
    cal = calibration_or_none()  # read once for every candidate
    resolved = resolve_quality_target(req, scene_plan=plan, max_spp=max_spp, allowed=allowed,
                                      seconds_of=lambda r: hologram_seconds(r, scene_plan=plan, max_spp=max_spp,
                                                                            calibration=cal))
    return resolved, req.quality_db


def scene_plane_border(ctx: ServiceContext, req: JobRequest, scene: dict) -> Optional[int]:
    """The widest border of the job's deeper recording planes on this scene (None while its plan is pending:
    the scheduler checks the memory again before the job runs). ApiError (422) when the plane count the job asks
    for cannot fit the render's memory budget (the CLI's line, with the figure)."""
    try:
        return plane_border_px(req, scene_plan=scene["plan"], plan_state=scene["plan_state"],
                               limits=ctx.settings.job_limits)
    except ValueError as exc:
        raise ApiError(422, str(exc)) from None


def reusable_job(ctx: ServiceContext, key: str, owner: str, *, fresh: bool = False) -> Optional[dict]:
    """The newest succeeded job of ``owner`` with the content address ``key`` whose artifacts all still match
    their hashes (another owner's identical job is never reused: its id, timing and existence are theirs).
    ``fresh``: the files are hashed now, not taken from the cache (a submit that hands them to a new job)."""
    for prev in ctx.db.succeeded_jobs_with_key(key, owner=owner, limit=5):
        d = Path(prev["artifact_dir"] or "")
        others = [(d / name, info.get("sha256")) for name, info in (prev["artifacts"] or {}).items()]
        if all(artifact_intact(p, sha, fresh=fresh) for p, sha in [(d / "stack.npz", prev["stack_sha256"]), *others]):
            return prev
    return None


def job_spec(req: JobRequest, limits: JobLimits) -> JobSpec:
    """The job's stored options (its ``spec``): the effective optics and the request's render options (a
    time-limited render's spp is its cap: the request's, else the service's max_spp; a preset's own choice of
    spp is clamped to max_spp: ``max_spp``)."""
    timed = req.render_time_limit_s is not None
    return JobSpec(optics=effective_optics(req).model_dump(mode="json"),
                   **{**req.fields(), "spp": spp_cap(req, limits) if timed else req.spp,
                      "max_spp": binding_max_spp(req, limits)})


# ---- what an owner stores ----------------------------------------------------------------------------------
_finished_bytes: dict[str, tuple[int, int]] = {}  # a finished job's folder -> (its mtime_ns, bytes in it)


def _folder_bytes(folder: str) -> int:
    total = 0
    for dirpath, _dirs, files in os.walk(folder):  # never follows a symlinked folder
        for name in files:
            try:
                st = os.lstat(os.path.join(dirpath, name))
            except OSError:
                continue
            total += st.st_size
    return total


def _finished_folder_bytes(folder: str) -> int:
    try:
        mtime = os.stat(folder).st_mtime_ns
    except OSError:
        return 0
    hit = _finished_bytes.get(folder)
    if hit is None or hit[0] != mtime:
        hit = _finished_bytes[folder] = (mtime, _folder_bytes(folder))
    return hit[1]


def owner_stored_bytes(ctx: ServiceContext, owner: str) -> int:
    """What ``owner`` stores: its scenes' bundles, its finished jobs' folders (each folder once, while any of the
    owner's jobs holds it: a reused result keeps its folder on the disk after the job that computed it is
    deleted), for each queued or running job the most its run will leave, and a running job's scratch files.
    (A new job is checked with its own scratch: while it runs it holds that much too.)"""
    total = ctx.db.owner_scene_bytes(owner)
    counted: set[str] = set()
    for row in ctx.db.owner_job_folders(owner):
        folder = row["artifact_dir"] or ""
        if row["state"] in FINAL_STATES:
            if folder and folder not in counted:
                counted.add(folder)
                total += _finished_folder_bytes(folder)
        else:  # a running job's scratch is on the disk now; a queued job's only once it runs
            spec = row["spec"] or {}
            border = (((row.get("estimate") or {}).get("memory") or {}).get("plane_border_px"))
            total += output_bytes(spec.get("optics") or {}, keep_result=ctx.settings.keep_result,
                                  wrp_planes=spec.get("wrp_planes", 1),
                                  plane_border=border if row["state"] == "running" else 0,
                                  evaluate=bool(spec.get("evaluate")))
    return total


def storage_error(ctx: ServiceContext, owner: str, adding: int, what: str) -> Optional[ApiError]:
    """The 403 for an upload or job of ``adding`` bytes that would take ``owner`` past what it may store."""
    cap = ctx.settings.stored_bytes_per_owner
    stored = owner_stored_bytes(ctx, owner)
    if stored + adding <= cap:
        return None
    return ApiError(403, f"this owner stores {stored / 1e9:.2f} GB of scenes and job results (counting what its "
                         f"queued jobs will write) and {what} adds up to {adding / 1e9:.2f} GB, past the "
                         f"{cap / 1e9:.3g} GB one owner may store (max_stored_gb_per_owner): delete finished jobs "
                         "it no longer needs")


def _job(ctx: ServiceContext, job_id: str) -> dict:
    row = ctx.db.get_job(job_id)
    if row is None:
        raise ApiError(404, f"no job {job_id!r}")
    return row


def _replay(ctx: ServiceContext, prior: Optional[dict], body_hash: str) -> Submitted:
    if prior is None or prior["body_hash"] != body_hash:
        raise ApiError(422, "Idempotency-Key was used before with a different request body")
    return Submitted(_job(ctx, prior["job_id"]), replayed=True)


def submit_job(ctx: ServiceContext, req: JobRequest, principal: Principal,
               idempotency_key: Optional[str] = None) -> Submitted:
    """Queue a render job for ``principal`` (or record it succeeded at once, reusing an identical earlier result
    whose artifacts are intact). The same ``idempotency_key`` with the same body gives the first job back
    (``replayed``); with another body, ApiError 422. Admission failures are :func:`admit_job`'s."""
    if idempotency_key is not None and not IDEMPOTENCY_KEY.match(idempotency_key):
        raise ApiError(422, "Idempotency-Key must be 1-200 visible ASCII characters")
    body_hash = hashlib.sha256(req.model_dump_json().encode()).hexdigest()
    req, target_db = resolve_target(ctx, req, principal)
    scene = admit_job(ctx, req, principal)
    cap = ctx.settings.max_queued_jobs_per_owner
    if ctx.db.count_owner_jobs(principal.owner, ("queued", "running")) >= cap:
        raise ApiError(429, f"this owner has {cap} jobs queued or running, the most it may; submit more when "
                            "some have finished", headers={"Retry-After": "30"})
    if idempotency_key is not None:
        prior = ctx.db.get_idempotency(principal.token_id, idempotency_key)
        if prior is not None:
            return _replay(ctx, prior, body_hash)
    max_spp = binding_max_spp(req, ctx.settings.job_limits)
    key = cache_key(req, scene_sha256=scene["sha256"], entry=scene["entry"], code_version=ctx.code_version,
                    max_spp=max_spp)
    job_id = "j" + secrets.token_hex(10)
    now = time.time()
    row = {"id": job_id, "state": "queued", "display": req.display, "scene_id": req.scene_id,
           "spec": job_spec(req, ctx.settings.job_limits).model_dump(mode="json"), "cache_key": key, "created_at": now,
           "estimate": estimate_cost(req, scene_plan=scene["plan"], max_spp=max_spp,
                                     plane_border=scene_plane_border(ctx, req, scene), target_db=target_db,
                                     busy_threads=busy_threads(ctx)),
           "token_id": principal.token_id,
           "owner": principal.owner, "artifact_dir": str(ctx.settings.jobs_dir / job_id),
           "plan": {"summary": (scene["plan"] or {}).get("summary", []),
                    "source": "scene plan at default optics" if scene["plan"] else "pending"}}
    prev = reusable_job(ctx, key, principal.owner, fresh=True)
    if prev is None:  # a reused result adds nothing; a new run writes its outputs
        need = output_bytes(row["spec"]["optics"], keep_result=ctx.settings.keep_result, wrp_planes=req.wrp_planes,
                            plane_border=row["estimate"]["memory"]["plane_border_px"], evaluate=bool(req.evaluate))
        full = storage_error(ctx, principal.owner, need, "this job")
        if full is not None:
            raise full
    if prev is not None:
        row.update(state="succeeded", started_at=now, finished_at=now, artifact_dir=prev["artifact_dir"],
                   stack_sha256=prev["stack_sha256"], stack_bytes=prev["stack_bytes"], plan=prev["plan"],
                   artifacts=prev["artifacts"], reused_from=prev["reused_from"] or prev["id"],
                   timings={"reused": True}, progress={"step": "done", "stage": "reused", "done": 1, "total": 1,
                                                       "fraction": 1.0})
    try:
        with ctx.db.tx() as conn:
            ctx.db.insert_job(row, conn)
            if idempotency_key is not None:
                ctx.db.insert_idempotency(conn, token_id=principal.token_id, key=idempotency_key,
                                          body_hash=body_hash, job_id=job_id, created_at=now)
    except sqlite3.IntegrityError:  # a concurrent request with the same key won
        return _replay(ctx, ctx.db.get_idempotency(principal.token_id, idempotency_key or ""), body_hash)
    ctx.metrics.jobs_submitted.labels(reused=str(prev is not None).lower()).inc()
    ctx.wake_scheduler()
    return Submitted(_job(ctx, job_id))
