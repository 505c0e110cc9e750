"""From a scene and the optics to the WRP and SLM fields (DESIGN.md §1): load -> plan -> analyse -> trace ->
propagate. This is what `holo render` and the service's workers call."""

from __future__ import annotations

import json
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Literal, Optional

import numpy as np

from holocore import __version__
from holocore.config import OpticsConfig
from holocore.display import DisplayProfile

__all__ = ["RenderOptions", "RenderResult", "render", "render_loaded", "plan_scene"]

ProgressFn = Callable[[str, int, int], None]


@dataclass(frozen=True)
class RenderOptions:
    preset: Literal["fast", "balanced", "reference"] = "balanced"
    spp: Optional[int] = None
    method: Literal["wrp", "direct"] = "wrp"
    force_all_effects: bool = False
    tile_rays: int = 1 << 19

    def __post_init__(self) -> None:
        if self.method not in ("wrp", "direct"):
            raise ValueError(f"method must be 'wrp' or 'direct', got {self.method!r}")
        if self.spp is not None and not 1 <= self.spp <= 1_000_000:
            raise ValueError(f"spp must be in 1..1000000, got {self.spp}")


@dataclass
class RenderResult:
    slm_field: np.ndarray  # complex64 [F, C, H, W]
    wrp_field: np.ndarray  # complex64 [F, C, H, W]
    meta: dict


def plan_scene(loaded, optics: OpticsConfig, options: RenderOptions = RenderOptions()) -> dict:
    """The effect plan and the analysis of a loaded scene, without tracing the hologram. ``field_of_view``
    compares the hologram's view, 2 atan(W p / 2f), with the scene camera's; the plan's summary says it."""
    from holocore.analysis import analyze
    from holocore.display import field_of_view_report
    from holocore.effects import inventory, make_plan
    from holocore.mapping import HologramMap

    f = optics.focal_length_m(loaded.fov_x_deg)
    fov = field_of_view_report(optics, loaded.fov_x_deg)
    hmap = HologramMap.from_sensor(loaded.sensor, focal_length_m=f, z_inf_m=optics.z_inf_m)
    inv = inventory(loaded.scene)
    ana = analyze(loaded.scene, hmap, wavelengths_m=list(optics.wavelengths_m), pitch_m=optics.pitch_m,
                  shape_hw=optics.resolution_hw, margin_px=optics.wrp_margin_px,
                  max_wrp_distance_m=optics.max_wrp_distance_mm * 1e-3, seed=optics.seed)
    plan = make_plan(inv, preset=options.preset, frames=optics.frames, n_colors=len(optics.wavelengths_m),
                     colors_lit=ana.colors_lit, spp=options.spp, force_all=options.force_all_effects,
                     max_delta_seen=ana.max_delta_seen, prepass_capped=ana.prepass_capped,
                     subhologram_radius_px=ana.subhologram_radius_px,
                     theta_max=max(optics.theta_max(lam) for lam in optics.wavelengths_m))
    plan = plan.model_copy(update={"summary": [*plan.summary, fov["summary"]]})
    return {"hmap": hmap, "inventory": inv, "analysis": ana, "plan": plan, "focal_length_m": f,
            "field_of_view": fov}


def _banks(optics: OpticsConfig, shape_hw, device="cpu"):
    import torch

    from holocore.randomfield import phase_bank

    # Stored cell-major, all colors together ([H, W, C, F] in memory, each color seen as [F, H, W]): the tracer
    # gathers every frame of every color of a cell at once (tracer.combined_cells).
    H, W = shape_hw
    F, C = optics.frames, len(optics.wavelengths_m)
    cells = torch.empty((H, W, C, F), dtype=torch.complex64, device=device)
    for c, lam in enumerate(optics.wavelengths_m):
        ph = phase_bank(F, shape_hw, lam, optics.pitch_m, seed=optics.seed, device=device)
        cells[:, :, c, :] = torch.polar(torch.ones_like(ph), ph).to(torch.complex64).permute(1, 2, 0)
    return [cells[:, :, c, :].permute(2, 0, 1) for c in range(C)]


def render_loaded(loaded, optics: OpticsConfig, options: RenderOptions = RenderOptions(), *,
                  progress: Optional[ProgressFn] = None, display: Optional[DisplayProfile] = None) -> RenderResult:
    """Render a loaded scene: WRP field (two-stage) or SLM field (direct), then ASM to the other plane.
    ``display``: the profile ``optics`` came from, recorded in the meta (``display_profile``, ``display``)."""
    import torch

    from holocore.mitsuba_env import mitsuba, variant
    from holocore.propagation import asm
    from holocore.radiance_cache import build_cache
    from holocore.tracer import TraceSettings, TraceStats, trace_field

    mi = mitsuba()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pl = plan_scene(loaded, optics, options)
    hmap, ana, plan = pl["hmap"], pl["analysis"], pl["plan"]
    timings["analysis_s"] = time.perf_counter() - t0
    if progress:
        progress("analysis", 1, 1)
    H, W = optics.resolution_hw
    C, F = len(optics.wavelengths_m), optics.frames
    z_wrp = ana.z_wrp_m

    t1 = time.perf_counter()
    banks = _banks(optics, (H, W)) if plan.random_phase else None
    timings["bank_s"] = time.perf_counter() - t1

    integrator = mi.load_dict({"type": "path", "max_depth": max(1, plan.gi_depth)})
    cache = None
    if plan.use_cache:
        t2 = time.perf_counter()
        cache = build_cache(loaded.scene, hmap, shape_hw=(H, W), pitch_m=optics.pitch_m,
                            max_depth=max(1, plan.gi_depth), seed=optics.seed)
        timings["cache_s"] = time.perf_counter() - t2
    settings = TraceSettings(spp=plan.spp, amp_spp=plan.amp_spp, max_depth=max(1, plan.gi_depth),
                             max_delta=plan.max_delta if plan.coherent_delta else 0,
                             tile_rays=options.tile_rays, random_phase=plan.random_phase)
    stats = TraceStats()
    lit = plan.colors_lit
    wl_lit = [lam for lam, on in zip(optics.wavelengths_m, lit) if on]
    field = np.zeros((F, C, H, W), dtype=np.complex64)
    t3 = time.perf_counter()
    if wl_lit:
        plane = z_wrp if options.method == "wrp" else 0.0
        traced = trace_field(loaded.scene, hmap, wavelengths_m=wl_lit, pitch_m=optics.pitch_m, shape_hw=(H, W),
                             plane_z_m=plane, z_wrp_m=z_wrp, frames=F, settings=settings, integrator=integrator,
                             seed=optics.seed, radiance_cache=cache,
                             bank_phasors=None if banks is None else [b for b, on in zip(banks, lit) if on],
                             progress=progress, stats=stats)
        field[:, [i for i, on in enumerate(lit) if on]] = traced
    timings["trace_s"] = time.perf_counter() - t3

    t4 = time.perf_counter()
    out = np.empty_like(field)
    for c, lam in enumerate(optics.wavelengths_m):
        u = torch.from_numpy(field[:, c])
        dz = -z_wrp if options.method == "wrp" else z_wrp
        out[:, c] = asm(u, dz, lam, optics.pitch_m).numpy()
    timings["propagate_s"] = time.perf_counter() - t4
    timings["total_s"] = time.perf_counter() - t0
    if progress:
        progress("propagate", 1, 1)
    slm, wrp = (out, field) if options.method == "wrp" else (field, out)

    meta: dict[str, Any] = {
        "focal_length_m": pl["focal_length_m"],
        "z_inf_m": optics.z_inf_m,
        "z_wrp_m": z_wrp,
        "pitch_m": optics.pitch_m,
        "wavelengths_m": list(optics.wavelengths_m),
        "shape_fchw": [F, C, H, W],
        "method": options.method,
        "preset": options.preset,
        "scene": str(loaded.entry),
        "scene_sha256": getattr(loaded.bundle, "sha256", None),
        "optics": json.loads(optics.model_dump_json()),
        "plan": json.loads(plan.model_dump_json()),
        "analysis": json.loads(ana.model_dump_json()),
        "inventory": json.loads(pl["inventory"].model_dump_json()),
        "field_of_view": pl["field_of_view"],
        **_display_meta(display, optics),
        "stats": stats.as_dict(),
        "timings": timings,
        "versions": _versions(variant()),
    }
    return RenderResult(slm_field=slm, wrp_field=wrp, meta=meta)


def render(scene_path: str | Path, optics: OpticsConfig, options: RenderOptions = RenderOptions(), *,
           progress: Optional[ProgressFn] = None, display: Optional[DisplayProfile] = None) -> RenderResult:
    """Check and load a scene bundle, then :func:`render_loaded`."""
    from holocore.scene import load_scene

    return render_loaded(load_scene(scene_path), optics, options, progress=progress, display=display)


def _display_meta(display: Optional[DisplayProfile], optics: OpticsConfig) -> dict:
    """``display_profile`` (None: optics given directly, no profile) and ``display`` for a result's meta."""
    if display is None:
        return {"display_profile": None, "display": None}
    from holocore.display import display_meta

    return display_meta(display, optics)


def _versions(mi_variant: str) -> dict:
    import drjit
    import mitsuba
    import torch

    return {"holocore": __version__, "mitsuba": mitsuba.__version__, "drjit": drjit.__version__,
            "torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version(),
            "variant": mi_variant}
