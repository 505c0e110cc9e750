"""Ambient radiance cache for the fast variant (paper Sec. 4.2 and S1.4; DESIGN.md §8).

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

from holocore.mapping import HologramMap
from holocore.mitsuba_env import mitsuba

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

        res = self.res
        rel = (si.p - mi.Point3f(*[float(v) for v in self.bbox_min])) / self.cell
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


def build_cache(scene, hmap: HologramMap, *, shape_hw: tuple[int, int], pitch_m: float, integrator, seed: int,
                n_side: int = 160, samples: int = 16, res: int = 96, max_delta: int = 8) -> RadianceCache:
    """Pre-pass: eye rays over the hologram's field of view, ``samples`` radiance samples per image point."""
    mi = mitsuba()
    import drjit as dr

    from holocore.analysis import _camera_grid
    from holocore.wavetrace import aligned, trace_chain

    rng = np.random.default_rng([seed, 4242])
    dirs_c = _camera_grid(hmap, shape_hw, pitch_m, n_side, rng)
    R = dirs_c.shape[0]
    o = np.repeat(hmap.camera_to_world(np.zeros((1, 3))), R, axis=0)
    v = hmap.camera_dir_to_world(dirs_c)
    res_chain = trace_chain(scene, o, v, max_delta=max_delta, amp_spp=samples, integrator=integrator,
                            seed=seed + 99, surface_info=True)
    bb = scene.bbox()
    lo = np.array([bb.min[k] for k in range(3)], dtype=np.float64)
    hi = np.array([bb.max[k] for k in range(3)], dtype=np.float64)
    ext = float(np.max(hi - lo)) if np.all(np.isfinite(hi - lo)) else 1.0
    cell = max(ext, 1e-6) / res * 1.0001
    lo = lo - 1e-4 * ext
    ok = res_chain.valid
    table_np = np.zeros((res ** 3 * _BINS, 4), dtype=np.float64)
    if ok.any():
        idx = _index_np(res_chain.p_world[ok].astype(np.float64), res_chain.normal_p[ok].astype(np.float64),
                        lo, cell, res)
        reflected = np.maximum(res_chain.radiance_p[ok] - res_chain.emission_p[ok], 0.0).astype(np.float64)
        alb = res_chain.albedo_p[ok].astype(np.float64)
        for k in range(3):
            num = np.bincount(idx, weights=reflected[:, k], minlength=table_np.shape[0])
            den = np.bincount(idx, weights=alb[:, k], minlength=table_np.shape[0])
            table_np[:, k] = np.where(den > 1e-12, num / np.maximum(den, 1e-12), 0.0)
        counts = np.bincount(idx, minlength=table_np.shape[0])
        table_np[:, 3] = (counts > 0).astype(np.float64)
    table = mi.Float(aligned(table_np.ravel()))
    dr.eval(table)
    return RadianceCache(bbox_min=lo, cell=cell, res=res, table=table, cells_filled=int(table_np[:, 3].sum()),
                         samples=int(R * samples))
