"""Several wave recording planes (paper Sec. 6, future work; docs/design.md §4 "Convergence").

The Monte Carlo noise of an image point grows as the square of its distance to the plane that records it.
With K planes through a deep scene, each ray's contribution is recorded on the plane just in front of its
image point (no closer than the margin), and the planes are chained to the front one (the WRP proper) with the
band-limited ASM. Plane 0 is the WRP (z_wrp, in front of everything); planes 1..K-1 lie deeper (smaller z).
Plane k records the image points with hologram depth z in (z_k+1 - margin, z_k - margin] (plane 0: up to
z_wrp, the last plane: everything behind).

Placement minimises the mean squared distance of the image points (the analysis' depth
samples, luminance-weighted quantiles) to their planes: the best plane for a group of points lies one margin in
front of the group's frontmost point, so the candidates are the samples themselves and a small dynamic programme
is exact.
The rays still start on the WRP (one trace for all planes): each ray's contribution is recorded where it
crosses the plane that records its image point, so K planes cost one trace and K - 1 ASMs, and ``auto`` adds
planes while they cut the noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD
from holocore.plan.presets import MAX_WRP_PLANES  # one limit for the CLI, the API and the planner

if TYPE_CHECKING:
    import numpy as np

__all__ = ["WrpPlanes", "place_planes", "choose_planes", "MAX_WRP_PLANES"]

MIN_GAP = 0.25  # least distance between two planes, in margins


@dataclass(frozen=True)
class WrpPlanes:
    """Recording planes front to back (hologram z, m) and the margin that sets their slabs."""

    z_m: tuple[float, ...]  # z_m[0] is the WRP (z_wrp); strictly decreasing
    margin_m: float

    def __post_init__(self) -> None:
        if not self.z_m:
            raise ValueError("at least one recording plane is needed")
        if any(b >= a for a, b in zip(self.z_m, self.z_m[1:])):
            raise ValueError(f"recording planes must lie front to back (decreasing z), got {self.z_m}")

    @property
    def count(self) -> int:
        return len(self.z_m)

    def slab(self, k: int) -> tuple[float, float]:
        """Hologram depths (lo, hi] of the image points plane k records (m; -inf for the last plane). A plane
        placed one margin in front of a point keeps that point (a slack of 1e-6 margins absorbs rounding)."""
        return self._edge(k + 1), self._edge(k)

    def _edge(self, k: int) -> float:
        if k == 0:
            return self.z_m[0]
        if k >= self.count:
            return -math.inf
        return self.z_m[k] - self.margin_m * (1.0 - 1e-6)

    def border_px(self, k: int, *, pitch_m: float, theta_max: float) -> int:
        """Pixels a deeper plane's grid extends beyond the WRP's on each side: all the light that reaches the
        WRP's window inside the cone crosses plane k within it, (z_0 - z_k) tan(theta_max) / p."""
        t = math.tan(min(theta_max, MAX_CONE_HALF_ANGLE_RAD))
        return int(math.ceil((self.z_m[0] - self.z_m[k]) * t / pitch_m - 1e-9))

    def borders_px(self, *, pitch_m: float, theta_max: float) -> list[int]:
        """:meth:`border_px` of every plane, front to back (the WRP's is 0)."""
        return [self.border_px(k, pitch_m=pitch_m, theta_max=theta_max) for k in range(self.count)]

    def noise_energy(self, depths_m: Sequence[float]) -> list[float]:
        """Per plane, sum of r^2 over the (luminance-quantile) depth samples it records, r their distance to
        it, floored at one margin: the Monte Carlo noise energy of that plane per ray and pixel (docs/design.md §4)."""
        import numpy as np  # placement only: the API process reads this module without numpy
        k, r = self._assign(depths_m)
        return [float(v) for v in np.bincount(k, np.maximum(r, self.margin_m) ** 2, minlength=self.count)]

    def distances_by_plane_m(self, depths_m: Sequence[float]) -> list[np.ndarray]:
        """Per plane, the distances (m) from it of the depth samples it records."""
        k, r = self._assign(depths_m)
        return [r[k == j] for j in range(self.count)]

    def farthest_distance_m(self, depths_m: Sequence[float]) -> float:
        """The largest distance from an image point (hologram depths) to the plane that records it."""
        _k, r = self._assign(depths_m)
        return float(r.max()) if r.size else 0.0

    def _assign(self, depths_m: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """For the depths inside some slab: the plane that records each, and its distance to that plane."""
        import numpy as np  # placement only: the API process reads this module without numpy
        d = np.asarray(depths_m, dtype=np.float64).reshape(-1)
        ks, rs = [], []
        for k, z in enumerate(self.z_m):
            lo, hi = self.slab(k)
            sel = d[(d > lo) & (d <= hi)]
            ks.append(np.full(sel.size, k))
            rs.append(z - sel)
        return np.concatenate(ks).astype(np.int64), np.concatenate(rs)


def place_planes(depths_m: Sequence[float], *, z_wrp_m: float, margin_m: float, count: int) -> WrpPlanes:
    """``count`` planes (the first at z_wrp_m) minimising sum (z_plane - z)^2 over the depth samples.

    depths_m: hologram depths of image points (m), luminance-weighted quantiles (so each counts once). Fewer
    planes come back when the samples cannot use more (a plane needs points behind it, and distinct positions)."""
    import numpy as np  # placement only: the API process reads this module without numpy
    if not 1 <= count <= MAX_WRP_PLANES:
        raise ValueError(f"wrp planes must be 1..{MAX_WRP_PLANES}, got {count}")
    d = np.asarray(depths_m, dtype=np.float64).reshape(-1)
    d = d[np.isfinite(d) & (d < z_wrp_m)]
    if count == 1 or d.size == 0:
        return WrpPlanes((float(z_wrp_m),), float(margin_m))
    d = np.sort(d)[::-1]  # front to back
    n = d.size
    # Prefix sums: the cost of samples i..j-1 recorded on a plane at P is S0 P^2 - 2 S1 P + S2.
    c0, c1, c2 = (np.concatenate([[0.0], np.cumsum(d ** p)]) for p in (0, 1, 2))

    def cost(i: int, j: int, P: float) -> float:
        s0, s1, s2 = c0[j] - c0[i], c1[j] - c1[i], c2[j] - c2[i]
        return s0 * P * P - 2.0 * s1 * P + s2

    # Candidate plane for a group starting at sample i: one margin in front of it (below the WRP).
    cand = np.minimum(d + margin_m, z_wrp_m)
    INF = math.inf
    # best[k][j]: samples 0..j-1 on k planes (plane 0 at z_wrp); arg: where the last group starts.
    best = [[INF] * (n + 1) for _ in range(count + 1)]
    arg = [[-1] * (n + 1) for _ in range(count + 1)]
    for j in range(n + 1):
        best[1][j] = cost(0, j, z_wrp_m)
    for k in range(2, count + 1):
        for j in range(1, n + 1):
            for i in range(1, j):
                P = cand[i]
                if P > z_wrp_m - MIN_GAP * margin_m:  # hardly behind the WRP: no better than the WRP itself
                    continue
                v = best[k - 1][i] + cost(i, j, P)
                if v < best[k][j]:
                    best[k][j], arg[k][j] = v, i
    # The best k <= count (an extra plane never hurts the objective, but an empty one is dropped).
    k = min(range(1, count + 1), key=lambda kk: (best[kk][n], kk))
    starts, j = [], n
    for kk in range(k, 1, -1):
        i = arg[kk][j]
        starts.append(i)
        j = i
    z = [float(z_wrp_m)]
    for p in sorted((float(cand[i]) for i in starts), reverse=True):
        if z[-1] - p >= MIN_GAP * margin_m:  # planes closer than that would record almost the same points
            z.append(p)
    return WrpPlanes(tuple(z), float(margin_m))


def choose_planes(depths_m: Sequence[float], *, z_wrp_m: float, margin_m: float,
                  max_count: int = MAX_WRP_PLANES) -> WrpPlanes:
    """``auto``: one trace feeds every plane, so more planes only lower the noise (:meth:`WrpPlanes.noise_energy`,
    summed); each costs one ASM of the field and a scratch copy of it, so a plane is added only while it cuts
    the noise by at least 15%."""
    best = place_planes(depths_m, z_wrp_m=z_wrp_m, margin_m=margin_m, count=1)
    best_e = sum(best.noise_energy(depths_m))
    for k in range(2, max(1, min(max_count, MAX_WRP_PLANES)) + 1):
        planes = place_planes(depths_m, z_wrp_m=z_wrp_m, margin_m=margin_m, count=k)
        if planes.count <= best.count:
            break
        e = sum(planes.noise_energy(depths_m))
        if e > 0.85 * best_e:
            break
        best, best_e = planes, e
    return best
