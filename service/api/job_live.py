"""What a job is doing, read live from its folder and its processes (``GET /v1/jobs/{id}/live`` and the ``live``
event of its stream): the effect plan as soon as there is one (its render's, else the scene's plan at the job's
options), each step's estimated against its actual seconds, the time left, the running step's last log lines and
the worker's CPU and memory."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Optional

from holocore.display.optics import OpticsConfig
from holocore.plan import stored_plan
from holocore.scene.errors import scrub_message
from service.api.context import ServiceContext
from service.jobfiles import STEPS, JobSpec
from service.untrusted import read_job_json, read_job_tail
from service.workers.runfiles import step_weights
from service.workers.scheduler import pid_is_our_driver

__all__ = ["live_doc", "render_log_plan", "group_usage", "step_times", "time_left_s", "TAIL_LINES"]

TAIL_LINES = 40
# The steps a job runs, in order (the preview step makes the page's pictures too; its timing is pictures_s).
_STEPS = ("render", "encode", "package", "preview", "evaluate")
_TIMING = {"render": "render_s", "encode": "encode_s", "package": "package_s", "preview": "pictures_s",
           "evaluate": "evaluate_s"}
# `holo render` lists these before the plan's lines, under the same bullet
_NOT_PLAN = ("time limit ", "memory budget ", "note: the chunk plan")


def render_log_plan(text: str) -> list[str]:
    """The plan lines `holo render` printed at its end ("  - ..." after its "rendered ..." line), each joined
    back from the terminal's wrapping; [] when the render has not printed them."""
    lines = text.splitlines()
    starts = [i for i, ln in enumerate(lines) if ln.startswith("rendered ")]
    if not starts:
        return []
    out: list[str] = []
    for ln in lines[starts[-1] + 1:]:
        if ln.startswith("  - "):
            out.append(ln[4:].strip())
        elif out and ln.strip() and not ln.startswith(("error:", "Traceback")):
            out[-1] = f"{out[-1]} {ln.strip()}"
        elif out:
            break
    return [ln for ln in out if not ln.startswith(_NOT_PLAN)]


def _folder_plan(folder: Path) -> Optional[dict]:
    """The plan the job's render made: plan.json (the driver writes it when the render ends), else the lines its
    render.log lists."""
    try:
        doc = read_job_json(folder, "plan.json")
        if isinstance(doc, dict) and isinstance(doc.get("summary"), list) and doc["summary"]:
            return {"summary": [str(s) for s in doc["summary"]],
                    "warnings": [str(w) for w in doc.get("warnings") or []], "source": "render"}
    except (OSError, ValueError):
        pass
    try:
        summary = render_log_plan(read_job_tail(folder, "render.log", tail_bytes=64 * 1024)[0].decode(
            "utf-8", errors="replace"))
    except OSError:
        return None
    return {"summary": summary, "warnings": [], "source": "render"} if summary else None


def _options_plan(ctx: ServiceContext, row: dict) -> Optional[dict]:
    """The scene's stored plan read at the job's own options (before its render makes one)."""

    scene = ctx.db.get_scene(row["scene_id"])
    if scene is None or scene.get("plan_state") != "ready":
        return None
    try:
        spec = JobSpec.model_validate(row["spec"])
        plan = stored_plan.plan_at_options(scene["plan"], OpticsConfig(**spec.optics), spec.hologram_options(),
                                           max_spp=row["spec"].get("max_spp"))
    except (TypeError, ValueError, KeyError, AttributeError):
        return None
    return {**plan, "warnings": []} if plan else None


def job_plan(ctx: ServiceContext, row: dict, folder: Optional[Path]) -> Optional[dict]:
    plan = row.get("plan")
    if isinstance(plan, dict) and plan.get("summary") and not plan.get("source"):
        return {"summary": plan["summary"], "warnings": plan.get("warnings") or [], "source": "render"}
    own = _folder_plan(folder) if folder is not None else None
    if own is not None or row["state"] not in ("queued", "running"):
        return own
    return _options_plan(ctx, row)


def _last_t(folder: Path, step: str) -> Optional[float]:
    """When a step last reported (the "t" of its progress file's last line)."""
    try:
        lines = read_job_tail(folder, f"progress-{step}.jsonl", tail_bytes=4096)[0].splitlines()
    except OSError:
        return None
    for ln in reversed(lines):
        try:
            t = json.loads(ln).get("t")
        except (ValueError, AttributeError):
            continue
        if isinstance(t, (int, float)):
            return float(t)
    return None


def _current_step(folder: Optional[Path]) -> tuple[Optional[str], Optional[float]]:
    try:
        doc = read_job_json(folder, "step.json")
        step, t = doc.get("step"), doc.get("t")
    except (OSError, ValueError, AttributeError, TypeError):
        return None, None
    return (step if step in _STEPS else None), (float(t) if isinstance(t, (int, float)) else None)


def step_times(row: dict, folder: Optional[Path], now: float) -> tuple[list[dict], Optional[str]]:
    """Each step the job runs with its estimated seconds (the estimate's ``steps_s``), its actual seconds (the
    run's timings once it ended; while it runs, the time between the steps' last progress lines, the running
    step's since it started) and its state (done, running, waiting, stopped); and the running step."""
    est = (row.get("estimate") or {}).get("steps_s") or {}
    timings = row.get("timings") or {}
    evaluating = bool((row.get("spec") or {}).get("evaluate"))
    steps = [s for s in _STEPS if s != "evaluate" or evaluating]
    if timings.get("reused"):
        return [], None  # nothing ran: the result is an earlier job's
    current, current_t = _current_step(folder) if folder is not None and row.get("started_at") else (None, None)
    live = row["state"] == "running" or (row["state"] in ("failed", "cancelled") and "render_s" not in timings)
    end = now if row["state"] == "running" else (row.get("finished_at") or now)
    out, prev_end = [], row.get("started_at")
    for s in steps:
        e = est.get(s)
        item = {"step": s, "estimated_s": round(float(e), 2) if isinstance(e, (int, float)) else None,
                "actual_s": None, "state": "waiting"}
        if isinstance(timings.get(_TIMING[s]), (int, float)):
            item.update(actual_s=round(float(timings[_TIMING[s]]), 2), state="done")
        elif live and current is not None and steps.index(s) < steps.index(current):
            t = _last_t(folder, s)
            if t is not None and prev_end is not None:
                item.update(actual_s=round(max(0.0, t - prev_end), 2))
            item["state"] = "done"
            prev_end = t if t is not None else prev_end
        elif live and s == current:
            start = current_t if current_t is not None else prev_end
            if start is not None:
                item["actual_s"] = round(max(0.0, end - start), 2)
            item["state"] = "running" if row["state"] == "running" else "stopped"
        out.append(item)
    return out, (current if row["state"] == "running" else None)


def time_left_s(steps: list[dict], within: Optional[float]) -> Optional[float]:
    """Seconds left of a running job: the steps to come at their estimates times the pace measured so far (the
    finished steps' actual over estimated seconds), and the running step's rest: from its own pace once it has
    reported a tenth of its work (``within``: its fraction done), else its estimate at the measured pace less
    the time it has run."""
    done = [s for s in steps if s["state"] == "done" and s["estimated_s"] and s["actual_s"] is not None]
    est_done = sum(s["estimated_s"] for s in done)
    pace = min(10.0, max(0.3, sum(s["actual_s"] for s in done) / est_done)) if est_done > 1 else 1.0
    left = 0.0
    for s in steps:
        if s["state"] == "waiting":
            if s["estimated_s"] is None:
                return None
            left += s["estimated_s"] * pace
        elif s["state"] == "running":
            ran = s["actual_s"] or 0.0
            if within is not None and within >= 0.1:
                left += ran * (1 - within) / within
            elif s["estimated_s"] is None:
                return None
            else:
                left += max(s["estimated_s"] * pace - ran, 0.1 * s["estimated_s"] * pace)
    return round(left, 1)


def group_usage(pgid: int) -> Optional[dict]:
    """CPU seconds (user + system) and resident memory summed over the live processes of group ``pgid`` (the
    job's driver and the step it runs), read from /proc; None when the group has none here."""
    tick, page = os.sysconf("SC_CLK_TCK"), os.sysconf("SC_PAGE_SIZE")
    cpu, rss, n = 0.0, 0, 0
    try:
        pids = [p for p in os.listdir("/proc") if p.isdigit()]
    except OSError:
        return None
    for p in pids:
        try:
            with open(f"/proc/{p}/stat", "rb") as fh:
                rest = fh.read().rsplit(b")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if len(rest) < 22 or int(rest[2]) != pgid or rest[0] == b"Z":
            continue
        cpu += (int(rest[11]) + int(rest[12])) / tick
        rss += int(rest[21]) * page
        n += 1
    return {"cpu_s": round(cpu, 2), "rss_bytes": rss, "processes": n} if n else None


def _worker(row: dict, folder: Optional[Path]) -> Optional[dict]:
    pid = row.get("worker_pid")
    if row["state"] != "running" or not pid or folder is None or not pid_is_our_driver(pid, folder):
        return None
    return group_usage(pid)


def _tail(folder: Optional[Path], step: Optional[str], roots: list[str]) -> Optional[dict]:
    """The running step's last log lines (``source`` "log"); while its log is still empty (a CLI prints its
    summary at its end), its last progress lines instead, as "stage done/total" (``source`` "progress")."""
    if folder is None or step is None:
        return None
    try:
        data = read_job_tail(folder, f"{step}.log", tail_bytes=16 * 1024)[0].decode("utf-8", errors="replace")
    except OSError:
        data = ""
    lines = [ln for ln in data.splitlines() if ln.strip()][-TAIL_LINES:]
    if lines:
        return {"step": step, "source": "log", "lines": [scrub_message(ln, roots=roots, limit=4000) for ln in lines]}
    try:
        raw = read_job_tail(folder, f"progress-{step}.jsonl", tail_bytes=8192)[0].splitlines()
    except OSError:
        raw = []
    out = []
    for ln in raw[-TAIL_LINES:]:
        try:
            doc = json.loads(ln)
            out.append(f"{str(doc['stage'])[:60]} {int(doc['done'])}/{int(doc['total'])}")
        except (ValueError, KeyError, TypeError):
            continue
    return {"step": step, "source": "progress", "lines": out}


def live_doc(ctx: ServiceContext, row: dict, within: Optional[float] = None) -> dict:
    """What the page shows of a job as it runs (see the module's doc)."""
    now = time.time()
    folder = Path(row["artifact_dir"]) if row.get("artifact_dir") else None
    steps, current = step_times(row, folder, now)
    progress = row.get("progress") or {}
    if within is None and current is not None:
        within = _within(folder, current, progress)
    started = row.get("started_at")
    end = now if row["state"] == "running" else row.get("finished_at")
    roots = [str(folder), str(folder.resolve())] if folder is not None else []
    return {"id": row["id"], "state": row["state"], "plan": job_plan(ctx, row, folder), "step": current,
            "steps": steps, "elapsed_s": round(end - started, 1) if started and end else None,
            "left_s": time_left_s(steps, within) if current is not None else None,
            "log": _tail(folder, current, roots) if current is not None else None,
            "worker": _worker(row, folder)}


def _within(folder: Optional[Path], step: str, progress: dict) -> Optional[float]:
    """The running step's own fraction done, from the job's fraction and the steps' weights."""
    f = progress.get("fraction")
    if folder is None or progress.get("step") != step or not isinstance(f, (int, float)):
        return None
    w = step_weights(folder)
    if not w.get(step):
        return None
    base = sum(w.get(s, 0.0) for s in STEPS[:STEPS.index(step)])
    return max(0.0, min(1.0, (f - base) / w[step]))
