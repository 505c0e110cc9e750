"""Ambient radiance cache for the fast variant (paper Sec. 4.2 and S1.4; docs/design.md §8).

The paper bakes view-independent ambient radiance into textures; we keep it in world space. A pre-pass
traces rays from the eye (through the delta chain, like the hologram rays) and estimates, with many
incoherent samples, the radiance leaving each image point P. Each sample is split as
L = emission + albedo * R, and the cache keeps R (reflected radiance per unit diffuse albedo, i.e.
irradiance / pi for a diffuse surface) in a hashed voxel grid keyed also by the dominant axis of the
shading normal. A lookup re-evaluates emission and albedo (textures included) at the ray's own hit point and
reads R: O(1) per ray, exact for view-independent radiance up to the voxel size of the lighting. Cells the
pre-pass never reached fall back to incoherent path tracing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holocore.runtime.mitsuba_env import mitsuba
from holocore.runtime.recording import recording_kernels
from holocore.trace.kernel import trace_wave_paths
from holocore.trace.mapping import camera_grid
from holocore.trace.mapping import HologramMap

__all__ = ["RadianceCache", "build_cache"]

_BINS = 6  # dominant normal axis and its sign


@dataclass
class RadianceCache:
    bbox_min: np.ndarray
    cell: float
    res: int
    table: object  # mi.Float of size res^3 * 6 * 4 (R, G, B, has)
    cells_filled: int
    samples: int

    def lookup(self, si, albedo, emission, active):
        """(L, has): cached radiance leaving si.p and whether the cell holds data."""
        mi = mitsuba()
        import drjit as dr

        idx = self._index(si)
        base = idx * 4
        has = active & (dr.gather(mi.Float, self.table, base + 3, active) > 0)
        R = mi.Color3f(*[dr.gather(mi.Float, self.table, base + k, has) for k in range(3)])
        return emission + albedo * R, has

    def _index(self, si):
        mi = mitsuba()
        import drjit as dr

        # Kernel parameters, not constants: the tracer's kernel is compiled once for every cache.
        res = dr.opaque(mi.Int32, self.res)
        lo = mi.Point3f(*[dr.opaque(mi.Float, float(v)) for v in self.bbox_min])
        rel = (si.p - lo) / dr.opaque(mi.Float, float(self.cell))
        ijk = [dr.clip(mi.Int32(dr.floor(rel[k])), 0, res - 1) for k in range(3)]
        n = si.sh_frame.n
        an = [dr.abs(n[k]) for k in range(3)]
        axis = dr.select((an[0] >= an[1]) & (an[0] >= an[2]), 0, dr.select(an[1] >= an[2], 1, 2))
        comp = dr.select(axis == 0, n[0], dr.select(axis == 1, n[1], n[2]))
        b = mi.Int32(axis) * 2 + dr.select(comp >= 0, 0, 1)
        return mi.UInt32(((ijk[0] * res + ijk[1]) * res + ijk[2]) * _BINS + b)


def _index_np(p: np.ndarray, n: np.ndarray, lo: np.ndarray, cell: float, res: int) -> np.ndarray:
    """numpy twin of RadianceCache._index."""
    ijk = np.clip(np.floor((p - lo) / cell).astype(np.int64), 0, res - 1)
    axis = np.argmax(np.abs(n), axis=1)
    comp = n[np.arange(len(n)), axis]
    b = axis * 2 + (comp < 0)
    return ((ijk[:, 0] * res + ijk[:, 1]) * res + ijk[:, 2]) * _BINS + b


@recording_kernels()
def build_cache(scene, hmap: HologramMap, *, shape_hw: tuple[int, int], pitch_m: float, seed: int,
                n_side: int = 160, samples: int = 16, res: int = 96, max_delta: int = 8,
                max_depth: int = 6) -> RadianceCache:
    """Pre-pass: eye rays over the hologram's field of view, ``samples`` radiance samples per direction.

    Each sample is its own wave path (:func:`holocore.trace.kernel.trace_wave_paths`, one kernel for all of
    them): the cache bins every (P, reflected radiance) pair by P's cell, so a direction's samples need not
    share one P. ``max_depth``: incoherent path depth from P (the pipeline passes the plan's).
    """
    mi = mitsuba()
    import drjit as dr

    rng = np.random.default_rng([seed, 4242])
    dirs_c = camera_grid(hmap, shape_hw, pitch_m, n_side, rng)
    v = np.repeat(hmap.camera_dir_to_world(dirs_c), samples, axis=0)
    R = v.shape[0]
    o = hmap.camera_to_world(np.zeros((1, 3)))[0]
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed + 99, R)
    v64 = mi.Vector3d(*[mi.Float64(np.ascontiguousarray(v[:, i])) for i in range(3)])
    o64 = mi.Point3d(*[dr.full(mi.Float64, float(o[i]), R) for i in range(3)])
    wp = trace_wave_paths(scene, o64, v64, sampler, max_delta=max_delta, max_depth=max_depth, surface=True)
    sf = wp.surface
    thr = sf["thr"]
    ok = wp.valid & (dr.min(thr) > 0)
    # Radiance leaving P (the chain's throughput divided out), minus what P emits: reflected radiance.
    reflected = dr.maximum(wp.radiance / dr.select(ok, thr, 1.0) - sf["emission"], 0.0)
    dr.eval(ok, reflected, sf)
    ok_np = np.asarray(ok).astype(bool)

    def col3(x, dtype=np.float64):
        return np.stack([np.asarray(x[k], dtype=dtype)[ok_np] for k in range(3)], axis=1)

    bb = scene.bbox()
    lo = np.array([bb.min[k] for k in range(3)], dtype=np.float64)
    hi = np.array([bb.max[k] for k in range(3)], dtype=np.float64)
    ext = float(np.max(hi - lo)) if np.all(np.isfinite(hi - lo)) else 1.0
    cell = max(ext, 1e-6) / res * 1.0001
    lo = lo - 1e-4 * ext
    table = dr.zeros(mi.Float, res ** 3 * _BINS * 4)
    filled = 0
    if ok_np.any():
        idx = _index_np(col3(sf["p"]), col3(sf["normal"]), lo, cell, res)
        keys, inv = np.unique(idx, return_inverse=True)  # the cells reached (thousands of ~5e6)
        refl, alb = col3(reflected), col3(sf["albedo"])
        vals = np.empty((keys.size, 4), dtype=np.float32)
        for k in range(3):
            num = np.bincount(inv, weights=refl[:, k], minlength=keys.size)
            den = np.bincount(inv, weights=alb[:, k], minlength=keys.size)
            vals[:, k] = np.where(den > 1e-12, num / np.maximum(den, 1e-12), 0.0)
        vals[:, 3] = 1.0
        filled = int(keys.size)
        slots = (keys[:, None] * 4 + np.arange(4)[None, :]).ravel().astype(np.uint32)
        dr.scatter(table, mi.Float(vals.ravel()), mi.UInt32(slots))
    dr.eval(table)
    return RadianceCache(bbox_min=lo, cell=cell, res=res, table=table, cells_filled=filled, samples=int(R))
