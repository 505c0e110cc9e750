"""What a job's hologram looks like, for the web page: a focal sweep and a view grid of the simulated
reconstruction, as PNGs with a JSON index, made by a worker when the job finishes (never inside a request).

Run as ``python -m service.workers.pictures STACK.npz --out DIR [--preview PNG --preview-focus-mm MM]`` (the job
driver's ``preview`` step: the job's preview image, as ``holo view`` makes it, and the pictures, in one process
that reads the stack once). It uses
holocore's viewing code, as ``holo view --sweep`` does (holocore.evaluate.preview: ``focus_depths``, ``view_rgb``,
``to_png8``):

- sweep: ``--sweep N`` views (default 9) with a 4 mm pupil, focused from far to near across the scene's image
  volume (the render's analysis), one white level for all of them so that brightness compares across focus;
  a volume thinner than 6 depths of field (a flat card) is widened to +-3 depths of field around its middle
  (``widened`` in the index) so that the sweep shows focus and defocus;
- grid: 3 x 3 eye positions (left/centre/right by up/centre/down) focused mid-volume. The eye box is the disc
  at the pupil plane that holds 80 % of the hologram's light (its angular spectrum; at most the recording cone
  f lambda_min / 2p), of radius R: the pupil is R across and the eyes sit R/2 apart, so each sees much of
  the light and the views differ by the parallax across the box; one white level for the grid.

``DIR/index.json`` names every picture with its focus depth (mm from the SLM, and in words), eye offset,
SHA-256 and size, plus ``key``: the SHA-256 of the stack's hash, the parameters and this module's version;
a stack already pictured with the same key is not computed again. The folder is written beside ``DIR`` and
renamed into place, so a reader never sees half of it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Callable, Optional

from holocore.evaluate.preview import depth_words, focus_depths, to_png8, view_rgb
from holocore.formats.hashing import file_sha256
from holocore.formats.meta import ViewMeta, parse_view_meta
from holocore.io import load_stack
from holocore.optics.viewing import depth_of_field_m

__all__ = ["make_pictures", "write_preview", "picture_key", "PICTURES_VERSION", "depth_words"]

PICTURES_VERSION = 1
GRID = 3


def picture_key(stack_sha256: str, params: dict) -> str:
    doc = {"stack": stack_sha256, "params": params, "version": PICTURES_VERSION}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def _field(stack: Path):
    """(complex64 SLM field [F, C, H, W], meta): exp(i phase) lit with the encoder's laser powers."""
    import numpy as np

    phase, _, meta = load_stack(stack)
    field = np.exp(1j * phase.astype(np.float32)).astype(np.complex64)
    power = (meta.get("encoder") or {}).get("illumination")
    if power is not None:
        p = np.asarray(power, dtype=np.float64)
        if p.shape == field.shape[:2] and np.all(np.isfinite(p)) and not np.any(p < 0):
            field *= np.sqrt(p).astype(np.float32)[..., None, None]
    return field, parse_view_meta(meta, what=f"stack {Path(stack).name}")


def light_radius_m(field, meta: ViewMeta, *, share: float = 0.8) -> float:
    """Radius (m, at the pupil plane) of the disc around the axis that holds ``share`` of the hologram's light,
    from the angular spectrum of the first frame (direction sine lambda f_x, times f), at most the recording
    cone f lambda_min / 2p."""
    import numpy as np

    f_m, p_m = meta.focal_length_m, float(meta.pitch_m)
    lams = list(meta.wavelengths_m)
    cone = f_m * min(1.0, min(lams) / (2 * p_m))
    radii, weights = [], []
    for c, lam in enumerate(lams):
        spec = np.abs(np.fft.fft2(field[0, c])) ** 2
        h, w = spec.shape
        sy, sx = lam * np.fft.fftfreq(h, d=p_m), lam * np.fft.fftfreq(w, d=p_m)
        radii.append((f_m * np.hypot(sy[:, None], sx[None, :])).ravel())
        weights.append(spec.ravel())
    r, wgt = np.concatenate(radii), np.concatenate(weights)
    order = np.argsort(r)
    cum = np.cumsum(wgt[order])
    if cum[-1] <= 0:
        return cone
    k = int(np.searchsorted(cum, share * cum[-1]))
    return float(min(cone, max(r[order][min(k, len(r) - 1)], 1e-6)))


def _save(views, white: float, out: Path, names: list[str]) -> list[dict]:
    from PIL import Image

    rows = []
    for v, name in zip(views, names):
        Image.fromarray(to_png8(v, white=white)).save(out / name, optimize=True)
        rows.append({"file": name, "sha256": file_sha256(out / name), "bytes": (out / name).stat().st_size})
    return rows


def write_preview(loaded, out_png: Path, *, focus_mm: float, pupil_mm: float = 4.0) -> None:
    """The job's preview of a stack read by ``_field`` (``loaded``: field, meta): the centre view focused at
    ``focus_mm`` (mm from the SLM) through a ``pupil_mm`` pupil, white at its 99.5th percentile, as
    ``holo view STACK --focus-mm F --pupil-mm P --out PNG`` writes it."""
    from PIL import Image

    field, meta = loaded
    rgb = view_rgb(field, meta, focus_z_m=focus_mm * 1e-3, pupil_diameter_m=pupil_mm * 1e-3)
    tmp = out_png.with_name(f".{out_png.name}.tmp")
    Image.fromarray(to_png8(rgb)).save(tmp, format="PNG")
    os.replace(tmp, out_png)


def make_pictures(stack: Path, out: Path, *, sweep: int = 9, pupil_mm: float = 4.0, loaded=None,
                  progress: Optional[Callable[[str, int, int], None]] = None) -> dict:
    """Write the sweep and grid PNGs and ``index.json`` into ``out``; returns the index. ``loaded``: the
    stack's (field, meta) when the caller has read it already. ``progress(stage, done, total)`` after each
    view (the sweep's, then the grid's)."""
    tick = progress or (lambda stage, done, total: None)
    import numpy as np

    stack_sha = file_sha256(stack)
    params = {"sweep": sweep, "pupil_mm": pupil_mm, "grid": GRID}
    key = picture_key(stack_sha, params)
    try:
        old = json.loads((out / "index.json").read_text())
        if old.get("key") == key and all((out / p["file"]).is_file() for p in _all(old)):
            return old
    except (OSError, ValueError, KeyError, TypeError):
        pass
    t0 = time.monotonic()
    field, meta = loaded if loaded is not None else _field(stack)
    f_m = meta.focal_length_m
    tmp = out.with_name(f".{out.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)

    pupil_m = pupil_mm * 1e-3
    depths = [float(z) for z in focus_depths(meta, sweep)]
    # A shallow scene (a flat card) has an image volume thinner than the eye's depth of field, where every
    # view would look the same: the sweep then spans at least +-3 depths of field around the volume's middle.
    dof = depth_of_field_m(float(np.median(meta.wavelengths_m)), f_m, pupil_m)
    mid, half = 0.5 * (depths[0] + depths[-1]), 0.5 * abs(depths[-1] - depths[0])
    widened = half < 3 * dof
    if widened:
        sign = 1.0 if depths[-1] >= depths[0] else -1.0
        depths = [float(z) for z in np.linspace(mid - sign * 3 * dof, mid + sign * 3 * dof, sweep)]
    total = len(depths) + GRID * GRID
    views = []
    for z in depths:
        views.append(view_rgb(field, meta, focus_z_m=z, pupil_diameter_m=pupil_m))
        tick("sweep", len(views), total)
    white = float(np.percentile(np.stack(views), 99.5)) or 1.0
    rows = _save(views, white, tmp, [f"sweep-{i:02d}.png" for i in range(len(depths))])
    for row, z in zip(rows, depths):
        row.update(z_mm=round(z * 1e3, 4), words=depth_words(z, meta))

    half_box = light_radius_m(field, meta)
    g_pupil = half_box  # pupil radius R/2, edge eyes at R/2, corner eyes at 0.71 R: each sees much of the light
    step = half_box / 2
    offsets = [((i - GRID // 2) * step, (GRID // 2 - j) * step) for j in range(GRID) for i in range(GRID)]
    gviews = []
    for e in offsets:
        gviews.append(view_rgb(field, meta, focus_z_m=mid, pupil_diameter_m=g_pupil, view_offset_m=e))
        tick("grid", len(depths) + len(gviews), total)
    gwhite = float(np.percentile(np.stack(gviews), 99.5)) or 1.0
    grows = _save(gviews, gwhite, tmp, [f"view-{k:02d}.png" for k in range(len(offsets))])
    for row, (ex, ey) in zip(grows, offsets):
        row.update(offset_mm=[round(ex * 1e3, 4), round(ey * 1e3, 4)])

    F, C, H, W = field.shape
    index = {"version": PICTURES_VERSION, "key": key, "stack_sha256": stack_sha, "params": params,
             "shape_hw": [H, W], "frames": F, "colors": C,
             "sweep": {"pupil_mm": pupil_mm, "order": "far to near", "depth_of_field_mm": round(dof * 1e3, 4),
                       "widened": widened, "pictures": rows},
             "grid": {"rows": GRID, "cols": GRID, "pupil_mm": round(g_pupil * 1e3, 4), "focus_mm": round(mid * 1e3, 4),
                      "focus_words": depth_words(mid, meta), "eye_box_mm": round(2 * half_box * 1e3, 4),
                      "eye_step_mm": round(step * 1e3, 4),
                      "pictures": grows},
             "seconds": round(time.monotonic() - t0, 3)}
    (tmp / "index.json").write_text(json.dumps(index, indent=1))
    old_dir = out.with_name(f".{out.name}.old")
    shutil.rmtree(old_dir, ignore_errors=True)
    if out.exists():
        os.replace(out, old_dir)
    os.replace(tmp, out)
    shutil.rmtree(old_dir, ignore_errors=True)
    return index


def _all(index: dict) -> list[dict]:
    return [*index["sweep"]["pictures"], *index["grid"]["pictures"]]


def main(argv: Optional[list[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stack", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--sweep", type=int, default=9)
    ap.add_argument("--pupil-mm", type=float, default=4.0)
    ap.add_argument("--preview", type=Path, default=None,
                    help="also write the job's preview PNG here (one view, focused at --preview-focus-mm)")
    ap.add_argument("--preview-focus-mm", type=float, default=None)
    ap.add_argument("--progress-jsonl", type=Path, default=None,
                    help="append {stage, done, total, t} lines here as the views are made (the job's progress)")
    args = ap.parse_args(argv)
    if (args.preview is None) != (args.preview_focus_mm is None) or (
            args.preview_focus_mm is not None and not math.isfinite(args.preview_focus_mm)):
        print("error: --preview and a finite --preview-focus-mm go together", file=sys.stderr)
        return 2
    if not 2 <= args.sweep <= 64:
        print("error: --sweep must be in 2..64", file=sys.stderr)
        return 2
    if not (math.isfinite(args.pupil_mm) and 0 < args.pupil_mm <= 100):
        print("error: --pupil-mm must be in (0, 100]", file=sys.stderr)
        return 2
    def progress(stage: str, done: int, total: int) -> None:
        if args.progress_jsonl is not None:
            with open(args.progress_jsonl, "a") as fh:
                fh.write(json.dumps({"stage": stage, "done": done, "total": total, "t": time.time()}) + "\n")

    progress("load", 1, 1)
    loaded = None
    if args.preview is not None:  # first, and on its own: a failed preview does not stop the pictures
        try:
            loaded = _field(args.stack)
            write_preview(loaded, args.preview, focus_mm=args.preview_focus_mm, pupil_mm=args.pupil_mm)
            print(f"preview: {args.preview}", file=sys.stderr)
        except (OSError, ValueError, KeyError) as exc:
            print(f"error: no preview: {type(exc).__name__}: {exc}", file=sys.stderr)
    try:
        index = make_pictures(args.stack, args.out, sweep=args.sweep, pupil_mm=args.pupil_mm, loaded=loaded,
                              progress=progress)
    except (OSError, ValueError, KeyError) as exc:
        print(f"error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    print(f"pictures: {len(_all(index))} PNGs in {index['seconds']} s -> {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
