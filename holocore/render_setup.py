"""What a render decides before its first ray (docs/design.md §1): the options, the scene's plan, the lit colours, how
many frames one trace pass and one propagation chunk hold in the memory budget, the cone equalisers, the trace
settings, the ray schedule of a time-limited render and the frame-phase mode, in one frozen :class:`RenderSetup`
that :func:`prepare_render` makes and :mod:`holocore.render_passes` and :mod:`holocore.pipeline` read.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Literal, Optional, Union

import torch

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, OpticsConfig
from holocore.display.profiles import field_of_view_report
from holocore.optics.cone_equaliser import plane_equalisers
from holocore.optics.propagation import asm, padded_shape
from holocore.options import HologramOptions, check
from holocore.plan.analysis import analyze
from holocore.plan.effects import capped_share, inventory, lobe_spread_px, make_plan
from holocore.plan.memory_estimate import DEFAULT_TILE_RAYS, admit_placed_planes
from holocore.plan.focus_depth import focus_depth
from holocore.plan.presets import PresetName, RenderMethod
from holocore.plan.scene_plan import ScenePlan
from holocore.plan.time_budget import SppSchedule
from holocore.plan.wrp_planes import WrpPlanes, choose_planes, place_planes
from holocore.runtime.membudget import frames_per_chunk
from holocore.runtime.membudget import memory_budget_bytes as _budget
from holocore.runtime.mitsuba_env import compute_device, mitsuba
from holocore.scene.load import sensor_film_hw
from holocore.trace.hologram_rays import TraceSettings
from holocore.trace.mapping import HologramMap
from holocore.trace.radiance_cache import build_cache

__all__ = ["RenderOptions", "RenderSetup", "plan_scene", "prepare_render"]


@dataclass(frozen=True)
class RenderOptions:
    preset: PresetName = "balanced"
    spp: Optional[int] = None
    max_spp: Optional[int] = None  # without spp: the most rays per pixel the preset may choose (a service's cap)
    method: RenderMethod = "wrp"
    force_all_effects: bool = False
    tile_rays: int = DEFAULT_TILE_RAYS
    max_delta: Optional[int] = None  # the delta-bounce cap (None: the plan's), to measure what a cap drops
    # recording planes (holocore.plan.wrp_planes); "auto": from the depth
    wrp_planes: Union[int, Literal["auto"]] = "auto"
    # each pixel's rays stratified over the cone (holocore.trace.hologram_rays); False: independent
    stratified: bool = True
    ray_seed: Optional[int] = None  # seed of the traced rays alone (None: the optics' seed, which also seeds the
    # random-phase bank): two ray seeds give independent Monte Carlo estimates of one field
    cone_equaliser: bool = True  # flatten each recording plane's spectrum (holocore.optics.cone_equaliser)
    equalise_noise: bool = True  # ... signal plus its fitted Monte Carlo noise (Eq. C4); False: signal alone (C3),
    # a linear filter, for comparing estimators by their noise
    time_limit_s: Optional[float] = None  # wall time of the whole render, s: passes of rays until it is spent
    # (holocore.plan.time_budget; ``spp`` is then the most rays per pixel); None: one pass of ``spp``

    def __post_init__(self) -> None:
        # the user's options are checked by their one model (holocore.options); the kernel's own fields here
        check(preset=self.preset, spp=self.spp, max_spp=self.max_spp, method=self.method,
              wrp_planes=self.wrp_planes, render_time_limit_s=self.time_limit_s)

    @classmethod
    def from_options(cls, options: HologramOptions, **kernel: Any) -> "RenderOptions":
        """The render's part of a hologram's options (holocore.options), with the kernel's own fields
        (``force_all_effects``, ``tile_rays``, ...) as given."""
        return cls(preset=options.preset, spp=options.spp, max_spp=options.max_spp, method=options.method,
                   wrp_planes=options.wrp_planes, time_limit_s=options.render_time_limit_s, **kernel)


def plan_scene(loaded, optics: OpticsConfig, options: RenderOptions = RenderOptions(), *,
               memory_budget_bytes: Optional[int] = None) -> ScenePlan:
    """The effect plan and the analysis of a loaded scene, without tracing the hologram. ``field_of_view``
    compares the hologram's view, 2 atan(W p / 2f), with the scene camera's; the plan's summary says it.
    ``memory_budget_bytes`` (default: HOLO_MEMORY_BUDGET_MB, else 8 GiB) bounds the deeper recording planes'
    grids: ``auto`` keeps the planes that fit, a count asked for that does not fit is a ValueError."""
    f = optics.focal_length_m(loaded.fov_x_deg)
    fov = field_of_view_report(optics, loaded.fov_x_deg, camera_film_hw=sensor_film_hw(loaded.sensor))
    hmap = HologramMap.from_sensor(loaded.sensor, focal_length_m=f, z_inf_m=optics.z_inf_m,
                                  scene_scale=optics.scene_scale)
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
    planes, admission = admit_placed_planes(planes, optics, auto=options.wrp_planes == "auto",
                                            budget_bytes=_budget(memory_budget_bytes), tile_rays=options.tile_rays)
    # The noise target is set by the farthest image point from the plane that records it.
    radius_px = ana.subhologram_radius_px if planes.count == 1 or not depths else \
        planes.farthest_distance_m(depths) * px_per_m
    plan = make_plan(inv, preset=options.preset, frames=optics.frames, n_colors=len(optics.wavelengths_m),
                     colors_lit=ana.colors_lit, spp=options.spp, max_spp=options.max_spp,
                     force_all=options.force_all_effects,
                     max_delta_seen=ana.max_delta_seen, prepass_capped=ana.prepass_capped,
                     delta_bounces=ana.delta_bounces,
                     subhologram_radius_px=radius_px, theta_max=theta_max, wrp_planes_m=list(planes.z_m),
                     wrp_planes_asked=options.wrp_planes if options.method == "wrp" else 1,
                     z_inf_m=optics.z_inf_m,
                     lobe_spread_px=lobe_spread_px(inv.near_smooth.values(), focal_length_m=f, pitch_m=optics.pitch_m,
                                                   zc_surface_m=ana.zc_first_min_m, zc_image_m=ana.zc_image_max_m))
    ignored = [f"ignored: {what}" for what in (getattr(loaded.bundle, "ignored", None) or [])]
    focus = focus_depth(image_depths_holo_m=depths, z_inf_m=optics.z_inf_m, focal_length_m=f,
                        wavelengths_m=optics.wavelengths_m, pitch_m=optics.pitch_m,
                        scene_scale=optics.scene_scale)
    if options.max_delta is not None and plan.coherent_delta:  # a cap asked for: the plan says what it drops
        plan = plan.model_copy(update={"max_delta": int(options.max_delta),
                                       "delta_capped_share": capped_share(ana.delta_bounces, int(options.max_delta))})
    notes = [admission.note] if admission.note else []
    plan = plan.model_copy(update={"summary": [*plan.summary, *notes, fov["summary"], focus.summary, *ignored]})
    return ScenePlan(hmap=hmap, inventory=inv, analysis=ana, plan=plan, focal_length_m=f, field_of_view=fov,
                     planes=planes, focus=focus)


@dataclass(frozen=True)
class RenderSetup:
    """A render's decisions before its first ray (:func:`prepare_render`); ``schedule`` records the passes of a
    time-limited render as they run (its one mutable part)."""
    loaded: Any  # the loaded scene (holocore.scene.load)
    optics: OpticsConfig
    options: RenderOptions
    scene: ScenePlan  # the effect plan, analysis, hologram map and recording planes
    lit_idx: tuple[int, ...]  # the colours with light, indices into optics.wavelengths_m
    frames_per_pass: int  # frames of one trace pass (its phase bank fits the budget)
    frames_per_chunk: int  # frames of one propagation chunk
    peak_bytes: int  # the chunk planner's estimate of the peak
    budget_bytes: int  # the memory budget the chunks were sized for
    in_memory: bool  # both fields held in memory (False: the traced one in a scratch file, the other streamed)
    equalisers: Optional[tuple]  # one cone equaliser per recording plane, None: off
    settings: Any  # holocore.trace.hologram_rays.TraceSettings
    integrator: Any  # the Mitsuba integrator that shades the rays' ends
    cache: Any  # the fast preset's radiance cache, None: none
    ray_seed: int
    passes: tuple[int, ...]  # the first frame of each trace pass
    schedule: Optional[SppSchedule]  # a time-limited render's passes of rays, None: one pass of the plan's spp
    device: Any  # the torch device of the fields

    @property
    def wl_lit(self) -> list[float]:
        return [self.optics.wavelengths_m[i] for i in self.lit_idx]

    @property
    def direct(self) -> bool:
        return self.options.method == "direct"

    @property
    def shape_fchw(self) -> tuple[int, int, int, int]:
        H, W = self.optics.resolution_hw
        return self.optics.frames, len(self.optics.wavelengths_m), H, W

    @property
    def trace_chunks(self) -> int:
        """Trace passes over chunks of frames (one when the phases are not random: every frame alike)."""
        return len(self.passes) if self.scene.plan.random_phase else min(1, len(self.passes))


def prepare_render(loaded, optics: OpticsConfig, options: RenderOptions, *, memory_budget_bytes: Optional[int],
                   in_memory: bool, timings: dict, t0: float, progress=None) -> RenderSetup:
    """Plan the scene and size the render (:class:`RenderSetup`); ``timings`` gets analysis_s and cache_s (s),
    ``t0`` (time.perf_counter) is the render's start, from which a time limit counts."""
    dev = compute_device()
    budget = _budget(memory_budget_bytes)
    pl = plan_scene(loaded, optics, options, memory_budget_bytes=budget)
    plan, ana, planes = pl.plan, pl.analysis, pl.planes
    timings["analysis_s"] = time.perf_counter() - t0
    if progress:
        progress("analysis", 1, 1)
    H, W = optics.resolution_hw
    C, F = len(optics.wavelengths_m), optics.frames
    lit_idx = tuple(i for i, on in enumerate(plan.colors_lit) if on)
    wl_lit = [optics.wavelengths_m[i] for i in lit_idx]
    ft, fp, peak = _chunk_plan(H, W, C, len(wl_lit), F, budget, plan.random_phase, in_memory,
                               padded_shape((H, W), 2))
    equalisers = None
    if options.cone_equaliser and options.method != "direct" and wl_lit:
        mode = optics.frame_phase_mode()
        equalisers = tuple(plane_equalisers(planes.distances_by_plane_m(ana.image_depths_holo_m), wl_lit,
                                            optics.pitch_m, noise_aware=options.equalise_noise and mode.noise_aware,
                                            rim_ripple=mode.rim_ripple))
    cache = None
    if plan.use_cache:
        t2 = time.perf_counter()
        cache = build_cache(loaded.scene, pl.hmap, shape_hw=(H, W), pitch_m=optics.pitch_m,
                            max_depth=max(1, plan.gi_depth), seed=optics.seed)
        timings["cache_s"] = time.perf_counter() - t2
    settings = TraceSettings(spp=plan.spp, amp_spp=plan.amp_spp, max_depth=max(1, plan.gi_depth),
                             max_delta=plan.max_delta if plan.coherent_delta else 0,
                             tile_rays=_tile_rays(options.tile_rays, dev), random_phase=plan.random_phase,
                             stratified=options.stratified)
    passes = tuple(range(0, F, ft)) if wl_lit else ()
    schedule = None
    if options.time_limit_s is not None and passes:
        # The budget left for tracing: the limit less the setup so far and what follows the trace (estimated).
        n_chunk = len(passes) if plan.random_phase else 1
        reserve = _after_trace_seconds(optics, list(lit_idx), ana.z_wrp_m, planes, equalisers is not None, dev)
        left = float(options.time_limit_s) - (time.perf_counter() - t0) - reserve
        schedule = SppSchedule(budget_s=max(1e-3, left / n_chunk), max_spp=options.spp or 1_000_000,
                               first_spp=min(16, options.spp or 16))
        timings["propagation_reserve_s"] = reserve
    integrator = mitsuba().load_dict({"type": "path", "max_depth": max(1, plan.gi_depth)})
    return RenderSetup(loaded=loaded, optics=optics, options=options, scene=pl, lit_idx=lit_idx,
                       frames_per_pass=ft, frames_per_chunk=fp, peak_bytes=peak, budget_bytes=budget,
                       in_memory=in_memory,
                       equalisers=equalisers, settings=settings, integrator=integrator, cache=cache,
                       ray_seed=optics.seed if options.ray_seed is None else int(options.ray_seed),
                       passes=passes, schedule=schedule, device=dev)


# What the planner counts (bytes): the process without fields (Python, torch, Mitsuba and its kernels, the
# scene, the ambient cache, a tracer tile) and, per complex sample of a padded propagation grid, the ASM's
# workspace, spectrum and output.
_FIXED_BYTES = 1.0 * 2**30
_ASM_GRIDS = 3


def _chunk_plan(H, W, C, C_lit, F, budget, random_phase, in_memory, pad_hw):
    """(frames per trace pass, frames per propagation chunk, estimated peak bytes)."""
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


def _after_trace_seconds(optics: OpticsConfig, lit_idx, z_wrp: float, planes, equalised: bool, dev) -> float:
    """Seconds of what follows the trace, from one timed ASM of one frame (the first call, which also builds
    and caches the colour's transfer function, is not the one timed), counted in frame-sized ASMs per frame and
    lit colour: the final propagation, each plane's equaliser and each deeper plane's ASM to the plane in
    front, on grids wider by their borders (holocore.optics.plane_chain), with a margin for their files."""


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
