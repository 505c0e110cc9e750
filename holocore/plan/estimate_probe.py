"""A render's time predicted from a short probe render of the scene itself.

The calibrated model (``holocore.plan.estimate``) knows this machine's rates on the calibration scene; a scene it
has never seen differs in what a ray costs (delta depth, glossy share, BVH size, texture lookups), and a
command also pays its start-up and the first kernel compilation. So before predicting, the probe renders the
scene (``holocore.calibration.probe_scene``, above the pipeline) three times with the job's preset, spp and
method and one frame: small (cold), small (warm) and with twice the sides (warm):

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
from dataclasses import dataclass
from typing import Any, Optional

from holocore.display.optics import OpticsConfig
from holocore.plan.estimate import estimate_breakdown, features, load_calibration

__all__ = ["Probe", "PROBE_HW", "process_age_s", "estimate_with_probe"]

PROBE_HW = (32, 64)  # small enough to take a second warm, wide enough for several sub-holograms


@dataclass(frozen=True)
class Probe:
    """What the probe measured: seconds of start-up and compilation, warm seconds per ray and color (an idle
    machine's: divided by ``load_slowdown``, the slowdown of the load other work made as it ran), and its own
    wall time."""

    startup_s: float
    compile_s: float
    ray_color_s: float
    probe_s: float
    load_slowdown: float = 1.0


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


def estimate_with_probe(optics: OpticsConfig, options: Any, probe: Probe, *, scene_primitives: Optional[int],
                        subhologram_radius_px: Optional[float], calibration: Optional[dict] = None) -> dict:
    """Predicted seconds of ``holo render`` by stage (``startup``, ``compile``, the calibrated stages with the
    probe's ray cost) and ``total``."""
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
