"""Request and response bodies of the HTTP API (pydantic; these make the OpenAPI schema at /docs).

Only light imports here: ``holocore.display.optics`` is pydantic and math, nothing heavy (docs/design.md §1).
"""

from __future__ import annotations

import hashlib
import json
import math
from typing import Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field

from holocore.display.optics import OpticsConfig
from holocore.plan.memory_estimate import MemoryEstimate, deepest_border_px, estimate_memory
from holocore.plan.presets import PRESETS
from service.jobfiles import JobFields
from service.scene_view import FieldOfViewBox
from service.settings import JobLimits

__all__ = ["NAME_PATTERN", "ID_PATTERN", "JobRequest", "optics_sanity_errors", "Heartbeat", "Showing", "JobOut", "JobList", "SceneOut",
           "DisplayOut", "DisplayList", "Problem", "job_limit_errors", "job_memory", "memory_admission_error", "cache_key", "effective_optics",
           "estimate_cost", "hologram_seconds", "calibration_or_none", "spp_cap", "preset_spp_cap", "binding_max_spp", "plane_border_px"]

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$"
ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"


class JobRequest(JobFields):
    """A render job: scene, optics, the job fields (service.jobfiles.JobFields: quality, encoder, recording
    layout), and the display it is for."""

    model_config = ConfigDict(extra="forbid")

    scene_id: str = Field(pattern=ID_PATTERN, description="Id from POST /v1/scenes.")
    optics: OpticsConfig = Field(default_factory=OpticsConfig, description="The display's optics (OpticsConfig).")
    display: Optional[str] = Field(default=None, pattern=NAME_PATTERN, description="Display the job is for.")
    name: Optional[str] = Field(default=None, min_length=1, max_length=120, pattern=r"^[^\x00-\x1f\x7f]+$",
                                description="A name for people (the web page offers the uploaded file's); not "
                                            "part of the result's content address.")


class Showing(BaseModel):
    model_config = ConfigDict(extra="forbid")
    job_id: str = Field(max_length=128)
    frame: int = Field(ge=0, le=1_000_000)


class Heartbeat(BaseModel):
    """What a display agent reports every few seconds."""

    model_config = ConfigDict(extra="forbid")
    agent_version: str = Field(max_length=64)
    showing: Optional[Showing] = None
    state: str = Field(max_length=64)
    message: str = Field(default="", max_length=2000)


class JobOut(BaseModel):
    id: str
    name: Optional[str] = None
    state: Literal["queued", "running", "succeeded", "failed", "cancelled"]
    display: Optional[str] = None
    scene_id: str
    created_at: str
    started_at: Optional[str] = None
    finished_at: Optional[str] = None
    stack_sha256: Optional[str] = None
    stack_bytes: Optional[int] = None
    options: dict[str, Any]
    progress: Optional[dict[str, Any]] = None
    timings: Optional[dict[str, Any]] = None
    plan: Optional[dict[str, Any]] = None
    error: Optional[str] = None
    attempts: int = 0
    worker_pid: Optional[int] = None
    estimate: Optional[dict[str, Any]] = None
    reused_from: Optional[str] = None
    cache_key: str
    sent_at: Optional[str] = Field(default=None, description="In GET /v1/jobs?display=NAME only: when the job was "
                                   "last sent to NAME (POST /v1/jobs/{id}/display), else its submit time; that "
                                   "list is in this order, the job the display shows next first.")
    field_of_view_box: Optional[FieldOfViewBox] = Field(
        default=None, description="In GET /v1/jobs/{id} only: where the hologram's view lies in the scene's "
                                  "picture at the job's optics (None until the scene's plan is ready).")
    links: dict[str, str]


class JobList(BaseModel):
    jobs: list[JobOut]


class SceneOut(BaseModel):
    id: str
    sha256: str
    entry: str
    created_at: str
    report: dict[str, Any]
    plan_state: Literal["pending", "running", "ready", "failed"]
    plan: Optional[dict[str, Any]] = None
    plan_error: Optional[str] = None
    picture_url: Optional[str] = Field(default=None, description="The scene through its camera (PNG), made with "
                                       "its plan; None while the plan is pending, or when it failed.")
    field_of_view_box: Optional[FieldOfViewBox] = Field(
        default=None, description="Where the hologram's view lies in that picture at the plan's (the default "
                                  "display's) optics; POST /v1/jobs/estimate gives it at a request's.")


class DisplayOut(BaseModel):
    name: str
    owner: Optional[str] = None
    last_seen: str
    age_s: float
    agent_version: Optional[str] = None
    showing: Optional[dict[str, Any]] = None
    state: Optional[str] = None
    message: Optional[str] = None


class DisplayList(BaseModel):
    displays: list[DisplayOut]


class Problem(BaseModel):
    """RFC 9457 problem details (media type application/problem+json)."""

    type: str = "about:blank"
    title: str
    status: int
    detail: str
    instance: Optional[str] = None


def effective_optics(req: JobRequest) -> OpticsConfig:
    """The optics the job renders with (``frames`` applied)."""
    if req.frames is None:
        return req.optics
    return req.optics.model_copy(update={"frames": req.frames})


# Physical bounds of the numbers a display may have: legal but absurd values (a pitch of 1e-300 um) overflow
# in the numerics long after submit, so they are refused here, in the user's units.
_PITCH_UM = (0.01, 1000.0)
_LENGTH_MM = (0.001, 10_000.0)
_FOV_DEG = (0.001, 179.0)


def optics_sanity_errors(o: OpticsConfig) -> list[str]:
    """Why a display's numbers cannot describe a real display (empty when they can)."""
    errs = []
    if not _PITCH_UM[0] <= o.pitch_um <= _PITCH_UM[1]:
        errs.append(f"optics.pitch_um: must be in {_PITCH_UM[0]}..{_PITCH_UM[1]} um, got {o.pitch_um:g}")
    if not _LENGTH_MM[0] <= o.z_inf_mm <= _LENGTH_MM[1]:
        errs.append(f"optics.z_inf_mm: must be in {_LENGTH_MM[0]}..{_LENGTH_MM[1]} mm, got {o.z_inf_mm:g}")
    if o.focal_length_mm is not None and not _LENGTH_MM[0] <= o.focal_length_mm <= _LENGTH_MM[1]:
        errs.append(f"optics.focal_length_mm: must be in {_LENGTH_MM[0]}..{_LENGTH_MM[1]} mm, got "
                    f"{o.focal_length_mm:g}")
    if o.fov_x_deg is not None:
        if not _FOV_DEG[0] <= o.fov_x_deg <= _FOV_DEG[1]:
            errs.append(f"optics.fov_x_deg: must be in {_FOV_DEG[0]}..{_FOV_DEG[1]} degrees, got {o.fov_x_deg:g}")
        elif not errs:
            f_mm = o.focal_length_m(o.fov_x_deg) * 1e3
            if not (math.isfinite(f_mm) and _LENGTH_MM[0] <= f_mm <= _LENGTH_MM[1]):
                errs.append(f"optics.fov_x_deg: {o.fov_x_deg:g} degrees on this SLM means an eyepiece f of {f_mm:.3g} "
                            f"mm, outside {_LENGTH_MM[0]}..{_LENGTH_MM[1]} mm")
    return errs


def job_limit_errors(req: JobRequest, limits: JobLimits) -> list[str]:
    """Why a job asks for too much (empty when it is within the service's limits)."""
    o = effective_optics(req)
    h, w = o.resolution_hw
    c = len(o.wavelengths_nm)
    errs = []
    if max(h, w) > limits.max_side_px:
        errs.append(f"optics.resolution_hw: each side must be at most {limits.max_side_px} px, got {h}x{w}")
    if h * w > limits.max_pixels:
        errs.append(f"optics.resolution_hw: at most {limits.max_pixels} pixels, got {h * w}")
    if o.frames > limits.max_frames:
        errs.append(f"frames: must be in 1..{limits.max_frames}, got {o.frames}")
    if c > limits.max_wavelengths:
        errs.append(f"optics.wavelengths_nm: at most {limits.max_wavelengths} colors, got {c}")
    if req.spp is not None and req.spp > limits.max_spp:
        errs.append(f"spp: must be in 1..{limits.max_spp}, got {req.spp}")
    if req.render_time_limit_s is not None and req.render_time_limit_s > limits.max_render_time_s:
        errs.append(f"render_time_limit_s: must be in (0, {limits.max_render_time_s:g}] s, "
                    f"got {req.render_time_limit_s:g}")
    if o.max_wrp_distance_mm > limits.max_wrp_distance_mm:
        errs.append(f"optics.max_wrp_distance_mm: at most {limits.max_wrp_distance_mm:g} mm, got "
                    f"{o.max_wrp_distance_mm:g}")
    if req.iterations is not None and req.iterations > limits.max_iterations:
        errs.append(f"iterations: must be in 0..{limits.max_iterations}, got {req.iterations}")
    # The most rays the job may trace: a preset chooses its spp from the scene depth at render time, up to its
    # spp_max (clamped to max_spp), so that bound is what is counted, not a typical value.
    timed = req.render_time_limit_s is not None
    most_spp = spp_cap(req, limits) if timed else (req.spp if req.spp is not None else preset_spp_cap(req, limits))
    rays = h * w * c * most_spp
    if rays > limits.max_ray_budget:
        what = "up to " if timed or req.spp is None else ""
        hint = ("; give a smaller spp, the most rays per pixel of a time-limited render" if timed else
                f"; the {req.preset} preset may choose up to {most_spp} rays per pixel: give a smaller spp or "
                "another preset" if req.spp is None else "")
        errs.append(f"job traces {what}{rays:.3g} rays (H*W*colors*spp), more than the limit "
                    f"{limits.max_ray_budget:.3g}" + hint)
    return errs


def preset_spp_cap(req: JobRequest, limits: JobLimits) -> int:
    """The most rays per pixel the job's preset may choose when spp is not given: its spp_max, clamped to the
    service's max_spp (the render is told the clamp: JobOptions.max_spp)."""
    return min(PRESETS[req.preset].spp_max, limits.max_spp)


def binding_max_spp(req: JobRequest, limits: JobLimits) -> Optional[int]:
    """The clamp the render must apply to its preset's choice of spp: max_spp when it is below the preset's own
    spp_max and spp is not given (None otherwise: the preset's bounds already hold)."""
    if req.spp is not None or req.render_time_limit_s is not None:
        return None
    cap = preset_spp_cap(req, limits)
    return cap if cap < PRESETS[req.preset].spp_max else None


def spp_cap(req: JobRequest, limits: JobLimits) -> int:
    """The most rays per pixel a time-limited job may trace: its spp, else the service's max_spp."""
    return req.spp if req.spp is not None else limits.max_spp


# Rays per pixel a preset typically picks when spp is not given (the renderer chooses from the scene depth,
# between the preset's bounds; see holocore/plan/presets.py PRESETS).
_TYPICAL_SPP = {"fast": 16, "balanced": 128, "reference": 1024}


def _spp(req: JobRequest) -> int:
    return req.spp if req.spp is not None else _TYPICAL_SPP[req.preset]


def estimate_cost(req: JobRequest, *, scene_plan: Optional[dict] = None, max_spp: Optional[int] = None,
                  plane_border: Optional[int] = 0, target_db: Optional[float] = None,
                  busy_threads: float = 0.0) -> dict[str, Any]:
    """Predicted seconds of a job, shown at submit time: :func:`_hologram_cost`, plus the evaluation against
    ground truth when the job asks for it (``evaluate_s``, service/workers/evaluation.py's model), and the
    quality its options buy (``quality``, service/quality.py; ``target_db``: the quality target the options
    were chosen for). ``seconds`` is for an idle machine; ``load`` is the machine's load now, less
    ``busy_threads`` (the threads of this service's own running jobs, which a queued job does not run beside),
    and ``seconds_at_load`` the time at that load (``holocore.plan.estimate.load_slowdown``)."""
    from holocore.plan.estimate import machine_load
    from service.quality import job_quality

    out = _hologram_cost(req, scene_plan=scene_plan, max_spp=max_spp, plane_border=plane_border)
    cal = calibration_or_none()  # read once for every candidate the quality prices
    out["quality"] = job_quality(req, scene_plan=scene_plan, max_spp=max_spp, seconds=out["seconds"],
                                 seconds_of=lambda r: hologram_seconds(r, scene_plan=scene_plan, max_spp=max_spp,
                                                                       calibration=cal),
                                 target_db=target_db)
    if req.evaluate:
        from service.workers.evaluation import evaluation_seconds

        o = effective_optics(req)
        ev = evaluation_seconds(height=o.height, width=o.width, colors=len(o.wavelengths_nm), frames=o.frames)
        out = {**out, "seconds": round(out["seconds"] + ev, 1), "evaluate_s": round(ev, 1),
               "steps_s": {**out["steps_s"], "evaluate": round(ev, 2)}, "model": out["model"] + " + evaluation"}
    load = machine_load(own_threads=busy_threads)
    return {**out, "load": load, "seconds_at_load": round(out["seconds"] * load["slowdown"], 1)}


def hologram_seconds(req: JobRequest, *, scene_plan: Optional[dict] = None, max_spp: Optional[int] = None,
                     calibration: Optional[dict] = None) -> float:
    """Predicted seconds of a job's hologram alone (:func:`_hologram_time`'s), without its memory."""
    return float(_hologram_time(req, scene_plan=scene_plan, max_spp=max_spp, calibration=calibration)["seconds"])


def calibration_or_none() -> Optional[dict]:
    """The time model's rates, read once for many predictions; None where none is usable (each prediction then
    falls back as :func:`_hologram_time` does)."""
    from holocore.plan.estimate import load_calibration

    try:
        return load_calibration()
    except (ValueError, OSError):
        return None


def _scene_probe(scene_plan: Optional[dict]):
    """The probe render the scene's plan timed (``holo plan --probe``), or None when it has none (a plan made
    before the probe, or a probe that failed)."""
    from holocore.plan.estimate_probe import Probe

    doc = (scene_plan or {}).get("probe")
    try:
        probe = Probe(startup_s=float(doc["startup_s"]), compile_s=float(doc["compile_s"]),
                      ray_color_s=float(doc["ray_color_s"]), probe_s=float(doc["probe_s"]))
    except (TypeError, KeyError, ValueError):
        return None
    ok = all(math.isfinite(v) and v >= 0 for v in (probe.compile_s, probe.ray_color_s)) and probe.ray_color_s > 0
    return probe if ok else None


def _hologram_cost(req: JobRequest, *, scene_plan: Optional[dict] = None, max_spp: Optional[int] = None,
                   plane_border: Optional[int] = 0) -> dict[str, Any]:
    """:func:`_hologram_time` and the job's predicted peak memory (``memory``)."""
    memory = {**job_memory(req, plane_border=plane_border).as_dict(), "plane_border_px": plane_border}
    return {**_hologram_time(req, scene_plan=scene_plan, max_spp=max_spp), "memory": memory}


def _hologram_time(req: JobRequest, *, scene_plan: Optional[dict] = None, max_spp: Optional[int] = None,
                   calibration: Optional[dict] = None) -> dict[str, Any]:
    """Predicted seconds of a job's hologram (render, encode, package, pictures).

    The render and the SGD encoder come from ``holocore.plan.estimate`` (rates calibrated on this machine by
    `holo bench calibrate`, else the committed default), with the scene's depth (its sub-hologram radius, which
    sets the preset's rays per pixel) and primitive count from its effect plan when the plan is ready; plus
    3.5 s for starting each of the job's four processes (driver, render, encode, preview), the DPAC encoder (1e-7
    s per pixel-frame-color) and the preview (2e-7 s per pixel-color); ``steps_s`` has each step's seconds (a
    running job's progress is weighed by them, service/workers/runfiles.py). When the scene's plan timed a probe render (``holo plan --probe``, run by
    the planner), the render's stages take the scene's own cost per ray and kernel compilation from it
    (``holocore.plan.estimate_probe``; the calibration alone, made on the demo scene, can be 5x low on
    another). Without a usable calibration: a linear model fitted on a 2-core CPU. ``calibration``: the rates
    (default: loaded here, :func:`holocore.plan.estimate.load_calibration`)."""
    from types import SimpleNamespace

    o = effective_optics(req)
    h, w = o.resolution_hw
    c = len(o.wavelengths_nm)
    f = o.frames
    spp = _spp(req) if max_spp is None else min(_spp(req), max_spp)
    rays = h * w * c * spp
    pix = h * w * c * f
    from holocore.plan.estimate import stop_iterations

    # without an asked count the encoder runs to at most 500 iterations, but its stop rule ends it far sooner
    iters = req.iterations if req.iterations is not None else stop_iterations(h, w)
    # each of the job's four processes (driver, render, encode, preview) starts Python and its imports: 3.5 s
    start = 3.5
    encoder_fixed = 1e-7 * pix if req.encoder == "dpac" else 0.0
    preview = start + 2e-7 * h * w * c
    ana = (scene_plan or {}).get("analysis") or {}
    inv = (scene_plan or {}).get("inventory") or {}

    def out(render: float, encode: float, rays_counted: Optional[int], spp_assumed: Optional[int], model: str):
        steps = {"render": 2 * start + render, "encode": start + encoder_fixed + encode, "package": 0.0,
                 "preview": preview}
        return {"seconds": round(sum(steps.values()), 1), "rays": rays_counted, "spp_assumed": spp_assumed,
                "encode_s": round(encode, 1), "steps_s": {k: round(v, 2) for k, v in steps.items()}, "model": model}

    try:
        from holocore.plan.estimate import estimate_breakdown, features
        from holocore.plan.estimate_probe import estimate_with_probe

        options = SimpleNamespace(preset=req.preset, spp=req.spp, method=req.method, max_spp=max_spp)
        radius = ana.get("subhologram_radius_px")
        stages = estimate_breakdown(o, options, scene_primitives=inv.get("primitives"), subhologram_radius_px=radius,
                                    encode_iterations=iters if req.encoder == "sgd" else 0,
                                    z_wrp_m=_wrp_distance_m(o, scene_plan), calibration=calibration)
        encode = stages.get("encode", 0.0)
        render = stages["total"] - encode
        probe = _scene_probe(scene_plan)
        if probe is not None:  # the scene's own cost per ray (its plan's probe render) for the render's stages
            est = estimate_with_probe(o, options, probe, scene_primitives=inv.get("primitives"),
                                      subhologram_radius_px=radius, calibration=calibration)
            render = est["total"] - est["startup"]  # start-up: the processes' own, above
        spp = int(features(o, options, subhologram_radius_px=radius)["spp"])
        if req.render_time_limit_s is not None:  # the render takes its limit; the encoder what it takes
            return out(req.render_time_limit_s, encode, None, None, "render time limit + calibrated encoder")
        return out(render, encode, h * w * c * spp, spp,
                   "calibrated" + (" + scene probe" if probe is not None else " + scene plan" if ana else ""))
    except (ValueError, OSError, KeyError, TypeError):  # no usable calibration: the linear model
        enc = 0.0 if req.encoder == "dpac" else 2.5e-7 * pix * iters
        if req.render_time_limit_s is not None:
            return out(req.render_time_limit_s, enc, None, None, "render time limit + cpu-linear-v1 encoder")
        return out(1.5e-6 * rays + 4e-7 * pix, enc, rays, spp, "cpu-linear-v1")


def _wrp_distance_m(o: OpticsConfig, scene_plan: Optional[dict]) -> Optional[float]:
    """The WRP's distance from the SLM with these optics (m), from the scene's plan (made at its own optics):
    its depth beyond z_inf scales with (f / f_plan)^2 like every hologram depth. None (z_inf is then assumed)
    when the plan does not say."""
    try:
        ana = scene_plan["analysis"]
        f_plan = float(scene_plan["focal_length_m"])
        beyond = float(ana["z_wrp_m"]) - float(scene_plan["optics"]["z_inf_mm"]) * 1e-3
        f = o.focal_length_m((scene_plan.get("field_of_view") or {}).get("camera_fov_x_deg"))
    except (KeyError, TypeError, ValueError):
        return None
    z = o.z_inf_m + (f / f_plan) ** 2 * beyond
    return z if math.isfinite(z) and z > 0 else None


def _scene_depth_m(o: OpticsConfig, scene_plan: Optional[dict]) -> Optional[float]:
    """How far behind the WRP the scene's farthest image point lies with these optics (m), from the scene's
    plan (made at its own optics): hologram depth is z_inf + f^2 / zc, so depths scale with (f / f_plan)^2,
    and the WRP lies one margin in front of the nearest point. None when the plan does not say."""
    try:
        ana = scene_plan["analysis"]
        near, far = ana["z_near_holo_m"], ana["z_far_holo_m"]
        f_plan = float(scene_plan["focal_length_m"])
        z_inf_plan = float(scene_plan["optics"]["z_inf_mm"]) * 1e-3
        cam_fov = (scene_plan.get("field_of_view") or {}).get("camera_fov_x_deg")
        f = o.focal_length_m(cam_fov)
    except (KeyError, TypeError, ValueError):
        return None
    if near is None or far is None:  # nothing visible: one plane will do
        return 0.0
    scale = (f / f_plan) ** 2
    theta_min = min(o.theta_max(lam) for lam in o.wavelengths_m)
    margin = o.wrp_margin_px * o.pitch_m / math.tan(theta_min)
    depth = scale * (float(near) - float(far)) + margin
    return depth if math.isfinite(depth) and depth >= 0 else None


def plane_border_px(req: JobRequest, *, scene_plan: Optional[dict], plan_state: str = "ready",
                    limits: Optional[JobLimits] = None) -> Optional[int]:
    """The widest border (px) a deeper recording plane of the job can have: 0 with one plane; from the scene's
    depth at the job's optics when its plan is ready, bounded by the plane distance limit
    (optics.max_wrp_distance_mm, at most the service's), that bound alone when the plan failed; None while the
    plan is pending (the scheduler asks again before the job runs) or when it does not say the depth."""
    if req.method == "direct" or req.wrp_planes == 1:
        return 0
    o = effective_optics(req)
    bound_m = o.max_wrp_distance_mm * 1e-3
    if limits is not None:
        bound_m = min(bound_m, limits.max_wrp_distance_mm * 1e-3)
    if plan_state in ("pending", "running"):
        return None
    theta = max(o.theta_max(lam) for lam in o.wavelengths_m)
    if plan_state != "ready":  # the plan failed: nothing is known of the scene but the bound
        return deepest_border_px(bound_m, pitch_m=o.pitch_m, theta_max=theta)
    depth = _scene_depth_m(o, scene_plan)
    if depth is None:  # a plan without the analysis (from before it was stored): not known
        return None
    return deepest_border_px(min(depth, bound_m), pitch_m=o.pitch_m, theta_max=theta)


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


def cache_key(req: JobRequest, *, scene_sha256: str, entry: str, code_version: str,
              max_spp: Optional[int] = None) -> str:
    """Content address of a job's result: scene content + optics + options + code version (not the display).
    ``max_spp``: the clamp on the preset's choice of spp (:func:`binding_max_spp`), when there is one."""
    # every job field (service.jobfiles.JobFields) but frames, which the effective optics hold: a field added
    # there is part of the address without a line here, so no two jobs that differ in one share a result
    fields = {k: v for k, v in req.fields().items() if k != "frames"}
    doc = {"scene": scene_sha256, "entry": entry, "optics": effective_optics(req).model_dump(mode="json"),
           "fields": fields, "code": code_version, **({"max_spp": max_spp} if max_spp is not None else {})}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()
