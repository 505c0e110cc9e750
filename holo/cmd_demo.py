"""`holo demo`: build the embedded demo scene, render it, encode it and write pictures of what a viewer sees."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from holo.common import OpticsOptions, fail, with_optics_options


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)


DEMO_RESOLUTION = "384x512"
DEMO_FRAMES = 4


@with_optics_options
def demo(
    out: Path = typer.Option(Path("out/demo"), "--out", help="Folder for the scene, RESULT.npz and pictures."),
    preset: str = typer.Option("fast", help="fast | balanced | reference"),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """Render the project's own demo scene (textured wall, clay, mirror and glass spheres) end to end, for a
    display (default: the paper's, f = 50 mm, on a 384x512 part of its SLM with 4 frames, so that it runs in
    seconds; --resolution and --frames give the whole display)."""
    from holocore.demo_scene import write_demo_scene
    from holocore.io import save_result
    from holocore.pipeline import RenderOptions, render
    from holocore.preview import focal_sweep_png

    profile, optics_cfg = optics.resolve(resolution_hw=DEMO_RESOLUTION, frames=DEMO_FRAMES)
    if preset not in ("fast", "balanced", "reference"):
        fail(f"--preset must be fast, balanced or reference, got {preset!r}")
    xml = write_demo_scene(out / "scene")
    t0 = time.perf_counter()
    try:
        result = render(xml, optics_cfg, RenderOptions(preset=preset), display=profile)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    save_result(out / "RESULT.npz", slm_field=result.slm_field, wrp_field=result.wrp_field, meta=result.meta)
    pictures = focal_sweep_png(result.slm_field, result.meta, out / "focal_sweep.png", n_planes=3)
    typer.echo(f"demo rendered in {time.perf_counter() - t0:.1f} s: {out / 'RESULT.npz'}; views: {pictures}")
    for line in result.meta["plan"]["summary"]:
        typer.echo(f"  - {line}")
