"""From a scene and the optics to the WRP and SLM fields (DESIGN.md §1): load -> plan -> analyse -> trace ->
propagate. This is what `holo render` and the service's workers call.

Memory is bounded by a budget (:mod:`holocore.runtime.membudget`: keyword, HOLO_MEMORY_BUDGET_MB, default 8 GiB) that
sizes chunks of frames: the tracer runs one pass per chunk of frames whose random-phase bank fits (one pass
for every frame when it fits, as it does at 1080x1920 x 3 x 24 in 8 GiB; each pass retraces the same rays, so
the result does not depend on the chunking), and the propagation runs per chunk of frames and color.
:func:`render_to_file` streams both fields into RESULT.npz (the traced one through a scratch file), so no
[F, C, H, W] array is ever held; :func:`render` / :func:`render_loaded` return them in memory.
"""

from __future__ import annotations

import json
import math
import platform
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Literal, Optional, Union

import numpy as np

from holocore import __version__
from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, OpticsConfig
from holocore.display.profiles import DisplayProfile
from holocore.optics.cone_equaliser import plane_equalisers
from holocore.optics.plane_chain import chain_planes
from holocore.plan.presets import RENDER_METHODS, PresetName, RenderMethod
from holocore.plan.scene_plan import ScenePlan
from holocore.plan.time_budget import SppSchedule
from holocore.sinks import FileSink, MemorySink

__all__ = ["RenderOptions", "RenderResult", "render", "render_loaded", "render_to_file", "plan_scene"]

ProgressFn = Callable[[str, int, int], None]


@dataclass(frozen=True)
class RenderOptions:
    preset: PresetName = "balanced"
    spp: Optional[int] = None
    max_spp: Optional[int] = None  # without spp: the most rays per pixel the preset may choose (a service's cap)
    method: RenderMethod = "wrp"
    force_all_effects: bool = False
    tile_rays: int = 1 << 19
    wrp_planes: Union[int, Literal["auto"]] = "auto"  # recording planes (holocore.plan.wrp_planes); "auto": from the depth
    stratified: bool = True  # each pixel's rays stratified over the cone (holocore.trace.hologram_rays); False: independent
    ray_seed: Optional[int] = None  # seed of the traced rays alone (None: the optics' seed, which also seeds the
    # random-phase bank): two ray seeds give independent Monte Carlo estimates of one field
    cone_equaliser: bool = True  # flatten each recording plane's spectrum (holocore.optics.cone_equaliser)
    equalise_noise: bool = True  # ... signal plus its fitted Monte Carlo noise (Eq. C4); False: signal alone (C3),
    # a linear filter, for comparing estimators by their noise
    time_limit_s: Optional[float] = None  # wall time of the whole render, s: passes of rays until it is spent
    # (holocore.plan.time_budget; ``spp`` is then the most rays per pixel); None: one pass of ``spp``

    def __post_init__(self) -> None:
        from holocore.plan.wrp_planes import MAX_WRP_PLANES

        if self.method not in RENDER_METHODS:
            raise ValueError(f"method must be 'wrp' or 'direct', got {self.method!r}")
        if self.wrp_planes != "auto" and not (isinstance(self.wrp_planes, int)
                                              and 1 <= self.wrp_planes <= MAX_WRP_PLANES):
            raise ValueError(f"wrp_planes must be 1..{MAX_WRP_PLANES} or 'auto', got {self.wrp_planes!r}")
        if self.method == "direct" and self.wrp_planes not in (1, "auto"):
            raise ValueError("several recording planes need method 'wrp' (the direct method records on the SLM)")
        if self.spp is not None and not 1 <= self.spp <= 1_000_000:
            raise ValueError(f"spp must be in 1..1000000, got {self.spp}")
        if self.max_spp is not None and not 1 <= self.max_spp <= 1_000_000:
            raise ValueError(f"max_spp must be in 1..1000000, got {self.max_spp}")
        if self.time_limit_s is not None and not (isinstance(self.time_limit_s, (int, float))
                                                  and 0 < self.time_limit_s < 1e7):
            raise ValueError(f"time_limit_s must be in (0, 1e7) s, got {self.time_limit_s!r}")


@dataclass
class RenderResult:
    slm_field: np.ndarray  # complex64 [F, C, H, W]
    wrp_field: np.ndarray  # complex64 [F, C, H, W]
    meta: dict


def plan_scene(loaded, optics: OpticsConfig, options: RenderOptions = RenderOptions()) -> ScenePlan:
    """The effect plan and the analysis of a loaded scene, without tracing the hologram. ``field_of_view``
    compares the hologram's view, 2 atan(W p / 2f), with the scene camera's; the plan's summary says it."""
    from holocore.display.profiles import field_of_view_report
    from holocore.plan.analysis import analyze
    from holocore.plan.effects import inventory, make_plan
    from holocore.plan.wrp_planes import WrpPlanes, choose_planes, place_planes
    from holocore.trace.mapping import HologramMap

    f = optics.focal_length_m(loaded.fov_x_deg)
    fov = field_of_view_report(optics, loaded.fov_x_deg)
    hmap = HologramMap.from_sensor(loaded.sensor, focal_length_m=f, z_inf_m=optics.z_inf_m)
    inv = inventory(loaded.scene)
    ana = analyze(loaded.scene, hmap, wavelengths_m=list(optics.wavelengths_m), pitch_m=optics.pitch_m,
                  shape_hw=optics.resolution_hw, margin_px=optics.wrp_margin_px,
                  max_wrp_distance_m=optics.max_wrp_distance_mm * 1e-3, seed=optics.seed)
    theta_max = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    px_per_m = math.tan(min(theta_max, MAX_CONE_HALF_ANGLE_RAD)) / optics.pitch_m  # sub-hologram radius per distance
    depths, margin = ana.image_depths_holo_m, ana.margin_m
    if options.method == "direct" or options.wrp_planes == 1:
        planes = WrpPlanes((ana.z_wrp_m,), margin)
    elif options.wrp_planes == "auto":
        planes = choose_planes(depths, z_wrp_m=ana.z_wrp_m, margin_m=margin)
    else:
        planes = place_planes(depths, z_wrp_m=ana.z_wrp_m, margin_m=margin, count=options.wrp_planes)
    # The noise target is set by the farthest image point from the plane that records it.
    radius_px = ana.subhologram_radius_px if planes.count == 1 or not depths else \
        planes.farthest_distance_m(depths) * px_per_m
    plan = make_plan(inv, preset=options.preset, frames=optics.frames, n_colors=len(optics.wavelengths_m),
                     colors_lit=ana.colors_lit, spp=options.spp, max_spp=options.max_spp,
                     force_all=options.force_all_effects,
                     max_delta_seen=ana.max_delta_seen, prepass_capped=ana.prepass_capped,
                     subhologram_radius_px=radius_px, theta_max=theta_max, wrp_planes_m=list(planes.z_m),
                     wrp_planes_asked=options.wrp_planes if options.method == "wrp" else 1,
                     z_inf_m=optics.z_inf_m)
    ignored = [f"ignored: {what}" for what in (getattr(loaded.bundle, "ignored", None) or [])]
    plan = plan.model_copy(update={"summary": [*plan.summary, fov["summary"], *ignored]})
    return ScenePlan(hmap=hmap, inventory=inv, analysis=ana, plan=plan, focal_length_m=f, field_of_view=fov,
                     planes=planes)


def frame_banks(optics: OpticsConfig, shape_hw, device="cpu", *, first_frame: int = 0, frames: Optional[int] = None,
                wavelengths_m=None):
    """exp(i phi_m) per color as [F, H, W] views of one cell-major tensor ([H, W, C, F] in memory): the tracer
    gathers every frame of every color of a cell at once (hologram_rays.combined_cells). Frames first_frame..
    first_frame+frames-1 (default: all of optics.frames), colors ``wavelengths_m`` (default: all), built frame by
    frame (no [F, H, W] temporaries) by the optics' frame-phase mode (holocore.trace.frame_phases)."""
    import torch

    mode = optics.frame_phase_mode()
    H, W = shape_hw
    F = optics.frames - first_frame if frames is None else frames
    lams = list(optics.wavelengths_m if wavelengths_m is None else wavelengths_m)
    C = len(lams)
    cells = torch.empty((H, W, C, F), dtype=torch.complex64, device=device)
    for c, lam in enumerate(lams):
        gain = mode.gain(lam, pitch_m=optics.pitch_m, wavelengths_m=optics.wavelengths_m)
        maps = mode.lateral_phases(F, shape_hw, lam, pitch_m=optics.pitch_m, wavelengths_m=optics.wavelengths_m,
                                   seed=optics.seed, first_frame=first_frame, bank_frames=optics.frames)
        for m, phi in enumerate(maps):
            ph = torch.from_numpy(phi).to(device)
            cells[:, :, c, m] = torch.polar(torch.full_like(ph, gain), ph).to(torch.complex64)
    return [cells[:, :, c, :].permute(2, 0, 1) for c in range(C)]


def frame_depth_terms(optics: OpticsConfig, *, first_frame: int, frames: int, wavelengths_m):
    """The per-ray depth part of the optics' frame phases (directional frames' Eq. B1, relative to the WRP) for
    frames first_frame.. of colours ``wavelengths_m``; None for phases that do not depend on depth."""
    return optics.frame_phase_mode().depth_terms(frames=frames, first_frame=first_frame, bank_frames=optics.frames,
                                                 wavelengths_m=wavelengths_m, all_wavelengths_m=optics.wavelengths_m,
                                                 pitch_m=optics.pitch_m)


# What the planner counts (bytes): the process without fields (Python, torch, Mitsuba and its kernels, the
# scene, the ambient cache, a tracer tile) and, per complex sample of a padded propagation grid, the ASM's
# workspace, spectrum and output.
_FIXED_BYTES = 1.0 * 2**30
_ASM_GRIDS = 3


def _chunk_plan(H, W, C, C_lit, F, budget, random_phase, in_memory, pad_hw):
    """(frames per trace pass, frames per propagation chunk, estimated peak bytes)."""
    from holocore.runtime.membudget import frames_per_chunk

    hp, wp = pad_hw
    plane = 8 * H * W  # one complex64 frame of one color
    held = 2 * F * C * plane if in_memory else 0  # the in-memory result holds both fields
    tf = 2 * C * 8 * hp * wp  # cached transfer functions (H and conj(H)/N per color)
    fixed = _FIXED_BYTES + held
    ft = F if not random_phase else frames_per_chunk(F, per_frame_bytes=C_lit * plane, fixed_bytes=fixed,
                                                    budget_bytes=budget)
    per_prop = _ASM_GRIDS * 8 * hp * wp + 2 * plane + (0 if in_memory else C * plane)
    fp = frames_per_chunk(F, per_frame_bytes=per_prop, fixed_bytes=fixed + tf, budget_bytes=budget)
    peak = max(fixed + (ft * C_lit * plane if random_phase else 0), fixed + tf + fp * per_prop)
    return ft, fp, int(peak)


def _tile_rays(asked: int, dev) -> int:
    """Rays per tracer tile: the option as given, except that the CPU default grows 16x on a GPU (a kernel of
    2^19 rays leaves most of a large GPU idle; 2^23 rays hold about 0.3 GB of outputs there)."""
    default = RenderOptions.__dataclass_fields__["tile_rays"].default
    return asked if dev.type != "cuda" or asked != default else 16 * default


def _render_into(sink_factory, loaded, optics: OpticsConfig, options: RenderOptions, *, progress, display,
                 memory_budget_bytes, in_memory):
    """The render, its fields handed to the sink that ``sink_factory(shape, traced, other)`` makes; returns
    (sink, meta)."""
    import torch

    from holocore.optics.propagation import asm, padded_shape
    from holocore.runtime.membudget import memory_budget_bytes as _budget
    from holocore.runtime.mitsuba_env import compute_device, mitsuba, variant
    from holocore.trace.hologram_rays import (
        RecordingGrid,
        TraceSettings,
        TraceStats,
        trace_field,
    )
    from holocore.trace.radiance_cache import build_cache

    mi = mitsuba()
    dev = compute_device()
    budget = _budget(memory_budget_bytes)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pl = plan_scene(loaded, optics, options)
    hmap, ana, plan, planes = pl.hmap, pl.analysis, pl.plan, pl.planes
    timings["analysis_s"] = time.perf_counter() - t0
    if progress:
        progress("analysis", 1, 1)
    H, W = optics.resolution_hw
    C, F = len(optics.wavelengths_m), optics.frames
    z_wrp = ana.z_wrp_m
    lit = plan.colors_lit
    lit_idx = [i for i, on in enumerate(lit) if on]
    wl_lit = [optics.wavelengths_m[i] for i in lit_idx]
    ft, fp, peak = _chunk_plan(H, W, C, len(wl_lit), F, budget, plan.random_phase, in_memory,
                               padded_shape((H, W), 2))
    direct = options.method == "direct"
    equalisers = None
    if options.cone_equaliser and not direct and wl_lit:
        equalisers = plane_equalisers(planes.distances_by_plane_m(ana.image_depths_holo_m), wl_lit, optics.pitch_m,
                                      noise_aware=options.equalise_noise and optics.frame_phase_mode().noise_aware,
                                      rim_ripple=optics.frame_phase_mode().rim_ripple)
    sink = sink_factory((F, C, H, W), "slm_field" if direct else "wrp_field", "wrp_field" if direct else "slm_field")

    integrator = mi.load_dict({"type": "path", "max_depth": max(1, plan.gi_depth)})
    cache = None
    if plan.use_cache:
        t2 = time.perf_counter()
        cache = build_cache(loaded.scene, hmap, shape_hw=(H, W), pitch_m=optics.pitch_m,
                            max_depth=max(1, plan.gi_depth), seed=optics.seed)
        timings["cache_s"] = time.perf_counter() - t2
    settings = TraceSettings(spp=plan.spp, amp_spp=plan.amp_spp, max_depth=max(1, plan.gi_depth),
                             max_delta=plan.max_delta if plan.coherent_delta else 0,
                             tile_rays=_tile_rays(options.tile_rays, dev), random_phase=plan.random_phase,
                             stratified=options.stratified)
    stats = TraceStats()
    ray_seed = optics.seed if options.ray_seed is None else int(options.ray_seed)
    timings["bank_s"] = 0.0
    timings["trace_s"] = 0.0
    passes = list(range(0, F, ft)) if wl_lit else []
    n_chunk = len(passes) if plan.random_phase else min(1, len(passes))
    schedule = None
    if options.time_limit_s is not None and passes:
        # The budget left for tracing: the limit less the setup so far and what follows the trace (estimated).
        reserve = _after_trace_seconds(optics, lit_idx, z_wrp, planes, equalisers is not None, dev)
        left = float(options.time_limit_s) - (time.perf_counter() - t0) - reserve
        schedule = SppSchedule(budget_s=max(1e-3, left / n_chunk), max_spp=options.spp or 1_000_000,
                               first_spp=min(16, options.spp or 16))
        timings["propagation_reserve_s"] = reserve
    for pi, f0 in enumerate(passes):
        f1 = min(F, f0 + ft)
        t1 = time.perf_counter()
        banks = frame_banks(optics, (H, W), dev, first_frame=f0, frames=f1 - f0, wavelengths_m=wl_lit) \
            if plan.random_phase else None
        depth_terms = frame_depth_terms(optics, first_frame=f0, frames=f1 - f0, wavelengths_m=wl_lit) \
            if plan.random_phase else None
        timings["bank_s"] += time.perf_counter() - t1
        t3 = time.perf_counter()
        n_f = (f1 - f0) if banks else F

        def trace_plane(spec, on_plane_rows, _banks=banks, _pi=pi, _depth=depth_terms):
            def run(spp, seed, rows, tick=None):
                def tile_progress(stage, done, total):
                    if tick is not None:
                        tick()
                    elif progress:
                        progress(stage, _pi * total + done, n_chunk * total)

                grid = RecordingGrid(wavelengths_m=wl_lit, pitch_m=optics.pitch_m, shape_hw=(H, W),
                                     plane_z_m=0.0 if direct else z_wrp, z_wrp_m=z_wrp, planes=spec)
                trace_field(loaded.scene, hmap, grid, frames=n_f, settings=replace(settings, spp=spp),
                            integrator=integrator, seed=seed, radiance_cache=cache, bank_phasors=_banks,
                            progress=tile_progress, stats=stats if _pi == 0 else TraceStats(), device=dev,
                            on_tile=None if spec else (lambda r0, r1, block: rows(0, r0, block)),
                            on_plane_rows=rows if spec else None, depth_terms=_depth)

            if schedule is None:
                run(plan.spp, ray_seed, on_plane_rows)
                return None
            return _trace_to_deadline(schedule, run, on_plane_rows, ray_seed=ray_seed, first_chunk=_pi == 0,
                                      progress=progress, chunk=(_pi, n_chunk))

        chain_planes(sink, planes, trace_plane, f0=f0, n_f=n_f, fp=fp, lit_idx=lit_idx, optics=optics, dev=dev,
                     timings=timings, equalisers=equalisers)
        # the closure's default argument holds the pass's phase bank too (F x C complex64 frames: 1.2 GB at
        # 1080x1920 x 3 x 24): both go before the propagation, which the chunk planner sized without it
        del banks, depth_terms, trace_plane
        timings["trace_s"] += time.perf_counter() - t3
        if not plan.random_phase:
            break  # one pass wrote every frame

    t4 = time.perf_counter()
    dz = z_wrp if direct else -z_wrp
    cut = optics.eyebox_sine()  # a common eyebox: both fields of every colour within one disc of directions
    chunks = list(range(0, F, fp))
    for ci, f0 in enumerate(chunks):
        f1 = min(F, f0 + fp)
        block = np.zeros((f1 - f0, C, H, W), dtype=np.complex64)
        for c, lam in enumerate(optics.wavelengths_m):
            if c not in lit_idx:
                continue  # the field of an unlit color is zero on both planes
            u = torch.from_numpy(sink.read_traced(f0, f1, c)).to(dev)
            if cut is not None:
                u = asm(u, 0.0, lam, optics.pitch_m, cone_sine=cut)
                sink.write_rows(f0, [c], 0, u.cpu().numpy()[:, None])
            block[:, c] = asm(u, dz, lam, optics.pitch_m).cpu().numpy()
            del u
        sink.write_other(f0, block)
        del block
        if progress:
            progress("propagate", ci + 1, len(chunks))
    timings["propagate_s"] = time.perf_counter() - t4
    timings["total_s"] = time.perf_counter() - t0

    meta: dict[str, Any] = {
        "focal_length_m": pl.focal_length_m,
        "z_inf_m": optics.z_inf_m,
        "z_wrp_m": z_wrp,
        "wrp_planes_m": list(planes.z_m),
        "cone_equaliser": None if equalisers is None else [
            {"fresnel_zones": eq.fresnel_zones, "filtered": [eq.active(c) for c in range(len(wl_lit))],
             "noise_to_signal": [round(eq.noise[c].noise_to_signal, 4) if c in eq.noise else None
                                 for c in range(len(wl_lit))]}
            for eq in equalisers],
        "pitch_m": optics.pitch_m,
        "wavelengths_m": list(optics.wavelengths_m),
        "shape_fchw": [F, C, H, W],
        "method": options.method,
        "preset": options.preset,
        "scene": loaded.entry.name,  # bundle-relative (the loader's root is the XML's folder): no server path
        "scene_sha256": getattr(loaded.bundle, "sha256", None),
        "optics": json.loads(optics.model_dump_json()),
        "plan": json.loads(_sampled_plan(plan, schedule).model_dump_json()),
        "analysis": json.loads(ana.model_dump_json()),
        "inventory": json.loads(pl.inventory.model_dump_json()),
        "field_of_view": pl.field_of_view,
        **display_meta_fields(display, optics),
        "stats": stats.as_dict(),
        "timings": timings,
        "sampling": _sampling_meta(options, plan.spp, schedule),
        "memory": {"budget_bytes": budget, "estimated_peak_bytes": peak, "trace_passes": len(passes),
                   "frames_per_trace_pass": ft, "frames_per_propagation_chunk": fp, "streamed": not in_memory},
        "device": str(dev),
        "versions": software_versions(variant()),
    }
    return sink, meta


def _after_trace_seconds(optics: OpticsConfig, lit_idx, z_wrp: float, planes, equalised: bool, dev) -> float:
    """Seconds of what follows the trace, from one timed ASM of one frame (the first call, which also builds
    and caches the colour's transfer function, is not the one timed), counted in frame-sized ASMs per frame and
    lit colour: the final propagation, each plane's equaliser and each deeper plane's ASM to the plane in
    front, on grids wider by their borders (holocore.optics.plane_chain), with a margin for their files."""
    import torch

    from holocore.optics.propagation import asm

    H, W = optics.resolution_hw
    u = torch.zeros((1, H, W), dtype=torch.complex64, device=dev)
    lam = optics.wavelengths_m[lit_idx[0]]
    asm(u, -z_wrp, lam, optics.pitch_m)
    t = time.perf_counter()
    asm(u, -z_wrp, lam, optics.pitch_m)
    t_asm = time.perf_counter() - t
    theta = max(optics.theta_max(x) for x in optics.wavelengths_m)
    units = 1.0 + (1.0 if equalised else 0.0)  # the final propagation; the WRP's equaliser
    units += 1.0 if optics.eyebox_sine() is not None else 0.0  # the common eyebox's cut
    for k in range(1, planes.count):
        b = planes.border_px(k, pitch_m=optics.pitch_m, theta_max=theta)
        units += (H + 2 * b) * (W + 2 * b) / (H * W) * (2.0 if equalised else 1.0)
    return 1.3 * t_asm * units * optics.frames * len(lit_idx)


def _trace_to_deadline(schedule: SppSchedule, run, on_plane_rows, *, ray_seed, first_chunk, progress, chunk) -> float:
    """Passes of rays until ``schedule`` says the budget is spent (the first chunk of frames), or the first
    chunk's passes again, same spp and seeds (the others: every frame sees the same rays). Pass k has ray seed
    ``ray_seed + 7919 k``; each pass's recordings, times its spp, are added to the planes (the first written),
    so the planes hold sum_k s_k U_k; returns 1 / sum_k s_k, the factor that makes that the spp-weighted mean
    (holocore.plan.time_budget), which the recording-plane chain applies once."""
    replay = None if first_chunk else [s for s, _ in schedule.passes]
    t0, done, k = time.perf_counter(), 0, 0
    whole = max(1, math.ceil(schedule.budget_s))

    def tick():  # progress in seconds of the trace budget (each tile of each pass)
        if progress:
            progress("trace", chunk[0] * whole + min(whole, int(time.perf_counter() - t0)), chunk[1] * whole)

    while True:
        spp = schedule.next_spp(time.perf_counter() - t0) if first_chunk else (
            replay[k] if k < len(replay) else None)
        if spp is None:
            break
        tk = time.perf_counter()
        stored = [0.0]  # seconds spent storing this pass's rows: the part of a pass that does not grow with spp

        def rows(plane, r0, block, _w=float(spp), _add=k > 0, _t=stored):
            ts = time.perf_counter()
            on_plane_rows(plane, r0, block * _w, add=_add)
            _t[0] += time.perf_counter() - ts

        run(spp, ray_seed + 7919 * k, rows, tick)
        done += spp
        k += 1
        if first_chunk:
            schedule.record(spp, time.perf_counter() - tk, fixed_s=stored[0])
    return 1.0 / done


def _sampled_plan(plan, schedule: Optional[SppSchedule]):
    """The plan as rendered: a time-limited render's rays per pixel, noise and summary line are the passes'."""
    if schedule is None or not schedule.passes:
        return plan
    n = schedule.spp
    line = (f"{n} rays per WRP pixel (time limit: {len(schedule.passes)} pass(es) filled "
            f"{schedule.budget_s:.1f} s of tracing), Monte Carlo noise about "
            f"{plan.noise_to_signal * plan.spp / n:.2g}x the farthest image point's signal power")
    summary = [line if w.startswith(f"{plan.spp} rays per WRP pixel") else w for w in plan.summary]
    return plan.model_copy(update={"spp": n, "noise_to_signal": plan.noise_to_signal * plan.spp / n,
                                   "summary": summary})


def _sampling_meta(options: RenderOptions, planned_spp: int, schedule: Optional[SppSchedule]) -> dict:
    """How many rays per pixel the render traced, and in which passes (a time-limited render)."""
    if schedule is None:
        return {"time_limit_s": None, "spp": planned_spp, "passes": [{"spp": planned_spp}]}
    return {"time_limit_s": options.time_limit_s, "spp": schedule.spp, "trace_budget_s": schedule.budget_s,
            "passes": [{"spp": s, "seconds": round(t, 4)} for s, t in schedule.passes]}


def render_loaded(loaded, optics: OpticsConfig, options: RenderOptions = RenderOptions(), *,
                  progress: Optional[ProgressFn] = None, display: Optional[DisplayProfile] = None,
                  memory_budget_bytes: Optional[int] = None) -> RenderResult:
    """Render a loaded scene: WRP field (two-stage) or SLM field (direct), then ASM to the other plane.
    ``display``: the profile ``optics`` came from, recorded in the meta (``display_profile``, ``display``).
    ``memory_budget_bytes``: sizes the chunks (see the module docstring); the two fields returned are held
    in memory whatever it says (use :func:`render_to_file` to stream them)."""
    sink, meta = _render_into(lambda shape, _t, _o: MemorySink(shape), loaded, optics, options,
                              progress=progress, display=display, memory_budget_bytes=memory_budget_bytes,
                              in_memory=True)
    slm, wrp = (sink.traced, sink.other) if options.method == "direct" else (sink.other, sink.traced)
    return RenderResult(slm_field=slm, wrp_field=wrp, meta=meta)


def render(scene_path: str | Path, optics: OpticsConfig, options: RenderOptions = RenderOptions(), *,
           progress: Optional[ProgressFn] = None, display: Optional[DisplayProfile] = None,
           memory_budget_bytes: Optional[int] = None) -> RenderResult:
    """Check and load a scene bundle, then :func:`render_loaded`."""
    from holocore.scene.load import load_scene

    return render_loaded(load_scene(scene_path), optics, options, progress=progress, display=display,
                         memory_budget_bytes=memory_budget_bytes)


def render_to_file(scene, out_path: str | Path, optics: OpticsConfig, options: RenderOptions = RenderOptions(), *,
                   progress: Optional[ProgressFn] = None, display: Optional[DisplayProfile] = None,
                   memory_budget_bytes: Optional[int] = None) -> dict:
    """Render ``scene`` (a bundle path or a loaded scene) straight into RESULT.npz at ``out_path`` in bounded
    memory (the same file :func:`holocore.io.save_result` writes, equal fields); returns the meta."""
    from holocore.formats.meta import parse_result_meta
    from holocore.io import NpzWriter
    from holocore.scene.load import load_scene

    loaded = load_scene(scene) if isinstance(scene, (str, Path)) else scene
    with NpzWriter(out_path) as writer:
        sink, meta = _render_into(lambda shape, t, o: FileSink(writer, shape, t, o), loaded, optics, options,
                                  progress=progress, display=display, memory_budget_bytes=memory_budget_bytes,
                                  in_memory=False)
        sink.finish()
        checked = parse_result_meta(meta, what=f"result {Path(out_path).name}")  # MetaError naming the field
        writer.add("meta", np.array(json.dumps(checked.to_dict())))
    return meta


def display_meta_fields(display: Optional[DisplayProfile], optics: OpticsConfig) -> dict:
    """``display_profile`` (None: optics given directly, no profile) and ``display`` for a result's meta."""
    if display is None:
        return {"display_profile": None, "display": None}
    from holocore.display.profiles import display_meta

    return display_meta(display, optics)


def software_versions(mi_variant: str) -> dict:
    import drjit
    import mitsuba
    import torch

    return {"holocore": __version__, "mitsuba": mitsuba.__version__, "drjit": drjit.__version__,
            "torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version(),
            "variant": mi_variant}
