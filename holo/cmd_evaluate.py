"""`holo evaluate`: score a hologram (RESULT.npz or STACK.npz) against ground truth (by default the wave-optical
one, docs/evaluation.md) over a grid of focus planes x views (docs/design.md §7), print PSNR / SSIM per cell and write
side-by-side images."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Optional

import typer

from holo.common import fail, progress_writer


def register(app: typer.Typer) -> None:
    app.command("evaluate")(evaluate)


def evaluate(
    source: Path = typer.Argument(..., help="RESULT.npz (complex SLM field) or STACK.npz (phase-only)."),
    scene: Path = typer.Option(..., "--scene", help="The scene bundle (folder or XML) the hologram shows."),
    out: Path = typer.Option(..., "--out", help="Folder for metrics.csv/json, per-cell images, focus_sheet.png."),
    focus_planes: int = typer.Option(5, "--focus-planes", help="Focus depths uniform across the image volume."),
    focus_mm: Optional[str] = typer.Option(None, "--focus-mm", help="Focus depths instead, in mm from the SLM, "
                                                                    "comma-separated (as holo view's --focus-mm)."),
    views: int = typer.Option(7, "--views", help="An N x N grid of eye positions (1: centre only)."),
    views_at: str = typer.Option("all", "--views-at", help="all: every view at every focus; middle: the centre "
                                                          "view at every focus, the others at the middle focus "
                                                          "only (focus + N^2 - 1 cells; N odd)."),
    view_deg: float = typer.Option(0.5, "--view-deg", help="The grid spans +-this many degrees (pupil centre "
                                                             "direction sine = sin(angle))."),
    pupil_mm: Optional[float] = typer.Option(None, "--pupil-mm", help="Eye pupil diameter in mm (default: the "
                                                                        "largest that stays in every color's "
                                                                        "recording cone at every view)."),
    gt_spp: int = typer.Option(256, "--gt-spp", help="Samples per pixel of the ground-truth renders."),
    truth_kind: str = typer.Option("wave", "--truth", help="wave: what an ideal hologram of this display shows "
                                   "(wave-optical defocus through the pupil within the SLM's band); thinlens: "
                                   "Mitsuba's thin-lens render with the in-focus Airy pattern (docs/evaluation.md)."),
    images: bool = typer.Option(True, "--images/--no-images", help="Write one side-by-side PNG per cell."),
    pairs: bool = typer.Option(False, "--pairs", help="Also write each cell's reconstruction and ground truth as "
                                                      "two PNGs (pairs/recon-fFF-vVV.png, pairs/truth-...), at one "
                                                      "white level for all cells."),
    progress_jsonl: Optional[Path] = typer.Option(None, "--progress-jsonl", help="Append progress as JSON lines."),
    viewer: bool = typer.Option(False, "--viewer", help="The viewer-faithful score instead (docs/evaluation.md): "
                                                        "every pupil of --pupils-mm x an --eye-grid of eye "
                                                        "positions x the focus planes, one brightness scale per "
                                                        "colour for all of them; writes viewer.json."),
    pupils_mm: str = typer.Option("1.6,2,3,4,6", "--pupils-mm", help="With --viewer: pupil diameters (mm)."),
    eye_grid: int = typer.Option(5, "--eye-grid", help="With --viewer: an N x N grid of eye positions, jittered."),
    eye_span_mm: Optional[float] = typer.Option(None, "--eye-span-mm", help="With --viewer: the grid spans +-this "
                                                                            "(default: half the bluest eyebox)."),
    seed: int = typer.Option(0, "--seed", help="With --viewer: the eye grid's jitter."),
    memory_budget_mb: Optional[int] = typer.Option(
        None, "--memory-budget-mb", help="Peak memory to stay within (MiB): the hologram is read and viewed in "
                                         "chunks of frames that fit; default: HOLO_MEMORY_BUDGET_MB, else 8192."),
) -> None:
    """Simulated views vs ground truth (--truth): PSNR/SSIM per (focus, view) after one brightness scale."""
    focus_z_m = _check_grid(focus_planes=focus_planes, focus_mm=focus_mm, views=views, views_at=views_at,
                            view_deg=view_deg, pupil_mm=pupil_mm, truth_kind=truth_kind, gt_spp=gt_spp)
    pupils_m = _check_viewer(pupils_mm, eye_grid=eye_grid, eye_span_mm=eye_span_mm, seed=seed) if viewer else []
    if not source.is_file():
        fail(f"input not found: {source}")
    if not scene.exists():
        fail(f"scene not found: {scene}")

    from holocore.evaluate.score_files import write_outputs
    from holocore.evaluate.scoring import evaluate as run_eval
    from holocore.runtime.membudget import memory_budget_bytes

    t0 = time.perf_counter()
    write_progress = progress_writer(progress_jsonl)
    write_progress("load", 1, 1)
    try:
        budget = memory_budget_bytes(None if memory_budget_mb is None else memory_budget_mb << 20)
        field, truth = _field_and_truth(source, scene, truth_kind, gt_spp)
        if viewer:
            from holocore.evaluate.viewer import viewer_score

            vs = viewer_score(field, field.meta, truth, pupils_m=pupils_m, eye_grid=eye_grid, seed=seed,
                              eye_span_m=None if eye_span_mm is None else eye_span_mm * 1e-3,
                              focus_planes=focus_planes, focus_z_m=focus_z_m, progress=write_progress,
                              memory_budget_bytes=budget)
            return _write_viewer(vs, out, source.name)
        ev = run_eval(field, field.meta, truth, focus_planes=focus_planes, focus_z_m=focus_z_m, views=views,
                      view_deg=view_deg, views_at=views_at,
                      pupil_diameter_m=None if pupil_mm is None else pupil_mm * 1e-3, keep_images=images or pairs,
                      progress=write_progress, memory_budget_bytes=budget)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    paths = write_outputs(ev, out, label=source.name, sheets=images, pairs=pairs)
    _print_cells(ev, field)
    typer.echo(f"evaluated in {time.perf_counter() - t0:.1f} s (ground truth {truth.seconds:.1f} s) -> {out} "
               f"({', '.join(p.name for p in paths.values())})", err=True)


def _check_grid(*, focus_planes: int, focus_mm: Optional[str], views: int, views_at: str, view_deg: float,
                pupil_mm: Optional[float], truth_kind: str, gt_spp: int) -> Optional[list[float]]:
    """The cells' options checked (one line and exit 2 otherwise); the --focus-mm depths in m, if given."""
    from holocore.evaluate.truths import TRUTHS

    if not 1 <= focus_planes <= 64:
        fail(f"--focus-planes must be in 1..64, got {focus_planes}")
    if not 1 <= views <= 15:
        fail(f"--views must be in 1..15, got {views}")
    if not (math.isfinite(view_deg) and 0 <= view_deg < 45):
        fail(f"--view-deg must be in [0, 45) degrees, got {view_deg}")
    if pupil_mm is not None and not (math.isfinite(pupil_mm) and 0 < pupil_mm <= 1000):
        fail(f"--pupil-mm must be in (0, 1000] mm, got {pupil_mm}")
    if truth_kind not in TRUTHS:
        fail(f"--truth must be one of {', '.join(TRUTHS)}, got {truth_kind!r}")
    if not 1 <= gt_spp <= 65536:
        fail(f"--gt-spp must be in 1..65536, got {gt_spp}")
    if views_at not in ("all", "middle"):
        fail(f"--views-at must be all or middle, got {views_at!r}")
    if views_at == "middle" and views % 2 == 0:
        fail(f"--views-at middle needs an odd --views (the centre view is scored at every focus), got {views}")
    if focus_mm is None:
        return None
    try:
        focus_z_m = [float(v) * 1e-3 for v in focus_mm.split(",") if v.strip()]
    except ValueError:
        fail(f"--focus-mm must be a comma-separated list of depths in mm, got {focus_mm!r}")
    if not 1 <= len(focus_z_m) <= 64 or not all(math.isfinite(z) and 0 <= z <= 10.0 for z in focus_z_m):
        fail(f"--focus-mm must list 1..64 depths in [0, 10000] mm, got {focus_mm!r}")
    return focus_z_m


def _check_viewer(pupils_mm: str, *, eye_grid: int, eye_span_mm: Optional[float], seed: int) -> list[float]:
    """The viewer score's options checked; its pupil diameters in m."""
    try:
        pupils_m = [float(v) * 1e-3 for v in pupils_mm.split(",") if v.strip()]
    except ValueError:
        fail(f"--pupils-mm must be a comma-separated list of diameters in mm, got {pupils_mm!r}")
    if not pupils_m or not all(math.isfinite(v) and 0 < v <= 0.05 for v in pupils_m):
        fail(f"--pupils-mm must list diameters in (0, 50] mm, got {pupils_mm!r}")
    if not 1 <= eye_grid <= 9:
        fail(f"--eye-grid must be in 1..9, got {eye_grid}")
    if eye_span_mm is not None and not (math.isfinite(eye_span_mm) and 0 <= eye_span_mm <= 50):
        fail(f"--eye-span-mm must be in [0, 50] mm, got {eye_span_mm}")
    if seed < 0:
        fail(f"--seed must be >= 0, got {seed}")
    return pupils_m


def _field_and_truth(source: Path, scene: Path, truth_kind: str, gt_spp: int):
    """(the hologram's SLM field as a chunked source, its ground truth); a note when the scene changed since."""
    from holocore.evaluate.truths import ground_truth
    from holocore.optics.fieldsource import open_slm_field
    from holocore.scene.load import load_scene

    field = open_slm_field(source)
    loaded = load_scene(scene)
    sha = getattr(loaded.bundle, "sha256", None)
    if field.meta.get("scene_sha256") and sha and field.meta["scene_sha256"] != sha:
        typer.echo(f"  note: {source.name} was rendered from a different version of this scene "
                   "(content hash differs)", err=True)
    return field, ground_truth(truth_kind, loaded, field.meta, shape_hw=tuple(field.shape[-2:]), spp=gt_spp)


def _write_viewer(vs, out: Path, label: str) -> None:
    """viewer.json and the viewer score's table, a row per pupil."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "viewer.json").write_text(json.dumps({"label": label, **vs.to_dict()}, indent=1, default=float))
    typer.echo(f"{'pupil mm':>8} {'PSNR dB':>8} {'SSIM':>6} {'bright max/min':>14} {'cast':>6} {'edge err':>8} "
               f"{'parallax px':>11} {'band':>5}")
    for p in vs.pupils:
        typer.echo(f"{p.pupil_mm:8.2f} {p.mean_psnr_db:8.2f} {p.mean_ssim:6.3f} {p.brightness_max_over_min:14.3f} "
                   f"{p.colour_cast:6.3f} {p.edge_error:8.3f} {p.parallax_error_px:11.2f} {p.band_share:5.2f}")
    typer.echo(f"mean over {len(vs.cells)} cells: PSNR {vs.mean_psnr_db:.2f} dB, one scale per colour "
               f"(per-cell scales spread {vs.scale_spread:.2f}x) -> {out / 'viewer.json'}")


def _print_cells(ev, field) -> None:
    """The table of cells: focus, the depth it shows, the eye's offset, PSNR and SSIM; then their mean."""
    meta = field.meta
    f_m = meta.focal_length_m
    typer.echo(f"{'focus mm':>9} {'depth m':>8} {'view x,y mm':>14} {'PSNR dB':>8} {'SSIM':>6}")
    for c in ev.cells:
        dz = c.focus_z_m - meta.z_inf_m
        depth = f"{f_m * f_m / dz:8.3g}" if dz > 0 else "     inf"
        typer.echo(f"{c.focus_z_m * 1e3:9.4f} {depth} {c.view_offset_m[0] * 1e3:6.3f},"
                   f"{c.view_offset_m[1] * 1e3:<7.3f} {c.score.psnr_db:8.2f} {c.score.ssim:6.3f}")
    typer.echo(f"mean over {len(ev.cells)} cells: PSNR {ev.mean_psnr_db:.2f} dB, SSIM {ev.mean_ssim:.3f} "
               f"({field.kind}, {field.shape[0]} frame(s), pupil {ev.pupil_diameter_m * 1e3:.4g} mm)")
