"""The per-ray work of wave path tracing, vectorised in Dr.Jit (paper Sec. 4.2, DESIGN.md §4).

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
  it is the mirror equation's image distance. (DESIGN.md §4 names B alone; B alone is right only where
  A = I, i.e. without curved surfaces: see docs/physics.md.)
* ``radiance``: the RGB radiance reaching O along the ray: delta-chain throughput times the radiance leaving P
  towards the previous vertex, from incoherent path tracing (Mitsuba's own integrator, ``amp_spp`` samples)
  or from an ambient cache.
* ``n_delta``, ``opl_m`` (world optical path, for diagnostics) and status flags.

Python loops run over bounces only (a handful); every ray of the batch moves together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holocore.mitsuba_env import mitsuba

__all__ = ["ChainResult", "trace_chain"]

_EPS_COS = 1e-7  # |cos| below this at a delta vertex: the differential transfer is singular, drop the ray


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
    p_world: np.ndarray  # float32 [R, 3] the real image point P (world)
    radiance_p: np.ndarray  # float32 [R, 3] radiance leaving P (before the delta-chain throughput)
    emission_p: np.ndarray  # float32 [R, 3] emitted radiance at P
    albedo_p: np.ndarray  # float32 [R, 3] diffuse reflectance at P
    normal_p: np.ndarray  # float32 [R, 3] shading normal at P
    path_samples: int = 0  # incoherent path-tracing samples spent on the radiance


def _dot(a, b):
    import drjit as dr

    return dr.dot(a, b)


def trace_chain(
    scene,
    origins: np.ndarray,
    directions: np.ndarray,
    *,
    max_delta: int,
    amp_spp: int,
    integrator,
    seed: int,
    radiance_cache=None,
) -> ChainResult:
    """Trace world rays through the delta chain and estimate the radiance at the image point.

    origins, directions: float64 [R, 3] world-space. ``integrator`` is a Mitsuba sampling integrator used
    for the incoherent radiance leaving P (ignored where ``radiance_cache`` answers).
    """
    mi = mitsuba()
    import drjit as dr

    R = int(origins.shape[0])
    if R == 0:
        z = np.zeros(0)
        z3 = np.zeros((0, 3), np.float32)
        return ChainResult(z.astype(bool), z, z3, z.astype(np.int32), z, z.astype(bool), z.astype(bool), z3, z3, z3,
                           z3, z3)
    F64, V3d = mi.Float64, mi.Vector3d

    o = np.ascontiguousarray(origins, dtype=np.float64)
    v = np.ascontiguousarray(directions, dtype=np.float64)
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(o[:, i].astype(np.float32)) for i in range(3)]),
                   mi.Vector3f(*[mi.Float(v[:, i].astype(np.float32)) for i in range(3)]))
    # Two unit vectors perpendicular to v: the angular perturbations of the differentials.
    helper = np.where(np.abs(v[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(v, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(v, e1)
    D = V3d(*[F64(v[:, i]) for i in range(3)])
    # Differentials 0, 1: lateral shifts of O along e1, e2; 2, 3: angular perturbations of v along e1, e2.
    E = [V3d(*[F64(e[:, i]) for i in range(3)]) for e in (e1, e2)]
    dP = [E[0], E[1], V3d(0.0), V3d(0.0)]
    dD = [V3d(0.0), V3d(0.0), E[0], E[1]]
    ND = 4
    frame = [V3d(*[F64(e[:, i]) for i in range(3)]) for e in (e1, e2)]

    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, R)
    ctx = mi.BSDFContext()

    active = mi.Bool(True)
    done = mi.Bool(False)  # reached P
    escaped = mi.Bool(False)
    bad = mi.Bool(False)  # singular transfer / non-finite
    n_delta = mi.UInt32(0)
    n_cur = F64(1.0)
    opl = F64(0.0)
    thr = mi.Color3f(1.0)
    d_out = F64(0.0)
    p_world = mi.Point3f(0.0)
    final_ray = mi.Ray3f(ray)

    for bounce in range(max_delta + 1):
        si = scene.ray_intersect(ray, mi.RayFlags.All | mi.RayFlags.dNSdUV, False, active)
        miss = active & ~si.is_valid()
        escaped |= miss
        active &= si.is_valid()
        t = F64(si.t)
        N = V3d(si.sh_frame.n)
        cosD = _dot(D, N)
        dPt = [dP[i] + t * dD[i] for i in range(ND)]

        bsdf = si.bsdf(ray)
        bs, w = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active), active)
        is_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta) & (bs.pdf > 0)
        # Emitters end the chain too: they are seen, not traversed.
        stop = active & (~is_delta | si.shape.is_emitter())
        # The image point: lateral displacement perpendicular to the last segment, along the carried frame.
        lat = [dPt[i] - _dot(dPt[i], D) * D for i in range(ND)]
        a11, a12 = _dot(lat[0], frame[0]), _dot(lat[1], frame[0])
        a21, a22 = _dot(lat[0], frame[1]), _dot(lat[1], frame[1])
        b11, b12 = _dot(lat[2], frame[0]), _dot(lat[3], frame[0])
        b21, b22 = _dot(lat[2], frame[1]), _dot(lat[3], frame[1])
        det_b = b11 * b22 - b12 * b21
        # tr(B^-1 A) with B^-1 = adj(B) / det(B)
        tr = (b22 * a11 - b12 * a21 - b21 * a12 + b11 * a22)
        d_here = 2.0 * det_b / dr.select(dr.abs(tr) > 0, tr, 1e-300)
        d_out = dr.select(stop, d_here, d_out)
        opl = dr.select(active, opl + n_cur * t, opl)
        p_world = dr.select(stop, si.p, p_world)
        final_ray = dr.select(stop, ray, final_ray)
        done |= stop
        cont = active & ~stop
        if bounce == max_delta:
            active = cont  # still in the chain after the cap: dropped below
            break

        # ---- transfer the differentials through the delta vertex (float64) -------------------------
        bad |= cont & (dr.abs(cosD) < _EPS_COS)
        dtt = [-_dot(dPt[i], N) / dr.select(dr.abs(cosD) < _EPS_COS, 1.0, cosD) for i in range(ND)]
        dPh = [dPt[i] + dtt[i] * D for i in range(ND)]
        dpdu, dpdv = V3d(si.dp_du), V3d(si.dp_dv)
        dndu, dndv = V3d(si.dn_du), V3d(si.dn_dv)
        a, b, c = _dot(dpdu, dpdu), _dot(dpdu, dpdv), _dot(dpdv, dpdv)
        det = a * c - b * b
        det_ok = det > 1e-30
        inv_det = dr.select(det_ok, 1.0 / dr.select(det_ok, det, 1.0), 0.0)
        dN = []
        for i in range(ND):
            r1, r2 = _dot(dPh[i], dpdu), _dot(dPh[i], dpdv)
            du = (c * r1 - b * r2) * inv_det
            dv = (a * r2 - b * r1) * inv_det
            dN.append(dndu * du + dndv * dv)

        wo = si.to_world(bs.wo)
        D_new = V3d(wo)
        D_new = D_new / dr.norm(D_new)
        is_refl = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Reflection)
        # Reflection: D' = D - 2(D.N)N
        dD_refl, fr_refl = [], []
        for i in range(ND):
            dDN = _dot(dD[i], N) + _dot(D, dN[i])
            dD_refl.append(dD[i] - 2.0 * (cosD * dN[i] + dDN * N))
        for i in range(2):
            fr_refl.append(frame[i] - 2.0 * _dot(frame[i], N) * N)
        # Refraction (Igehy): with N facing the incoming ray, D' = eta D + mu N, mu = eta c1 - c2.
        sgn = dr.select(cosD < 0, 1.0, -1.0)
        Nf = N * sgn
        eta = 1.0 / F64(dr.select(bs.eta > 0, bs.eta, 1.0))  # n1 / n2
        c1 = -_dot(D, Nf)
        c2 = dr.maximum(-_dot(D_new, Nf), 1e-9)
        mu = eta * c1 - c2
        axis = dr.cross(D, D_new)
        s_ax = dr.norm(axis)
        rot_ok = s_ax > 1e-12
        axis = axis / dr.select(rot_ok, s_ax, 1.0)
        u_old, u_new = dr.cross(axis, D), dr.cross(axis, D_new)
        dD_refr, fr_refr = [], []
        for i in range(ND):
            dNf = dN[i] * sgn
            dc1 = -(_dot(dD[i], Nf) + _dot(D, dNf))
            dc2 = eta * eta * c1 * dc1 / c2
            dmu = eta * dc1 - dc2
            dD_refr.append(eta * dD[i] + dmu * Nf + mu * dNf)
        for i in range(2):
            rotated = _dot(frame[i], axis) * axis + _dot(frame[i], u_old) * u_new
            fr_refr.append(dr.select(rot_ok, rotated, frame[i]))

        for i in range(ND):
            dP[i] = dr.select(cont, dPh[i], dP[i])
            dD[i] = dr.select(cont, dr.select(is_refl, dD_refl[i], dD_refr[i]), dD[i])
        for i in range(2):
            frame[i] = dr.select(cont, dr.select(is_refl, fr_refl[i], fr_refr[i]), frame[i])
        n_cur = dr.select(cont & ~is_refl, n_cur * F64(bs.eta), n_cur)
        thr = dr.select(cont, thr * w, thr)
        n_delta = dr.select(cont, n_delta + 1, n_delta)
        D = dr.select(cont, D_new, D)
        ray = dr.select(cont, si.spawn_ray(wo), ray)
        active = cont
        dr.eval(dP, dD, frame, D, ray, active, done, escaped, bad, n_delta, n_cur, opl, thr, d_out, p_world,
                final_ray)

    capped = active  # still following delta lobes when the cap was reached

    # ---- radiance leaving P towards the previous vertex --------------------------------------------
    ok = done & ~bad & ~capped & (d_out > 0)
    si_p = scene.ray_intersect(final_ray, mi.RayFlags.All, False, ok)
    ok &= si_p.is_valid()
    emission = si_p.emitter(scene).eval(si_p, ok)
    albedo = si_p.bsdf().eval_diffuse_reflectance(si_p, ok)
    L_p = mi.Color3f(0.0)
    need = mi.Bool(ok)
    if radiance_cache is not None:
        L_c, has = radiance_cache.lookup(si_p, albedo, emission, ok)
        L_p = dr.select(has, L_c, L_p)
        need = ok & ~has
    L_int = mi.Color3f(0.0)
    rd = mi.RayDifferential3f(final_ray)
    for _ in range(max(1, amp_spp)):
        spec, valid, _aov = integrator.sample(scene, sampler, rd, None, need)
        L_int += dr.select(valid & need, spec, 0.0)
        dr.eval(L_int)
    L_p = dr.select(need, L_int / max(1, amp_spp), L_p)
    L = L_p * thr
    n_p = si_p.sh_frame.n
    n_need = int(dr.count(need)[0]) if dr.width(need) > 1 else (R if bool(need[0]) else 0)
    dr.eval(L, L_p, d_out, ok, emission, albedo, n_p)

    def _np1(x, dtype):
        return np.broadcast_to(np.asarray(x, dtype=dtype).reshape(-1), (R,)).copy()

    def _np3(x, dtype=np.float32):
        return np.stack([_np1(x[i], dtype) for i in range(3)], axis=1)

    rad = _np3(L)
    d_np = _np1(d_out, np.float64)
    ok_np = _np1(ok, bool) & np.isfinite(d_np) & np.all(np.isfinite(rad), axis=1)
    rad = np.where(ok_np[:, None], np.maximum(rad, 0.0), 0.0).astype(np.float32)
    return ChainResult(
        valid=ok_np,
        d=np.where(ok_np, d_np, 0.0),
        radiance=rad,
        n_delta=_np1(n_delta, np.int32),
        opl_m=_np1(opl, np.float64),
        escaped=_np1(escaped, bool),
        capped=_np1(capped, bool),
        p_world=_np3(p_world),
        radiance_p=np.where(ok_np[:, None], _np3(L_p), 0.0).astype(np.float32),
        emission_p=np.where(ok_np[:, None], _np3(emission), 0.0).astype(np.float32),
        albedo_p=np.where(ok_np[:, None], _np3(albedo), 0.0).astype(np.float32),
        normal_p=_np3(n_p),
        path_samples=n_need * max(1, amp_spp),
    )
