"""What `holo render --estimate` prints: the render's time (a probe render of the scene, and the calibrated model),
the encode's, the machine's load, the predicted quality with its alternatives, and the peak memory. Imports of
Mitsuba, Dr.Jit and torch stay inside the functions, so `holo` starts fast for the commands that need none."""

from __future__ import annotations

from pathlib import Path

from holo.common import fail
from holo.render_quality import estimate_lines, quality_context
from holocore.plan.encode_steps import DEFAULT_OPTIMISER, rule
from holocore.plan.estimate import (
    encode_iterations,
    encode_work,
    estimate_seconds,
    load_calibration,
    machine_load,
    user_calibration_path,
)
from holocore.plan.estimate_probe import estimate_with_probe, process_age_s
from holocore.plan.memory_estimate import estimate_memory

__all__ = ["print_estimate"]


def print_estimate(scene: Path, loaded, optics_cfg, options, profile, console) -> None:
    """Print the estimate of rendering ``scene`` (``loaded`` when already loaded) at these options."""
    from holocore.calibration import probe_scene  # Mitsuba and Dr.Jit: only once an estimate is asked for
    from holocore.pipeline import plan_scene
    from holocore.scene.load import load_scene

    try:  # the scene's depth sets the preset's rays per pixel; its size, the cost of a ray
        loaded = loaded or load_scene(scene)
        startup = process_age_s()
        pl = plan_scene(loaded, optics_cfg, options)
        probe = probe_scene(loaded, optics_cfg, options, startup_s=startup)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    cal = load_calibration()
    secs = estimate_seconds(optics_cfg, options, scene_primitives=pl.inventory.primitives,
                            subhologram_radius_px=pl.analysis.subhologram_radius_px, calibration=cal)
    source = f"calibrated on {cal.get('scene', 'this machine')}" if user_calibration_path().is_file() else \
        "committed default calibration; run `holo bench calibrate` on this machine for a closer figure"
    full = estimate_with_probe(optics_cfg, options, probe, scene_primitives=pl.inventory.primitives,
                               subhologram_radius_px=pl.analysis.subhologram_radius_px, calibration=cal)
    console.print(f"estimated time of `holo render`: {full['total']:.1f} s (start-up {full['startup']:.1f} s, "
                  f"kernel compilation {full['compile']:.1f} s, tracing {full['trace']:.1f} s at this scene's "
                  f"cost per ray from a {probe.probe_s:.1f} s probe render)")
    console.print(f"estimated warm render time: {secs:.1f} s ({source})")
    console.print(_encode_estimate(optics_cfg, options, pl, cal))
    load = machine_load()
    slower = (f": at that load expect about {load['slowdown']:.1f}x longer (the render about "
              f"{full['total'] * load['slowdown']:.0f} s)" if load["slowdown"] >= 1.2 else "")
    console.print(f"these times are for an otherwise idle machine; {load['runnable']:.1f} threads are running or "
                  f"ready on its {load['cores']} cores now (one-minute load average {load['load_1min']:.1f})"
                  + slower)
    qctx = quality_context(loaded, pl, profile, optics_cfg, probe=probe, calibration=cal)
    for line in estimate_lines(qctx, optics_cfg, options, most_frames=max(optics_cfg.frames, profile.frames)):
        console.print(line)
    theta = max(optics_cfg.theta_max(lam) for lam in optics_cfg.wavelengths_m)
    border = max(pl.planes.borders_px(pitch_m=optics_cfg.pitch_m, theta_max=theta))
    mem = estimate_memory(height_px=optics_cfg.height, width_px=optics_cfg.width,
                          colors=len(optics_cfg.wavelengths_nm), frames=optics_cfg.frames, plane_border_px=border)
    console.print(f"estimated peak memory: render {mem.render_bytes / 1e9:.2f} GB, encode (sgd) "
                  f"{mem.encode_bytes / 1e9:.2f} GB, view {mem.view_bytes / 1e9:.2f} GB")


def _encode_estimate(optics_cfg, options, pl, cal) -> str:
    """The line on `holo encode`'s time (sgd, its default optimiser's iterations; Adam's stop rule for the one who
    asks for Adam: the median and 90th percentile of the iterations that rule runs at this size), on the
    encoder's grid at this scene's WRP distance."""
    h, w = optics_cfg.height, optics_cfg.width
    n = encode_iterations(h, w)
    med, p90 = (encode_iterations(h, w, optimiser="adam", quantile=q) for q in ("median", "p90"))
    per_it = cal["rates"]["enc"] * encode_work(optics_cfg, pl.analysis.z_wrp_m)
    return (f"estimated `holo encode` time (sgd): {per_it * rule(None).cost * n:.1f} s ({n} {DEFAULT_OPTIMISER} "
            f"iterations); with --optimiser adam {per_it * med:.1f} s ({med} iterations, its stop rule's median at "
            f"this size; up to {per_it * p90:.1f} s at its 90th percentile, {p90})")
