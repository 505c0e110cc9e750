"""The per-ray work of wave path tracing, vectorised in Dr.Jit (paper Sec. 4.2, docs/design.md §4).

For a batch of world rays (eye-camera origins near the WRP, unit directions) this follows the delta chain
(mirrors, smooth dielectrics) coherently, stops at the first non-delta vertex P (the real image point), and
returns per ray:

* ``d``: the apparent distance of P along the first ray direction v, so that the virtual image point is
  P' = O + d v. It comes from analytic ray differentials (Igehy 1999) carried through every reflection and
  refraction in float64. Four differentials are carried: two angular perturbations of v and two lateral
  shifts of O, all perpendicular to v. At P their displacements perpendicular to the last segment, read
  along the frame transported through the chain, give the 2x2 blocks A (per shift) and B (per angle) of
  the chain's ray-transfer matrix; the rays from P that reach the neighbourhood of O satisfy
  A dx + B dtheta = 0, so they appear to diverge from distance d = 1 / (tr(B^-1 A) / 2) (mean vergence
  of the two principal sections). With no delta bounce, or through plane mirrors, A = I and d = |B| = t,
  the unfolded path length; through a slab it is t(1 - 1/n) shorter than that, and through curved mirrors
  it is the mirror equation's image distance. (docs/design.md §4 names B alone; B alone is right only where
  A = I, i.e. without curved surfaces: see docs/physics.md.)
* ``radiance``: the RGB radiance reaching O along the ray: delta-chain throughput times the radiance leaving P
  towards the previous vertex, from incoherent path tracing (Mitsuba's own integrator, ``amp_spp`` samples).

The tracer itself runs :mod:`holocore.trace.kernel` (one fused kernel, the same vertex code); this is its
reference implementation, used by the scene analysis and by the tests that compare the two.
* ``n_delta``, ``opl_m`` (world optical path, for diagnostics) and status flags.

Python loops run over bounces only (a handful); every ray of the batch moves together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holocore.runtime.mitsuba_env import mitsuba
from holocore.runtime.recording import recording_kernels
from holocore.trace.differentials import igehy_transfer
from holocore.trace.near_smooth import is_near_smooth, near_smooth_table

__all__ = ["ChainResult", "trace_chain"]


@dataclass
class ChainResult:
    """Per-ray outcome of :func:`trace_chain` (numpy arrays, length R)."""

    valid: np.ndarray  # bool: a finite image point with positive apparent distance and finite radiance
    d: np.ndarray  # float64 apparent distance along v (m, world)
    radiance: np.ndarray  # float32 [R, 3] RGB radiance reaching the origin along the ray
    n_delta: np.ndarray  # int32 delta bounces before P
    opl_m: np.ndarray  # float64 world optical path length O -> P (sum n_i L_i)
    escaped: np.ndarray  # bool: left the scene (no image point)
    capped: np.ndarray  # bool: exceeded the delta-bounce cap
    path_samples: int = 0  # incoherent path-tracing samples spent on the radiance


def aligned(a: np.ndarray, dtype=np.float32) -> np.ndarray:
    """A 64-byte aligned contiguous copy. Dr.Jit wraps numpy memory without copying and bakes the pointer's
    alignment into the kernel, so unaligned inputs would defeat its kernel cache (a recompile every call)."""
    a = np.asarray(a, dtype=dtype)
    buf = np.empty(a.nbytes + 64, dtype=np.uint8)
    off = (-buf.ctypes.data) % 64
    out = buf[off:off + a.nbytes].view(dtype).reshape(a.shape)
    out[...] = a
    return out


@recording_kernels()
def trace_chain(
    scene,
    origins: np.ndarray,
    directions: np.ndarray,
    *,
    max_delta: int,
    amp_spp: int,
    integrator,
    seed: int,
) -> ChainResult:
    """Trace world rays through the delta chain and estimate the radiance at the image point.

    origins, directions: float64 [R, 3] world-space. ``integrator`` is a Mitsuba sampling integrator used
    for the incoherent radiance leaving P.

    The first hit is handled for every ray at once; only the rays whose first lobe is a delta lobe (usually
    a few percent) are compacted and carried through the chain with their float64 differentials.
    """
    mi = mitsuba()
    import drjit as dr

    R = int(origins.shape[0])
    if R == 0:
        z = np.zeros(0)
        z3 = np.zeros((0, 3), np.float32)
        return ChainResult(z.astype(bool), z, z3, z.astype(np.int32), z, z.astype(bool), z.astype(bool))
    o = np.ascontiguousarray(origins, dtype=np.float64)
    v = np.ascontiguousarray(directions, dtype=np.float64)
    ray0 = mi.Ray3f(mi.Point3f(*[mi.Float(aligned(o[:, i])) for i in range(3)]),
                    mi.Vector3f(*[mi.Float(aligned(v[:, i])) for i in range(3)]))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, R)
    ctx = mi.BSDFContext()
    flags = mi.RayFlags.All | mi.RayFlags.dNSdUV
    near_smooth = near_smooth_table(scene)  # near-smooth surfaces carry the chain too (holocore.trace.near_smooth)
    st, cont = _first_hits(mi, dr, scene, ray0, sampler, ctx, flags, R, near_smooth)
    lanes = dr.compress(cont)
    if dr.width(lanes) > 0 and max_delta > 0:
        _delta_chains(mi, dr, scene, ctx, flags, o, v, np.asarray(lanes, dtype=np.int64), st, max_delta, seed,
                      near_smooth)
    else:
        st["capped"] = mi.Bool(cont)
    dr.eval(*st.values())
    L, ok, n_need = _radiance_at_p(mi, dr, scene, sampler, integrator, st, amp_spp, R)

    def _np1(x, dtype):
        return np.broadcast_to(np.asarray(x, dtype=dtype).reshape(-1), (R,)).copy()

    rad = np.stack([_np1(L[i], np.float32) for i in range(3)], axis=1)
    d_np = _np1(st["d_out"], np.float64)
    ok_np = _np1(ok, bool) & np.isfinite(d_np) & np.all(np.isfinite(rad), axis=1)
    rad = np.where(ok_np[:, None], np.maximum(rad, 0.0), 0.0).astype(np.float32)
    return ChainResult(
        valid=ok_np,
        d=np.where(ok_np, d_np, 0.0),
        radiance=rad,
        n_delta=_np1(st["n_delta"], np.int32),
        opl_m=_np1(st["opl"], np.float64),
        escaped=_np1(st["escaped"], bool),
        capped=_np1(st["capped"], bool),
        path_samples=n_need * max(1, amp_spp),
    )


def _first_hits(mi, dr, scene, ray0, sampler, ctx, flags, R: int, near_smooth) -> tuple[dict, object]:
    """Every ray's first hit, where most paths end (P = first hit, d = t): the chain's state of every ray (each
    array of the full width R, which scatters need: a literal of width 1 would be written out of bounds) and
    which rays go on through a delta lobe."""
    F64 = mi.Float64
    si = scene.ray_intersect(ray0, flags, False, True)
    hit = si.is_valid()
    bsdf = si.bsdf(ray0)
    bs, w = bsdf.sample(ctx, si, sampler.next_1d(hit), sampler.next_2d(hit), hit)
    is_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
    if near_smooth is not None:
        is_delta |= mi.has_flag(bs.sampled_type, mi.BSDFFlags.Glossy) & is_near_smooth(near_smooth, bsdf, hit)
    is_delta &= bs.pdf > 0
    stop = hit & (~is_delta | si.shape.is_emitter())
    cont = hit & ~stop
    st = {"d_out": dr.select(stop, F64(si.t), dr.zeros(F64, R)), "fin_o": mi.Point3f(ray0.o),
          "fin_d": mi.Vector3f(ray0.d), "thr": dr.full(mi.Color3f, 1.0, R), "n_delta": dr.zeros(mi.UInt32, R),
          "opl": dr.select(hit, F64(si.t), dr.zeros(F64, R)), "escaped": mi.Bool(~hit), "done": mi.Bool(stop),
          "capped": dr.full(mi.Bool, False, R), "bad": dr.full(mi.Bool, False, R)}
    dr.eval(cont, *st.values())
    return st, cont


def _delta_chains(mi, dr, scene, ctx, flags, o: np.ndarray, v: np.ndarray, idx: np.ndarray, st: dict,
                  max_delta: int, seed: int, near_smooth) -> None:
    """Carry the rays ``idx`` that go on through delta vertices with their float64 differentials (0, 1: lateral
    shifts of O along e1, e2; 2, 3: angular perturbations of v along them) and scatter what they end with into
    ``st``."""
    oo, vv = o[idx], v[idx]
    helper = np.where(np.abs(vv[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(vv, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(vv, e1)
    sub = _DeltaChain(mi, scene, ctx, flags, oo, vv, e1, e2, seed, near_smooth)
    sub.run(max_delta)
    lanes = mi.UInt32(aligned(idx, np.uint32))
    for name in ("d_out", "fin_o", "fin_d", "thr", "n_delta", "opl", "escaped", "done", "capped", "bad"):
        dr.scatter(st[name], getattr(sub, name), lanes)


def _radiance_at_p(mi, dr, scene, sampler, integrator, st: dict, amp_spp: int, R: int):
    """(the radiance leaving P towards the previous vertex times the chain's throughput, which paths are
    valid, how many needed the integrator)."""
    ok = st["done"] & ~st["bad"] & ~st["capped"] & (st["d_out"] > 0)
    need = mi.Bool(ok)
    L_int = mi.Color3f(0.0)
    rd = mi.RayDifferential3f(mi.Ray3f(st["fin_o"], st["fin_d"]))
    for _ in range(max(1, amp_spp)):
        spec, valid, _aov = integrator.sample(scene, sampler, rd, None, need)
        L_int += dr.select(valid & need, spec, 0.0)
        dr.eval(L_int)
    L = dr.select(need, L_int / max(1, amp_spp), 0.0) * st["thr"]
    n_need = int(dr.count(need)[0]) if dr.width(need) > 1 else (R if bool(need[0]) else 0)
    dr.eval(L, st["d_out"], ok)
    return L, ok, n_need


class _DeltaChain:
    """The rays whose first lobe was a delta lobe, compacted, followed coherently bounce by bounce.

    Restarts them at the first vertex (re-intersected; the lobe is sampled anew with its own random numbers)
    and carries four analytic differentials in float64 (see the module docstring). After every bounce the
    lanes that ended (image point found, escaped, singular, capped) write their outputs and leave: the next
    bounce traces only the lanes still in the chain (most paths leave after one or two delta vertices).
    """

    def __init__(self, mi, scene, ctx, flags, oo, vv, e1, e2, seed, near_smooth=None):
        """oo, vv: float64 [n, 3] origins and unit directions of the lanes; e1, e2: unit vectors with (vv, e1, e2)
        orthonormal; near_smooth: the scene's near-smooth BSDF table (holocore.trace.near_smooth), or None."""
        import drjit as dr

        F64, V3d = mi.Float64, mi.Vector3d
        self.mi, self.scene, self.ctx, self.flags = mi, scene, ctx, flags
        self.near_smooth = near_smooth
        n = oo.shape[0]
        # Working state of the lanes still in the chain (compacted after every bounce); lane: their output slot.
        self.lane = dr.arange(mi.UInt32, n)
        self.ray = mi.Ray3f(mi.Point3f(*[mi.Float(aligned(oo[:, i])) for i in range(3)]),
                            mi.Vector3f(*[mi.Float(aligned(vv[:, i])) for i in range(3)]))
        self.D = V3d(*[F64(aligned(vv[:, i], np.float64)) for i in range(3)])
        E = [V3d(*[F64(aligned(e[:, i], np.float64)) for i in range(3)]) for e in (e1, e2)]
        self.dP = [E[0], E[1], dr.zeros(V3d, n), dr.zeros(V3d, n)]
        self.dD = [dr.zeros(V3d, n), dr.zeros(V3d, n), E[0], E[1]]
        self.frame = [E[0], E[1]]
        self.n_cur = dr.full(F64, 1.0, n)
        self.opl_w = dr.zeros(F64, n)
        self.thr_w = dr.full(mi.Color3f, 1.0, n)
        self.nd_w = dr.zeros(mi.UInt32, n)
        # Random numbers for lobe choices come from numpy (kernel inputs, so Dr.Jit's kernel cache still hits).
        self.rng = np.random.default_rng([seed, 0x5EED, n])
        # Outputs, one slot per lane.
        self.done = dr.full(mi.Bool, False, n)
        self.escaped = dr.full(mi.Bool, False, n)
        self.bad = dr.full(mi.Bool, False, n)
        self.capped = dr.full(mi.Bool, False, n)
        self.n_delta = dr.zeros(mi.UInt32, n)
        self.opl = dr.zeros(F64, n)
        self.thr = dr.full(mi.Color3f, 1.0, n)
        self.d_out = dr.zeros(F64, n)
        self.fin_o = mi.Point3f(self.ray.o)
        self.fin_d = mi.Vector3f(self.ray.d)

    def _put(self, name: str, value, mask) -> None:
        """Write ``value`` into output ``name`` at the slots of the lanes in ``mask``."""
        import drjit as dr

        dr.scatter(getattr(self, name), value, self.lane, mask)

    def _leave(self, mask) -> None:
        """Lanes in ``mask`` end here: record the path so far (throughput, bounces, optical path)."""
        self._put("thr", self.thr_w, mask)
        self._put("n_delta", self.nd_w, mask)
        self._put("opl", self.opl_w, mask)

    def _compact(self, keep) -> bool:
        """Keep only the lanes in ``keep``; False when none is left."""
        import drjit as dr

        ids = dr.compress(keep)
        if dr.width(ids) == 0:
            return False
        mi = self.mi

        def take(x):
            return dr.gather(type(x), x, ids)

        self.lane, self.D, self.n_cur = take(self.lane), take(self.D), take(self.n_cur)
        self.opl_w, self.thr_w, self.nd_w = take(self.opl_w), take(self.thr_w), take(self.nd_w)
        self.dP, self.dD = [take(x) for x in self.dP], [take(x) for x in self.dD]
        self.frame = [take(x) for x in self.frame]
        self.ray = mi.Ray3f(take(self.ray.o), take(self.ray.d))
        return True

    def run(self, max_delta: int) -> None:
        import drjit as dr

        mi = self.mi
        for bounce in range(max_delta + 1):
            si = self.scene.ray_intersect(self.ray, self.flags, False, True)
            active = si.is_valid()
            self._put("escaped", True, ~active)
            bsdf = si.bsdf(self.ray)
            u = self.rng.random((3, dr.width(active)), dtype=np.float32)
            bs, w = bsdf.sample(self.ctx, si, mi.Float(aligned(u[0])), mi.Point2f(mi.Float(aligned(u[1])),
                                                                             mi.Float(aligned(u[2]))), active)
            micro = None
            is_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            if self.near_smooth is not None:  # near-smooth surfaces carry the chain too (holocore.trace.near_smooth)
                micro = (active & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Glossy)
                         & is_near_smooth(self.near_smooth, bsdf, active))
                is_delta |= micro
            is_delta &= bs.pdf > 0
            stop = active & (~is_delta | si.shape.is_emitter())
            cont = active & ~stop
            if bounce == max_delta:
                cont_here = mi.Bool(False)
            else:
                cont_here = cont
            # The image point (where the chain stops) and the transfer through the vertex (where it goes on):
            # the same code as the fused kernel's.
            d_here, singular, D, dP, dD, frame, n_cur, _nd = igehy_transfer(
                si, bs, cont_here, self.D, self.dP, self.dD, self.frame, self.n_cur, self.nd_w, micro=micro)
            self.opl_w = dr.select(active, self.opl_w + self.n_cur * mi.Float64(si.t), self.opl_w)
            self._put("d_out", d_here, stop)
            self._put("fin_o", self.ray.o, stop)
            self._put("fin_d", self.ray.d, stop)
            self._put("done", True, stop)
            if bounce == max_delta:
                self._put("capped", True, cont)
                self._leave(mi.Bool(True))
                break
            self._put("bad", True, singular)
            keep = cont & ~singular
            self.D, self.dP, self.dD, self.frame, self.n_cur = D, dP, dD, frame, n_cur
            self.thr_w = dr.select(keep, self.thr_w * w, self.thr_w)
            self.nd_w = dr.select(keep, self.nd_w + 1, self.nd_w)
            self.ray = dr.select(keep, si.spawn_ray(si.to_world(bs.wo)), self.ray)
            self._leave(~keep)
            dr.eval(self.dP, self.dD, self.frame, self.D, self.ray, self.n_cur, self.opl_w, self.thr_w, self.nd_w,
                    self.done, self.escaped, self.bad, self.capped, self.n_delta, self.opl, self.thr, self.d_out,
                    self.fin_o, self.fin_d)
            if not self._compact(keep):
                break
        dr.eval(self.done, self.escaped, self.bad, self.capped, self.n_delta, self.opl, self.thr, self.d_out,
                self.fin_o, self.fin_d)
