"""A render's passes (docs/design.md §1): the frames' phase banks, the trace of every recording plane in passes over
chunks of frames (a time-limited render: passes of rays until its budget is spent), and the propagation of the
traced field to the other plane, every colour first cut to the common eyebox when the optics ask for one. Each
step reads the :class:`holocore.render_setup.RenderSetup` and writes into the render's sink
(:mod:`holocore.sinks`); times go into a ``timings`` dict (s)."""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Optional

from holocore.display.optics import OpticsConfig
from holocore.optics.grids import reach_grid
from holocore.optics.plane_chain import chain_planes
from holocore.optics.propagation import asm, asm_to
from holocore.plan.time_budget import SppSchedule
from holocore.render_setup import RenderOptions, RenderSetup
from holocore.runtime.heap import heap_reuse
from holocore.trace.hologram_rays import RecordingGrid, trace_field
from holocore.trace.hologram_rays import TraceStats

__all__ = ["frame_banks", "frame_depth_terms", "trace_passes", "propagate_other", "sampled_plan", "sampling_meta"]


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


def trace_passes(setup: RenderSetup, sink, *, timings: dict, progress=None):
    """Trace every pass of frames into the sink's traced field (the WRP's, or the SLM's with the direct method),
    the recording planes chained to it; returns the first pass's TraceStats."""
    stats = TraceStats()
    timings["bank_s"] = 0.0
    timings["trace_s"] = 0.0
    for k, f0 in enumerate(setup.passes):
        _trace_pass(setup, sink, k, f0, stats if k == 0 else TraceStats(), timings=timings, progress=progress)
        if not setup.scene.plan.random_phase:
            break  # one pass wrote every frame
    return stats


def _trace_pass(setup: RenderSetup, sink, k: int, f0: int, stats, *, timings: dict, progress) -> None:
    """Pass k: frames f0.. with their phase bank (random phases), every recording plane traced and chained."""
    optics, plan, z_wrp = setup.optics, setup.scene.plan, setup.scene.analysis.z_wrp_m
    H, W = optics.resolution_hw
    n_chunk = setup.trace_chunks
    f1 = min(optics.frames, f0 + setup.frames_per_pass)
    t1 = time.perf_counter()
    banks = frame_banks(optics, (H, W), setup.device, first_frame=f0, frames=f1 - f0, wavelengths_m=setup.wl_lit) \
        if plan.random_phase else None
    depth_terms = frame_depth_terms(optics, first_frame=f0, frames=f1 - f0, wavelengths_m=setup.wl_lit) \
        if plan.random_phase else None
    timings["bank_s"] += time.perf_counter() - t1
    t3 = time.perf_counter()
    n_f = (f1 - f0) if banks else optics.frames

    def trace_plane(spec, on_plane_rows, _banks=banks, _depth=depth_terms):
        def run(spp, seed, rows, tick=None):
            def tile_progress(stage, done, total):
                if tick is not None:
                    tick()
                elif progress:
                    progress(stage, k * total + done, n_chunk * total)

            grid = RecordingGrid(wavelengths_m=setup.wl_lit, pitch_m=optics.pitch_m, shape_hw=(H, W),
                                 plane_z_m=0.0 if setup.direct else z_wrp, z_wrp_m=z_wrp, planes=spec)
            trace_field(setup.loaded.scene, setup.scene.hmap, grid, frames=n_f,
                        settings=replace(setup.settings, spp=spp), integrator=setup.integrator, seed=seed,
                        radiance_cache=setup.cache, bank_phasors=_banks, progress=tile_progress, stats=stats,
                        device=setup.device, on_tile=None if spec else (lambda r0, r1, block: rows(0, r0, block)),
                        on_plane_rows=rows if spec else None, depth_terms=_depth)

        if setup.schedule is None:
            run(plan.spp, setup.ray_seed, on_plane_rows)
            return None
        return _trace_to_deadline(setup.schedule, run, on_plane_rows, ray_seed=setup.ray_seed, first_chunk=k == 0,
                                  progress=progress, chunk=(k, n_chunk))

    chain_planes(sink, setup.scene.planes, trace_plane, f0=f0, n_f=n_f, fp=setup.frames_per_chunk,
                 lit_idx=list(setup.lit_idx), optics=optics, dev=setup.device, timings=timings,
                 equalisers=None if setup.equalisers is None else list(setup.equalisers))
    # the closure's default argument holds the pass's phase bank too (F x C complex64 frames: 1.2 GB at
    # 1080x1920 x 3 x 24): both go before the propagation, which the chunk planner sized without it
    del banks, depth_terms, trace_plane
    timings["trace_s"] += time.perf_counter() - t3


def propagate_other(setup: RenderSetup, sink, *, timings: dict, progress=None) -> None:
    """The other plane's field from the traced one by the ASM, chunk by chunk of frames; with a common eyebox
    both fields of every colour are first cut to its disc of directions (docs/physics.md)."""
    import torch

    optics = setup.optics
    F = setup.shape_fchw[0]
    z_wrp = setup.scene.analysis.z_wrp_m
    t4 = time.perf_counter()
    dz = z_wrp if setup.direct else -z_wrp
    cut = optics.eyebox_sine()  # a common eyebox: both fields of every colour within one disc of directions
    fp = setup.frames_per_chunk
    chunks = list(range(0, F, fp))
    with heap_reuse(torch.device(setup.device).type == "cpu"):  # the transforms' outputs on reused pages
        for ci, f0 in enumerate(chunks):
            _propagate_chunk(setup, sink, f0, min(F, f0 + fp), dz, cut)
            if progress:
                progress("propagate", ci + 1, len(chunks))
    timings["propagate_s"] = time.perf_counter() - t4


def _propagate_chunk(setup: RenderSetup, sink, f0: int, f1: int, dz: float, cut) -> None:
    """Frames f0..f1 of :func:`propagate_other`."""
    import numpy as np
    import torch

    optics = setup.optics
    _, C, H, W = setup.shape_fchw
    block = np.zeros((f1 - f0, C, H, W), dtype=np.complex64)
    for c, lam in enumerate(optics.wavelengths_m):
        if c not in setup.lit_idx:
            continue  # the field of an unlit color is zero on both planes
        u = torch.from_numpy(sink.read_traced(f0, f1, c)).to(setup.device)
        grid = reach_grid((H, W), dz, lam, optics.pitch_m)  # the SLM's window only: its reach, not 2x
        if cut is not None:  # the cut field and its propagation from one transform of the traced field
            u, v = asm_to(u, [0.0, dz], lam, optics.pitch_m, cone_sine=cut, grid=grid)
            sink.write_rows(f0, [c], 0, u.cpu().numpy()[:, None])
        else:
            v = asm(u, dz, lam, optics.pitch_m, grid=grid)
        block[:, c] = v.cpu().numpy()
        del u, v
    sink.write_other(f0, block)


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


def sampled_plan(plan, schedule: Optional[SppSchedule]):
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


def sampling_meta(options: RenderOptions, planned_spp: int, schedule: Optional[SppSchedule]) -> dict:
    """How many rays per pixel the render traced, and in which passes (a time-limited render)."""
    if schedule is None:
        return {"time_limit_s": None, "spp": planned_spp, "passes": [{"spp": planned_spp}]}
    return {"time_limit_s": options.time_limit_s, "spp": schedule.spp, "trace_budget_s": schedule.budget_s,
            "passes": [{"spp": s, "seconds": round(t, 4)} for s, t in schedule.passes]}
