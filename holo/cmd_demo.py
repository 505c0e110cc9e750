"""`holo demo`: build the embedded demo scene, render it, encode it and write pictures of what a viewer sees."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from holo.common import OpticsOptions, fail, with_optics_options


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)


DEMO_RESOLUTION = "384x512"
DEMO_FRAMES = 4
# The paper scenes (holocore.scene.paper): their focus cues lie in the central half of the paper display's
# view, which a 540 x 960 part of its SLM shows; virtual infinity at 10 mm (not 80) so that a 4 mm pupil's views
# of that part are lit by the SLM all over (an image point z from the SLM gathers light from z NA / p pixels
# around). Depths beyond z_inf are the paper's either way: z = z_inf + f^2 / zc.
PAPER_SCENE_RESOLUTION = "540x960"
PAPER_SCENE_FRAMES = 4
PAPER_SCENE_Z_INF_MM = 10.0


@with_optics_options
def demo(
    out: Path = typer.Option(Path("out/demo"), "--out", help="Folder for the scene, RESULT.npz and pictures."),
    preset: Optional[str] = typer.Option(None, help="fast | balanced | reference (default fast; balanced for "
                                                    "--scene glossy, whose highlight the fast preset's "
                                                    "view-independent cache cannot show)"),
    scene: Optional[str] = typer.Option(
        None, "--scene", help="One of the paper's scenes with depth (holocore.scene.paper): depth (cards at "
                              "0.5, 0.9 and 10 m), mirror (a plane mirror's image 2 m away), glass (a glass "
                              "ball's image, Fig. 1), glossy (a highlight that moves with the view). Default: "
                              "the table-top demo scene."),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """Render one of the project's own scenes end to end for a display (default: the paper's, f = 50 mm).
    Without --scene: the table-top demo scene (textured wall, clay, mirror and glass spheres) on a 384x512 part
    of the SLM with 4 frames, so that it runs in seconds. With --scene NAME: that paper scene on a 540x960 part
    of the SLM (all of its focus cues), 4 frames, virtual infinity at 10 mm so the views are lit all over;
    --resolution, --frames and --z-inf-mm give the whole paper display (1080x1920, 24 frames, 80 mm)."""
    from holocore.evaluate.preview import focal_sweep_png
    from holocore.io import save_result
    from holocore.pipeline import RenderOptions, render
    from holocore.scene.demo import write_demo_scene
    from holocore.scene.paper import PAPER_SCENES, write_paper_scene

    if scene is not None and scene not in PAPER_SCENES:
        fail(f"--scene must be one of {', '.join(PAPER_SCENES)}, got {scene!r}")
    if scene is None:
        profile, optics_cfg = optics.resolve(resolution_hw=DEMO_RESOLUTION, frames=DEMO_FRAMES)
    else:
        profile, optics_cfg = optics.resolve(resolution_hw=PAPER_SCENE_RESOLUTION, frames=PAPER_SCENE_FRAMES,
                                             z_inf_mm=PAPER_SCENE_Z_INF_MM)
    if preset is None:
        preset = "balanced" if scene == "glossy" else "fast"
    if preset not in ("fast", "balanced", "reference"):
        fail(f"--preset must be fast, balanced or reference, got {preset!r}")
    xml = write_demo_scene(out / "scene") if scene is None else write_paper_scene(scene, out / "scene")
    t0 = time.perf_counter()
    try:
        result = render(xml, optics_cfg, RenderOptions(preset=preset), display=profile)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    save_result(out / "RESULT.npz", slm_field=result.slm_field, wrp_field=result.wrp_field, meta=result.meta)
    pictures = focal_sweep_png(result.slm_field, result.meta, out / "focal_sweep.png", n_planes=3)
    name = "demo" if scene is None else f"scene {scene}"
    typer.echo(f"{name} rendered in {time.perf_counter() - t0:.1f} s: {out / 'RESULT.npz'}; views: {pictures}")
    for line in result.meta["plan"]["summary"]:
        typer.echo(f"  - {line}")
