"""What a job may ask for: display numbers that can describe a real display, and the service's limits on a job's
size, rays, time and recording planes (service.settings.JobLimits), each answered as the words a 422 carries."""

from __future__ import annotations

import math
from typing import Any, Optional

from holocore.display.optics import MAX_SIDE_PX, OpticsConfig
from holocore.options import HologramOptions, bounds, choices
from holocore.plan.presets import PRESETS
from service.models import JobRequest, effective_optics
from service.settings import JobLimits

__all__ = ["optics_sanity_errors", "job_limit_errors", "preset_spp_cap", "binding_max_spp", "spp_cap",
           "option_limits"]

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
    service's max_spp and to the request's own max_spp (the render is told the clamp: JobOptions.max_spp)."""
    return min(PRESETS[req.preset].spp_max, limits.max_spp, req.max_spp or limits.max_spp)


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


def option_limits(limits: JobLimits) -> dict[str, dict[str, Any]]:
    """Each hologram option's allowed values on this service (``GET /v1/job-options``, what the page's form bounds
    its boxes with): the model's own (holocore.options), tightened by the service's job limits; and the SLM's
    side in pixels."""
    service_most = {"frames": limits.max_frames, "spp": limits.max_spp, "max_spp": limits.max_spp,
                    "iterations": limits.max_iterations, "render_time_limit_s": limits.max_render_time_s}
    out: dict[str, dict[str, Any]] = {}
    for name, field in HologramOptions.model_fields.items():
        lo, hi = bounds(name)
        if name in service_most:
            hi = min(hi, service_most[name])
        out[name] = {"min": lo, "max": hi, "choices": list(choices(name)), "default": field.default}
    out["resolution_px"] = {"min": 1, "max": min(MAX_SIDE_PX, limits.max_side_px), "choices": [], "default": None}
    return out
