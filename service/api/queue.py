"""``GET /v1/queue``: how busy the service is: the jobs waiting and running (everyone's, and the caller's),
the workers (engine, slots, busy slots) and the planner (scenes waiting for their plan). Counts only: no other
owner's job or scene is named, so a read token may ask."""

from __future__ import annotations

from typing import Literal, Optional

from fastapi import APIRouter
from pydantic import BaseModel, Field

from service.api.deps import Ctx, ReadScope
from service.api.problems import PROBLEM_RESPONSES

__all__ = ["router", "QueueStatus"]

router = APIRouter(tags=["jobs"])


class QueueJobs(BaseModel):
    queued: int = Field(description="Jobs waiting for a worker, everyone's.")
    queued_yours: int = Field(description="Of those, the caller's owner's.")
    running: int = Field(description="Jobs running now, everyone's.")
    running_yours: int = Field(description="Of those, the caller's owner's.")


class QueueWorkers(BaseModel):
    engine: Literal["local", "ray"] = Field(description="Where jobs run: local processes or a Ray cluster.")
    slots: int = Field(description="Jobs that may run at the same time (settings.workers).")
    busy_slots: int = Field(description="Slots running a job now, or still being taken back from a stopped one.")
    running_here: bool = Field(description="Whether this server runs the scheduler (holo serve does).")
    alive: Optional[bool] = Field(default=None, description="The scheduler has looked at the queue in the last 30 "
                                                            "s (None where it does not run in this server).")


class QueuePlanner(BaseModel):
    pending_scenes: int = Field(description="Scenes waiting for their plan (and picture), everyone's.")
    pending_scenes_yours: int = Field(description="Of those, the caller's owner's.")
    planning: bool = Field(description="A plan is being made now.")
    state: Literal["idle", "planning", "stopped"] = Field(description="idle: nothing to plan; planning: a plan "
                                                                      "runs or waits; stopped: no planner here.")


class QueueStatus(BaseModel):
    jobs: QueueJobs
    workers: QueueWorkers
    planner: QueuePlanner


def _scene_plans(ctx, owner: str) -> tuple[int, int, int]:
    """(pending everyone's, pending the owner's, being planned now)."""
    row = ctx.db.one(
        "SELECT COALESCE(SUM(plan_state = 'pending'), 0) AS pending, COALESCE(SUM(plan_state = 'running'), 0) AS "
        "planning, COALESCE(SUM(plan_state IN ('pending', 'running') AND id IN (SELECT scene_id FROM scene_owners "
        "WHERE owner = ?)), 0) AS yours FROM scenes WHERE plan_state IN ('pending', 'running')", (owner,))
    return int(row["pending"]), int(row["yours"]), int(row["planning"])


@router.get("/v1/queue", response_model=QueueStatus, responses=PROBLEM_RESPONSES)
def queue_status(ctx: Ctx, principal: ReadScope) -> QueueStatus:
    """Jobs waiting and running (everyone's and yours), the workers' slots, and the planner's waiting scenes."""
    everyone = ctx.db.count_jobs()
    mine = ctx.db.count_jobs(principal.owner)
    sched = ctx.scheduler
    if sched is not None:
        # a slot whose stopped run is still being taken back holds no job but cannot take one either
        busy = len(sched.running) + len(getattr(sched, "_draining", ()))
        engine = getattr(sched.engine, "name", ctx.settings.engine)
        alive: Optional[bool] = bool(sched.alive())
    else:
        busy, engine, alive = everyone["running"], ctx.settings.engine, None
    pending, pending_yours, planning = _scene_plans(ctx, principal.owner)
    planner_here = ctx.planner is not None
    state = "stopped" if not planner_here else "planning" if (pending or planning) else "idle"
    return QueueStatus(
        jobs=QueueJobs(queued=everyone["queued"], queued_yours=mine["queued"], running=everyone["running"],
                       running_yours=mine["running"]),
        workers=QueueWorkers(engine=engine if engine in ("local", "ray") else ctx.settings.engine,
                             slots=ctx.settings.workers, busy_slots=min(busy, ctx.settings.workers),
                             running_here=sched is not None, alive=alive),
        planner=QueuePlanner(pending_scenes=pending + planning, pending_scenes_yours=pending_yours,
                             planning=planning > 0, state=state))
