"""Peak memory of a job's stages (render, encode, view), predicted from the size of its fields.

Each stage's peak resident set grows with the number of complex field samples it holds, N = H W C F (SLM rows,
columns, colors, frames). The model interpolates peak RSS measured with ``/usr/bin/time -f %M`` on the demo
scene (a 2-core x86_64 CPU, torch 2.13 CPU, Mitsuba 3.9 llvm_ad_rgb; 2026-12-02) linearly in N between the
measured sizes and extrapolates with the last segment's slope; below the smallest size it keeps the smallest
measurement (the processes' fixed cost: Python, torch, Mitsuba). Re-measure with ``bench/bench_memory.py``
when the hot code changes (its results: ``bench/results/memory.md``).

Several recording planes (holocore.plan.wrp_planes) add to the render: each deeper plane k lives on a grid wider
than the SLM's by its border b_k = (z_0 - z_k) tan(theta_max) / p on each side, and chaining it to the plane in
front (holocore.optics.plane_chain) holds at least one frame of one colour of that grid padded to twice each
side for the ASM, several times over (the field, its spectrum, the transfer function, their product). That part
does not shrink with the SLM: b grows with the plane's depth, which grows with f^2, so a 32x48 SLM with a deep
plane can need gigabytes. :func:`plane_chain_bytes` is that term for the widest plane (``ASM_COPIES``, from
measured peaks, kept above them); :func:`deepest_border_px` bounds the widest border from the depth of the
scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Optional, Sequence

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, OpticsConfig
from holocore.plan.wrp_planes import WrpPlanes

__all__ = ["MemoryEstimate", "estimate_memory", "STAGES", "MEASURED_PEAKS", "plane_chain_bytes",
           "deepest_border_px", "recording_planes_bytes", "admit_planes", "admit_placed_planes", "PlaneAdmission",
           "DEFAULT_TILE_RAYS", "ASM_COPIES", "evaluation_bytes", "EVAL_MAX_CELLS"]

Stage = Literal["render", "encode", "view"]
STAGES: tuple[Stage, ...] = ("render", "encode", "view")

_MB = 1e6
# (N = H*W*C*F samples, peak RSS in bytes) per stage, increasing N: bench/results/memory.md, 2026-12-02 (after the
# cone equaliser; demo scene, fast preset, default 8 GiB budget, render and view chunked and streamed, SGD encode
# streamed; a view of the full-size stack). Render and view no longer grow in proportion to N beyond the
# 1080x1920x3x24 points (their chunks are sized by the budget), so the extrapolation above them is an upper
# estimate.
MEASURED_PEAKS: dict[Stage, tuple[tuple[float, float], ...]] = {
    "render": ((135 * 240 * 3 * 8, 634 * _MB), (270 * 480 * 3 * 8, 853 * _MB), (1080 * 1920 * 3 * 24, 6584 * _MB)),
    "encode": ((135 * 240 * 3 * 8, 405 * _MB), (270 * 480 * 3 * 8, 744 * _MB), (1080 * 1920 * 3 * 24, 7158 * _MB)),
    "view": ((135 * 240 * 3 * 8, 306 * _MB), (270 * 480 * 3 * 8, 496 * _MB), (1080 * 1920 * 3 * 24, 1754 * _MB)),
}


@dataclass(frozen=True)
class MemoryEstimate:
    """Predicted peak resident bytes of each stage; ``peak_bytes`` is the largest (stages run one at a time)."""

    render_bytes: int
    encode_bytes: int
    view_bytes: int
    evaluate_bytes: int = 0  # the evaluation against ground truth (:func:`evaluation_bytes`); 0: not asked for

    @property
    def peak_bytes(self) -> int:
        return max(self.render_bytes, self.encode_bytes, self.view_bytes, self.evaluate_bytes)

    @property
    def peak_stage(self) -> str:
        return max((*STAGES, "evaluate"), key=lambda s: getattr(self, f"{s}_bytes"))

    def as_dict(self) -> dict[str, int | str]:
        return {"render_bytes": self.render_bytes, "encode_bytes": self.encode_bytes, "view_bytes": self.view_bytes,
                **({"evaluate_bytes": self.evaluate_bytes} if self.evaluate_bytes else {}),
                "peak_bytes": self.peak_bytes, "peak_stage": self.peak_stage}


def _interpolate(points: tuple[tuple[float, float], ...], n: float) -> float:
    if n <= points[0][0]:
        return points[0][1]
    for (n0, b0), (n1, b1) in zip(points, points[1:]):
        if n <= n1:
            return b0 + (b1 - b0) * (n - n0) / (n1 - n0)
    (n0, b0), (n1, b1) = points[-2], points[-1]
    return b1 + (b1 - b0) / (n1 - n0) * (n - n1)


# Complex64 copies of a deeper plane's padded grid (holocore.optics.propagation.asm pads to twice each side) the
# render holds on top of its single-plane peak: field, spectrum, transfer function, product, and the chaining's
# own buffers. Measured with /usr/bin/time -f %M (2-core x86_64 CPU, 2026-12-03): two emitting spheres at 0.3 m
# and 3 m, 32x48 px, 520 nm, 1 frame, wrp_planes 2: f = 200 mm (border 494 px) 777 MB, f = 300 mm (border
# 1109 px) 1470 MB, against 565 MB with one plane: 6.3 and 5.5 copies; 7 keeps the estimate above both.
ASM_COPIES = 7.0


def plane_chain_bytes(height_px: int, width_px: int, border_px: int) -> int:
    """Bytes the chaining of a deeper plane with ``border_px`` adds to the render's peak: one frame of one colour
    of its (H + 2b) x (W + 2b) grid, padded to twice each side, complex64, ``ASM_COPIES`` times (0 for b = 0)."""
    if border_px <= 0:
        return 0
    grid = (height_px + 2 * border_px) * (width_px + 2 * border_px)
    return int(ASM_COPIES * 4 * grid * 8)


def recording_planes_bytes(height_px: int, width_px: int, borders_px, *, colors: int, frames: int,
                           ring_rows: int) -> int:
    """Bytes the deeper recording planes hold beyond the one-plane render: the tracer's ring buffers (every
    deeper plane's ``ring_rows`` + 2b + 1 rows of its W + 2b columns, complex64, per colour and frame of a pass;
    holocore.trace.hologram_rays) and the chaining of the widest plane (:func:`plane_chain_bytes`). Counted
    before anything is allocated, so that a pitch whose cone is wide (b grows as tan(theta_max) / p) is refused
    or given fewer planes instead of asking for terabytes."""
    deeper = [int(b) for b in list(borders_px)[1:]]
    if not deeper:
        return 0
    ring = sum((ring_rows + 2 * b + 1) * (width_px + 2 * b) for b in deeper) * colors * frames * 8
    return int(ring + plane_chain_bytes(height_px, width_px, max(deeper)))


# Rays a tracer pass holds (holocore.render_setup.RenderOptions.tile_rays): the ring buffers of the deeper planes
# hold one pass's rows of the SLM and their borders.
DEFAULT_TILE_RAYS = 1 << 19


@dataclass(frozen=True)
class PlaneAdmission:
    """The recording planes that fit a memory budget (:func:`admit_planes`): the first ``kept`` of those placed,
    the widest border (px) among them, their bytes, and a line for the plan when planes were dropped."""

    kept: int
    widest_border_px: int
    bytes: int
    note: Optional[str] = None


def admit_planes(borders_px: Sequence[int], *, height_px: int, width_px: int, colors: int, frames: int,
                 pitch_m: float, budget_bytes: int, auto: bool, tile_rays: int = DEFAULT_TILE_RAYS) -> PlaneAdmission:
    """The recording planes placed front to back with these borders (plane 0, the WRP, first) that fit
    ``budget_bytes``, by :func:`recording_planes_bytes`. A deeper plane's grid grows by (z_0 - z_k) tan(theta_max)
    / p on each side, so a fine pitch (a wide cone, a small pixel) can make it terabytes: ``auto`` drops the
    deepest planes until the rest fit (their points are recorded on the deepest one kept, noisier but exact); a
    count asked for (``auto`` False) that does not fit is a ValueError with the figure, in one line. The CLI's
    render and the service's admission both ask this, so they keep and refuse the same planes."""
    borders = [int(b) for b in borders_px]
    ring_rows = min(height_px, max(1, tile_rays // width_px))

    def need(n: int) -> int:
        return recording_planes_bytes(height_px, width_px, borders[:n], colors=colors, frames=frames,
                                      ring_rows=ring_rows)

    full = need(len(borders))
    if len(borders) <= 1 or full <= budget_bytes:
        return PlaneAdmission(len(borders), max(borders, default=0), full)
    pitch, widest = f"{pitch_m * 1e6:g} µm", max(borders)
    if not auto:
        raise ValueError(f"{len(borders)} wave recording planes at {pitch} pitch need about {full / 1e9:.3g} GB "
                         f"(the deepest plane's grid is {height_px + 2 * widest}x{width_px + 2 * widest} px), more "
                         f"than the memory budget of {budget_bytes / 2**20:.0f} MiB: use --wrp-planes auto or 1, "
                         "or a coarser pitch")
    kept = len(borders)
    while kept > 1 and need(kept) > budget_bytes:
        kept -= 1
    note = (f"recording planes cut to {kept} of the {len(borders)} auto placed: at {pitch} pitch the deeper "
            f"planes' grids need about {full / 1e9:.3g} GB, more than the memory budget of "
            f"{budget_bytes / 2**20:.0f} MiB (the points behind are recorded on the deepest plane kept)")
    return PlaneAdmission(kept, max(borders[:kept]), need(kept), note)


def admit_placed_planes(planes: WrpPlanes, optics: OpticsConfig, *, auto: bool, budget_bytes: int,
                        tile_rays: int = DEFAULT_TILE_RAYS) -> tuple[WrpPlanes, PlaneAdmission]:
    """:func:`admit_planes` for planes placed at ``optics``: (the planes kept, the deepest dropped; the admission).
    The render's plan and the service's admission both ask this."""
    theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    h, w = optics.resolution_hw
    adm = admit_planes(planes.borders_px(pitch_m=optics.pitch_m, theta_max=theta), height_px=h, width_px=w,
                       colors=len(optics.wavelengths_m), frames=optics.frames, pitch_m=optics.pitch_m,
                       budget_bytes=budget_bytes, auto=auto, tile_rays=tile_rays)
    kept = planes if adm.kept == planes.count else WrpPlanes(planes.z_m[:adm.kept], planes.margin_m)
    return kept, adm


def deepest_border_px(depth_m: float, *, pitch_m: float, theta_max: float) -> int:
    """The widest border a deeper plane can have when no plane lies more than ``depth_m`` behind the WRP:
    ``depth_m`` tan(theta_max) / p, as :meth:`holocore.plan.wrp_planes.WrpPlanes.border_px`."""
    if not (math.isfinite(depth_m) and depth_m > 0):
        return 0
    t = math.tan(min(theta_max, MAX_CONE_HALF_ANGLE_RAD))
    return int(math.ceil(depth_m * t / pitch_m - 1e-9))


# The evaluate step (service/workers/evaluation.py: `holo evaluate`, the wave-optical ground truth at GT_SPP
# samples, whose depth layers and their binning grow with the pixels, and a simulated eye view per cell, each
# cell's reconstruction and truth kept as float64 [C, H, W] until its PNG pair is written; then, for more than one
# frame, the viewer score in a process of its own) grows with the SLM's pixels, well beyond the other stages: a
# fixed cost, a cost per pixel (the layers, up to 64 x 3 float32, and their float64 binning; the truth's pass of
# Dr.Jit state is bounded), one per sample H W C F (the view of every frame) and one per cell, pixel and colour
# (the kept images, 16 bytes, and the view's transients), for the most cells either process scores
# (EVAL_MAX_CELLS: the sweep's 9 depths and 8 more views at its middle one, 17; the viewer's 2 pupils x 3 x 3
# eyes, 18). Measured with GNU time on the demo scene (bench/bench_evaluation_memory.py,
# bench/results/evaluation_memory.md, 2026-12-06): the fixed and per-pixel constants are the line through two
# 1-frame runs (352x480 with 2 cells 1111 MB, 540x960 with 9 cells 2309 MB), less the per-sample and per-cell
# terms; the per-cell and per-sample constants are from the thin-lens truth's runs (23.6 bytes from 2 to 17 cells
# at 540-720 px, 57 bytes from the viewer run's growth from 2 to 8 frames at 352x480); EVAL_MARGIN keeps the model
# above the runs' noise (the fit has no spare point to absorb it).
EVAL_MAX_CELLS = 18
EVAL_FIXED_BYTES = 532 * _MB
EVAL_BYTES_PER_SAMPLE = 57.0
EVAL_BYTES_PER_CELL_SAMPLE = 23.6
# the measured slope, 3429 bytes a pixel, less one frame's samples and the cells' share of 3 colours
EVAL_BYTES_PER_PIXEL = 3429.0 - 3 * EVAL_BYTES_PER_SAMPLE - 3 * EVAL_MAX_CELLS * EVAL_BYTES_PER_CELL_SAMPLE
EVAL_MARGIN = 1.15


def evaluation_bytes(*, height_px: int, width_px: int, colors: int, frames: int) -> int:
    """Predicted peak bytes of a job's evaluate step on an SLM of ``height_px`` x ``width_px`` pixels, ``colors``
    wavelengths and ``frames`` frames, with every cell an evaluation can have (the model above)."""
    px = float(height_px) * width_px
    return int(EVAL_MARGIN * (EVAL_FIXED_BYTES + EVAL_BYTES_PER_PIXEL * px + EVAL_BYTES_PER_SAMPLE * px * colors
                              * frames + EVAL_BYTES_PER_CELL_SAMPLE * EVAL_MAX_CELLS * colors * px))


def estimate_memory(*, height_px: int, width_px: int, colors: int, frames: int,
                    plane_border_px: int = 0, evaluate: bool = False) -> MemoryEstimate:
    """Peak bytes of render, encode and view for an SLM of ``height_px`` x ``width_px`` pixels, ``colors``
    wavelengths and ``frames`` frames; ``plane_border_px``: the widest border of a deeper recording plane (0:
    one plane), whose chaining the render holds on top (:func:`plane_chain_bytes`); ``evaluate``: the job is
    evaluated against ground truth too (:func:`evaluation_bytes`)."""
    for name, v in (("height_px", height_px), ("width_px", width_px), ("colors", colors), ("frames", frames)):
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    if not isinstance(plane_border_px, int) or plane_border_px < 0:
        raise ValueError(f"plane_border_px must be an integer >= 0, got {plane_border_px!r}")
    n = float(height_px) * width_px * colors * frames
    peaks = {s: int(_interpolate(MEASURED_PEAKS[s], n)) for s in STAGES}
    peaks["render"] += plane_chain_bytes(height_px, width_px, plane_border_px)
    if evaluate:
        peaks["evaluate"] = evaluation_bytes(height_px=height_px, width_px=width_px, colors=colors, frames=frames)
    return MemoryEstimate(**{f"{s}_bytes": b for s, b in peaks.items()})
