"""Evaluation: simulated eye views of a hologram against Mitsuba thin-lens ground truth (docs/design.md §7; paper
Sec. 5: focus planes across the image volume, a grid of views).

For every cell (focus depth z_f, eye offset e) the reconstruction is what the eye sees: the SLM field
(RESULT.npz's ``slm_field`` or exp(i phase) of a STACK.npz, lit with the encoder's laser powers) filtered by
the pupil disc of centre e / f and radius D / 2f, propagated to z_f and frame-averaged
(:func:`holocore.optics.viewing.simulate_view`). That intensity lives on the plane z_f; the eye, at e behind the
eyepiece, sees a point x of that plane at tan = x / f - e (z_f - z_inf) / f^2 (a thin eyepiece with the eye at its
back focal point). So the view is shifted by -e (z_f - z_inf) / f before it is compared: the shift is applied
to the SLM field's spectrum (exact, band-limited) on a grid padded by the shift. The centre view needs no
shift, and then pixel x = f tan(angle) as in the ground truth.

Only the part of the view the SLM lights fully is scored. The rays that reach the pupil through an image
point x at depth z_f left the SLM (z = 0) within z_f (NA + |e| / f) of x (NA = D / 2f): nearer than that to
the SLM's edge the view is vignetted by the SLM's aperture, a property of the display's size, not an error of
the hologram. That border (:func:`lit_margin_px`) is left out of the scores (the images keep it).

Score of a cell (one least-squares brightness scale, docs/design.md §7): with w the 99th percentile of the ground
truth G (the display's white; emitters above it saturate), the scale s minimises ||s R - G||^2 over the pixels
where G < w; both images are then clipped to [0, w] and divided by w, and PSNR / SSIM use data range 1. One
scale serves all colors of a cell, so a wrong colour balance costs PSNR.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from holocore.formats.meta import MetaLike, ViewMeta, parse_view_meta
from holocore.io import load_result, load_stack
from holocore.optics.fieldsource import SlmFieldSource

__all__ = ["CellScore", "Cell", "Evaluation", "load_slm_field", "focus_planes_m", "view_offsets_m",
           "default_pupil_m", "lit_margin_px", "view_shift_px", "eye_view", "compare", "evaluate", "VIEWS_AT"]

MAX_FOCUS_PLANES = 64
MAX_VIEWS = 15


@dataclass(frozen=True)
class CellScore:
    psnr_db: float
    ssim: float
    scale: float  # least-squares brightness scale applied to the reconstruction
    white: float  # ground-truth white level (linear radiance)


@dataclass
class Cell:
    focus_index: int
    view_index: tuple[int, int]  # (column, row) in the view grid, (0, 0) top left
    focus_z_m: float
    view_offset_m: tuple[float, float]
    score: CellScore
    margin_px: int = 0  # border left out of the score (SLM-aperture vignetting)
    recon: Optional[np.ndarray] = None  # [C, H, W] linear (unscaled)
    truth: Optional[np.ndarray] = None  # [C, H, W] linear


@dataclass
class Evaluation:
    cells: list[Cell]
    pupil_diameter_m: float
    wavelengths_m: list[float]
    meta: dict = field(default_factory=dict)

    @property
    def mean_psnr_db(self) -> float:
        vals = [c.score.psnr_db for c in self.cells]
        finite = [v for v in vals if math.isfinite(v)]
        return float(np.mean(finite)) if finite else (math.inf if vals else math.nan)

    @property
    def mean_ssim(self) -> float:
        return float(np.mean([c.score.ssim for c in self.cells])) if self.cells else math.nan

    def table(self) -> list[dict]:
        """One row per cell: indices, focus (mm from the SLM), view (mm), PSNR (dB), SSIM, scale."""
        return [{"focus_index": c.focus_index, "view_col": c.view_index[0], "view_row": c.view_index[1],
                 "focus_mm": c.focus_z_m * 1e3, "view_x_mm": c.view_offset_m[0] * 1e3,
                 "view_y_mm": c.view_offset_m[1] * 1e3, "psnr_db": c.score.psnr_db, "ssim": c.score.ssim,
                 "scale": c.score.scale, "white": c.score.white, "margin_px": c.margin_px} for c in self.cells]


# ---- inputs -------------------------------------------------------------------------------------------------
def load_slm_field(path: str | Path) -> tuple[np.ndarray, ViewMeta, str]:
    """(SLM field complex64 [F, C, H, W], meta, "result" | "stack") from RESULT.npz or STACK.npz.

    A stack is exp(i phase) lit with the encoder's relative laser power per frame and color
    (``meta["encoder"]["illumination"]``), which carries the scene's colour balance.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"input not found: {p}")
    with np.load(p, allow_pickle=False) as z:
        keys = set(z.files)
    if "phase" in keys:
        phase, _, meta = load_stack(p)
        fieldv = np.exp(1j * phase.astype(np.float32)).astype(np.complex64)
        power = (meta.get("encoder") or {}).get("illumination")
        if power is not None:
            pw = np.asarray(power, dtype=np.float64)
            if pw.shape != fieldv.shape[:2] or not np.all(np.isfinite(pw)) or np.any(pw < 0):
                raise ValueError(f"{p}: encoder illumination must be [F, C] powers >= 0, got shape {pw.shape}")
            fieldv *= np.sqrt(pw).astype(np.float32)[..., None, None]
        kind = "stack"
    elif "slm_field" in keys:
        slm, _, meta = load_result(p)
        fieldv, kind = np.ascontiguousarray(slm, dtype=np.complex64), "result"
    else:
        raise ValueError(f"{p} is neither a STACK.npz (phase) nor a RESULT.npz (slm_field)")
    meta = parse_view_meta(meta, what=str(p))
    if fieldv.ndim != 4 or fieldv.shape[1] != len(meta.wavelengths_m):
        raise ValueError(f"{p}: field must be [F, C, H, W] with one color per wavelength, got {fieldv.shape}")
    if not np.all(np.isfinite(fieldv)):
        raise ValueError(f"{p}: the field holds NaN or infinite values")
    return fieldv, meta, kind


def focus_planes_m(meta: MetaLike, n: int) -> list[float]:
    """n hologram depths (m) uniform from the nearest to the farthest image point (uniform in dioptres).

    Uses the render's analysis (``z_near_holo_m``, ``z_far_holo_m``), else ``z_inf_m`` (all that is read: a
    mapping with just those does); one plane: the middle of the volume.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_FOCUS_PLANES:
        raise ValueError(f"focus planes must be an integer in 1..{MAX_FOCUS_PLANES}, got {n!r}")
    ana = meta.get("analysis") or {}
    near, far = ana.get("z_near_holo_m"), ana.get("z_far_holo_m")
    if near is None or far is None:
        near = far = meta["z_inf_m"]
    near, far = float(near), float(far)
    if n == 1:
        return [0.5 * (near + far)]
    return [float(z) for z in np.linspace(near, far, n)]


def fair_focus_planes_m(meta: MetaLike, n: int, *, seed: int, avoid_m: Sequence[float] = (),
                        min_gap_m: float = 0.0) -> list[float]:
    """n focus depths (m) for a fair comparison (docs/evaluation.md, "Focus planes"): one drawn (``seed``) in each
    of n equal slices of the image volume (uniform in dioptres), and kept at least ``min_gap_m`` from every depth
    in ``avoid_m`` (the methods' own planes: a focal stack's targets, the layers' planes) where its slice leaves
    room, else as far from them as its slice allows. A plane is never scored twice (each slice holds one) and
    does not sit on a plane a method was fitted to, where that method would be scored at its best.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_FOCUS_PLANES:
        raise ValueError(f"focus planes must be an integer in 1..{MAX_FOCUS_PLANES}, got {n!r}")
    ends = focus_planes_m(meta, 2)
    far, near = min(ends), max(ends)
    avoid = np.asarray([float(z) for z in avoid_m], dtype=np.float64)
    gap = max(0.0, float(min_gap_m))
    rng = np.random.default_rng([int(seed), 0x46414952])  # "FAIR": its own stream, not the eye grid's
    out = []
    for i in range(n):
        lo = far + (near - far) * i / n
        hi = far + (near - far) * (i + 1) / n
        cand = lo + (hi - lo) * rng.random(64)
        if avoid.size:
            dist = np.min(np.abs(cand[:, None] - avoid[None, :]), axis=1)
            ok = dist >= gap
            z = float(cand[ok][0]) if ok.any() else float(cand[np.argmax(dist)])
        else:
            z = float(cand[0])
        out.append(z)
    return out


def view_offsets_m(meta: MetaLike, n: int, view_deg: float) -> list[tuple[tuple[int, int], tuple[float, float]]]:
    """An n x n grid of eye offsets e (m) whose directions span +-view_deg: e = f sin(angle) per axis.

    Returns [((col, row), (e_x, e_y))], row 0 at the top (e_y > 0: the eye moved up); n = 1: the centre.
    """
    meta = parse_view_meta(meta)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_VIEWS:
        raise ValueError(f"views must be an integer in 1..{MAX_VIEWS} (an n x n grid), got {n!r}")
    v = float(view_deg)
    if not (math.isfinite(v) and 0.0 <= v < 45.0):
        raise ValueError(f"view_deg must be in [0, 45) degrees, got {view_deg!r}")
    f = meta.focal_length_m
    s = np.sin(np.radians(np.linspace(-v, v, n))) if n > 1 else np.zeros(1)
    out = []
    for row in range(n):
        for col in range(n):
            out.append(((col, row), (float(f * s[col]), float(f * s[n - 1 - row]))))
    return out


def default_pupil_m(meta: MetaLike, *, view_deg: float) -> float:
    """Largest pupil (m) that stays inside every color's recording cone at every view of the grid.

    The pupil accepts direction sines within D / 2f of the view's e / f; the bluest line records only
    sin(theta_max) = lambda / 2p, and the corner views sit sqrt(2) sin(view_deg) off axis.
    """
    meta = parse_view_meta(meta)
    f, p = meta.focal_length_m, float(meta.pitch_m)
    s_cone = min(min(1.0, float(lam) / (2.0 * p)) for lam in meta.wavelengths_m)
    s_view = math.sqrt(2.0) * math.sin(math.radians(float(view_deg)))
    na = s_cone - s_view
    if na < 0.1 * s_cone:
        raise ValueError(f"views of +-{view_deg} deg reach sin = {s_view:.4f}, at or past the recording cone "
                         f"(sin theta_max = {s_cone:.4f} for the bluest line): use a smaller --view-deg "
                         f"(at most {math.degrees(math.asin(0.9 * s_cone / math.sqrt(2))):.3f} deg) or give --pupil-mm")
    return 2.0 * f * na


def lit_margin_px(meta: MetaLike, *, focus_z_m: float, pupil_diameter_m: float,
                  view_offset_m: tuple[float, float] = (0.0, 0.0)) -> int:
    """Border (pixels) where the SLM's aperture vignettes the view: ceil(z_f (NA + max|e| / f) / p)."""
    meta = parse_view_meta(meta)
    f, p = meta.focal_length_m, float(meta.pitch_m)
    na = float(pupil_diameter_m) / (2.0 * f)
    e = max(abs(float(view_offset_m[0])), abs(float(view_offset_m[1])))
    return int(math.ceil(max(0.0, float(focus_z_m)) * (na + e / f) / p - 1e-9))


# ---- one view -----------------------------------------------------------------------------------------------
def view_shift_px(meta: MetaLike, *, focus_z_m: float, view_offset_m: tuple[float, float]) -> tuple[float, float]:
    """(rows, cols) shift of the focus plane's content that an eye at ``view_offset_m`` (m) sees, in pixels
    (:func:`holocore.optics.viewing.view_intensities`'s ``shift_px``): the eye sees plane point x at
    f tan = x - e dz / f with dz = z_f - z_inf, so content moves by -e dz / f (x right, y up; rows run down).
    One function for :func:`eye_view` and the fits that must see what it sees (the focal stack's pupil-aware fit)."""
    meta = parse_view_meta(meta)
    f, p = meta.focal_length_m, float(meta.pitch_m)
    ex, ey = (float(v) for v in view_offset_m)
    dz = float(focus_z_m) - meta.z_inf_m
    return -ey * dz / f / p, ex * dz / f / p  # U'[i, j] = U[i + a_row, j + a_col]


def eye_view(field_slm, meta: MetaLike, *, focus_z_m: float, pupil_diameter_m: float,
             view_offset_m: tuple[float, float] = (0.0, 0.0), memory_budget_bytes: Optional[int] = None,
             device=None, fourier_filter: Optional[bool] = None, pixel_orders: Optional[bool] = None) -> np.ndarray:
    """Frame-averaged intensity float64 [C, H, W] the eye sees, on the ground truth's pixel grid.

    ``field_slm`` complex [F, C, H, W] on the SLM (z = 0), in memory or a chunked source
    (:func:`holocore.optics.fieldsource.open_slm_field`: read in chunks of frames of one color, sized by
    ``memory_budget_bytes``); focus at hologram depth ``focus_z_m`` (m); pupil ``pupil_diameter_m`` (m); eye
    offset ``view_offset_m`` (m). See the module docstring for the shift. ``fourier_filter``: whether the display
    passes only each colour's recording cone (holocore.optics.viewing); None: as the meta's display profile says.
    Without the filter the eye also takes the SLM pixels' diffraction orders its pupil reaches (``pixel_orders``;
    None: exactly then; False: an ideal SLM of point-like pixels, as the ground truth assumes).
    """
    meta = parse_view_meta(meta)
    from holocore.optics.viewing import view_intensities

    if isinstance(field_slm, SlmFieldSource):
        src = field_slm
    else:
        u = np.asarray(field_slm)
        if u.ndim != 4 or not np.iscomplexobj(u):
            raise ValueError(f"field_slm must be complex [F, C, H, W], got {u.dtype} {u.shape}")
        src = SlmFieldSource.from_array(u)
    f, p = meta.focal_length_m, float(meta.pitch_m)
    z_f = float(focus_z_m)
    if not math.isfinite(z_f):
        raise ValueError(f"focus_z_m must be finite, got {focus_z_m!r}")
    ex, ey = (float(v) for v in view_offset_m)
    a_row, a_col = view_shift_px(meta, focus_z_m=z_f, view_offset_m=(ex, ey))
    out = view_intensities(src, wavelengths_m=list(meta.wavelengths_m), pitch_m=p, focal_length_m=f,
                           pupil_diameter_m=float(pupil_diameter_m), distances_m=[z_f], view_offset_m=(ex, ey),
                           shift_px=(a_row, a_col), device=device, memory_budget_bytes=memory_budget_bytes,
                           fourier_filter=meta.fourier_filter if fourier_filter is None else bool(fourier_filter),
                           pixel_orders=pixel_orders)[0]
    out = out.cpu().numpy().astype(np.float64)
    return np.ascontiguousarray(out.clip(min=0.0))


def compare(recon: np.ndarray, truth: np.ndarray, *, white_percentile: float = 99.0) -> CellScore:
    """PSNR (dB) and SSIM of a reconstruction [C, H, W] against ground truth after one brightness scale.

    See the module docstring: white w = ``white_percentile`` of the truth, least squares over the truth's
    unsaturated pixels, both clipped to [0, w] and compared with data range w.
    """
    from holocore.evaluate.metrics import psnr, ssim

    r = np.asarray(recon, dtype=np.float64)
    g = np.asarray(truth, dtype=np.float64)
    if r.shape != g.shape or r.ndim != 3:
        raise ValueError(f"recon and truth must both be [C, H, W], got {r.shape} and {g.shape}")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(g))):
        raise ValueError("recon or truth holds NaN or infinite values")
    if not 50.0 <= float(white_percentile) <= 100.0:
        raise ValueError(f"white_percentile must be in 50..100, got {white_percentile!r}")
    w = float(np.percentile(g, white_percentile))
    if w <= 0:
        w = float(g.max()) if g.max() > 0 else 1.0
    unsat = g < w
    if not unsat.any():
        unsat = np.ones_like(g, dtype=bool)
    den = float(np.sum(r[unsat] ** 2))
    s = float(np.sum(r[unsat] * g[unsat])) / den if den > 0 else 1.0
    rd = np.clip(s * r / w, 0.0, 1.0)
    gd = np.clip(g / w, 0.0, 1.0)
    return CellScore(psnr_db=float(psnr(rd, gd, data_range=1.0, channel_axis=0)),
                     ssim=float(ssim(rd, gd, data_range=1.0, channel_axis=0)), scale=s, white=w)


# ---- the grid -----------------------------------------------------------------------------------------------
VIEWS_AT = ("all", "middle")


def evaluate(field_slm: np.ndarray, meta: MetaLike, truth: Any, *, focus_planes: int = 5, views: int = 7,
             view_deg: float = 0.5, pupil_diameter_m: Optional[float] = None,
             focus_z_m: Optional[Sequence[float]] = None, views_at: str = "all", keep_images: bool = False,
             crop: bool = True, progress: Optional[Any] = None, memory_budget_bytes: Optional[int] = None,
             device=None) -> Evaluation:
    """Score a hologram on a grid of focus planes x views against ground truth.

    ``truth``: a :class:`holocore.evaluate.groundtruth.GroundTruth` (or anything with ``channels(focus_z_m=,
    pupil_diameter_m=, view_offset_m=)`` -> [C, H, W]). ``focus_planes`` (1..64) uniform over the image volume
    unless ``focus_z_m`` lists depths (m); ``views`` x ``views`` eye offsets spanning +-``view_deg`` degrees;
    ``views_at``: ``"all"`` scores every view at every focus, ``"middle"`` the centre view at every focus and the
    other views at the middle focus only (``len(focus) + views^2 - 1`` cells instead of the product; ``views``
    odd); pupil ``pupil_diameter_m`` (m, default :func:`default_pupil_m`). ``keep_images`` keeps both images per
    cell; ``crop`` scores only the fully lit part (:func:`lit_margin_px`). ``field_slm``: an array or a chunked
    source (:func:`holocore.optics.fieldsource.open_slm_field`), viewed in chunks that fit ``memory_budget_bytes``.
    """
    meta = parse_view_meta(meta)
    zs = [float(z) for z in focus_z_m] if focus_z_m is not None else focus_planes_m(meta, focus_planes)
    if not 1 <= len(zs) <= MAX_FOCUS_PLANES:
        raise ValueError(f"focus depths must number 1..{MAX_FOCUS_PLANES}, got {len(zs)}")
    if views_at not in VIEWS_AT:
        raise ValueError(f"views_at must be one of {VIEWS_AT}, got {views_at!r}")
    grid = view_offsets_m(meta, views, view_deg)
    if views_at == "middle" and views % 2 == 0:
        raise ValueError(f"views_at 'middle' needs an odd number of views (the centre view is scored at every "
                         f"focus), got {views}")
    centre, middle = (views // 2, views // 2), len(zs) // 2
    cells_at = [grid if views_at == "all" or fi == middle else [v for v in grid if v[0] == centre]
                for fi in range(len(zs))]
    pupil = float(pupil_diameter_m) if pupil_diameter_m is not None else default_pupil_m(meta, view_deg=view_deg)
    if not (math.isfinite(pupil) and pupil > 0):
        raise ValueError(f"pupil_diameter_m must be finite and > 0, got {pupil_diameter_m!r}")
    cells: list[Cell] = []
    total = sum(len(g) for g in cells_at)
    for fi, z in enumerate(zs):
        for idx, e in cells_at[fi]:
            rec = eye_view(field_slm, meta, focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=e,
                           memory_budget_bytes=memory_budget_bytes, device=device)
            gt = np.asarray(truth.channels(focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=e), dtype=np.float64)
            if gt.shape != rec.shape:
                raise ValueError(f"ground truth {gt.shape} and reconstruction {rec.shape} differ in shape")
            m = lit_margin_px(meta, focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=e) if crop else 0
            H, W = rec.shape[-2:]
            if min(H, W) - 2 * m < 16:
                raise ValueError(
                    f"the SLM ({H}x{W} px) is too small for this view: an image point {z * 1e3:.2f} mm from it "
                    f"gathers light from {m} px around, so no part of the view is fully lit; put virtual "
                    f"infinity closer (z_inf_mm, now {meta.z_inf_m * 1e3:g}), use a smaller pupil or "
                    f"view angle, or a larger SLM")
            sc = compare(rec[:, m:H - m, m:W - m], gt[:, m:H - m, m:W - m])
            cells.append(Cell(focus_index=fi, view_index=idx, focus_z_m=z, view_offset_m=e, score=sc, margin_px=m,
                              recon=rec if keep_images else None, truth=gt if keep_images else None))
            if progress is not None:
                progress("evaluate", len(cells), total)
    return Evaluation(cells=cells, pupil_diameter_m=pupil, wavelengths_m=list(meta.wavelengths_m),
                      meta={"focus_z_m": zs, "views": views, "view_deg": float(view_deg), "views_at": views_at})


# ---- outputs ------------------------------------------------------------------------------------------------
