"""`holo render` and `holo plan`: a scene bundle to RESULT.npz, and the effect plan alone."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Optional

import typer

from holo.common import OpticsOptions, fail, parse_wrp_planes, progress_writer, with_optics_options


def register(app: typer.Typer) -> None:
    app.command("render")(render)
    app.command("plan")(plan)


@with_optics_options
def render(
    scene: Path = typer.Argument(..., help="Scene folder (a bundle) or its Mitsuba XML file."),
    out: Path = typer.Option(..., "--out", help="Where to write RESULT.npz."),
    preset: str = typer.Option("balanced", help="fast | balanced | reference"),
    spp: Optional[int] = typer.Option(None, help="Rays per WRP pixel (default: from the preset; with "
                                                 "--time-limit-s, the most)."),
    max_spp: Optional[int] = typer.Option(None, "--max-spp", help="Without --spp: the most rays per WRP pixel the "
                                                                  "preset may choose (a cap below its own)."),
    time_limit_s: Optional[float] = typer.Option(
        None, "--time-limit-s", help="Render for about this many seconds of wall time (setup, tracing and "
                                     "propagation; not the file writing): passes of rays until the time is spent; "
                                     "without --frames, the frame count (up to the display's) predicted best in it."),
    method: str = typer.Option("wrp", help="wrp (two-stage) | direct (rays from the SLM plane)."),
    force_all_effects: bool = typer.Option(False, "--force-all-effects", help="Simulate every effect."),
    wrp_planes: str = typer.Option("auto", "--wrp-planes", help="Wave recording planes: 1..8, or auto (chosen from "
                                                             "the scene depth; the plan says where)."),
    progress_jsonl: Optional[Path] = typer.Option(None, "--progress-jsonl", help="Append progress as JSON lines."),
    estimate: bool = typer.Option(False, "--estimate", help="Print the predicted time and quality and exit."),
    quality_db: Optional[float] = typer.Option(
        None, "--quality-db", help="Aim at this viewer-faithful PSNR (dB, 5..40): the frames (up to --frames, else "
                                   "the display's) and rays per pixel predicted to reach it soonest "
                                   "(holocore.plan.quality_choice); says the `holo encode --iterations` to run."),
    device: Optional[str] = typer.Option(None, "--device", help="auto (CUDA when available) | cpu | cuda; "
                                                                 "default: HOLO_DEVICE, else auto."),
    memory_budget_mb: Optional[int] = typer.Option(
        None, "--memory-budget-mb", help="Peak memory to stay within (MiB): frames are traced and propagated in "
                                         "chunks that fit and streamed to --out; default: HOLO_MEMORY_BUDGET_MB, "
                                         "else 8192."),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """Render a scene into WRP and SLM wave fields (RESULT.npz) for a display (default: the paper's)."""
    profile, optics_cfg = optics.resolve()
    from holocore.runtime.device import select_device
    from holocore.runtime.membudget import memory_budget_bytes

    try:
        select_device(device)
        budget = memory_budget_bytes(None if memory_budget_mb is None else memory_budget_mb << 20)
    except ValueError as exc:
        fail(str(exc))
    from holocore.plan.presets import PRESET_NAMES, RENDER_METHODS

    if preset not in PRESET_NAMES:
        fail(f"--preset must be fast, balanced or reference, got {preset!r}")
    if method not in RENDER_METHODS:
        fail(f"--method must be wrp or direct, got {method!r}")
    if not scene.exists():
        fail(f"scene not found: {scene}")

    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from holocore.pipeline import RenderOptions, render_to_file

    try:
        options = RenderOptions(preset=preset, spp=spp, max_spp=max_spp, method=method,
                                force_all_effects=force_all_effects,
                                wrp_planes=parse_wrp_planes(wrp_planes), time_limit_s=time_limit_s)
    except ValueError as exc:
        msg = str(exc).replace("time_limit_s", "--time-limit-s")
        fail("--max-spp" + msg[len("max_spp"):] if msg.startswith("max_spp") else msg.replace("spp must", "--spp must"))
    console = Console(stderr=True)
    if quality_db is not None and not (5.0 <= quality_db <= 40.0):
        fail(f"--quality-db must be in 5..40 dB, got {quality_db!r}")
    if quality_db is not None and (spp is not None or time_limit_s is not None):
        fail("--quality-db chooses the rays per pixel (and frames up to --frames, else the display's): give it "
             "without --spp and --time-limit-s")
    loaded = None
    if quality_db is not None:
        from holo.render_quality import choose_options

        loaded, ctx = _scene_quality(scene, optics_cfg, options, profile)
        optics_cfg, options, chosen = choose_options(ctx, optics_cfg, options, quality_db)
        reach = "predicted to reach it" if chosen.psnr_db >= quality_db else "the best predicted; it falls short"
        it = "" if chosen.iterations is None else f" --iterations {chosen.iterations}"
        console.print(f"--quality-db {quality_db:g}: {chosen.words()} ({reach}); then `holo encode{it}`")
    if time_limit_s is not None and optics.frames is None and optics.optics_json is None:
        # the time buys frames as well as rays: the frame count (up to the display's) whose rays in that time
        # predict the best score; frames given (--frames, or a job's --optics-json) are kept
        from holo.render_quality import frames_for_time

        loaded, ctx = _scene_quality(scene, optics_cfg, options, profile)
        pick = frames_for_time(ctx, optics_cfg, options, time_limit_s)
        if pick is not None:
            optics_cfg = optics_cfg.model_copy(update={"frames": pick[0]})
            console.print(f"--time-limit-s {time_limit_s:g}: {pick[0]} frames, about {pick[2]} rays per pixel, "
                          f"expected about {pick[1]:.0f} dB (the mix of frames and rays predicted best in that time; "
                          "--frames fixes the frames)")
    if estimate and time_limit_s is not None:
        console.print(f"estimated time of `holo render`: {time_limit_s:.1f} s (the time limit: the render traces "
                      f"rays until it is spent)")
        return
    if estimate:
        from holocore.pipeline import plan_scene
        from holocore.plan.estimate import (
            estimate_seconds,
            load_calibration,
            user_calibration_path,
        )
        from holocore.calibration import probe_scene
        from holocore.plan.estimate_probe import estimate_with_probe, process_age_s
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
        from holocore.plan.estimate import machine_load

        load = machine_load()
        slower = (f": at that load expect about {load['slowdown']:.1f}x longer (the render about "
                  f"{full['total'] * load['slowdown']:.0f} s)" if load["slowdown"] >= 1.2 else "")
        console.print(f"these times are for an otherwise idle machine; {load['runnable']:.1f} threads are running or "
                      f"ready on its {load['cores']} cores now (one-minute load average {load['load_1min']:.1f})"
                      + slower)
        from holo.render_quality import estimate_lines, quality_context

        qctx = quality_context(loaded, pl, profile, optics_cfg, probe=probe, calibration=cal)
        for line in estimate_lines(qctx, optics_cfg, options, most_frames=max(optics_cfg.frames, profile.frames)):
            console.print(line)
        from holocore.plan.memory_estimate import estimate_memory

        mem = estimate_memory(height_px=optics_cfg.height, width_px=optics_cfg.width,
                              colors=len(optics_cfg.wavelengths_nm), frames=optics_cfg.frames)
        console.print(f"estimated peak memory: render {mem.render_bytes / 1e9:.2f} GB, encode (sgd) "
                      f"{mem.encode_bytes / 1e9:.2f} GB, view {mem.view_bytes / 1e9:.2f} GB")
        return
    write_progress = progress_writer(progress_jsonl)
    t0 = time.perf_counter()
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeElapsedColumn(), console=console, transient=True, disable=not sys.stderr.isatty()) as bar:
        tasks: dict[str, int] = {}

        def progress(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)
            write_progress(stage, done, total)

        try:
            m = render_to_file(loaded or scene, out, optics_cfg, options, progress=progress, display=profile,
                               memory_budget_bytes=budget)
        except (ValueError, FileNotFoundError) as exc:
            fail(str(exc))
    F, C, H, W = m["shape_fchw"]
    st = m["stats"]
    console.print(
        f"rendered {Path(scene).name} for display {profile.name}: {F} frame(s) x {C} color(s) x {H}x{W}, "
        f"f = {m['focal_length_m'] * 1e3:.4g} mm, {st['rays']:,} rays "
        f"({st['valid'] / max(1, st['rays']):.0%} with an image point), z_wrp = {m['z_wrp_m'] * 1e3:.3f} mm, "
        f"in {time.perf_counter() - t0:.1f} s on {m['device']} -> {out}"
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
    for line in m["plan"]["summary"]:
        console.print(f"  - {line}")


def _encode_estimate(optics_cfg, options, pl, cal) -> str:
    """The line on `holo encode`'s time (sgd, its stop rule): the median and 90th percentile of the iterations
    that rule runs at this size, on the encoder's grid at this scene's WRP distance."""
    from holocore.plan.estimate import encode_work, stop_iterations

    med, p90 = (stop_iterations(optics_cfg.height, optics_cfg.width, quantile=q) for q in ("median", "p90"))
    per_it = cal["rates"]["enc"] * encode_work(optics_cfg, pl.analysis.z_wrp_m)
    return (f"estimated `holo encode` time (sgd): {per_it * med:.1f} s ({med} iterations, its stop rule's median "
            f"at this size; up to {per_it * p90:.1f} s at its 90th percentile, {p90})")


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


def _write_picture(loaded, path: Path, *, width: int, spp: int) -> dict:
    """The scene through its camera as an sRGB PNG at ``path``; what the plan's JSON says of it. A picture
    that cannot be made is said, not fatal: the plan stands without it."""
    import numpy as np
    from PIL import Image

    from holocore.evaluate.groundtruth import camera_picture
    from holocore.evaluate.metrics import white_power
    from holocore.evaluate.preview import to_png8

    try:
        rgb = camera_picture(loaded, max_width_px=width, spp=spp)
        q = white_power(rgb)
        # white at the 99th percentile: a small bright lamp saturates instead of darkening the whole scene
        u8 = to_png8(np.moveaxis(rgb, 0, -1), white=float(np.percentile(rgb, 99.0)) or 1.0)
        Image.fromarray(u8).save(path, format="PNG")
    except (ValueError, RuntimeError, OSError) as exc:
        return {"error": f"no picture: {str(exc).splitlines()[0][:300] if str(exc) else type(exc).__name__}"}
    return {"file": path.name, "width_px": int(u8.shape[1]), "height_px": int(u8.shape[0]), "spp": int(spp),
            "image_q": round(q, 5)}


def _probe(loaded, optics_cfg, options, *, startup_s: float) -> dict:
    """What a probe render of the scene measured (holocore.plan.estimate_probe), as the plan's JSON says it;
    a probe that fails leaves the plan as it is and says why."""
    from holocore.calibration import probe_scene

    try:
        p = probe_scene(loaded, optics_cfg, options, startup_s=startup_s)
    except (ValueError, RuntimeError, MemoryError) as exc:
        return {"error": f"no probe: {str(exc).splitlines()[0][:300] if str(exc) else type(exc).__name__}"}
    return {"startup_s": round(p.startup_s, 4), "compile_s": round(p.compile_s, 4),
            "ray_color_s": p.ray_color_s, "probe_s": round(p.probe_s, 4), "load_slowdown": round(p.load_slowdown, 3)}


@with_optics_options
def plan(
    scene: Path = typer.Argument(..., help="Scene folder or XML."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
    preset: str = typer.Option("balanced", help="fast | balanced | reference"),
    force_all_effects: bool = typer.Option(False, "--force-all-effects"),
    wrp_planes: str = typer.Option("auto", "--wrp-planes", help="Wave recording planes: 1..8, or auto (chosen from "
                                                             "the scene depth; the plan says where)."),
    picture: Optional[Path] = typer.Option(None, "--picture", help="Also write a small picture of the scene "
                                                                  "through its own camera (PNG, at most "
                                                                  "--picture-width px wide)."),
    picture_width: int = typer.Option(320, "--picture-width", min=8, max=4096, help="Its width in px."),
    picture_spp: int = typer.Option(32, "--picture-spp", min=1, max=4096, help="Its samples per pixel."),
    probe: bool = typer.Option(False, "--probe", help="Also time a short probe render of the scene (a few "
                                                      "seconds) and give its cost per ray, from which a "
                                                      "render's time is predicted (the service's estimates)."),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """Analyse a scene and print what the renderer would simulate (the EffectPlan), for the same display and
    optics options as `holo render`. ``--picture`` writes what the scene's camera sees, the view the
    hologram's field of view is drawn over."""
    profile, optics_cfg = optics.resolve()
    if not scene.exists():
        fail(f"scene not found: {scene}")
    from holocore.pipeline import RenderOptions, plan_scene
    from holocore.scene.load import load_scene

    from holocore.plan.estimate_probe import process_age_s

    try:
        loaded = load_scene(scene)
        startup_s = process_age_s()
        render_options = RenderOptions(preset=preset, force_all_effects=force_all_effects,
                                       wrp_planes=parse_wrp_planes(wrp_planes))
        pl = plan_scene(loaded, optics_cfg, render_options)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    from holocore.display.profiles import display_meta

    doc = {**pl.to_dict(), "optics": json.loads(optics_cfg.model_dump_json()), **display_meta(profile, optics_cfg)}
    if picture is not None:
        doc["picture"] = _write_picture(loaded, picture, width=picture_width, spp=picture_spp)
    if probe:
        doc["probe"] = _probe(loaded, optics_cfg, render_options, startup_s=startup_s)
    if as_json:
        print(json.dumps(doc, indent=2))
    else:
        over = doc["display"]["overridden"]
        print(f"- display {profile.name}" + (f" (overridden: {', '.join(over)})" if over else "")
              + f": {optics_cfg.height}x{optics_cfg.width} px at {optics_cfg.pitch_um:g} µm, "
              f"f = {pl.focal_length_m * 1e3:.4g} mm, virtual infinity at {optics_cfg.z_inf_mm:g} mm, "
              f"{optics_cfg.frames} frame(s)")
        for line in pl.plan.summary:
            print(f"- {line}")
        a = pl.analysis
        print(f"- WRP at {a.z_wrp_m * 1e3:.3f} mm from the SLM; image volume "
              f"{(a.z_near_holo_m or 0) * 1e3:.3f}..{(a.z_far_holo_m or 0) * 1e3:.3f} mm")
        if picture is not None:
            pic = doc["picture"]
            print(f"- {pic['error']}" if "error" in pic else
                  f"- picture: {picture} ({pic['width_px']}x{pic['height_px']} px, {pic['spp']} spp)")
