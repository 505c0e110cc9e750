"""Display agents: heartbeats in, the list of displays (with their last heartbeat) out.

A display belongs to the owner of the agent token that first sends its heartbeat (or to the owner an admin
assigns with ``PUT /v1/displays/{name}``); afterwards only that owner's tokens heartbeat for it, see it, or
aim jobs at it, and an agent receives only that owner's jobs."""

from __future__ import annotations

import re
import time

from fastapi import APIRouter
from fastapi import Path as PathParam
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field

from service.api.deps import AdminScope, AgentScope, Ctx, ReadScope
from service.api.problems import PROBLEM_RESPONSES, ApiError
from service.api.scenes import iso
from service.models import NAME_PATTERN, DisplayList, Heartbeat

__all__ = ["router"]

router = APIRouter(tags=["displays"])
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")


class DisplayOwner(BaseModel):
    model_config = ConfigDict(extra="forbid")
    owner: str = Field(pattern=NAME_PATTERN, description="The owner whose tokens may use this display.")


@router.post("/v1/displays/{name}/heartbeat", status_code=204, response_class=Response, responses=PROBLEM_RESPONSES)
def heartbeat(body: Heartbeat, ctx: Ctx, principal: AgentScope,
              name: str = PathParam(pattern=NAME_PATTERN)) -> Response:
    """A display agent says it is alive and what it shows (scope agent or admin; the display's owner only)."""
    db = ctx.db
    holder = db.claim_display(name, principal.owner, principal.token_id)
    if not principal.sees(holder):
        raise ApiError(403, f"display {name!r} is registered to another owner; only its agents send its heartbeats")
    db.heartbeat(name, agent_version=_CONTROL.sub("", body.agent_version),
                 showing=body.showing.model_dump() if body.showing is not None else None,
                 state=_CONTROL.sub("", body.state), message=_CONTROL.sub("", body.message),
                 token_id=principal.token_id)
    return Response(status_code=204)


@router.put("/v1/displays/{name}", status_code=204, response_class=Response, responses=PROBLEM_RESPONSES)
def assign_display(body: DisplayOwner, ctx: Ctx, principal: AdminScope,
                   name: str = PathParam(pattern=NAME_PATTERN)) -> Response:
    """Register a display to an owner, or move it to another (admin)."""
    db = ctx.db
    db.claim_display(name, body.owner, principal.token_id)
    db.set_display_owner(name, body.owner)
    return Response(status_code=204)


@router.get("/v1/displays", response_model=DisplayList, responses=PROBLEM_RESPONSES)
def list_displays(ctx: Ctx, principal: ReadScope):
    """The displays of this token's owner (every display for admin), with their last heartbeat."""
    now = time.time()
    rows = ctx.db.list_displays(owner=None if principal.is_admin else principal.owner)
    return {"displays": [{"name": r["name"], "last_seen": iso(r["last_seen"]), "age_s": round(now - r["last_seen"], 3),
                          "agent_version": r["agent_version"], "showing": r["showing"], "state": r["state"],
                          "message": r["message"], "owner": r["owner"] or "default"} for r in rows]}
