"""`holo render`: a scene bundle to RESULT.npz (the WRP and SLM wave fields). Its options are the hologram's
(holocore.options: the flags below, or one ``--options-json`` document as a service's job hands them over) and
the optics (holo.common.OPTICS_OPTIONS)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Optional

import typer

from holo.common import OpticsOptions, fail, hologram_options, progress_writer, with_optics_options
from holocore.options import MAX_WRP_PLANES


def register(app: typer.Typer) -> None:
    app.command("render")(render)


@with_optics_options
def render(
    scene: Path = typer.Argument(..., help="Scene folder (a bundle) or its Mitsuba XML file."),
    out: Path = typer.Option(..., "--out", help="Where to write RESULT.npz."),
    preset: Optional[str] = typer.Option(None, help="fast | balanced (default) | reference"),
    spp: Optional[int] = typer.Option(None, help="Rays per WRP pixel (default: from the preset; with "
                                                 "--time-limit-s, the most)."),
    max_spp: Optional[int] = typer.Option(None, "--max-spp", help="Without --spp: the most rays per WRP pixel the "
                                                                  "preset may choose (a cap below its own)."),
    time_limit_s: Optional[float] = typer.Option(
        None, "--time-limit-s", help="Render for about this many seconds of wall time (setup, tracing and "
                                     "propagation; not the file writing): passes of rays until the time is spent; "
                                     "without --frames, the frame count (up to the display's) predicted best in it."),
    method: Optional[str] = typer.Option(None, help="wrp (two-stage, default) | direct (rays from the SLM plane)."),
    force_all_effects: bool = typer.Option(False, "--force-all-effects", help="Simulate every effect."),
    wrp_planes: Optional[str] = typer.Option(
        None, "--wrp-planes", help=f"Wave recording planes: 1..{MAX_WRP_PLANES}, or auto "
                                   "(default: chosen from the scene depth)."),
    quality_db: Optional[float] = typer.Option(
        None, "--quality-db", help="Aim at this viewer-faithful PSNR (dB, 5..40): the frames (up to --frames, else "
                                   "the display's) and rays per pixel predicted to reach it soonest "
                                   "(holocore.plan.quality_choice); says the `holo encode --iterations` to run."),
    options_json: Optional[Path] = typer.Option(None, "--options-json", help="The hologram's options as one JSON "
                                                "document (holocore.options.HologramOptions; docs/options.md); "
                                                "the flags above override it."),
    progress_jsonl: Optional[Path] = typer.Option(None, "--progress-jsonl", help="Append progress as JSON lines."),
    estimate: bool = typer.Option(False, "--estimate", help="Print the predicted time and quality and exit."),
    device: Optional[str] = typer.Option(None, "--device", help="auto (CUDA when available) | cpu | cuda; "
                                                                 "default: HOLO_DEVICE, else auto."),
    memory_budget_mb: Optional[int] = typer.Option(
        None, "--memory-budget-mb", help="Peak memory to stay within (MiB): frames are traced and propagated in "
                                         "chunks that fit and streamed to --out; default: HOLO_MEMORY_BUDGET_MB, "
                                         "else 8192."),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """Render a scene into WRP and SLM wave fields (RESULT.npz) for a display (default: the paper's)."""
    hopts = hologram_options(options_json, "render", preset=preset, frames=optics.frames, spp=spp, max_spp=max_spp,
                             render_time_limit_s=time_limit_s, method=method, wrp_planes=wrp_planes,
                             quality_db=quality_db)
    profile, optics_cfg = optics.resolve()
    if hopts.frames is not None:
        optics_cfg = optics_cfg.model_copy(update={"frames": hopts.frames})
    from holocore.runtime.device import select_device
    from holocore.runtime.membudget import memory_budget_bytes

    try:
        select_device(device)
        budget = memory_budget_bytes(None if memory_budget_mb is None else memory_budget_mb << 20)
    except ValueError as exc:
        fail(str(exc))
    if not scene.exists():
        fail(f"scene not found: {scene}")

    from rich.console import Console

    from holocore.pipeline import RenderOptions

    options = RenderOptions.from_options(hopts, force_all_effects=force_all_effects)
    console = Console(stderr=True)
    loaded = None
    if hopts.quality_db is not None:
        loaded, optics_cfg, options = _for_quality(scene, optics_cfg, options, profile, hopts.quality_db, console)
    if hopts.render_time_limit_s is not None and hopts.frames is None and optics.optics_json is None:
        loaded, optics_cfg = _frames_for_time(scene, optics_cfg, options, profile, console)
    if estimate and hopts.render_time_limit_s is not None:
        console.print(f"estimated time of `holo render`: {hopts.render_time_limit_s:.1f} s (the time limit: the "
                      f"render traces rays until it is spent)")
    elif estimate:
        from holo.render_estimate import print_estimate

        print_estimate(scene, loaded, optics_cfg, options, profile, console)
    else:
        m = _render(loaded or scene, out, optics_cfg, options, profile, budget, progress_jsonl, console)
        _print_result(m, Path(scene).name, profile, out, console)


def _for_quality(scene: Path, optics_cfg, options, profile, target_db: float, console):
    """(loaded scene, optics, options) with the frames and rays predicted to reach ``target_db`` soonest."""
    from holo.render_quality import choose_options

    loaded, ctx = _scene_quality(scene, optics_cfg, options, profile)
    optics_cfg, options, chosen = choose_options(ctx, optics_cfg, options, target_db)
    reach = "predicted to reach it" if chosen.psnr_db >= target_db else "the best predicted; it falls short"
    it = "" if chosen.iterations is None else f" --iterations {chosen.iterations}"
    console.print(f"--quality-db {target_db:g}: {chosen.words()} ({reach}); then `holo encode{it}`")
    return loaded, optics_cfg, options


def _frames_for_time(scene: Path, optics_cfg, options, profile, console):
    """The time buys frames as well as rays: the frame count (up to the display's) whose rays in that time
    predict the best score; frames given (--frames, or a job's options) are kept."""
    from holo.render_quality import frames_for_time

    loaded, ctx = _scene_quality(scene, optics_cfg, options, profile)
    pick = frames_for_time(ctx, optics_cfg, options, options.time_limit_s)
    if pick is not None:
        optics_cfg = optics_cfg.model_copy(update={"frames": pick[0]})
        console.print(f"--time-limit-s {options.time_limit_s:g}: {pick[0]} frames, about {pick[2]} rays per pixel, "
                      f"expected about {pick[1]:.0f} dB (the mix of frames and rays predicted best in that time; "
                      "--frames fixes the frames)")
    return loaded, optics_cfg


def _render(scene, out: Path, optics_cfg, options, profile, budget: int, progress_jsonl: Optional[Path], console):
    """Render to ``out`` with a progress bar on a terminal and JSON lines in ``progress_jsonl``; its meta."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from holocore.pipeline import render_to_file

    write_progress = progress_writer(progress_jsonl)
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeElapsedColumn(), console=console, transient=True, disable=not sys.stderr.isatty()) as bar:
        tasks: dict[str, int] = {}

        def progress(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)
            write_progress(stage, done, total)

        t0 = time.perf_counter()
        try:
            m = render_to_file(scene, out, optics_cfg, options, progress=progress, display=profile,
                               memory_budget_bytes=budget)
        except (ValueError, FileNotFoundError) as exc:
            fail(str(exc))
    return {**m, "wall_s": time.perf_counter() - t0}


def _print_result(m: dict, scene_name: str, profile, out: Path, console) -> None:
    """What a render did, in a few lines: shape, rays, where the WRP went, time, passes, memory, the plan."""
    F, C, H, W = m["shape_fchw"]
    st = m["stats"]
    console.print(
        f"rendered {scene_name} for display {profile.name}: {F} frame(s) x {C} color(s) x {H}x{W}, "
        f"f = {m['focal_length_m'] * 1e3:.4g} mm, {st['rays']:,} rays "
        f"({st['valid'] / max(1, st['rays']):.0%} with an image point), z_wrp = {m['z_wrp_m'] * 1e3:.3f} mm, "
        f"in {m['wall_s']:.1f} s on {m['device']} -> {out}"
    )
    sm = m["sampling"]
    if sm["time_limit_s"] is not None:
        console.print(f"  - time limit {sm['time_limit_s']:g} s: {sm['spp']} rays per pixel in {len(sm['passes'])} "
                      f"pass(es) of {', '.join(str(p['spp']) for p in sm['passes'])}")
    mem = m["memory"]
    if mem["trace_passes"] > 1 or mem["frames_per_propagation_chunk"] < F:
        console.print(f"  - memory budget {mem['budget_bytes'] / 2**20:.0f} MiB: {mem['trace_passes']} trace "
                      f"pass(es) of {mem['frames_per_trace_pass']} frame(s), propagation in chunks of "
                      f"{mem['frames_per_propagation_chunk']} frame(s)")
    if mem["estimated_peak_bytes"] > mem["budget_bytes"]:
        console.print(f"  - note: the chunk plan estimates a peak of {mem['estimated_peak_bytes'] / 2**20:.0f} "
                      f"MiB, more than the budget of {mem['budget_bytes'] / 2**20:.0f} MiB")
    dc = m.get("delta_capped") or {}
    if dc.get("rays_capped"):
        console.print(f"  - {dc['rays_capped_share']:.1%} of the rays ({dc['rays_capped']:,}) ran past the cap of "
                      f"{dc['max_delta']} delta bounces (mirrors, glass) and were dropped: their light is missing")
    for line in m["plan"]["summary"]:
        console.print(f"  - {line}")


def _scene_quality(scene: Path, optics_cfg, options, profile):
    """(the loaded scene, what the quality predictions read of it: holo.render_quality.quality_context) for
    --quality-db and a time limit's frames; a scene that cannot be loaded or planned exits with one line."""
    from holocore.pipeline import plan_scene
    from holocore.scene.load import load_scene

    from holo.render_quality import quality_context

    try:
        loaded = load_scene(scene)
        return loaded, quality_context(loaded, plan_scene(loaded, optics_cfg, options), profile, optics_cfg)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
