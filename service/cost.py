"""What a job costs before it runs: its seconds (render, encode, process starts, pictures, evaluation; at an idle
machine and at the present load), its peak memory and what its deeper recording planes add to it, and the
quality its options buy (service/quality.py). Shown at submit, stored with the job, and what admission checks.
Light imports only: the API process estimates with it (holocore.plan's models need no numpy; placing a job's
recording planes loads numpy when a multi-plane job is first estimated)."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any, Optional

from holocore.plan.estimate import (
    encode_iterations,
    estimate_breakdown,
    features,
    load_calibration,
    machine_load,
)
from holocore.plan.estimate_probe import Probe, estimate_with_probe
from holocore.plan.memory_estimate import MemoryEstimate, admit_planes, deepest_border_px, estimate_memory
from holocore.plan.presets import MAX_WRP_PLANES, PRESETS
from holocore.plan.stored_plan import scene_depth_m, wrp_distance_m
from holocore.plan.stored_planes import admitted_planes
from holocore.runtime.membudget import memory_budget_bytes
from service.evaluation_rules import evaluation_output_bytes, evaluation_seconds, evaluation_too_small
from service.models import JobRequest, effective_optics
from service.quality import job_quality, recording_radius
from service.settings import JobLimits

__all__ = ["output_bytes", "estimate_cost", "hologram_seconds", "calibration_or_none", "plane_border_px", "job_memory",
           "memory_admission_error"]

def _spp(req: JobRequest) -> int:
    """Rays per pixel: the job's, else what its preset typically picks (the renderer chooses from the depth)."""
    return req.spp if req.spp is not None else PRESETS[req.preset].typical_spp


def estimate_cost(req: JobRequest, *, scene_plan: Optional[dict] = None, max_spp: Optional[int] = None,
                  plane_border: Optional[int] = 0, target_db: Optional[float] = None,
                  busy_threads: float = 0.0) -> dict[str, Any]:
    """Predicted seconds of a job, shown at submit time: :func:`_hologram_cost`, plus the evaluation against
    ground truth when the job asks for it (``evaluate_s``, service/workers/evaluation.py's model), and the
    quality its options buy (``quality``, service/quality.py; ``target_db``: the quality target the options
    were chosen for). ``seconds`` is for an idle machine; ``load`` is the machine's load now, less
    ``busy_threads`` (the threads of this service's own running jobs, which a queued job does not run beside),
    and ``seconds_at_load`` the time at that load (``holocore.plan.estimate.load_slowdown``)."""
    cal = calibration_or_none()  # read once for the job and every candidate the quality prices
    out = _hologram_cost(req, scene_plan=scene_plan, max_spp=max_spp, plane_border=plane_border, calibration=cal)
    out["quality"] = job_quality(req, scene_plan=scene_plan, max_spp=max_spp, seconds=out["seconds"],
                                 seconds_of=lambda r: hologram_seconds(r, scene_plan=scene_plan, max_spp=max_spp,
                                                                       calibration=cal),
                                 target_db=target_db)
    if req.evaluate and not evaluation_skipped(req, scene_plan):
        o = effective_optics(req)
        ev = evaluation_seconds(height=o.height, width=o.width, colors=len(o.wavelengths_nm), frames=o.frames)
        out = {**out, "seconds": round(out["seconds"] + ev, 1), "evaluate_s": round(ev, 1),
               "steps_s": {**out["steps_s"], "evaluate": round(ev, 2)}, "model": out["model"] + " + evaluation"}
    load = machine_load(own_threads=busy_threads)
    return {**out, "load": load, "seconds_at_load": round(out["seconds"] * load["slowdown"], 1)}


def evaluation_skipped(req: JobRequest, scene_plan: Optional[dict]) -> Optional[str]:
    """Why a job that asks for an evaluation gets none (its SLM too small to score; None when it gets one):
    such a job's time has no evaluation in it, and its estimate says so in a warning instead."""
    cam = ((scene_plan or {}).get("field_of_view") or {}).get("camera_fov_x_deg")
    return evaluation_too_small(effective_optics(req), camera_fov_x_deg=float(cam) if isinstance(cam, (int, float))
                                else None)


def hologram_seconds(req: JobRequest, *, scene_plan: Optional[dict] = None, max_spp: Optional[int] = None,
                     calibration: Optional[dict] = None) -> float:
    """Predicted seconds of a job's hologram alone (:func:`_hologram_time`'s), without its memory."""
    return float(_hologram_time(req, scene_plan=scene_plan, max_spp=max_spp, calibration=calibration)["seconds"])


def calibration_or_none() -> Optional[dict]:
    """The time model's rates, read once for many predictions; None where none is usable (each prediction then
    falls back as :func:`_hologram_time` does)."""
    try:
        return load_calibration()
    except (ValueError, OSError):
        return None


def _scene_probe(scene_plan: Optional[dict]):
    """The probe render the scene's plan timed (``holo plan --probe``), or None when it has none (a plan made
    before the probe, or a probe that failed)."""
    doc = (scene_plan or {}).get("probe")
    try:
        probe = Probe(startup_s=float(doc["startup_s"]), compile_s=float(doc["compile_s"]),
                      ray_color_s=float(doc["ray_color_s"]), probe_s=float(doc["probe_s"]))
    except (TypeError, KeyError, ValueError):
        return None
    ok = all(math.isfinite(v) and v >= 0 for v in (probe.compile_s, probe.ray_color_s)) and probe.ray_color_s > 0
    return probe if ok else None


def _hologram_cost(req: JobRequest, *, scene_plan: Optional[dict] = None, max_spp: Optional[int] = None,
                   plane_border: Optional[int] = 0, calibration: Optional[dict] = None) -> dict[str, Any]:
    """:func:`_hologram_time` and the job's predicted peak memory (``memory``)."""
    memory = {**job_memory(req, plane_border=plane_border).as_dict(), "plane_border_px": plane_border}
    return {**_hologram_time(req, scene_plan=scene_plan, max_spp=max_spp, calibration=calibration),
            "memory": memory}


# The pictures step's views of the hologram: the preview, a focal sweep of 9 and a 3 x 3 grid of eye positions
# (service/workers/pictures.py), each of every frame and colour.
PICTURE_VIEWS = 1 + 9 + 3 * 3


def _hologram_time(req: JobRequest, *, scene_plan: Optional[dict] = None, max_spp: Optional[int] = None,
                   calibration: Optional[dict] = None) -> dict[str, Any]:
    """Predicted seconds of a job's hologram (render, encode, package, pictures).

    The render and the SGD encoder come from ``holocore.plan.estimate`` (rates calibrated on this machine by
    `holo bench calibrate`, else the committed default), with the scene's depth (its sub-hologram radius, which
    sets the preset's rays per pixel) and primitive count from its effect plan when the plan is ready; plus
    3.5 s for starting each of the job's four processes (driver, render, encode, preview), the DPAC encoder (1e-7
    s per pixel-frame-color) and the pictures (:data:`PICTURE_VIEWS` views, each an ASM of every frame and colour
    at the calibration's rate); ``steps_s`` has each step's seconds (a
    running job's progress is weighed by them, service/workers/runfiles.py). When the scene's plan timed a
    probe render (``holo plan --probe``, run by the planner), the render's stages take the scene's own cost per
    ray and kernel compilation from it (``holocore.plan.estimate_probe``; the calibration alone, made on the demo
    scene, can be 5x low on another). Without a usable calibration: a linear model fitted on a 2-core CPU.
    ``calibration``: the rates (default: loaded here, :func:`holocore.plan.estimate.load_calibration`)."""
    o = effective_optics(req)
    h, w = o.resolution_hw
    c = len(o.wavelengths_nm)
    f = o.frames
    spp = _spp(req) if max_spp is None else min(_spp(req), max_spp)
    rays = h * w * c * spp
    pix = h * w * c * f
    # without an asked count: the optimiser's default (L-BFGS 28; Adam's stop rule ends its 500 far sooner)
    iters = encode_iterations(h, w, optimiser=req.optimiser, iterations=req.iterations)
    # each of the job's four processes (driver, render, encode, preview) starts Python and its imports: 3.5 s
    start = 3.5
    encoder_fixed = 1e-7 * pix if req.encoder == "dpac" else 0.0
    ana = (scene_plan or {}).get("analysis") or {}
    inv = (scene_plan or {}).get("inventory") or {}

    def out(render: float, encode: float, rays_counted: Optional[int], spp_assumed: Optional[int], model: str,
            pictures: float):
        steps = {"render": 2 * start + render, "encode": start + encoder_fixed + encode, "package": 0.0,
                 "preview": start + pictures}
        return {"seconds": round(sum(steps.values()), 1), "rays": rays_counted, "spp_assumed": spp_assumed,
                "encode_s": round(encode, 1), "steps_s": {k: round(v, 2) for k, v in steps.items()}, "model": model}

    try:
        cal = calibration if calibration is not None else load_calibration()
        # each picture is a view of every frame and colour through the ASM on its padded grid
        pictures = cal["rates"]["fft"] * PICTURE_VIEWS * features(o, SimpleNamespace(
            preset=req.preset, spp=1, method=req.method))["fft"]
        options = SimpleNamespace(preset=req.preset, spp=req.spp, method=req.method, max_spp=max_spp)
        radius = recording_radius(scene_plan) if scene_plan else None
        stages = estimate_breakdown(o, options, scene_primitives=inv.get("primitives"), subhologram_radius_px=radius,
                                    encode_iterations=iters if req.encoder == "sgd" else 0,
                                    encode_optimiser=req.optimiser, z_wrp_m=wrp_distance_m(scene_plan, o),
                                    calibration=cal)
        encode = stages.get("encode", 0.0)
        render = stages["total"] - encode
        probe = _scene_probe(scene_plan)
        if probe is not None:  # the scene's own cost per ray (its plan's probe render) for the render's stages
            est = estimate_with_probe(o, options, probe, scene_primitives=inv.get("primitives"),
                                      subhologram_radius_px=radius, calibration=cal)
            render = est["total"] - est["startup"]  # start-up: the processes' own, above
        spp = int(features(o, options, subhologram_radius_px=radius)["spp"])
        if req.render_time_limit_s is not None:  # the render takes its limit; the encoder what it takes
            return out(req.render_time_limit_s, encode, None, None, "render time limit + calibrated encoder", pictures)
        return out(render, encode, h * w * c * spp, spp,
                   "calibrated" + (" + scene probe" if probe is not None else " + scene plan" if ana else ""), pictures)
    except (ValueError, OSError, KeyError, TypeError):  # no usable calibration: the linear model
        enc = 0.0 if req.encoder == "dpac" else 2.5e-7 * pix * iters
        if req.render_time_limit_s is not None:
            return out(req.render_time_limit_s, enc, None, None, "render time limit + cpu-linear-v1 encoder",
                       2e-7 * h * w * c)
        return out(1.5e-6 * rays + 4e-7 * pix, enc, rays, spp, "cpu-linear-v1", 2e-7 * h * w * c)


def plane_border_px(req: JobRequest, *, scene_plan: Optional[dict], plan_state: str = "ready",
                    limits: Optional[JobLimits] = None) -> Optional[int]:
    """The widest border (px) of the job's deeper recording planes: 0 with one plane; when its scene's plan is
    ready, that of the planes its render will keep (holocore.plan.stored_planes: placed on the plan's image
    depths at the job's optics, the deepest cut while they do not fit the render's memory budget,
    HOLO_MEMORY_BUDGET_MB, which the workers inherit); a ValueError, with the CLI's line, when the plane count it
    asks for cannot fit. A plan from before it stored its depths: bounded from the scene's depth and the plane
    distance limit (optics.max_wrp_distance_mm, at most the service's), that bound alone when the plan failed;
    None while the plan is pending (the scheduler asks again before the job runs) or when it does not say the
    depth."""
    if req.method == "direct" or req.wrp_planes == 1:
        return 0
    if plan_state in ("pending", "running"):
        return None
    o = effective_optics(req)
    budget = memory_budget_bytes()
    if plan_state == "ready":
        kept = admitted_planes(scene_plan, o, wrp_planes=req.wrp_planes, budget_bytes=budget)
        if kept is not None:
            return kept.widest_border_px
    bound_m = o.max_wrp_distance_mm * 1e-3
    if limits is not None:
        bound_m = min(bound_m, limits.max_wrp_distance_mm * 1e-3)
    theta = max(o.theta_max(lam) for lam in o.wavelengths_m)
    if plan_state != "ready":  # the plan failed: nothing is known of the scene but the bound
        return deepest_border_px(bound_m, pitch_m=o.pitch_m, theta_max=theta)
    depth = scene_depth_m(scene_plan, o)
    if depth is None:  # a plan without the analysis (from before it was stored): not known
        return None
    # where the planes' depths are not known, every deeper plane is taken at the deepest border
    widest = deepest_border_px(min(depth, bound_m), pitch_m=o.pitch_m, theta_max=theta)
    count = _MOST_PLANES if req.wrp_planes == "auto" else int(req.wrp_planes)
    return admit_planes([0] + [widest] * (count - 1), height_px=o.height, width_px=o.width,
                        colors=len(o.wavelengths_nm), frames=o.frames, pitch_m=o.pitch_m, budget_bytes=budget,
                        auto=req.wrp_planes == "auto").widest_border_px


def job_memory(req: JobRequest, *, plane_border: Optional[int] = 0) -> MemoryEstimate:
    """Predicted peak bytes of the job's render, encode and preview (holocore.plan.memory_estimate), with its
    deeper recording planes' widest border (:func:`plane_border_px`; None, not known yet, counts as 0), and its
    evaluation against ground truth when it asks for one."""
    o = effective_optics(req)
    return estimate_memory(height_px=o.height, width_px=o.width, colors=len(o.wavelengths_nm), frames=o.frames,
                           plane_border_px=plane_border or 0, evaluate=bool(req.evaluate))


def memory_admission_error(req: JobRequest, worker_memory_bytes: int, *,
                           plane_border: Optional[int] = 0) -> Optional[str]:
    """Why the workers cannot hold the job (None when they can)."""
    m = job_memory(req, plane_border=plane_border)
    if m.peak_bytes <= worker_memory_bytes:
        return None
    o = effective_optics(req)
    planes = (f"; its deeper recording planes are {plane_border} px wider on each side than the SLM (their depth "
              "grows with f^2): wrp_planes 1, a shorter f or a shallower scene needs less" if plane_border else "")
    evaluation = ("; its evaluation against ground truth grows with the SLM's pixels: without evaluate it needs "
                  f"{max(m.render_bytes, m.encode_bytes, m.view_bytes) / 1e9:.1f} GB"
                  if m.peak_stage == "evaluate" else "")
    return (f"the job needs about {m.peak_bytes / 1e9:.1f} GB at its peak ({m.peak_stage}; "
            f"{o.height}x{o.width} px x {len(o.wavelengths_nm)} colors x {o.frames} frames), but the workers have "
            f"{worker_memory_bytes / 1e9:.1f} GB: lower optics.resolution_hw, frames or the number of wavelengths "
            f"(memory grows with their product){planes}{evaluation}")


# ---- what a job stores ----------------------------------------------------------------------------------------
# Bytes a job writes per pixel, frame and colour: STACK.npz's float32 phase and 8-bit frames, frames.zip (PNGs
# of those 8-bit frames, at most about their size), RESULT.npz's two complex64 fields when results are kept.
_OUT_PER_SAMPLE = 4 + 1 + 1
_RESULT_PER_SAMPLE = 16
_OUT_FIXED = 4 << 20  # logs, the preview and the pictures, the small files


_MOST_PLANES = MAX_WRP_PLANES  # wrp_planes up to it; auto chooses at most as many


def output_bytes(optics: dict, *, keep_result: bool, wrp_planes="auto", plane_border: Optional[int] = 0,
                 evaluate: bool = False) -> int:
    """The most bytes a job with these (effective) optics has in its folder: what it leaves (its evaluation's
    folder when ``evaluate``), and while it renders the scratch files of its deeper recording planes (each a
    [frames, colours] stack of its grid, ``plane_border`` px wider than the SLM on each side, complex64;
    unlinked, but on the disk until the render ends)."""
    h, w = (int(v) for v in optics.get("resolution_hw") or (1080, 1920))
    c, f = len(optics.get("wavelengths_nm") or (0, 0, 0)), int(optics.get("frames") or 1)
    out = h * w * c * f * (_OUT_PER_SAMPLE + (_RESULT_PER_SAMPLE if keep_result else 0)) + 8 * h * w + _OUT_FIXED
    if evaluate:
        out += evaluation_output_bytes(height_px=h, width_px=w)
    b = int(plane_border or 0)
    deeper = (_MOST_PLANES if wrp_planes == "auto" else int(wrp_planes)) - 1
    return out + (deeper * f * c * (h + 2 * b) * (w + 2 * b) * 8 if b > 0 and deeper > 0 else 0)
