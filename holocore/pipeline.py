"""From a scene and the optics to the WRP and SLM fields (docs/design.md §1): load -> plan -> analyse -> trace ->
propagate. This is what `holo render` and the service's workers call.

Memory is bounded by a budget (:mod:`holocore.runtime.membudget`: keyword, HOLO_MEMORY_BUDGET_MB, default 8 GiB) that
sizes chunks of frames: the tracer runs one pass per chunk of frames whose random-phase bank fits (one pass
for every frame when it fits, as it does at 1080x1920 x 3 x 24 in 8 GiB; each pass retraces the same rays, so
the result does not depend on the chunking), and the propagation runs per chunk of frames and color.
:func:`render_to_file` streams both fields into RESULT.npz (the traced one through a scratch file), so no
[F, C, H, W] array is ever held; :func:`render` / :func:`render_loaded` return them in memory.

A render reads one :class:`holocore.render_setup.RenderSetup` (:func:`holocore.render_setup.prepare_render`), runs
its passes (:mod:`holocore.render_passes`: trace, then propagate) and describes itself in the result's meta
(:func:`holocore.render_meta.result_meta`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from holocore.display.optics import OpticsConfig
from holocore.display.profiles import DisplayProfile
from holocore.formats.meta import parse_result_meta
from holocore.io import NpzWriter
from holocore.render_meta import RenderResult, display_meta_fields, result_meta, software_versions
from holocore.render_passes import frame_banks, propagate_other, sampled_plan, sampling_meta, trace_passes
from holocore.render_setup import RenderOptions, RenderSetup, plan_scene, prepare_render
from holocore.scene.load import load_scene
from holocore.sinks import FileSink, MemorySink

__all__ = ["RenderOptions", "RenderResult", "render", "render_loaded", "render_to_file", "plan_scene",
           "frame_banks", "display_meta_fields", "software_versions"]

ProgressFn = Callable[[str, int, int], None]


def _render_into(sink_factory, loaded, optics: OpticsConfig, options: RenderOptions, *, progress, display,
                 memory_budget_bytes, in_memory):
    """The render, its fields handed to the sink that ``sink_factory(shape, traced, other)`` makes; returns
    (sink, meta)."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    setup = prepare_render(loaded, optics, options, memory_budget_bytes=memory_budget_bytes, in_memory=in_memory,
                           timings=timings, t0=t0, progress=progress)
    direct = setup.direct
    sink = sink_factory(setup.shape_fchw, "slm_field" if direct else "wrp_field",
                        "wrp_field" if direct else "slm_field")
    stats = trace_passes(setup, sink, timings=timings, progress=progress)
    propagate_other(setup, sink, timings=timings, progress=progress)
    timings["total_s"] = time.perf_counter() - t0
    return sink, _result_meta(setup, stats=stats, timings=timings, display=display)


def _result_meta(setup: RenderSetup, *, stats, timings: dict, display: Optional[DisplayProfile]) -> dict:
    """The RESULT meta of a render (:func:`holocore.render_meta.result_meta` and the renderer's own fields)."""
    pl, optics, options, eqs = setup.scene, setup.optics, setup.options, setup.equalisers
    n_lit = len(setup.lit_idx)
    own = {
        "wrp_planes_m": list(pl.planes.z_m),
        "cone_equaliser": None if eqs is None else [
            {"fresnel_zones": eq.fresnel_zones, "filtered": [eq.active(c) for c in range(n_lit)],
             "noise_to_signal": [round(eq.noise[c].noise_to_signal, 4) if c in eq.noise else None
                                 for c in range(n_lit)]}
            for eq in eqs],
        "inventory": json.loads(pl.inventory.model_dump_json()),
        "sampling": sampling_meta(options, pl.plan.spp, setup.schedule),
        "memory": {"budget_bytes": setup.budget_bytes, "estimated_peak_bytes": setup.peak_bytes,
                   "trace_passes": len(setup.passes), "frames_per_trace_pass": setup.frames_per_pass,
                   "frames_per_propagation_chunk": setup.frames_per_chunk, "streamed": not setup.in_memory},
        "device": str(setup.device),
    }
    return result_meta(method=options.method, preset=options.preset, loaded=setup.loaded, optics=optics,
                       scene_plan=pl, shape_fchw=setup.shape_fchw, timings=timings, display=display,
                       plan=json.loads(sampled_plan(pl.plan, setup.schedule).model_dump_json()),
                       stats=stats.as_dict(), extra=own)


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
    return render_loaded(load_scene(scene_path), optics, options, progress=progress, display=display,
                         memory_budget_bytes=memory_budget_bytes)


def render_to_file(scene, out_path: str | Path, optics: OpticsConfig, options: RenderOptions = RenderOptions(), *,
                   progress: Optional[ProgressFn] = None, display: Optional[DisplayProfile] = None,
                   memory_budget_bytes: Optional[int] = None) -> dict:
    """Render ``scene`` (a bundle path or a loaded scene) straight into RESULT.npz at ``out_path`` in bounded
    memory (the same file :func:`holocore.io.save_result` writes, equal fields); returns the meta."""
    loaded = load_scene(scene) if isinstance(scene, (str, Path)) else scene
    with NpzWriter(out_path) as writer:
        sink, meta = _render_into(lambda shape, t, o: FileSink(writer, shape, t, o), loaded, optics, options,
                                  progress=progress, display=display, memory_budget_bytes=memory_budget_bytes,
                                  in_memory=False)
        sink.finish()
        checked = parse_result_meta(meta, what=f"result {Path(out_path).name}")  # MetaError naming the field
        writer.add("meta", np.array(json.dumps(checked.to_dict())))
    return meta
