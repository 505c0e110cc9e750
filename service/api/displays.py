"""Display agents: heartbeats in, the list of displays (with their last heartbeat) out.

A display is registered to an owner by an admin (``PUT /v1/displays/{name}``, optionally to one agent token);
only the owners named in ``open_display_owners`` (the default owner: a single-tenant service) register a name
with their agent's first heartbeat. Afterwards only that owner's agents (that token, when one is named)
heartbeat for it, and only that owner's tokens see it; an agent receives only its owner's jobs. A name that is
another owner's and a name nobody registered get the same 403, so heartbeats cannot probe for displays."""

from __future__ import annotations

import re
import time
from typing import Optional

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
    agent_token_id: Optional[str] = Field(default=None, pattern=r"^[0-9a-f]{12}$", description="Only this "
                                          "agent token (its id, from `holo token list`) sends the display's "
                                          "heartbeats; default: any agent token of the owner.")


@router.post("/v1/displays/{name}/heartbeat", status_code=204, response_class=Response, responses=PROBLEM_RESPONSES)
def heartbeat(body: Heartbeat, ctx: Ctx, principal: AgentScope,
              name: str = PathParam(pattern=NAME_PATTERN)) -> Response:
    """A display agent says it is alive and what it shows (scope agent or admin; the display's owner only)."""
    db = ctx.db
    row = db.display_row(name)
    if row is None and (principal.is_admin or principal.owner in ctx.settings.open_display_owners):
        db.claim_display(name, principal.owner, principal.token_id)
        row = db.display_row(name)
    if row is None or not principal.sees(row["owner"]) or (
            row["agent_token"] is not None and not principal.is_admin and row["agent_token"] != principal.token_id):
        raise ApiError(403, f"display {name!r} is not registered to this agent; an admin registers displays "
                            f"(PUT /v1/displays/{name})")
    db.heartbeat(name, agent_version=_CONTROL.sub("", body.agent_version),
                 showing=body.showing.model_dump() if body.showing is not None else None,
                 state=_CONTROL.sub("", body.state), message=_CONTROL.sub("", body.message),
                 token_id=principal.token_id)
    return Response(status_code=204)


@router.put("/v1/displays/{name}", status_code=204, response_class=Response, responses=PROBLEM_RESPONSES)
def assign_display(body: DisplayOwner, ctx: Ctx, principal: AdminScope,
                   name: str = PathParam(pattern=NAME_PATTERN)) -> Response:
    """Register a display to an owner (and optionally one of its agent tokens), or move it (admin)."""
    db = ctx.db
    db.claim_display(name, body.owner, principal.token_id)
    db.set_display_owner(name, body.owner, body.agent_token_id)
    return Response(status_code=204)


@router.get("/v1/displays", response_model=DisplayList, responses=PROBLEM_RESPONSES)
def list_displays(ctx: Ctx, principal: ReadScope):
    """The displays of this token's owner (every display for admin), with their last heartbeat."""
    now = time.time()
    rows = ctx.db.list_displays(owner=None if principal.is_admin else principal.owner)
    return {"displays": [{"name": r["name"], "last_seen": iso(r["last_seen"]), "age_s": round(now - r["last_seen"], 3),
                          "agent_version": r["agent_version"], "showing": r["showing"], "state": r["state"],
                          "message": r["message"], "owner": r["owner"] or "default"} for r in rows]}
