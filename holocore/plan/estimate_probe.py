"""A render's time predicted from a short probe render of the scene itself (issue 11 item 2).

The calibrated model (``holocore.plan.estimate``) knows this machine's rates on the calibration scene; a scene it
has never seen differs in what a ray costs (delta depth, glossy share, BVH size, texture lookups), and a
command also pays its start-up and the first kernel compilation. So before predicting, the probe renders the
scene three times with the job's preset, spp and method and one frame: small (cold), small (warm) and with
twice the sides (warm):

    compile_s  = t_cold - t_warm                                    (the first render compiles the kernels)
    ray_s      = (work_big - work_small) / ((rays_big - rays_small) C)   (warm seconds per ray and color;
                 work = the tracer's trace + accumulate seconds, so fixed per-render costs cancel)

and the prediction of ``holo render`` is

    startup_s + compile_s + calibrated stages, with the trace and accumulation of one frame replaced by
    ray_s R C (R = H W N rays, C colors) and the per-frame accumulation kept from the calibration,

where ``startup_s`` is the time from the process's start to the loaded scene (imports, Mitsuba, the bundle
check), measured by the caller. Every quantity is in seconds.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Any, Optional

from holocore.display.optics import OpticsConfig

__all__ = ["Probe", "process_age_s", "probe_scene", "estimate_with_probe"]

PROBE_HW = (32, 64)  # small enough to take a second warm, wide enough for several sub-holograms


@dataclass(frozen=True)
class Probe:
    """What the probe measured: seconds of start-up and compilation, warm seconds per ray and color."""

    startup_s: float
    compile_s: float
    ray_color_s: float
    probe_s: float


def process_age_s() -> float:
    """Seconds since this process started (Linux: /proc), 0 where that cannot be read."""
    try:
        with open("/proc/self/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
        start_ticks = int(fields[19])
        with open("/proc/uptime") as fh:
            uptime = float(fh.read().split()[0])
        return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return 0.0


def _work(result: Any) -> tuple[float, float]:
    """(rays, seconds of tracing and accumulation) of a render's meta."""
    stats, timings = result.meta.get("stats") or {}, result.meta.get("timings") or {}
    rays = float(stats.get("rays") or 0)
    work = float(stats.get("seconds_trace", 0.0)) + float(stats.get("seconds_accumulate", 0.0))
    if rays <= 0 or work <= 0:  # a black scene traces nothing: the whole trace stage then
        return max(rays, 1.0), float(timings.get("trace_s", 0.0))
    return rays, work


def probe_scene(loaded: Any, optics: OpticsConfig, options: Any, *, startup_s: float) -> Probe:
    """Render ``loaded`` at ``PROBE_HW`` (cold, then warm) and at twice its sides (warm), one frame, with
    ``options``; the warm pair's difference is the cost of the extra rays alone (no fixed costs)."""
    from holocore.pipeline import render_loaded

    small = optics.model_copy(update={"resolution_hw": PROBE_HW, "frames": 1})
    big = small.model_copy(update={"resolution_hw": (2 * PROBE_HW[0], 2 * PROBE_HW[1])})
    t0 = time.perf_counter()
    render_loaded(loaded, small, options)
    t1 = time.perf_counter()
    warm_small = render_loaded(loaded, small.model_copy(update={"seed": small.seed + 1}), options)
    t2 = time.perf_counter()
    warm_big = render_loaded(loaded, big, options)
    t3 = time.perf_counter()
    (r1, w1), (r2, w2) = _work(warm_small), _work(warm_big)
    n_colors = len(optics.wavelengths_m)
    per_ray = (w2 - w1) / (r2 - r1) if r2 > r1 and w2 > w1 else w2 / r2
    return Probe(startup_s=float(startup_s), compile_s=max(0.0, (t1 - t0) - (t2 - t1)),
                 ray_color_s=per_ray / n_colors, probe_s=t3 - t0)


def estimate_with_probe(optics: OpticsConfig, options: Any, probe: Probe, *, scene_primitives: Optional[int],
                        subhologram_radius_px: Optional[float], calibration: Optional[dict] = None) -> dict:
    """Predicted seconds of ``holo render`` by stage (``startup``, ``compile``, the calibrated stages with the
    probe's ray cost) and ``total``."""
    from holocore.plan.estimate import estimate_breakdown, features, load_calibration

    cal = calibration if calibration is not None else load_calibration()
    out = estimate_breakdown(optics, options, scene_primitives=scene_primitives,
                             subhologram_radius_px=subhologram_radius_px, calibration=cal)
    x = features(optics, options, subhologram_radius_px=subhologram_radius_px)
    r = cal["rates"]
    out["trace"] = r["tile"] * x["tiles"] + probe.ray_color_s * x["acc"]  # the scene's own warm ray cost
    out["accumulate"] = r["acc_frame"] * x["acc_frame"]  # what more frames add (a one-frame probe has none)
    out["startup"] = probe.startup_s
    out["compile"] = probe.compile_s
    out.pop("total")
    out["total"] = float(sum(out.values()))
    return out
