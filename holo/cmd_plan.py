"""`holo plan`: what the renderer would simulate for a scene (the EffectPlan), where its recording planes go, a
small picture through the scene's camera and a probe render's cost per ray (the service's planner runs it)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from holo.common import OpticsOptions, fail, hologram_options, with_optics_options
from holocore.options import MAX_WRP_PLANES


def register(app: typer.Typer) -> None:
    app.command("plan")(plan)


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
    preset: Optional[str] = typer.Option(None, help="fast | balanced (default) | reference"),
    force_all_effects: bool = typer.Option(False, "--force-all-effects"),
    wrp_planes: Optional[str] = typer.Option(
        None, "--wrp-planes", help=f"Wave recording planes: 1..{MAX_WRP_PLANES}, or auto "
                                   "(default: chosen from the scene depth; the "
                                   "plan says where)."),
    options_json: Optional[Path] = typer.Option(None, "--options-json", help="The hologram's options as one JSON "
                                                "document (docs/options.md); the flags above override it."),
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
    hopts = hologram_options(options_json, "render", preset=preset, frames=optics.frames, wrp_planes=wrp_planes)
    profile, optics_cfg = optics.resolve()
    if hopts.frames is not None:
        optics_cfg = optics_cfg.model_copy(update={"frames": hopts.frames})
    if not scene.exists():
        fail(f"scene not found: {scene}")
    from holocore.pipeline import RenderOptions, plan_scene
    from holocore.scene.load import load_scene

    from holocore.plan.estimate_probe import process_age_s

    try:
        loaded = load_scene(scene)
        startup_s = process_age_s()
        render_options = RenderOptions.from_options(hopts, force_all_effects=force_all_effects)
        pl = plan_scene(loaded, optics_cfg, render_options)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    from holocore.display.profiles import display_meta
    from holocore.plan.stored_plan import stored

    doc = {**stored(pl, optics_cfg), **display_meta(profile, optics_cfg)}
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
