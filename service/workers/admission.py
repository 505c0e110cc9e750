"""When a queued job may start, and what it needs: no job starts before its scene's plan is ready (the plan is
where Mitsuba first loads the scene, and a scene that crashes Mitsuba or outgrows its limits there would do so
again in the job), a job whose scene's plan failed is failed, and a job submitted before the plan said how deep
its recording planes go is estimated again from the plan and failed if it cannot fit the workers' memory, as a
submit would have been refused. Used by the scheduler (service.workers.scheduler) before each launch.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Optional

from service.cost import output_bytes
from service.cost import job_memory, memory_admission_error, plane_border_px
from service.jobfiles import JobSpec
from service.models import JobRequest

__all__ = ["Admission", "admit", "peak_bytes", "largest_file_bytes"]

log = logging.getLogger("holo.service.scheduler")


@dataclass(frozen=True)
class Admission:
    """What the scheduler does with a queued job now."""

    need_bytes: Optional[int]  # its predicted peak memory; None: leave it queued (its scene's plan is pending)
    refusal: Optional[str] = None  # it cannot run: fail it with this reason
    estimate: Optional[dict[str, Any]] = None  # a new estimate to store (its planes checked against the plan)


def peak_bytes(row: dict) -> int:
    """A job's predicted peak memory from its estimate (0 when it has none: jobs from before the estimate)."""
    mem = (row.get("estimate") or {}).get("memory") or {}
    peak = mem.get("peak_bytes")
    return int(peak) if isinstance(peak, (int, float)) and peak > 0 else 0


def largest_file_bytes(row: dict, spec: JobSpec) -> Optional[int]:
    """The most one file of the job can hold: all its folder may hold (service.cost.output_bytes, with
    RESULT.npz and its deeper planes' scratch), with a quarter to spare; None while its planes' border is not
    known (a job from before they were counted)."""
    mem = (row.get("estimate") or {}).get("memory") or {}
    border = 0 if spec.wrp_planes == 1 or spec.method == "direct" else mem.get("plane_border_px")
    if border is None:
        return None
    most = output_bytes(spec.optics, keep_result=True, wrp_planes=spec.wrp_planes, plane_border=border,
                        evaluate=bool(spec.evaluate))
    return most + most // 4


def admit(row: dict, scene: Optional[dict], settings: Any) -> Admission:
    """The :class:`Admission` of the queued job ``row`` whose scene row is ``scene`` (None: gone)."""
    if scene is not None and scene["plan_state"] in ("pending", "running"):
        return Admission(None)
    if scene is not None and scene["plan_state"] == "failed":
        return Admission(-1, refusal=f"the scene's plan failed: {scene.get('plan_error') or ''}")
    mem = (row.get("estimate") or {}).get("memory") or {}
    if "plane_border_px" not in mem or mem["plane_border_px"] is not None or mem.get("planes_checked"):
        return Admission(peak_bytes(row))  # known at submit or checked already (or from before planes were counted)
    try:
        spec = JobSpec.model_validate(row["spec"])
        req = JobRequest(scene_id=row["scene_id"], optics=spec.optics, **spec.fields())
    except ValueError as exc:  # a spec this version cannot read: the run will say what is wrong
        log.warning("job %s: memory not re-estimated (%s)", row["id"], exc)
        return Admission(peak_bytes(row))
    try:
        border = plane_border_px(req, scene_plan=(scene or {}).get("plan"),
                                 plan_state=(scene or {}).get("plan_state", "failed"), limits=settings.job_limits)
    except ValueError as exc:  # a plane count that cannot fit the render's memory budget: the render would refuse
        return Admission(-1, refusal=f"refused before it ran: {exc}")
    too_big = memory_admission_error(req, settings.worker_memory_bytes, plane_border=border)
    if too_big:
        return Admission(-1, refusal=f"refused before it ran: {too_big}")
    m = job_memory(req, plane_border=border)
    estimate = {**(row.get("estimate") or {}),
                "memory": {**m.as_dict(), "plane_border_px": border, "planes_checked": True}}
    return Admission(m.peak_bytes, estimate=estimate)
