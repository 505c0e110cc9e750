"""`holo demo`: build the embedded demo scene, render it, encode it and write pictures of what a viewer sees."""

from __future__ import annotations

import time
from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)


def demo(
    out: Path = typer.Option(Path("out/demo"), "--out", help="Folder for the scene, RESULT.npz and pictures."),
    resolution: str = typer.Option("384x512", help="SLM size HxW for the demo."),
    frames: int = typer.Option(4, help="Time-multiplexed frames."),
    preset: str = typer.Option("fast", help="fast | balanced | reference"),
) -> None:
    """Render the project's own demo scene (textured wall, clay, mirror and glass spheres) end to end."""
    from holo.common import optics_from_options
    from holocore.demo_scene import write_demo_scene
    from holocore.io import save_result
    from holocore.pipeline import RenderOptions, render
    from holocore.preview import focal_sweep_png

    optics = optics_from_options(resolution=resolution, frames=frames)  # f fills the SLM with the 10 deg view
    xml = write_demo_scene(out / "scene")
    t0 = time.perf_counter()
    result = render(xml, optics, RenderOptions(preset=preset))
    save_result(out / "RESULT.npz", slm_field=result.slm_field, wrp_field=result.wrp_field, meta=result.meta)
    pictures = focal_sweep_png(result.slm_field, result.meta, out / "focal_sweep.png", n_planes=3)
    typer.echo(f"demo rendered in {time.perf_counter() - t0:.1f} s: {out / 'RESULT.npz'}; views: {pictures}")
    for line in result.meta["plan"]["summary"]:
        typer.echo(f"  - {line}")
