"""`holo baseline layers`: the layer-based (RGB-D) baseline hologram, in the renderer's RESULT.npz format, so
that `holo evaluate` and `holo encode` treat it like a render."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from holo.common import OpticsOptions, fail, with_optics_options

baseline_app = typer.Typer(help="Baseline holograms to compare against (same RESULT.npz format).",
                           no_args_is_help=True)


def register(app: typer.Typer) -> None:
    app.add_typer(baseline_app, name="baseline")


@baseline_app.command("layers")
@with_optics_options
def layers(
    scene: Path = typer.Argument(..., help="Scene folder (a bundle) or its Mitsuba XML file."),
    out: Path = typer.Option(..., "--out", help="Where to write RESULT.npz."),
    planes: int = typer.Option(8, "--planes", help="Depth layers, uniform in dioptres (1..256)."),
    spp: int = typer.Option(64, "--spp", help="Mitsuba samples per pixel of the RGB-D image (1..65536)."),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """RGB-D layers: sqrt(image) per depth bin with random phase per frame, ASM to the WRP and the SLM."""
    profile, optics_cfg = optics.resolve()
    if not 1 <= planes <= 256:
        fail(f"--planes must be in 1..256, got {planes}")
    if not 1 <= spp <= 65536:
        fail(f"--spp must be in 1..65536, got {spp}")
    if not scene.exists():
        fail(f"scene not found: {scene}")
    from holocore.baseline_layers import render_layers
    from holocore.io import save_result
    from holocore.scene import load_scene

    t0 = time.perf_counter()
    try:
        result = render_layers(load_scene(scene), optics_cfg, planes=planes, spp=spp, display=profile)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    save_result(out, slm_field=result.slm_field, wrp_field=result.wrp_field, meta=result.meta)
    m = result.meta
    F, C, H, W = m["shape_fchw"]
    used = sum(1 for n in m["layers"]["pixels_per_plane"] if n)
    typer.echo(f"layer baseline {Path(scene).name} for display {profile.name}: {F} frame(s) x {C} color(s) x {H}x{W}, {planes} planes "
               f"({used} hold pixels) from {m['layers']['plane_z_m'][0] * 1e3:.4f} to "
               f"{m['layers']['plane_z_m'][-1] * 1e3:.4f} mm, z_wrp = {m['z_wrp_m'] * 1e3:.3f} mm, "
               f"in {time.perf_counter() - t0:.1f} s -> {out}", err=True)
