"""What the scheduler reads of a run's directory: progress (``step.json`` and ``progress-<step>.jsonl``),
``status.json`` (typed in service/jobfiles.py) and the artifacts' hashes, computed here; and the partial outputs
it removes after a stopped run."""

from __future__ import annotations

import hashlib
import json
import math
import time
from pathlib import Path
from typing import Optional

from service.jobfiles import STEPS, Progress, RenderStage, Step
from service.untrusted import open_job_file, read_job_json, read_job_tail

__all__ = ["ARTIFACTS", "RUN_FILES", "STEP_WEIGHTS", "EVALUATE_WEIGHT", "RENDER_STAGE_END", "hash_artifacts",
           "read_progress", "step_weights", "remove_partials"]

ARTIFACTS = ("stack.npz", "frames.zip", "preview.png")
RUN_FILES = ("status.json", "step.json", "plan.json", "driver.log", *(f"progress-{s}.jsonl" for s in STEPS),
             *(f"{s}.log" for s in STEPS))
# Share of the whole run of each step with progress (the preview step makes the pictures too).
STEP_WEIGHTS: dict[Step, float] = {"render": 0.75, "encode": 0.15, "package": 0.03, "preview": 0.07}
# A job that asks for an evaluation (job.json's ``evaluate``) spends about this share of its run on it (a ground
# truth render and a simulated view per cell, service/workers/evaluation.py); the other steps share the rest in
# the proportions above. The parts step.json names (``stages``: the cells, then the viewer score; ``part``: the
# one running) share it evenly.
EVALUATE_WEIGHT = 0.25
# Stages a step reports as 1 of 1 before its real work starts (`holo encode` reads its input as "load").
STARTING_STAGES = frozenset({"load"})
# Where each stage of `holo render` ends, as a fraction of the render step (the stages it reports, in order).
RENDER_STAGE_END: dict[RenderStage, float] = {"analysis": 0.1, "trace": 0.9, "propagate": 1.0}


def hash_artifacts(job_dir: Path) -> dict[str, dict]:
    """{name: {"sha256", "bytes"}} of the job's artifacts, hashed here: plain files only (no symlink is
    followed, no file with other hard links counts; service/untrusted.py)."""
    out: dict[str, dict] = {}
    for name in ARTIFACTS:
        try:
            fh = open_job_file(job_dir, name)
        except OSError:
            continue
        with fh:
            h, n = hashlib.sha256(), 0
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
                n += len(chunk)
        out[name] = {"sha256": h.hexdigest(), "bytes": n}
    return out


def _last_json_line(job_dir: Path, name: str) -> Optional[dict]:
    try:
        lines = read_job_tail(job_dir, name, tail_bytes=4096)[0].strip().splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        try:
            doc = json.loads(line)
            if isinstance(doc, dict):
                return doc
        except ValueError:
            continue
    return None


def step_weights(job_dir: Path) -> dict[str, float]:
    """Each step's share of the run: from the steps' predicted seconds in job.json (its estimate's, which knows
    an encode at 80 mm from one at 4 mm) when it has them for every step, else :data:`STEP_WEIGHTS`, and the
    evaluation's share when job.json asks for one."""
    try:
        doc = read_job_json(job_dir, "job.json")
        evaluating = doc.get("evaluate") is True
        seconds = doc.get("step_seconds")
    except (OSError, ValueError, AttributeError):
        evaluating, seconds = False, None
    steps = [*STEP_WEIGHTS, *(["evaluate"] if evaluating else [])]
    if isinstance(seconds, dict) and all(isinstance(seconds.get(s), (int, float)) and math.isfinite(seconds[s])
                                         and seconds[s] >= 0 for s in steps):
        total = sum(float(seconds[s]) for s in steps)
        if total > 0:
            return {s: float(seconds[s]) / total for s in steps}
    if not evaluating:
        return dict(STEP_WEIGHTS)
    return {**{s: w * (1.0 - EVALUATE_WEIGHT) for s, w in STEP_WEIGHTS.items()}, "evaluate": EVALUATE_WEIGHT}


def read_progress(job_dir: Path) -> Optional[Progress]:
    """{"step", "stage", "done", "total", "fraction"} from a run's step.json and progress files (read as a job's
    files are, service/untrusted.py: a link, FIFO or huge file there reads as no progress, never blocks)."""
    try:
        doc = read_job_json(job_dir, "step.json")
        step = doc["step"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    weights = step_weights(job_dir)
    if not isinstance(step, str) or step not in weights:
        return None
    line = _last_json_line(job_dir, f"progress-{step}.jsonl") or {}
    done, total = line.get("done", 0), line.get("total", 0)
    within = min(1.0, done / total) if isinstance(done, int) and isinstance(total, int) and total > 0 else 0.0
    stage = line.get("stage")
    if stage in STARTING_STAGES:  # a step's first line ("load 1/1") says it began, not that it is done
        within = 0.0
    if step == "render" and stage in RENDER_STAGE_END:
        ends = list(RENDER_STAGE_END.values())
        i = list(RENDER_STAGE_END).index(stage)
        start = ends[i - 1] if i else 0.0
        within = start + (ends[i] - start) * within
    stages = doc.get("stages") if isinstance(doc, dict) else None
    if isinstance(stages, list) and stages:  # a step of several parts (each a process with its own count)
        part = doc.get("part") if isinstance(doc.get("part"), int) else 0
        part = stages.index(stage) if stage in stages else min(max(part, 0), len(stages) - 1)
        within = (part + within) / len(stages)
    base = sum(weights.get(s, 0.0) for s in STEPS[:STEPS.index(step)])
    return Progress(step=step, stage=str(line.get("stage", step)), done=done if isinstance(done, int) else 0,
                    total=total if isinstance(total, int) else 0,
                    fraction=round(min(0.999, base + weights[step] * within), 4))


def remove_partials(job_dir: Path, *, after_s: float = 0.0) -> None:
    """A stopped run's partial fields and artifacts are of no use; its logs stay. ``after_s``: wait first (a
    cancelled run's processes may still be writing)."""
    if after_s > 0:
        time.sleep(after_s)
    for name in ("result.npz", *ARTIFACTS):
        (job_dir / name).unlink(missing_ok=True)
