"""Send a finished job to one of its owner's displays: it becomes the job that display shows next.

A display's agent follows ``GET /v1/jobs?display=NAME&state=succeeded`` and shows the first job it can; that
list holds the jobs submitted for the display and those sent to it, the most recently sent first, so a send
reaches the display at the agent's next poll with no change to the agent. Sending a job to one display takes
it from no other display."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi import Path as PathParam
from pydantic import BaseModel, ConfigDict, Field

from service.api.deps import Ctx, SubmitScope, owned_job
from service.api.problems import PROBLEM_RESPONSES, ApiError
from service.api.scenes import iso
from service.models import ID_PATTERN, NAME_PATTERN

__all__ = ["router", "SendRequest", "SendOut"]

router = APIRouter(tags=["displays"])


class SendRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    display: str = Field(pattern=NAME_PATTERN, description="A display of the job's owner (GET /v1/displays).")


class SendOut(BaseModel):
    job_id: str
    display: str
    sent_at: str = Field(description="When the job was sent (ISO 8601, UTC); the display's list puts it first.")


@router.post("/v1/jobs/{job_id}/display", response_model=SendOut, responses=PROBLEM_RESPONSES)
def send_to_display(body: SendRequest, ctx: Ctx, principal: SubmitScope,
                    job_id: str = PathParam(pattern=ID_PATTERN)):
    """Make a succeeded job the one ``display`` shows next (scope submit; the display must be one of the job's
    owner's). Its agent switches at its next poll of ``GET /v1/jobs?display=NAME``."""
    row = owned_job(ctx, job_id, principal)
    if row["state"] != "succeeded":
        raise ApiError(409, f"job {job_id} is {row['state']}; only a succeeded job can be sent to a display")
    # The job's owner, not the caller: an admin sending a lab's job must pick that lab's display, the only one
    # whose agent can fetch it. An unknown display and another owner's get the same answer.
    owner = row.get("owner") or "default"
    display = ctx.db.display_row(body.display)
    if display is None or display["owner"] != owner:
        raise ApiError(404, f"no display {body.display!r} among the displays of this job's owner "
                            "(GET /v1/displays lists them)")
    sent = ctx.db.send_job(job_id, body.display, token_id=principal.token_id)
    if sent is None:
        raise ApiError(409, f"job {job_id} changed while it was being sent; it is no longer succeeded")
    return {"job_id": job_id, "display": body.display, "sent_at": iso(sent)}
