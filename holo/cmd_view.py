"""`holo view`: what an eye sees through the display (docs/design.md §7), from a phase stack or a render.

A STACK.npz is shown as the phase-only SLM field exp(i phase); a RESULT.npz as its complex SLM field. The eye
(pupil D, lateral offset e) sits behind the eyepiece and focuses at hologram depth z (metres from the SLM):
z = z_inf is optical infinity, z = z_inf + f^2 / d a scene distance d (docs/design.md §3).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer

from holo.common import fail

if TYPE_CHECKING:
    from holocore.formats.meta import ViewMeta

_LABEL_PX = 14  # strip above each sweep tile / GIF frame with its focus depth


def register(app: typer.Typer) -> None:
    app.command("view")(view)


def _parse_xy(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        fail(f"--view-mm must look like X,Y in mm (e.g. 1.5,0), got {text!r}")
    if not (math.isfinite(x) and math.isfinite(y)):
        fail(f"--view-mm must be finite, got {text!r}")
    return x, y


def _load(path: Path, quantized: bool, equal_power: bool):
    """A chunked SLM field source (:func:`holocore.optics.fieldsource.open_slm_field`) of a STACK.npz or a RESULT.npz.

    A stack's frame f, color c is lit with the relative laser power P[f, c] its encoder recorded
    (``meta["encoder"]["illumination"]``: the scene's colour balance), unless ``equal_power``."""
    import zipfile

    from holocore.optics.fieldsource import open_slm_field

    try:
        return open_slm_field(path, quantized=quantized, equal_power=equal_power)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        fail(f"cannot read {path}: {exc}")


def _warn_cone(meta: ViewMeta, pupil_m: float, offset_m: tuple[float, float]) -> None:
    """Say when the pupil accepts directions outside a color's recording cone (sin theta_max = lambda / 2p)."""
    f, p = meta.focal_length_m, float(meta.pitch_m)
    reach = (pupil_m / 2 + math.hypot(*offset_m)) / f
    wide = [f"{lam * 1e9:.0f} nm" for lam in meta.wavelengths_m if reach > min(1.0, lam / (2 * p))]
    if wide:
        typer.echo(f"  note: the pupil reaches sin = {reach:.3f}, past the recording cone of {', '.join(wide)}: "
                   "light outside the cone (Monte Carlo noise, light an encoder put there) shows", err=True)


def view(
    source: Path = typer.Argument(..., help="STACK.npz (phase-only: exp(i phase)) or RESULT.npz (complex field)."),
    out: Path = typer.Option(..., "--out", help="IMAGE.png for one view; with --sweep, SHEET.png (contact sheet) "
                                                "or ANIM.gif."),
    focus_mm: Optional[float] = typer.Option(
        None, "--focus-mm",
        help="Focus depth in hologram space, mm from the SLM: z_inf is optical infinity (80 mm in the paper's "
             "setup), z_inf + f^2/d focuses a scene distance d (f: eyepiece focal length; both in the meta)."),
    pupil_mm: float = typer.Option(4.0, "--pupil-mm", help="Eye pupil diameter, mm (> 0)."),
    view_mm: str = typer.Option("0,0", "--view-mm", help="Eye offset X,Y at the pupil plane, mm (x right, y up)."),
    sweep: Optional[int] = typer.Option(None, "--sweep", help="N views focused from far to near across the "
                                                              "scene's image volume (from the meta's analysis)."),
    quantized: bool = typer.Option(False, "--quantized", help="Show a stack through its 8-bit SLM levels."),
    equal_power: bool = typer.Option(False, "--equal-power", help="Light every frame and color of a stack "
                                                                  "equally (ignore the encoder's laser powers)."),
    frame_ms: int = typer.Option(300, "--frame-ms", help="GIF frame duration, ms."),
    white_percentile: float = typer.Option(99.5, "--white-percentile",
                                           help="Percentile of all views' intensities shown as white (50..100; "
                                                "100: the brightest pixel, nothing clips)."),
    device: Optional[str] = typer.Option(None, "--device", help="auto (CUDA when available) | cpu | cuda | cuda:N; "
                                                                 "default: HOLO_DEVICE, else auto."),
    memory_budget_mb: Optional[int] = typer.Option(
        None, "--memory-budget-mb", help="Peak memory to stay within (MiB): the field is read and viewed in chunks "
                                         "of frames that fit; default: HOLO_MEMORY_BUDGET_MB, else 8192."),
) -> None:
    """Simulate what an eye sees (frame-averaged, pupil-filtered, focused) and write a PNG, sheet or GIF."""
    _check(out, focus_mm=focus_mm, sweep=sweep, pupil_mm=pupil_mm, white_percentile=white_percentile,
           frame_ms=frame_ms)
    ex, ey = _parse_xy(view_mm)
    if not source.is_file():
        fail(f"input not found: {source}")

    import numpy as np

    from holocore.evaluate.preview import depth_words, focus_depths, views_rgb
    from holocore.runtime.device import select_device
    from holocore.runtime.membudget import memory_budget_bytes

    try:
        dev = select_device(device)
        budget = memory_budget_bytes(None if memory_budget_mb is None else memory_budget_mb << 20)
    except ValueError as exc:
        fail(str(exc))
    t0 = time.perf_counter()
    field = _load(source, quantized, equal_power)
    meta = field.meta
    pupil_m, offset_m = pupil_mm * 1e-3, (ex * 1e-3, ey * 1e-3)
    depths = [focus_mm * 1e-3] if focus_mm is not None else [float(z) for z in focus_depths(meta, sweep)]
    try:
        views = views_rgb(field, meta, focus_z_m=depths, pupil_diameter_m=pupil_m, view_offset_m=offset_m,
                          device=dev, memory_budget_bytes=budget)
    except ValueError as exc:
        fail(str(exc))
    white = float(np.percentile(np.stack(views), white_percentile)) or 1.0  # one white level for all views
    out.parent.mkdir(parents=True, exist_ok=True)
    _write_views(views, depths, out, white=white, sweep=sweep is not None, frame_ms=frame_ms)
    focus = [f"{z * 1e3:.3f} mm ({depth_words(z, meta)})" for z in depths]
    where = focus[0] if len(focus) == 1 else f"from {focus[0]} to {focus[-1]} in {len(focus)} views"
    typer.echo(f"viewed {source.name} ({field.kind}, {field.shape[0]} frame(s) averaged) with a {pupil_mm:g} mm "
               f"pupil at ({ex:g}, {ey:g}) mm, focus {where}, in {time.perf_counter() - t0:.1f} s -> {out}",
               err=True)
    _warn_cone(meta, pupil_m, offset_m)


def _check(out: Path, *, focus_mm: Optional[float], sweep: Optional[int], pupil_mm: float, white_percentile: float,
           frame_ms: int) -> None:
    """The options checked, one line and exit 2 for the first refused."""
    if (focus_mm is None) == (sweep is None):
        fail("give exactly one of --focus-mm (one view) or --sweep N (focal sweep)")
    if sweep is not None and not 1 <= sweep <= 64:
        fail(f"--sweep must be in 1..64 views, got {sweep}")
    if focus_mm is not None and not math.isfinite(focus_mm):
        fail(f"--focus-mm must be finite, got {focus_mm}")
    if not (math.isfinite(pupil_mm) and 0 < pupil_mm <= 1000):
        fail(f"--pupil-mm must be in (0, 1000] mm, got {pupil_mm}")
    if not 50.0 <= white_percentile <= 100.0:
        fail(f"--white-percentile must be in 50..100, got {white_percentile}")
    if not 10 <= frame_ms <= 60_000:
        fail(f"--frame-ms must be in 10..60000, got {frame_ms}")
    suffix = out.suffix.lower()
    if sweep is not None and suffix not in (".png", ".gif"):
        fail(f"--out for --sweep must end in .png (contact sheet) or .gif (animation), got {out.name!r}")
    if sweep is None and suffix not in (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp"):
        fail(f"--out must be an image file (.png, .jpg, ...), got {out.name!r}")


def _write_views(views: list, depths: list[float], out: Path, *, white: float, sweep: bool, frame_ms: int) -> None:
    """One view as an image; a sweep as labelled tiles in a contact sheet (.png) or an animation (.gif)."""
    from PIL import Image, ImageDraw

    from holocore.evaluate.preview import to_png8

    H, W = views[0].shape[:2]
    if not sweep:
        Image.fromarray(to_png8(views[0], white=white)).save(out)
        return
    tiles = []
    for v, z in zip(views, depths):
        tile = Image.new("RGB", (W, H + _LABEL_PX), (0, 0, 0))
        tile.paste(Image.fromarray(to_png8(v, white=white)), (0, _LABEL_PX))
        ImageDraw.Draw(tile).text((2, 1), f"{z * 1e3:.2f}mm", fill=(255, 255, 255))
        tiles.append(tile)
    if out.suffix.lower() == ".gif":
        tiles[0].save(out, save_all=True, append_images=tiles[1:], duration=frame_ms, loop=0)
        return
    cols = math.ceil(math.sqrt(len(tiles)))
    rows = math.ceil(len(tiles) / cols)
    sheet = Image.new("RGB", (cols * W, rows * (H + _LABEL_PX)), (0, 0, 0))
    for i, tile in enumerate(tiles):
        sheet.paste(tile, ((i % cols) * W, (i // cols) * (H + _LABEL_PX)))
    sheet.save(out)
