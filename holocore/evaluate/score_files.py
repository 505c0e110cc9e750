"""An evaluation's files (holocore.evaluate.scoring makes the evaluation): colour pictures of a cell, the
reconstruction beside its ground truth, the PNG pairs' names, and the folder ``holo evaluate`` writes (pairs,
contact sheets, scores as CSV and JSON)."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Sequence

import numpy as np

from holocore.display.optics import channel_of
from holocore.evaluate.preview import to_png8
from holocore.evaluate.scoring import Cell, Evaluation

__all__ = ["to_rgb", "side_by_side", "pair_names", "write_outputs"]


def to_rgb(img: np.ndarray, wavelengths_m: Sequence[float]) -> np.ndarray:
    """[C, H, W] per laser line -> [H, W, 3] linear RGB (one line: grey)."""
    a = np.asarray(img, dtype=np.float64)
    if len(wavelengths_m) == 1:
        return np.repeat(a[0][..., None], 3, axis=-1)
    rgb = np.zeros(a.shape[1:] + (3,))
    for c, lam in enumerate(wavelengths_m):
        rgb[..., channel_of(float(lam))] += a[c]
    return rgb


def side_by_side(cell: Cell, wavelengths_m: Sequence[float]) -> np.ndarray:
    """uint8 [H, 3W + 4, 3]: reconstruction (scaled) | ground truth | |difference| x 4, one white level."""
    if cell.recon is None or cell.truth is None:
        raise ValueError("the cell holds no images (evaluate with keep_images=True)")
    w = cell.score.white
    rec = to_rgb(cell.recon * cell.score.scale, wavelengths_m)
    gt = to_rgb(cell.truth, wavelengths_m)
    diff = np.abs(rec - gt) * 4.0
    tiles = [to_png8(x, white=w) for x in (rec, gt, diff)]
    H, W = tiles[0].shape[:2]
    sheet = np.zeros((H, 3 * W + 4, 3), dtype=np.uint8)
    for i, t in enumerate(tiles):
        sheet[:, i * (W + 2):i * (W + 2) + W] = t
    return sheet


def pair_names(cell: Cell, views: int) -> tuple[str, str]:
    """The file names of a cell's reconstruction and ground truth PNGs (``--pairs``): ``recon-fFF-vVV.png`` and
    ``truth-fFF-vVV.png``, FF the focus index, VV the view's index row * views + column (row 0 at the top)."""
    tag = f"f{cell.focus_index:02d}-v{cell.view_index[1] * views + cell.view_index[0]:02d}"
    return f"recon-{tag}.png", f"truth-{tag}.png"


def write_outputs(ev: Evaluation, out_dir: str | Path, *, label: str = "", sheets: bool = True,
                  pairs: bool = False) -> dict[str, Path]:
    """Write metrics.csv, metrics.json and, for the cells whose images were kept: with ``sheets`` one
    side-by-side PNG per cell (cells/) and focus_sheet.png (centre view: reconstructions over ground truths, near
    to far); with ``pairs`` each cell's reconstruction (at its brightness scale) and ground truth as two PNGs in
    pairs/ (:func:`pair_names`), all at one white, the largest cell white (``pair_white`` in metrics.json, gamma
    ``pair_gamma``), so that brightness compares across cells. Returns the paths."""
    from PIL import Image

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = ev.table()
    paths: dict[str, Path] = {"csv": out / "metrics.csv", "json": out / "metrics.json"}
    with paths["csv"].open("w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=list(rows[0].keys()) if rows else ["psnr_db"])
        wr.writeheader()
        for r in rows:
            wr.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    doc = {"label": label, "mean_psnr_db": ev.mean_psnr_db, "mean_ssim": ev.mean_ssim,
           "pupil_diameter_mm": ev.pupil_diameter_m * 1e3, "wavelengths_m": ev.wavelengths_m, **ev.meta,
           "cells": rows}
    kept = [c for c in ev.cells if c.recon is not None]
    n = int(ev.meta.get("views", 1))
    if pairs and kept:
        white = max(c.score.white for c in kept)
        pdir = out / "pairs"
        pdir.mkdir(exist_ok=True)
        for c, row in zip(ev.cells, rows):
            if c.recon is None:
                continue
            recon_name, truth_name = pair_names(c, n)
            Image.fromarray(to_png8(to_rgb(c.recon * c.score.scale, ev.wavelengths_m), white=white)).save(
                pdir / recon_name)
            Image.fromarray(to_png8(to_rgb(c.truth, ev.wavelengths_m), white=white)).save(pdir / truth_name)
            row.update(recon_png=f"pairs/{recon_name}", truth_png=f"pairs/{truth_name}")
        doc.update(pair_white=white, pair_gamma=2.2)
    paths["json"].write_text(json.dumps(doc, indent=1, default=float))
    if not kept or not sheets:
        return paths
    cdir = out / "cells"
    cdir.mkdir(exist_ok=True)
    for c in kept:
        name = f"f{c.focus_index}_v{c.view_index[0]}_{c.view_index[1]}.png"
        Image.fromarray(side_by_side(c, ev.wavelengths_m)).save(cdir / name)
    centre = (n // 2, n // 2)
    row = [c for c in kept if c.view_index == centre]
    if row:
        white = max(c.score.white for c in row)
        H, W = row[0].recon.shape[-2:]
        sheet = np.zeros((2 * H + 2, len(row) * (W + 2), 3), dtype=np.uint8)
        for i, c in enumerate(row):
            sheet[:H, i * (W + 2):i * (W + 2) + W] = to_png8(to_rgb(c.recon * c.score.scale, ev.wavelengths_m),
                                                             white=white)
            sheet[H + 2:, i * (W + 2):i * (W + 2) + W] = to_png8(to_rgb(c.truth, ev.wavelengths_m), white=white)
        paths["focus_sheet"] = out / "focus_sheet.png"
        Image.fromarray(sheet).save(paths["focus_sheet"])
    return paths
