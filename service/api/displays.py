"""Display agents: heartbeats in, the list of displays (with their last heartbeat) out."""

from __future__ import annotations

import json
import time

from fastapi import APIRouter, Depends, Path as PathParam, Request
from fastapi.responses import Response

from service.api.deps import get_ctx, require
from service.api.problems import PROBLEM_RESPONSES
from service.api.scenes import iso
from service.auth import Principal
from service.models import NAME_PATTERN, DisplayList, Heartbeat

__all__ = ["router"]

router = APIRouter(tags=["displays"])


@router.post("/v1/displays/{name}/heartbeat", status_code=204, response_class=Response, responses=PROBLEM_RESPONSES)
def heartbeat(body: Heartbeat, request: Request, name: str = PathParam(pattern=NAME_PATTERN),
              principal: Principal = Depends(require("agent"))) -> Response:
    """A display agent says it is alive and what it shows (scope agent or admin)."""
    showing = json.dumps(body.showing.model_dump()) if body.showing is not None else None
    get_ctx(request).db.execute(
        "INSERT INTO displays (name, last_seen, agent_version, showing, state, message, token_id) "
        "VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT(name) DO UPDATE SET last_seen = excluded.last_seen, "
        "agent_version = excluded.agent_version, showing = excluded.showing, state = excluded.state, "
        "message = excluded.message, token_id = excluded.token_id",
        (name, time.time(), body.agent_version, showing, body.state, body.message, principal.token_id))
    return Response(status_code=204)


@router.get("/v1/displays", response_model=DisplayList, responses=PROBLEM_RESPONSES)
def list_displays(request: Request, principal: Principal = Depends(require("read"))):
    """Every display that ever sent a heartbeat, with the last one."""
    now = time.time()
    rows = get_ctx(request).db.query("SELECT * FROM displays ORDER BY name")
    return {"displays": [{"name": r["name"], "last_seen": iso(r["last_seen"]), "age_s": round(now - r["last_seen"], 3),
                          "agent_version": r["agent_version"], "showing": r["showing"], "state": r["state"],
                          "message": r["message"]} for r in rows]}
