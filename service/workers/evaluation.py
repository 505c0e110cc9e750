"""A job's evaluation against ground truth (the job field ``evaluate``): the driver's ``evaluate`` step, after the
pictures, runs ``holo evaluate`` on the job's stack and scene and leaves ``JOB_DIR/evaluation/``:

- the cells: the centre view at each depth of the focal sweep the pictures step made
  (service/workers/pictures.py: the page's focus slider walks those depths, so that the ground truth and the
  score stand beside the sweep's picture at every slider position), and a 3 x 3 grid of views (+-0.5 degrees)
  at the sweep's middle depth (``holo evaluate --focus-mm ... --views 3 --views-at middle``);
  each through holo evaluate's own pupil, the largest inside every colour's recording cone at those views (1.61
  mm on the paper display; the sweep's 4 mm pupil is wider than blue's eyebox, and its views are lit fully only
  on an SLM of 820 px or more at the paper display's 80 mm); per cell the reconstruction as scored (its
  brightness scale applied) and the Mitsuba thin-lens ground truth as two PNGs at one white level
  (``--pairs``), PSNR and SSIM;
- for a stack of more than one frame, the viewer-faithful score (``holo evaluate --viewer``: one brightness
  scale per colour over pupils of 2 and 4 mm x a jittered 3 x 3 eye grid at the middle depth): a time-multiplexed
  stack's frames may favour some eye positions, which a per-cell fit at fixed views hides;
- ``index.json``: every depth of the sweep (those with no cell say why: beyond optical infinity, where no
  thin-lens camera focuses, or too deep for the SLM to light any of the view), every view, the viewer score,
  each PNG's SHA-256, and the stack's hash, as ``GET /v1/jobs/{id}/evaluation`` serves it.

The ground truth takes :data:`GT_SPP` samples per pixel: its Monte Carlo noise counts as the hologram's error,
a little at this count, and a cell costs a render of H x W x GT_SPP samples and a view of every frame
(:func:`evaluation_seconds`, in the job's estimate). The folder is built beside ``evaluation/`` and renamed into
place, so a reader never sees half of it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

from service.evaluation_rules import (
    EVALUATION_VERSION,
    FILE_PATTERN,
    GT_SPP,
    MIN_LIT_PX,
    SWEEP_DEPTHS,
    VIEW_DEG,
    VIEWER_EYE_GRID,
    VIEWER_PUPILS_MM,
    VIEWS,
    evaluation_cells,
    evaluation_seconds,
    evaluation_too_small,
)


__all__ = ["evaluation_too_small", "GT_SPP", "VIEWS", "VIEW_DEG", "VIEWER_PUPILS_MM", "VIEWER_EYE_GRID",
           "EVALUATION_VERSION", "FILE_PATTERN",
           "EvalPlan", "plan_evaluation", "cells_args", "viewer_args", "write_index", "run_evaluation",
           "evaluation_cells", "evaluation_seconds"]

def _num(v: Any) -> Optional[float]:
    """A finite float, else None (JSON has no infinity: a cell identical to its ground truth scores inf dB)."""
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


@dataclass
class EvalPlan:
    """What the step evaluates: the sweep's depths (each with its picture, or why it gets no cell), the views and
    the pupil."""

    depths: list[dict]  # {"index", "z_mm", "words", "sweep_file", "skipped"?}
    views: int
    pupil_mm: float
    viewer: bool
    notes: list[str] = field(default_factory=list)

    @property
    def scored(self) -> list[dict]:
        return [d for d in self.depths if "skipped" not in d]

    @property
    def middle_mm(self) -> float:
        s = self.scored
        return s[len(s) // 2]["z_mm"]


def plan_evaluation(job_dir: Path, meta: dict, *, shape_hw: tuple[int, int], frames: int,
                    stack_sha256: str) -> EvalPlan:
    """The depths of the job's focal sweep (``pictures/index.json``, when it pictures this stack; else the depths
    the sweep would start from), which of them the view can be scored at on an SLM of ``shape_hw``, and the views
    (ValueError when nothing can be scored, with the reason)."""
    from holocore.evaluate.preview import depth_words, focus_depths
    from holocore.evaluate.scoring import default_pupil_m, lit_margin_px
    from holocore.formats.meta import parse_view_meta

    vm = parse_view_meta(meta, what="the stack")
    depths: list[dict] = []
    notes: list[str] = []
    try:
        idx = json.loads((job_dir / "pictures" / "index.json").read_text())
        if idx.get("stack_sha256") != stack_sha256:
            raise ValueError("the pictures are another stack's")
        depths = [{"index": i, "z_mm": float(p["z_mm"]), "words": str(p["words"]), "sweep_file": str(p["file"])}
                  for i, p in enumerate(idx["sweep"]["pictures"])]
    except (OSError, ValueError, KeyError, TypeError):
        depths = [{"index": i, "z_mm": round(float(z) * 1e3, 4), "words": depth_words(float(z), vm), "sweep_file": None}
                  for i, z in enumerate(focus_depths(vm, SWEEP_DEPTHS))]
        notes.append("no focal sweep to pair with (the pictures step made none): the depths it would have used")
    pupil = default_pupil_m(vm, view_deg=VIEW_DEG)
    H, W = (int(v) for v in shape_hw)
    z_inf_mm = vm.z_inf_m * 1e3

    def lit(z_mm: float, e: tuple[float, float]) -> bool:
        m = lit_margin_px(vm, focus_z_m=z_mm * 1e-3, pupil_diameter_m=pupil, view_offset_m=e)
        return min(H, W) - 2 * m >= MIN_LIT_PX

    for d in depths:
        if d["z_mm"] < z_inf_mm:
            d["skipped"] = "beyond optical infinity: no eye (and no thin-lens camera) focuses there"
        elif not lit(d["z_mm"], (0.0, 0.0)):
            d["skipped"] = (f"the SLM ({H}x{W} px) lights none of the view at this depth through a "
                            f"{pupil * 1e3:.3g} mm pupil: a display with virtual infinity nearer than "
                            f"{z_inf_mm:g} mm, or a larger SLM, can be evaluated here")
    scored = [d for d in depths if "skipped" not in d]
    if not scored:
        raise ValueError(next((d["skipped"] for d in depths), "no focus depths"))
    e = vm.focal_length_m * math.sin(math.radians(VIEW_DEG))
    views = VIEWS if lit(scored[len(scored) // 2]["z_mm"], (e, e)) else 1
    if views == 1:
        notes.append(f"the centre view only: the SLM lights too little of the views +-{VIEW_DEG:g} deg off the axis")
    return EvalPlan(depths=depths, views=views, pupil_mm=pupil * 1e3, viewer=frames > 1, notes=notes)


def cells_args(stack: Path, scene: str, out: Path, plan: EvalPlan, progress: str) -> list[str]:
    """`holo evaluate` for the cells (after ``holo``)."""
    return ["evaluate", str(stack), "--scene", scene, "--out", str(out),
            "--focus-mm", ",".join(repr(d["z_mm"]) for d in plan.scored), "--views", str(plan.views),
            "--view-deg", repr(VIEW_DEG), "--views-at", "middle", "--gt-spp", str(GT_SPP), "--no-images", "--pairs",
            "--progress-jsonl", progress]


def viewer_args(stack: Path, scene: str, out: Path, plan: EvalPlan, progress: str) -> list[str]:
    """`holo evaluate --viewer` (after ``holo``): writes ``out/viewer.json``."""
    return ["evaluate", str(stack), "--scene", scene, "--out", str(out), "--viewer",
            "--pupils-mm", ",".join(f"{p:g}" for p in VIEWER_PUPILS_MM), "--eye-grid", str(VIEWER_EYE_GRID),
            "--focus-mm", repr(plan.middle_mm), "--gt-spp", str(GT_SPP), "--progress-jsonl", progress]


def _viewer_summary(doc: dict) -> dict:
    pupils = [{k: (_num(p.get(k)) if k != "pupil_mm" else float(p["pupil_mm"]))
               for k in ("pupil_mm", "mean_psnr_db", "mean_ssim", "brightness_max_over_min", "colour_cast",
                         "colour_tint", "edge_error", "parallax_error_px")} for p in doc.get("pupils") or []]
    span = _num(doc.get("eye_span_m"))
    return {"mean_psnr_db": _num(doc.get("mean_psnr_db")), "scale_spread": _num(doc.get("scale_spread")),
            "eye_grid": int(doc.get("eye_grid", VIEWER_EYE_GRID)),
            "eye_span_mm": None if span is None else round(span * 1e3, 4),
            "focus_mm": [round(float(z) * 1e3, 4) for z in doc.get("focus_z_m") or []],
            "cells": len(doc.get("cells") or []), "pupils": pupils}


def write_index(out: Path, plan: EvalPlan, *, stack_sha256: str, viewer_error: Optional[str] = None,
                seconds: float = 0.0) -> dict:
    """``out/index.json`` from holo evaluate's ``metrics.json`` (and ``viewer.json``) there; returns it."""
    from holocore.formats.hashing import file_sha256  # numpy comes with the package: not in the API process

    metrics = json.loads((out / "metrics.json").read_text())
    n = int(metrics.get("views", 1))
    centre = (n // 2, n // 2)
    cells = metrics["cells"]
    scored = plan.scored

    def files(c: dict) -> dict:
        rows = {}
        for key, col in (("hologram", "recon_png"), ("truth", "truth_png")):
            path = out / c[col]
            rows[f"{key}_file"] = path.name
            rows[f"{key}_sha256"] = file_sha256(path)
        return rows

    focus = []
    for d in plan.depths:
        row = {k: d[k] for k in ("index", "z_mm", "words", "sweep_file")}
        if "skipped" in d:
            focus.append({**row, "skipped": d["skipped"]})
            continue
        fi = scored.index(d)
        c = next(c for c in cells if c["focus_index"] == fi and (c["view_col"], c["view_row"]) == centre)
        focus.append({**row, "psnr_db": _num(c["psnr_db"]), "ssim": _num(c["ssim"]), "margin_px": int(c["margin_px"]),
                      **files(c)})
    mid = len(scored) // 2
    views = [{"col": int(c["view_col"]), "row": int(c["view_row"]),
              "offset_mm": [round(float(c["view_x_mm"]), 4), round(float(c["view_y_mm"]), 4)],
              "focus_mm": scored[mid]["z_mm"], "psnr_db": _num(c["psnr_db"]), "ssim": _num(c["ssim"]),
              "margin_px": int(c["margin_px"]), **files(c)}
             for c in cells if c["focus_index"] == mid] if n > 1 else []
    viewer = None
    if (out / "viewer.json").is_file():
        viewer = _viewer_summary(json.loads((out / "viewer.json").read_text()))
    index = {"version": EVALUATION_VERSION, "stack_sha256": stack_sha256, "pupil_mm": round(plan.pupil_mm, 4),
             "gt_spp": GT_SPP, "views": n, "view_deg": VIEW_DEG, "white": _num(metrics.get("pair_white")),
             "gamma": _num(metrics.get("pair_gamma")), "mean_psnr_db": _num(metrics.get("mean_psnr_db")),
             "mean_ssim": _num(metrics.get("mean_ssim")), "focus": focus, "view_grid": views, "viewer": viewer,
             "viewer_error": viewer_error, "notes": plan.notes, "seconds": round(seconds, 3)}
    (out / "index.json").write_text(json.dumps(index, indent=1))
    return index


# run(step, args, job_dir, append=, info=) -> seconds: the driver's way of running a CLI step
Runner = Callable[..., float]


def run_evaluation(job_dir: Path, *, scene_path: str, meta: dict, shape_fchw: tuple[int, ...], stack_sha256: str,
                   run: Runner, failed: type[Exception]) -> tuple[float, list[str]]:
    """The ``evaluate`` step: plan, holo evaluate (the cells, then the viewer score where it applies), the index,
    ``evaluation/`` in place. Returns (seconds, warnings). A failed cells run raises ``failed`` (the driver's
    StepFailed: a warning unless retryable); a failed viewer run is a warning, the cells stand."""
    t0 = time.monotonic()
    plan = plan_evaluation(job_dir, meta, shape_hw=(shape_fchw[-2], shape_fchw[-1]), frames=shape_fchw[0],
                           stack_sha256=stack_sha256)
    final, tmp = job_dir / "evaluation", job_dir / ".evaluation.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    progress = str(job_dir / "progress-evaluate.jsonl")
    stack = job_dir / "stack.npz"
    stages = ["evaluate", "viewer"] if plan.viewer else ["evaluate"]
    run("evaluate", cells_args(stack, scene_path, tmp, plan, progress), job_dir, info={"stages": stages, "part": 0})
    warnings: list[str] = []
    viewer_error = None
    if plan.viewer:
        try:
            run("evaluate", viewer_args(stack, scene_path, tmp, plan, progress), job_dir, append=True,
                info={"stages": stages, "part": 1})
        except failed as exc:
            if getattr(exc, "retryable", False):
                raise
            viewer_error = str(exc)
            warnings.append(f"no viewer-faithful score: {exc}")
    write_index(tmp, plan, stack_sha256=stack_sha256, viewer_error=viewer_error, seconds=time.monotonic() - t0)
    old = job_dir / ".evaluation.old"
    shutil.rmtree(old, ignore_errors=True)
    if final.exists():
        os.replace(final, old)
    os.replace(tmp, final)
    shutil.rmtree(old, ignore_errors=True)
    return time.monotonic() - t0, warnings


