"""The viewer-faithful score: what a real eye sees of a hologram, over pupils, eye positions and focus planes, at
one fixed brightness per colour (docs/design.md §7; docs/evaluation.md, "The viewer-faithful score").

The per-cell score of :mod:`holocore.evaluate.scoring` fits a brightness scale to every (focus, view) cell, and
its views sit where a method's layout may favour them (on the axis, on a beam). An eye does neither: its pupil
is 2-6 mm in daylight to dim rooms, it moves, and it never re-calibrates the display's brightness as it moves.
This score therefore

* views the hologram through every pupil of ``pupils_m`` (default 1.6, 2, 3, 4, 6 mm) from every eye position
  of a jittered n x n grid (:func:`eye_grid_m`; the jitter, from ``seed``, keeps the positions off any lattice
  a method's frames may be laid out on), at every focus plane;
* divides every colour's view by one share, that of the display's common eyebox (the cone every colour can fill,
  the smallest colour's) the pupil holds (:func:`aperture_share`): the light an ideal display sends through the
  pupil, so that a pupil partly outside the eyebox (a property of the display's pitch, not of the hologram) or a
  larger pupil (more light) does not count as an error, while brightness that steps with the eye does, and so
  does a colour balance that changes with the pupil (red's own cone is wider than blue's: a hologram that fills
  it turns redder through pupils larger than blue's eyebox, which an eye sees as a red cast);
* fits **one** brightness scale per colour for the whole grid (least squares, over the ground truth's
  unsaturated pixels) and scores every cell with it: PSNR / SSIM against the thin-lens ground truth through
  the same pupil, white at the 99th percentile of all ground-truth cells of that colour;
* reports what the one scale hides or blends: the spread of the per-cell best scales, the brightness over the
  eye grid per pupil (largest / smallest, and its coefficient of variation), the colour cast per pupil (how the
  per-colour best scales of one pupil differ from the global ones), the colour tint of single views (how a cell's
  own per-colour scales differ from each other: a colour that changes with the eye's position), the defocus-blur
  fidelity (the edge profile: relative error of the luminance gradient against the ground truth's, and the ratio
  of their energies, > 1 for copies, halos or speckle, < 1 for too much blur) and the motion parallax (the image
  shift between the two outer eye positions of a grid row, by phase correlation, against the ground truth's,
  :mod:`holocore.evaluate.parallax`).

Units: metres inside, ``_mm`` in the outputs; intensities linear; shifts in pixels of the view.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Optional, Sequence

import numpy as np

from holocore.display.optics import common_cone_sine, cone_sine
from holocore.display.optics import channel_of
from holocore.evaluate.metrics import psnr, ssim
from holocore.evaluate.parallax import image_shift_px, parallax_shifts
from holocore.evaluate.scoring import eye_view, focus_planes_m
from holocore.evaluate.wave_truth import band_share
from holocore.formats.meta import MetaLike, parse_view_meta

__all__ = ["DEFAULT_PUPILS_M", "eye_grid_m", "aperture_share", "ViewerCell", "PupilSummary", "ViewerScore",
           "viewer_score", "image_shift_px"]

DEFAULT_PUPILS_M = (1.6e-3, 2e-3, 3e-3, 4e-3, 6e-3)
MAX_EYE_GRID = 9
_JITTER = 0.3  # of the grid spacing, each axis


def eye_grid_m(meta: MetaLike, *, n: int = 5, span_m: Optional[float] = None,
               seed: int = 0) -> list[tuple[tuple[int, int], tuple[float, float]]]:
    """An n x n grid of eye offsets (m) over +-``span_m`` on both axes, each point jittered by up to 0.3 of the
    spacing (uniform, from ``seed``); [((col, row), (e_x, e_y))], row 0 at the top. Default span: half the
    eyebox radius of the bluest line, f sin(theta_max) / 2 (1.4 mm / 2 at the paper's display)."""
    meta = parse_view_meta(meta)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_EYE_GRID:
        raise ValueError(f"the eye grid must be an integer in 1..{MAX_EYE_GRID} (an n x n grid), got {n!r}")
    f, p = meta.focal_length_m, float(meta.pitch_m)
    span = 0.5 * f * common_cone_sine(meta.wavelengths_m, p) if span_m is None else float(span_m)
    if not (math.isfinite(span) and 0.0 <= span <= f):
        raise ValueError(f"the eye grid's span must be in [0, f] m, got {span_m!r}")
    if n == 1:
        return [((0, 0), (0.0, 0.0))]
    step = 2.0 * span / (n - 1)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xE7E]))
    jit = rng.uniform(-_JITTER, _JITTER, size=(n, n, 2)) * step
    out = []
    for row in range(n):
        for col in range(n):
            ex = -span + col * step + jit[row, col, 0]
            ey = span - row * step + jit[row, col, 1]
            out.append(((col, row), (float(ex), float(ey))))
    return out


def _disc_overlap(r1: float, r2: float, d: float) -> float:
    """Area of the intersection of two discs of radii r1, r2 whose centres are d apart."""
    if d >= r1 + r2:
        return 0.0
    if d <= abs(r1 - r2):
        return math.pi * min(r1, r2) ** 2
    a1 = r1 * r1 * math.acos((d * d + r1 * r1 - r2 * r2) / (2 * d * r1))
    a2 = r2 * r2 * math.acos((d * d + r2 * r2 - r1 * r1) / (2 * d * r2))
    tri = 0.5 * math.sqrt(max(0.0, (-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2)))
    return a1 + a2 - tri


def aperture_share(meta: MetaLike, *, pupil_diameter_m: float, eye_offset_m: tuple[float, float]) -> float:
    """The share of the display's common eyebox (the cone of direction sines every colour can fill,
    :func:`holocore.display.optics.common_cone_sine`) that the pupil of an eye at ``eye_offset_m`` (m) holds: what
    an ideal display with a flat angular spectrum in that cone sends through it, relative to all it sends. One
    share for every colour, so that a colour balance that changes with the pupil counts as the error it is."""
    meta = parse_view_meta(meta)
    f = meta.focal_length_m
    s_c = common_cone_sine(meta.wavelengths_m, float(meta.pitch_m))
    na = float(pupil_diameter_m) / (2.0 * f)
    d = math.hypot(float(eye_offset_m[0]), float(eye_offset_m[1])) / f
    return _disc_overlap(na, s_c, d) / (math.pi * s_c * s_c)


@dataclass(frozen=True)
class ViewerCell:
    pupil_mm: float
    focus_index: int
    focus_mm: float
    eye_index: tuple[int, int]  # (column, row) of the eye grid
    eye_mm: tuple[float, float]
    psnr_db: float  # with the one scale per colour
    ssim: float
    brightness: float  # luminance through the pupil (share-normalised, scaled) over the ground truth's, lit part
    best_scales: tuple[float, ...]  # this cell's own least-squares scale per colour, over the global one
    edge_error: float  # ||grad R - grad G|| / ||grad G||, luminance
    sharpness: float  # ||grad R||^2 / ||grad G||^2
    margin_px: int


@dataclass(frozen=True)
class PupilSummary:
    pupil_mm: float
    mean_psnr_db: float
    mean_ssim: float
    brightness_max_over_min: float  # over the eye grid (each eye: mean over the focus planes)
    brightness_cv: float  # standard deviation / mean over the eye grid
    brightness_max_dev: float  # largest |brightness / mean - 1| over the eye grid
    colour_cast: float  # max / min over colours of (this pupil's best scale / the global scale)
    colour_tint: float  # mean over the eye grid and focus of max / min over colours of the cell's best scales
    colour_tint_worst: float  # the largest of those: the worst-tinted view
    edge_error: float
    sharpness: float
    parallax_error_px: float  # mean |shift(recon) - shift(truth)| between the outer eyes of each grid row
    parallax_ratio: float  # mean shift(recon) / shift(truth) (1: right parallax), over pairs that move >= 0.5 px
    # share of the pupil the display can fill (the SLM's band, and the cone where a Fourier filter cuts it), mean
    # over the eye grid and colours: below 1 the pupil is wider than the display's eyebox, an etendue deficit of
    # the display reported beside the score, not charged in it (the wave ground truth has the same band)
    band_share: float = math.nan


@dataclass
class ViewerScore:
    cells: list[ViewerCell]
    pupils: list[PupilSummary]
    scales: tuple[float, ...]  # the one brightness scale per colour
    whites: tuple[float, ...]  # ground-truth white per colour
    wavelengths_m: tuple[float, ...]
    focus_z_m: tuple[float, ...]
    eye_offsets_m: tuple[tuple[float, float], ...]
    meta: dict = field(default_factory=dict)

    @property
    def mean_psnr_db(self) -> float:
        v = [c.psnr_db for c in self.cells if math.isfinite(c.psnr_db)]
        return float(np.mean(v)) if v else math.nan

    def mean_over(self, pupils_mm: Sequence[float]) -> float:
        """Mean PSNR (dB) over the cells of the listed pupils (mm, matched to 1 µm)."""
        want = {round(float(p), 3) for p in pupils_mm}
        v = [c.psnr_db for c in self.cells if round(c.pupil_mm, 3) in want and math.isfinite(c.psnr_db)]
        return float(np.mean(v)) if v else math.nan

    @property
    def scale_spread(self) -> float:
        """Largest / smallest per-cell best scale (luminance-weighted over colours): how much a per-cell fit hides."""
        v = np.array([float(np.mean(c.best_scales)) for c in self.cells])
        v = v[np.isfinite(v) & (v > 0)]
        return float(v.max() / v.min()) if v.size else math.nan

    def to_dict(self) -> dict:
        return {"mean_psnr_db": self.mean_psnr_db, "scale_spread": self.scale_spread, "scales": list(self.scales),
                "whites": list(self.whites), "wavelengths_m": list(self.wavelengths_m),
                "focus_z_m": list(self.focus_z_m), "eye_offsets_m": [list(e) for e in self.eye_offsets_m],
                "pupils": [asdict(p) for p in self.pupils], "cells": [asdict(c) for c in self.cells], **self.meta}


def _lum_weights(wavelengths_m: Sequence[float]) -> np.ndarray:
    rgb_w = (0.2126, 0.7152, 0.0722)
    w = np.array([rgb_w[channel_of(float(lam))] for lam in wavelengths_m], dtype=np.float64)
    return w / w.sum() if w.sum() > 0 else np.full(len(wavelengths_m), 1.0 / max(1, len(wavelengths_m)))


def _grad_norms(r: np.ndarray, g: np.ndarray) -> tuple[float, float]:
    gy_r, gx_r = np.gradient(r)
    gy_g, gx_g = np.gradient(g)
    den = float(np.sum(gy_g ** 2 + gx_g ** 2))
    if den <= 0:
        return math.nan, math.nan
    err = float(np.sqrt(np.sum((gy_r - gy_g) ** 2 + (gx_r - gx_g) ** 2) / den))
    return err, float(np.sum(gy_r ** 2 + gx_r ** 2) / den)


def _finite_mean(values: Sequence[float]) -> float:
    v = [float(x) for x in values if math.isfinite(x)]
    return float(np.mean(v)) if v else math.nan


def _lit_margin(meta, *, focus_z_m: float, pupil_m: float, eye_m: tuple[float, float]) -> int:
    """holocore.evaluate.scoring.lit_margin_px with the accepted directions capped at the widest colour's cone: a
    hologram sends nothing beyond it, so a pupil larger than the eyebox gathers from no farther."""
    f, p = meta.focal_length_m, float(meta.pitch_m)
    s_max = max(cone_sine(float(lam), p) for lam in meta.wavelengths_m)
    e = max(abs(float(eye_m[0])), abs(float(eye_m[1])))
    reach = min(float(pupil_m) / (2.0 * f) + e / f, s_max)
    return int(math.ceil(max(0.0, float(focus_z_m)) * reach / p - 1e-9))


def _gather_views(field_slm: Any, meta: Any, truth: Any, pupils: list[float], eyes: list, zs: list[float], *,
                  progress: Optional[Any], memory_budget_bytes: Optional[int],
                  device: Any) -> list[tuple[int, int, int, np.ndarray, np.ndarray, int]]:
    """Pass 1: every cell's (pupil index, eye index, focus index, view divided by the pupil's share, ground truth,
    margin px), both float32 [C, h, w] cropped to the lit part; ValueError where the two differ in shape."""
    C = len(meta.wavelengths_m)
    views: list[tuple[int, int, int, np.ndarray, np.ndarray, int]] = []
    total = len(pupils) * len(eyes) * len(zs)
    n_done = 0
    for pi_, D in enumerate(pupils):
        for ei, (_idx, e) in enumerate(eyes):
            share = np.full(C, aperture_share(meta, pupil_diameter_m=D, eye_offset_m=e))
            for zi, z in enumerate(zs):
                rec = eye_view(field_slm, meta, focus_z_m=z, pupil_diameter_m=D, view_offset_m=e,
                               memory_budget_bytes=memory_budget_bytes, device=device)
                gt = np.asarray(truth.channels(focus_z_m=z, pupil_diameter_m=D, view_offset_m=e), dtype=np.float64)
                if gt.shape != rec.shape:
                    raise ValueError(f"ground truth {gt.shape} and reconstruction {rec.shape} differ in shape")
                H, W = rec.shape[-2:]
                m = min(_lit_margin(meta, focus_z_m=z, pupil_m=D, eye_m=e), max(0, (min(H, W) - 16) // 2))
                r = rec[:, m:H - m, m:W - m] / np.maximum(share, 1e-12)[:, None, None]
                views.append((pi_, ei, zi, r.astype(np.float32), gt[:, m:H - m, m:W - m].astype(np.float32), m))
                n_done += 1
                if progress is not None:
                    progress("viewer", n_done, total)
    return views


def _whites_and_scales(views: list, C: int, white_percentile: float
                       ) -> tuple[list[float], np.ndarray, np.ndarray, np.ndarray]:
    """(white of each colour over all cells, the one scale per colour, per-cell least-squares numerators and
    denominators [cells, C]), over each cell's unsaturated ground-truth pixels (all of a flat or saturated one)."""
    whites = []
    for c in range(C):
        allg = np.concatenate([v[4][c].reshape(-1) for v in views])
        w = float(np.percentile(allg, white_percentile))
        whites.append(w if w > 0 else (float(allg.max()) if allg.max() > 0 else 1.0))
    cell_num, cell_den = np.zeros((len(views), C)), np.zeros((len(views), C))
    for k, (_p, _e, _z, r, g, _m) in enumerate(views):
        for c in range(C):
            un = g[c] < whites[c]
            if int(un.sum()) < 16:  # a flat or saturated colour: all its pixels (as compare does)
                un = np.ones_like(un)
            rc, gc = r[c][un].astype(np.float64), g[c][un].astype(np.float64)
            cell_num[k, c], cell_den[k, c] = float(np.sum(rc * gc)), float(np.sum(rc * rc))
    num, den = cell_num.sum(axis=0), cell_den.sum(axis=0)
    scales = np.where(den > 0, num / np.maximum(den, 1e-300), 1.0)
    return whites, scales, cell_num, cell_den


def _score_cells(views: list, eyes: list, pupils: list[float], zs: list[float], lum: np.ndarray, whites: list[float],
                 scales: np.ndarray, cell_num: np.ndarray, cell_den: np.ndarray
                 ) -> tuple[list[ViewerCell], dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]]:
    """Pass 2: (the cells scored at the one scale, the luminance images (recon, truth) of each cell by (pupil,
    focus, eye) index)."""
    C = len(whites)
    wv = np.asarray(whites)[:, None, None]
    cells: list[ViewerCell] = []
    lumimg: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
    for k, (pi_, ei, zi, r, g, m) in enumerate(views):
        rs = scales[:, None, None] * r.astype(np.float64)
        rd = np.clip(rs / wv, 0.0, 1.0)
        gd = np.clip(g.astype(np.float64) / wv, 0.0, 1.0)
        lr, lg = np.tensordot(lum, rs / wv, axes=1), np.tensordot(lum, g / wv, axes=1)
        bright = float(lr.sum() / lg.sum()) if lg.sum() > 0 else math.nan
        best = tuple(float(cell_num[k, c] / cell_den[k, c] / scales[c]) if cell_den[k, c] > 0 and scales[c] != 0
                     else math.nan for c in range(C))
        err, sharp = _grad_norms(np.tensordot(lum, rd, axes=1), np.tensordot(lum, gd, axes=1))
        (col, row), e = eyes[ei]
        cells.append(ViewerCell(pupil_mm=pupils[pi_] * 1e3, focus_index=zi, focus_mm=zs[zi] * 1e3,
                                eye_index=(col, row), eye_mm=(e[0] * 1e3, e[1] * 1e3),
                                psnr_db=float(psnr(rd, gd, data_range=1.0, channel_axis=0)),
                                ssim=float(ssim(rd, gd, data_range=1.0, channel_axis=0)), brightness=bright,
                                best_scales=best, edge_error=err, sharpness=sharp, margin_px=m))
        lumimg[(pi_, zi, ei)] = (np.tensordot(lum, rd, axes=1), np.tensordot(lum, gd, axes=1))
    return cells, lumimg


def _pupil_summary(pi_: int, D: float, cells: list[ViewerCell], views: list, cell_num: np.ndarray,
                   cell_den: np.ndarray, scales: np.ndarray, pr: list[tuple[float, float]], meta: Any,
                   lams: list[float], eyes: list) -> PupilSummary:
    """The summary of one pupil's cells: mean scores, brightness over the eye grid, colour cast and tint, edge
    fidelity, parallax and the display's band share."""
    C = len(lams)
    mine = [c for c in cells if round(c.pupil_mm, 6) == round(D * 1e3, 6)]
    by_eye = {}
    for c in mine:
        by_eye.setdefault(c.eye_index, []).append(c.brightness)
    b = np.array([np.mean(v) for v in by_eye.values()])
    b = b[np.isfinite(b)]
    ks = [k for k, v in enumerate(views) if v[0] == pi_]
    p_scale = [float(cell_num[ks, c].sum() / cell_den[ks, c].sum() / scales[c]) if cell_den[ks, c].sum() > 0
               else math.nan for c in range(C)]
    moving = [(sr, sg) for sr, sg in pr if abs(sg) >= 0.5]
    finite = lambda xs: [x for x in xs if math.isfinite(x)]  # noqa: E731
    return PupilSummary(
        pupil_mm=D * 1e3, mean_psnr_db=float(np.mean(finite([c.psnr_db for c in mine]))),
        mean_ssim=float(np.mean([c.ssim for c in mine])),
        brightness_max_over_min=float(b.max() / b.min()) if b.size and b.min() > 0 else math.nan,
        brightness_cv=float(b.std() / b.mean()) if b.size and b.mean() > 0 else math.nan,
        brightness_max_dev=float(np.abs(b / b.mean() - 1.0).max()) if b.size and b.mean() > 0 else math.nan,
        colour_cast=float(max(p_scale) / min(p_scale)) if all(math.isfinite(v) and v > 0 for v in p_scale)
        else math.nan,
        colour_tint=_finite_mean([max(c.best_scales) / min(c.best_scales) for c in mine
                                  if min(c.best_scales) > 0]),
        colour_tint_worst=max([max(c.best_scales) / min(c.best_scales) for c in mine if min(c.best_scales) > 0],
                              default=math.nan),
        edge_error=_finite_mean([c.edge_error for c in mine]),
        sharpness=_finite_mean([c.sharpness for c in mine]),
        parallax_error_px=float(np.mean([abs(sr - sg) for sr, sg in pr])) if pr else math.nan,
        parallax_ratio=float(np.mean([sr / sg for sr, sg in moving])) if moving else math.nan,
        band_share=float(np.mean([band_share(wavelength_m=lam, pitch_m=float(meta.pitch_m),
                                             focal_length_m=meta.focal_length_m, pupil_diameter_m=D,
                                             view_offset_m=e, fourier_filter=meta.fourier_filter, samples=128)
                                  for lam in lams for _i, e in eyes])))


def viewer_score(field_slm: Any, meta: MetaLike, truth: Any, *, pupils_m: Sequence[float] = DEFAULT_PUPILS_M,
                 eye_grid: int = 5, eye_span_m: Optional[float] = None, seed: int = 0, focus_planes: int = 3,
                 focus_z_m: Optional[Sequence[float]] = None, white_percentile: float = 99.0,
                 progress: Optional[Any] = None, memory_budget_bytes: Optional[int] = None,
                 device=None) -> ViewerScore:
    """Score a hologram as an eye sees it (module docstring). ``field_slm``: complex [F, C, H, W] on the SLM or a
    chunked source; ``truth``: anything with ``channels(focus_z_m=, pupil_diameter_m=, view_offset_m=)`` ->
    [C, H, W] (a :class:`holocore.evaluate.groundtruth.GroundTruth`); pupils in m; the eye grid n x n over
    +-``eye_span_m`` (default :func:`eye_grid_m`'s), jittered by ``seed``; ``focus_planes`` uniform over the
    image volume unless ``focus_z_m`` lists depths (m)."""
    meta = parse_view_meta(meta)
    pupils = [float(p) for p in pupils_m]
    if not pupils or not all(math.isfinite(p) and 0 < p <= 0.05 for p in pupils):
        raise ValueError(f"pupils must be diameters in (0, 50] mm, got {[p * 1e3 for p in pupils]}")
    zs = [float(z) for z in focus_z_m] if focus_z_m is not None else focus_planes_m(meta, focus_planes)
    eyes = eye_grid_m(meta, n=eye_grid, span_m=eye_span_m, seed=seed)
    lams = [float(v) for v in meta.wavelengths_m]
    lum = _lum_weights(lams)
    views = _gather_views(field_slm, meta, truth, pupils, eyes, zs, progress=progress,
                          memory_budget_bytes=memory_budget_bytes, device=device)
    whites, scales, cell_num, cell_den = _whites_and_scales(views, len(lams), white_percentile)
    cells, lumimg = _score_cells(views, eyes, pupils, zs, lum, whites, scales, cell_num, cell_den)
    par = parallax_shifts(lumimg, len(pupils), len(zs), eye_grid)
    summaries = [_pupil_summary(pi_, D, cells, views, cell_num, cell_den, scales, par[pi_], meta, lams, eyes)
                 for pi_, D in enumerate(pupils)]
    return ViewerScore(cells=cells, pupils=summaries, scales=tuple(float(s) for s in scales),
                       whites=tuple(whites), wavelengths_m=tuple(lams), focus_z_m=tuple(zs),
                       eye_offsets_m=tuple(e for _i, e in eyes),
                       meta={"eye_grid": int(eye_grid), "seed": int(seed),
                             "eye_span_m": float(eye_span_m) if eye_span_m is not None else
                             max(abs(e[0]) for _i, e in eyes) if eyes else 0.0})
