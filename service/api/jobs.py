"""Job routes: submit (202, idempotent, content-addressed reuse), list, status, events (SSE), cancel, delete, the
steps' logs, and the artifacts (stack with ETag/Range, 8-bit frames zip, preview PNG)."""

from __future__ import annotations

import asyncio
import json
import shutil
import time
from pathlib import Path
from typing import Literal, Optional

from fastapi import APIRouter, Header, Query, Request, Response
from fastapi import Path as PathParam
from fastapi.responses import JSONResponse, PlainTextResponse, StreamingResponse
from starlette.concurrency import run_in_threadpool

from holocore.display.optics import OpticsConfig
from holocore.scene.errors import scrub_message
from service.api import submission
from service.api.context import ServiceContext
from service.api.deps import Ctx, ReadScope, SubmitScope, owned_job
from service.api.files import file_response
from service.api.job_live import live_doc
from service.api.problems import PROBLEM_RESPONSES, ApiError
from service.api.scenes import iso
from service.api.sweeps import sweep_of
from service.auth import Principal
from service.db import FINAL_STATES
from service.integrity import artifact_intact
from service.models import ID_PATTERN, NAME_PATTERN, JobList, JobOut, JobRequest
from service.quality import quality_flag
from service.scene_view import scene_field_of_view_box
from service.untrusted import read_job_tail

__all__ = ["router", "job_out"]

router = APIRouter(tags=["jobs"])
_ARTIFACTS = {"stack": ("stack.npz", "application/octet-stream"), "frames": ("frames.zip", "application/zip"),
              "preview": ("preview.png", "image/png")}


def job_out(row: dict) -> dict:
    jid = row["id"]
    links = {"self": f"/v1/jobs/{jid}", "events": f"/v1/jobs/{jid}/events"}
    if row["state"] == "succeeded":
        links.update(stack=f"/v1/jobs/{jid}/stack", frames=f"/v1/jobs/{jid}/frames.zip",
                     preview=f"/v1/jobs/{jid}/preview.png", phase=f"/v1/jobs/{jid}/phase",
                     send=f"/v1/jobs/{jid}/display")
    spec = row["spec"] if isinstance(row["spec"], dict) else {}
    if row["state"] == "succeeded" and spec.get("evaluate"):
        links["evaluation"] = f"/v1/jobs/{jid}/evaluation"
    return {"id": jid, "name": spec.get("name"), "state": row["state"], "display": row["display"],
            "scene_id": row["scene_id"],
            "created_at": iso(row["created_at"]), "started_at": iso(row["started_at"]),
            "finished_at": iso(row["finished_at"]), "stack_sha256": row["stack_sha256"],
            "stack_bytes": row["stack_bytes"], "options": row["spec"], "progress": row["progress"],
            "timings": row["timings"], "plan": row["plan"], "error": row["error"], "attempts": row["attempts"],
            "worker_pid": row["worker_pid"] if row["state"] == "running" else None, "estimate": row["estimate"],
            "reused_from": row["reused_from"], "cache_key": row["cache_key"], "sent_at": iso(row.get("sent_at")),
            "quality": quality_flag(row), "links": links}


def _accepted(row: dict, *, replayed: bool = False) -> JSONResponse:
    headers = {"Location": f"/v1/jobs/{row['id']}"}
    if replayed:
        headers["Idempotent-Replayed"] = "true"
    return JSONResponse(job_out(row), status_code=202, headers=headers)


@router.post("/v1/jobs", status_code=202, response_model=JobOut, responses=PROBLEM_RESPONSES)
def submit_job(
    req: JobRequest,
    ctx: Ctx,
    principal: SubmitScope,
    idempotency_key: Optional[str] = Header(default=None, alias="Idempotency-Key",
                                            description="Repeat a submit safely: same key + same body = same job."),
):
    """Queue a render job (202 + Location). An identical earlier result (same scene content, optics, options
    and code version) is reused at once; ``estimate`` gives the predicted seconds."""
    done = submission.submit_job(ctx, req, principal, idempotency_key)
    job = done.job
    if req.name is not None and not done.replayed and job["spec"].get("name") != req.name:
        # the name is for people only: kept in the stored options, outside the content address
        ctx.db.update_job(job["id"], spec={**job["spec"], "name": req.name})
        job = owned_job(ctx, job["id"])
    return _accepted(job, replayed=done.replayed)


@router.get("/v1/jobs", response_model=JobList, responses=PROBLEM_RESPONSES)
async def list_jobs(
    ctx: Ctx,
    principal: ReadScope,
    state: Optional[Literal["queued", "running", "succeeded", "failed", "cancelled"]] = None,
    display: Optional[str] = Query(default=None, pattern=NAME_PATTERN),
    scene_id: Optional[str] = Query(default=None, pattern=ID_PATTERN),
    limit: int = Query(default=50, ge=1, le=500),
):
    """Jobs, newest first, filtered by state, display and scene; with ``display``, the jobs submitted for it or
    sent to it (POST /v1/jobs/{id}/display), the most recently sent first: the job it shows next."""
    rows = ctx.db.list_jobs(state=state, display=display, scene_id=scene_id, limit=limit,
                                         owner=None if principal.is_admin else principal.owner)
    return JSONResponse({"jobs": [job_out(r) for r in rows]})


@router.get("/v1/jobs/{job_id}", response_model=JobOut, responses=PROBLEM_RESPONSES)
async def get_job(ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """A job's state, progress, timings, plan and error."""
    # Polled by clients and agents: answered on the event loop (indexed reads) without re-validating the
    # body against JobOut (job_out builds exactly that shape; the schema tests check it).
    row = owned_job(ctx, job_id, principal)
    return JSONResponse({**job_out(row), "field_of_view_box": _job_fov_box(ctx, row),
                         "sweep_id": sweep_of(ctx, row)})


def _job_fov_box(ctx: ServiceContext, row: dict) -> Optional[dict]:
    """Where the hologram's view lies in the scene's picture at the job's optics (its stored spec's)."""
    scene = ctx.db.get_scene(row["scene_id"])
    spec = row["spec"] if isinstance(row["spec"], dict) else {}
    if scene is None or not isinstance(spec.get("optics"), dict):
        return None
    try:
        optics = OpticsConfig(**spec["optics"])
    except (TypeError, ValueError):
        return None
    return scene_field_of_view_box(scene, optics)


@router.delete("/v1/jobs/{job_id}", status_code=202, response_model=JobOut, responses=PROBLEM_RESPONSES)
def cancel_job(ctx: Ctx, principal: SubmitScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """Cancel a queued or running job (a running render's process group is killed)."""
    row = owned_job(ctx, job_id, principal)
    if not ctx.db.update_job(job_id, where_state=("queued", "running"), state="cancelled", finished_at=time.time()):
        raise ApiError(409, f"job {job_id} is already {owned_job(ctx, job_id)['state']}; only queued or running jobs "
                            "can be cancelled")
    ctx.metrics.jobs_finished.labels(state="cancelled").inc()
    if row["state"] == "running":
        ctx.wake_scheduler()
    return JSONResponse(job_out(owned_job(ctx, job_id)), status_code=202)


@router.post("/v1/jobs/{job_id}/delete", status_code=204, responses=PROBLEM_RESPONSES)
def delete_job(ctx: Ctx, principal: SubmitScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """Delete a finished (succeeded, failed or cancelled) job: its record, and its folder unless another job
    reuses that result. A queued or running job must be cancelled first (``DELETE /v1/jobs/{id}``)."""
    row = owned_job(ctx, job_id, principal)
    if row["state"] not in FINAL_STATES:
        raise ApiError(409, f"job {job_id} is {row['state']}; cancel it first (DELETE /v1/jobs/{job_id}), then "
                            "delete it")
    folder = Path(row["artifact_dir"] or "")
    if not ctx.db.delete_job(job_id, where_state=FINAL_STATES):
        raise ApiError(409, f"job {job_id} changed while it was being deleted; try again")
    jobs_dir = ctx.settings.jobs_dir.resolve()
    shared = ctx.db.jobs_with_artifact_dir(str(folder)) if row["artifact_dir"] else 1
    if not shared and folder.is_dir() and folder.resolve().parent == jobs_dir:
        shutil.rmtree(folder, ignore_errors=True)
    return Response(status_code=204)


_LOG_STEPS = ("render", "encode", "preview", "evaluate", "driver")  # the steps that run a process, and the driver
_LOG_TAIL_BYTES = 64 * 1024


def _log_text(path: Path, roots: list[str]) -> str:
    """The last 64 KiB of a step's log, each line with the job's folder shown relative and every other server
    path as ``<server path>`` (as the job's error says them)."""
    # While a sandboxed run goes on, its folder is its uid's and this process is root: the log may be swapped for
    # a link, a fifo or a hard link at any time, so it is read as every file of a job's is (service/untrusted.py).
    tail, size = read_job_tail(path.parent, path.name, tail_bytes=_LOG_TAIL_BYTES)
    data = tail.decode("utf-8", errors="replace")
    lines = data.splitlines()
    if size > _LOG_TAIL_BYTES and lines:
        lines = [f"[the first {size - _LOG_TAIL_BYTES} bytes are left out]", *lines[1:]]
    return "\n".join(scrub_message(ln, roots=roots, limit=4000) for ln in lines) + ("\n" if lines else "")


@router.get("/v1/jobs/{job_id}/logs", responses=PROBLEM_RESPONSES)
def job_logs(ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """The steps' logs the job has (render, encode, preview, evaluate: each step's output; driver), with their
    sizes and URLs. A reused result's logs are those of the job that computed it."""
    row = owned_job(ctx, job_id, principal)
    folder = Path(row["artifact_dir"] or "")
    out = []
    for step in _LOG_STEPS:
        p = folder / f"{step}.log"
        if row["artifact_dir"] and p.is_file() and not p.is_symlink():
            out.append({"step": step, "bytes": p.stat().st_size, "url": f"/v1/jobs/{job_id}/logs/{step}"})
    return JSONResponse({"logs": out})


@router.get("/v1/jobs/{job_id}/logs/{step}", responses={200: {"content": {"text/plain": {}}}, **PROBLEM_RESPONSES})
def job_log(ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN),
            step: Literal[_LOG_STEPS] = PathParam()):
    """One step's log as text (its last 64 KiB; server paths replaced by ``<server path>``)."""
    row = owned_job(ctx, job_id, principal)
    folder = Path(row["artifact_dir"] or "")
    p = folder / f"{step}.log"
    if not row["artifact_dir"] or not p.is_file() or p.is_symlink():
        raise ApiError(404, f"job {job_id} has no {step} log (yet)")
    try:
        text = _log_text(p, [str(folder), str(folder.resolve())])
    except OSError:  # a sandboxed run's folder is its slot's until the run ends
        raise ApiError(404, f"job {job_id}'s {step} log cannot be read while the job runs sandboxed") from None
    return PlainTextResponse(text, headers={"Cache-Control": "no-cache"})


@router.get("/v1/jobs/{job_id}/live", responses=PROBLEM_RESPONSES)
def job_live(ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """What the job is doing: its effect plan as soon as there is one (``source`` "render": its render's, also
    while the later steps run; else the scene's plan at the job's options), each step's estimated and actual
    seconds and state, the running step, the seconds run and left, the running step's last 40 log lines and the
    worker's CPU seconds and resident memory (its process group's). The event stream sends it as ``live``."""
    return JSONResponse(live_doc(ctx, owned_job(ctx, job_id, principal)), headers={"Cache-Control": "no-cache"})


def _sse(event: str, data: dict) -> str:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n"


@router.get("/v1/jobs/{job_id}/events", responses={200: {"content": {"text/event-stream": {}},
                                                         "description": "Server-sent events"}, **PROBLEM_RESPONSES})
async def job_events(request: Request, ctx: Ctx, principal: ReadScope,
                     job_id: str = PathParam(pattern=ID_PATTERN)):
    """Server-sent events: ``progress`` while running, ``state`` on every change, ``live`` (what
    ``GET /v1/jobs/{id}/live`` answers) at the start and about every second while it runs, and once more at the
    end; the stream ends when the job reaches succeeded, failed or cancelled."""
    await run_in_threadpool(owned_job, ctx, job_id, principal)
    held = _Held(ctx.streams_open, principal.owner, ctx.settings.max_streams_per_owner, job_id)

    async def stream():
        try:
            async for chunk in _events(request, ctx, job_id):
                yield chunk
        finally:
            held.release()

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


class _Held:
    """One of an owner's open event streams (``max_streams_per_owner``: each polls the database four times a
    second until its job ends); 429 when the owner holds as many. Released when the stream ends, or when a
    stream that never started is dropped."""

    def __init__(self, counts: dict, owner: str, cap: int, job_id: str) -> None:
        self.held = False
        if counts.get(owner, 0) >= cap:
            raise ApiError(429, f"this owner has {cap} event streams open, the most it may at once; close one or "
                                f"poll GET /v1/jobs/{job_id}", headers={"Retry-After": "10"})
        counts[owner] = counts.get(owner, 0) + 1
        self.counts, self.owner, self.held = counts, owner, True

    def release(self) -> None:
        if self.held:
            self.held = False
            self.counts[self.owner] -= 1
            if self.counts[self.owner] <= 0:
                del self.counts[self.owner]

    def __del__(self) -> None:
        self.release()


async def _events(request: Request, ctx: ServiceContext, job_id: str):
    """A job's events until it reaches a final state or the client goes."""
    last_state, last_progress, last_sent, last_live = None, None, time.monotonic(), 0.0
    while True:
        row = await run_in_threadpool(ctx.db.get_job, job_id)
        if row is None:
            return
        out = []
        final = row["state"] in FINAL_STATES
        state_changed = row["state"] != last_state
        if state_changed and not final:
            out.append(_sse("state", job_out(row)))
        if row["progress"] != last_progress and row["state"] in ("running", "succeeded"):
            out.append(_sse("progress", {"id": job_id, "state": row["state"], **(row["progress"] or {})}))
        if state_changed or (row["state"] == "running" and time.monotonic() - last_live >= 1.0):
            last_live = time.monotonic()
            try:
                out.append(_sse("live", await run_in_threadpool(live_doc, ctx, row)))
            except (OSError, ValueError, TypeError, KeyError):  # the job's folder mid-change: the next second's
                pass
        if state_changed and final:
            out.append(_sse("state", job_out(row)))
        last_state, last_progress = row["state"], row["progress"]
        if out:
            last_sent = time.monotonic()
            yield "".join(out)
        elif time.monotonic() - last_sent > 15:
            last_sent = time.monotonic()
            yield ": keep-alive\n\n"
        if final or await request.is_disconnected():
            return
        await asyncio.sleep(0.25)


def _artifact(request: Request, ctx: ServiceContext, job_id: str, kind: str, principal: Principal):
    row = owned_job(ctx, job_id, principal)
    if row["state"] != "succeeded":
        raise ApiError(409, f"job {job_id} is {row['state']}; its artifacts exist once it has succeeded")
    name, media = _ARTIFACTS[kind]
    path = Path(row["artifact_dir"]) / name
    info = (row["artifacts"] or {}).get(name) or {}
    sha = row["stack_sha256"] if kind == "stack" else info.get("sha256")
    if not path.is_file() or not sha:
        raise ApiError(404, f"job {job_id} has no {name}" + (" (the worker could not make it)" if kind == "preview"
                                                            else ""))
    if not artifact_intact(path, sha):
        raise ApiError(409, f"job {job_id}: the stored {name} fails its integrity check (its sha256 is no longer "
                            f"{sha[:12]}...); it is not served. Submit the job again to recompute it")
    return file_response(request, path, sha256=sha, media_type=media, filename=f"{job_id}-{name}")


_FILE_RESPONSES = {206: {"description": "Partial content (Range)"}, 304: {"description": "Not modified"},
                   416: {"description": "Range not satisfiable"}, **PROBLEM_RESPONSES}


@router.get("/v1/jobs/{job_id}/stack", responses={200: {"content": {"application/octet-stream": {}}},
                                                   **_FILE_RESPONSES})
def get_stack(request: Request, ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """STACK.npz: ``ETag`` is the sha256 of the file (also in ``X-Content-SHA256``); honours ``If-None-Match``,
    ``Range`` and ``If-Range``."""
    return _artifact(request, ctx, job_id, "stack", principal)


@router.get("/v1/jobs/{job_id}/frames.zip", responses={200: {"content": {"application/zip": {}}},
                                                        **_FILE_RESPONSES})
def get_frames(request: Request, ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """The 8-bit SLM frames as PNGs ``f{frame:03d}_c{color}.png`` in a zip."""
    return _artifact(request, ctx, job_id, "frames", principal)


@router.get("/v1/jobs/{job_id}/preview.png", responses={200: {"content": {"image/png": {}}}, **_FILE_RESPONSES})
def get_preview(request: Request, ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """What an eye sees (`holo view`, 4 mm pupil, focused mid-volume, frames averaged), made by the worker."""
    return _artifact(request, ctx, job_id, "preview", principal)
