"""Peak memory of a job's stages (render, encode, view), predicted from the size of its fields.

Each stage's peak resident set grows with the number of complex field samples it holds, N = H W C F (SLM rows,
columns, colors, frames). The model interpolates peak RSS measured with ``/usr/bin/time -f %M`` on the demo
scene (a 2-core x86_64 CPU, torch 2.13 CPU, Mitsuba 3.9 llvm_ad_rgb; 2026-12-02) linearly in N between the
measured sizes and extrapolates with the last segment's slope; below the smallest size it keeps the smallest
measurement (the processes' fixed cost: Python, torch, Mitsuba). Re-measure with ``bench/bench_memory.py``
when the hot code changes (its results: ``bench/results/memory.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["MemoryEstimate", "estimate_memory", "STAGES", "MEASURED_PEAKS"]

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

    @property
    def peak_bytes(self) -> int:
        return max(self.render_bytes, self.encode_bytes, self.view_bytes)

    @property
    def peak_stage(self) -> Stage:
        return max(STAGES, key=lambda s: getattr(self, f"{s}_bytes"))

    def as_dict(self) -> dict[str, int | str]:
        return {"render_bytes": self.render_bytes, "encode_bytes": self.encode_bytes, "view_bytes": self.view_bytes,
                "peak_bytes": self.peak_bytes, "peak_stage": self.peak_stage}


def _interpolate(points: tuple[tuple[float, float], ...], n: float) -> float:
    if n <= points[0][0]:
        return points[0][1]
    for (n0, b0), (n1, b1) in zip(points, points[1:]):
        if n <= n1:
            return b0 + (b1 - b0) * (n - n0) / (n1 - n0)
    (n0, b0), (n1, b1) = points[-2], points[-1]
    return b1 + (b1 - b0) / (n1 - n0) * (n - n1)


def estimate_memory(*, height_px: int, width_px: int, colors: int, frames: int) -> MemoryEstimate:
    """Peak bytes of render, encode and view for an SLM of ``height_px`` x ``width_px`` pixels, ``colors``
    wavelengths and ``frames`` frames."""
    for name, v in (("height_px", height_px), ("width_px", width_px), ("colors", colors), ("frames", frames)):
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    n = float(height_px) * width_px * colors * frames
    return MemoryEstimate(**{f"{s}_bytes": int(_interpolate(MEASURED_PEAKS[s], n)) for s in STAGES})
