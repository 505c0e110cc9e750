"""`holo display-profile`: show a display profile (built-in or file) and write it as a file to start one's own."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from holo.common import fail


def register(app: typer.Typer) -> None:
    app.command("display-profile")(display_profile)


def display_profile(
    display: str = typer.Argument("paper", help="A built-in profile name (paper) or a .json/.toml profile file."),
    out: Optional[Path] = typer.Option(None, "--out", help="Write the profile to this .json or .toml file."),
) -> None:
    """Print a display profile with the eyepiece's field of view and depth scale; --out writes it as a file."""
    from holocore.display.profiles import DisplayError, load_display, save_display

    try:
        prof = load_display(display)
        if out is not None:
            save_display(prof, out)
    except DisplayError as exc:
        fail(str(exc))
    f = prof.focal_length_mm
    typer.echo(f"display {prof.name}: {prof.resolution_hw[0]}x{prof.resolution_hw[1]} px at {prof.pitch_um:g} µm, "
               f"{'/'.join(f'{w:g}' for w in prof.wavelengths_nm)} nm, virtual infinity at {prof.z_inf_mm:g} mm, "
               f"f = {f:g} mm, {prof.frames} frame(s), Fourier filter: {'yes' if prof.fourier_filter else 'no'}")
    typer.echo(f"  field of view {prof.field_of_view_x_deg():.3g} deg; 10 m, 0.9 m and 0.5 m lie at "
               + ", ".join(f"{prof.z_inf_mm + f * f / (d * 1e3):.4g}" for d in (10.0, 0.9, 0.5)) + " mm")
    if prof.description:
        typer.echo(f"  {prof.description}")
    if out is not None:
        typer.echo(f"  -> {out}", err=True)
