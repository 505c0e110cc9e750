"""Sweeps: one job per value of one option, every other option the same (``POST /v1/sweeps``), read back as a
table of predicted and measured quality and time per value (``GET /v1/sweeps/{id}``), and cancelled together
(``DELETE /v1/sweeps/{id}``). Each job goes through the submission of ``POST /v1/jobs`` (its limits, its
estimate, content-addressed reuse); a sweep with any value that would be refused creates no job at all.

A sweep is a row of the ``sweeps`` table: its owner and a JSON ``doc`` {"option", "values", "jobs"} (the job
ids in the order of the values). A job deleted later is left out of its sweep's answers."""

from __future__ import annotations

import json
import secrets
import time
from typing import Any, Optional

from fastapi import APIRouter, Query
from fastapi import Path as PathParam
from fastapi.responses import JSONResponse
from pydantic import ValidationError

from service.api import submission
from service.api.context import ServiceContext
from service.api.deps import Ctx, ReadScope, SubmitScope
from service.api.problems import PROBLEM_RESPONSES, ApiError
from service.api.scenes import iso
from service.auth import Principal
from service.db import FINAL_STATES
from service.models import ID_PATTERN, JobRequest, SweepCreated, SweepList, SweepOut, SweepRequest
from service.quality import measured_psnr

__all__ = ["router", "sweep_out", "sweep_of"]

router = APIRouter(tags=["sweeps"])
_NAME_MOST = 120


def _label(value: Any) -> str:
    return json.dumps(value) if not isinstance(value, str) else value


def _requests(body: SweepRequest) -> list[JobRequest]:
    """One job request per value (422 naming the first value the job's model refuses, or a repeated one)."""
    seen: set[str] = set()
    base = body.job.model_dump(mode="json", exclude_unset=True)
    name = body.job.name or "sweep"
    out = []
    for value in body.values:
        key = json.dumps(value, sort_keys=True)
        if key in seen:
            raise ApiError(422, f"values: {body.option}={_label(value)} is given twice; each value once")
        seen.add(key)
        suffix = f" · {body.option}={_label(value)}"
        try:
            req = JobRequest.model_validate({**base, body.option: value,
                                             "name": name[: max(1, _NAME_MOST - len(suffix))] + suffix})
        except ValidationError as err:
            why = "; ".join(f"{'.'.join(str(p) for p in e['loc']) or body.option}: {e['msg']}" for e in err.errors())
            raise ApiError(422, f"{body.option}={_label(value)} is refused: {why}") from None
        out.append(req)
    return out


def _admit_all(ctx: ServiceContext, body: SweepRequest, reqs: list[JobRequest], principal: Principal) -> None:
    """Every check a submit makes before it creates a job, for every value; nothing is created on a refusal."""
    for value, req in zip(body.values, reqs):
        try:
            resolved, _ = submission.resolve_target(ctx, req, principal)
            submission.admit_job(ctx, resolved, principal)
        except ApiError as err:
            raise ApiError(422, f"{body.option}={_label(value)} is refused: {err.detail}") from None
    cap = ctx.settings.max_queued_jobs_per_owner
    have = ctx.db.count_owner_jobs(principal.owner, ("queued", "running"))
    if have + len(reqs) > cap:
        raise ApiError(429, f"this owner has {have} jobs queued or running and the sweep adds {len(reqs)}, past "
                            f"the {cap} it may have; submit it when some have finished", headers={"Retry-After": "30"})


def _cancel(ctx: ServiceContext, job_ids: list[str]) -> int:
    """Cancel those of ``job_ids`` that are queued or running; returns how many."""
    n = 0
    for jid in job_ids:
        row = ctx.db.get_job(jid)
        if row is None or row["state"] in FINAL_STATES:
            continue
        if ctx.db.update_job(jid, where_state=("queued", "running"), state="cancelled", finished_at=time.time()):
            n += 1
            ctx.metrics.jobs_finished.labels(state="cancelled").inc()
            if row["state"] == "running":
                ctx.wake_scheduler()
    return n


@router.post("/v1/sweeps", status_code=202, response_model=SweepCreated, responses=PROBLEM_RESPONSES)
def submit_sweep(body: SweepRequest, ctx: Ctx, principal: SubmitScope):
    """Queue one job per value of ``option`` (2 to 12 values), every other option ``job``'s. Each job is
    submitted as by ``POST /v1/jobs``; when any value would be refused, the sweep is refused (422 naming it)
    and no job is created."""
    reqs = _requests(body)
    _admit_all(ctx, body, reqs, principal)
    made: list[str] = []
    try:
        for req in reqs:
            job = submission.submit_job(ctx, req, principal).job
            if job["spec"].get("name") != req.name:  # a reused result: the name is for people, not the address
                ctx.db.update_job(job["id"], spec={**job["spec"], "name": req.name})
            made.append(job["id"])
    except ApiError as err:  # a limit that only the jobs made before it reach (storage): none of them stays
        _cancel(ctx, made)
        for jid in made:
            ctx.db.delete_job(jid, where_state=FINAL_STATES)
        raise ApiError(err.status, f"{body.option}={_label(body.values[len(made)])} is refused: {err.detail}; "
                                   "the sweep made no job", headers=err.headers) from None
    sid = "w" + secrets.token_hex(10)
    doc = {"option": body.option, "values": body.values, "jobs": made}
    ctx.db.execute("INSERT INTO sweeps (id, owner, doc, created_at) VALUES (?, ?, ?, ?)",
                   (sid, principal.owner, json.dumps(doc), time.time()))
    return JSONResponse({"id": sid, **doc, "links": {"self": f"/v1/sweeps/{sid}"}}, status_code=202,
                        headers={"Location": f"/v1/sweeps/{sid}"})


def _owned(ctx: ServiceContext, sweep_id: str, principal: Principal) -> dict:
    row = ctx.db.one("SELECT * FROM sweeps WHERE id = ?", (sweep_id,))
    if row is None or not principal.sees(row["owner"]):
        raise ApiError(404, f"no sweep {sweep_id!r}")
    return {**row, "doc": json.loads(row["doc"])}


def _job_entry(row: dict, value: Any) -> dict:
    est = row["estimate"] if isinstance(row["estimate"], dict) else {}
    quality = est.get("quality") if isinstance(est.get("quality"), dict) else {}
    timings = row["timings"] if isinstance(row["timings"], dict) else {}
    spec = row["spec"] if isinstance(row["spec"], dict) else {}
    measured, kind = measured_psnr(row)
    return {"id": row["id"], "value": value, "name": spec.get("name"), "state": row["state"],
            "progress": row["progress"], "estimate_s": est.get("seconds"),
            "predicted_psnr_db": quality.get("psnr_db"), "predicted_uncertainty_db": quality.get("uncertainty_db"),
            "run_s": timings.get("run_s"), "measured_psnr_db": measured, "measured_kind": kind,
            "error": row["error"]}


def sweep_of(ctx: ServiceContext, row: dict) -> Optional[str]:
    """The id of the sweep that made the job (``row``), else None."""
    # a sweep lists only jobs it made for its own owner: the job's id alone finds it
    hit = ctx.db.one("SELECT s.id FROM sweeps s, json_each(s.doc, '$.jobs') j WHERE j.value = ? LIMIT 1",
                     (row["id"],))
    return hit["id"] if hit else None


def sweep_out(ctx: ServiceContext, row: dict) -> dict:
    doc = row["doc"]
    jobs = []
    for jid, value in zip(doc["jobs"], doc["values"]):
        job = ctx.db.get_job(jid)
        if job is not None:
            jobs.append(_job_entry(job, value))
    return {"id": row["id"], "option": doc["option"], "values": doc["values"], "created_at": iso(row["created_at"]),
            "jobs": jobs}


@router.get("/v1/sweeps", response_model=SweepList, responses=PROBLEM_RESPONSES)
def list_sweeps(ctx: Ctx, principal: ReadScope, limit: int = Query(default=20, ge=1, le=50)):
    """The owner's sweeps, newest first, each with its jobs as ``GET /v1/sweeps/{id}`` gives them."""
    if principal.is_admin:
        rows = ctx.db.query("SELECT * FROM sweeps ORDER BY created_at DESC, rowid DESC LIMIT ?", (limit,))
    else:
        rows = ctx.db.query("SELECT * FROM sweeps WHERE owner = ? ORDER BY created_at DESC, rowid DESC LIMIT ?",
                            (principal.owner, limit))
    return JSONResponse({"sweeps": [sweep_out(ctx, {**r, "doc": json.loads(r["doc"])}) for r in rows]})


@router.get("/v1/sweeps/{sweep_id}", response_model=SweepOut, responses=PROBLEM_RESPONSES)
def get_sweep(ctx: Ctx, principal: ReadScope, sweep_id: str = PathParam(pattern=ID_PATTERN)):
    """The swept option and values, and per job its state and progress, the estimate's seconds and predicted
    quality, the measured run time and, once evaluated, the measured quality."""
    return JSONResponse(sweep_out(ctx, _owned(ctx, sweep_id, principal)))


@router.delete("/v1/sweeps/{sweep_id}", status_code=202, response_model=SweepOut, responses=PROBLEM_RESPONSES)
def cancel_sweep(ctx: Ctx, principal: SubmitScope, sweep_id: str = PathParam(pattern=ID_PATTERN)):
    """Cancel every job of the sweep that is queued or running (the finished ones stay as they are)."""
    row = _owned(ctx, sweep_id, principal)
    _cancel(ctx, row["doc"]["jobs"])
    return JSONResponse(sweep_out(ctx, row), status_code=202)
