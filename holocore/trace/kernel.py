"""Wave paths in one Dr.Jit loop: the delta chain and the incoherent radiance of its image point traced as
one path (paper Sec. 4.2, DESIGN.md §4).

A wave path starts like any path of a path tracer. While its vertices are delta vertices (mirrors, smooth
dielectrics) it is *coherent*: it carries the four float64 ray differentials of :mod:`holocore.trace.reference_chain`
(two lateral shifts of O, two angular perturbations of v) and its optical path. The first non-delta vertex
(or an emitter) is the real image point P; there the differentials give the apparent distance d, and from
then on the same path goes on as an ordinary incoherent path (emitter sampling with MIS, Russian roulette
from ``rr_depth``), whose radiance is the radiance leaving P times the chain's throughput. The path depth is
counted from P, so the radiance equals what Mitsuba's ``path`` integrator returns for a ray arriving at P.

Fusing the two (instead of a first hit, a chain, then ``integrator.sample`` from the last chain vertex) traces
P once, not twice, and keeps every ray in one kernel. :func:`holocore.trace.reference_chain.trace_chain` remains the
reference implementation (and the cache pre-pass's); tests compare the two.

A BSDF that mixes delta and smooth lobes (plastic) decides chain or image point with one sample; at an image
point it draws a fresh sample for the incoherent path, so that P's radiance includes all its lobes, as the
reference implementation's ``integrator.sample`` from the previous vertex does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from holocore.plan.effects import has_mixed_delta
from holocore.runtime.mitsuba_env import mitsuba

__all__ = ["WavePaths", "trace_wave_paths"]

_EPS_COS = 1e-7  # |cos| below this at a delta vertex: the differential transfer is singular, drop the ray


@dataclass
class WavePaths:
    """Per-ray outcome (Dr.Jit arrays of one width, not yet evaluated: the caller's own per-ray work joins
    the same kernel)."""

    valid: object  # Bool: a finite image point at a positive apparent distance, finite radiance
    d: object  # Float64 apparent distance of P along the first ray direction (m, world)
    radiance: object  # Color3f radiance reaching the origin along the ray (>= 0, 0 where invalid)
    n_delta: object  # UInt32 delta bounces before P
    escaped: object  # Bool: left the scene before any image point
    capped: object  # Bool: still on delta lobes after max_delta bounces
    sampled: object  # Bool: P's radiance came from path tracing (``amp_spp`` samples), not from the cache
    surface: Optional[dict] = None  # with ``surface=True``: p, normal (shading), emission, albedo at P and the
    # chain's throughput ``thr`` (radiance leaving P = radiance / thr)


def _mis(a, b):
    import drjit as dr

    a2 = a * a
    return dr.select(a > 0, a2 / (a2 + b * b), 0.0)  # power heuristic; a > 0 keeps 0/0 out


def trace_wave_paths(
    scene,
    o64,
    v64,
    sampler,
    *,
    max_delta: int,
    max_depth: int,
    rr_depth: int = 5,
    amp_spp: int = 1,
    integrator=None,
    radiance_cache=None,
    surface: bool = False,
) -> WavePaths:
    """Trace world rays (``o64``, ``v64``: mi.Point3d / unit mi.Vector3d of one width) as wave paths.

    ``max_depth``: path depth counted from P (Mitsuba's convention: 1 = emission at P only). ``amp_spp`` > 1
    adds ``amp_spp - 1`` samples of ``integrator`` from the ray that reached P. ``radiance_cache``: the fast
    variant's ambient cache; where it holds the cell of P, P's radiance is one lookup and the path ends.
    ``surface``: also record what the cache's pre-pass needs of P (see :class:`WavePaths`).
    """
    mi = mitsuba()
    import drjit as dr

    if max_depth < 1:
        raise ValueError(f"max_depth must be >= 1, got {max_depth}")
    F64, V3d = mi.Float64, mi.Vector3d
    R = dr.width(o64)
    ctx = mi.BSDFContext()
    Delta, Smooth = mi.BSDFFlags.Delta, mi.BSDFFlags.Smooth

    any_mixed = has_mixed_delta(scene)
    # Kernel parameters, not constants: one compiled kernel for every depth setting.
    op_delta, op_depth, op_rr = (dr.opaque(mi.UInt32, v) for v in (max_delta, max_depth, rr_depth))
    helper = dr.select(dr.abs(v64.z) < 0.9, V3d(0, 0, 1), V3d(1, 0, 0))
    e1 = dr.normalize(dr.cross(v64, helper))
    e2 = dr.cross(v64, e1)
    zero3 = dr.zeros(V3d, R)
    st = {
        "ray": mi.Ray3f(mi.Point3f(o64), mi.Vector3f(v64)),
        "active": dr.full(mi.Bool, True, R),
        "beta": dr.full(mi.Color3f, 1.0, R),
        "L": dr.zeros(mi.Color3f, R),
        "eta": dr.full(mi.Float, 1.0, R),
        "depth": dr.zeros(mi.UInt32, R),
        "si_prev": dr.zeros(mi.Interaction3f, R),  # what MIS needs of the previous vertex
        "pdf_prev": dr.full(mi.Float, 1.0, R),
        "delta_prev": dr.full(mi.Bool, True, R),
        # the coherent part
        "chain": dr.full(mi.Bool, True, R),
        "D": V3d(v64),
        "dP": [V3d(e1), V3d(e2), V3d(zero3), V3d(zero3)],
        "dD": [V3d(zero3), V3d(zero3), V3d(e1), V3d(e2)],
        "frame": [V3d(e1), V3d(e2)],
        "n_cur": dr.full(F64, 1.0, R),
        "nd": dr.zeros(mi.UInt32, R),
        # outputs
        "d": dr.zeros(F64, R),
        "done": dr.full(mi.Bool, False, R),
        "bad": dr.full(mi.Bool, False, R),
        "capped": dr.full(mi.Bool, False, R),
        "escaped": dr.full(mi.Bool, False, R),
        "cached": dr.full(mi.Bool, False, R),
    }
    extra = amp_spp > 1 and integrator is not None
    if extra or surface:  # the chain's throughput at P
        st["thr"] = dr.full(mi.Color3f, 1.0, R)
    if extra:  # more radiance samples from P start from the ray that reached P
        st["fin"] = mi.Ray3f(mi.Point3f(o64), mi.Vector3f(v64))
    if surface:
        st["surf"] = {"p": dr.zeros(mi.Point3f, R), "normal": dr.zeros(mi.Vector3f, R),
                      "emission": dr.zeros(mi.Color3f, R), "albedo": dr.zeros(mi.Color3f, R)}

    def cond(st, sampler):
        return st["active"]

    def body(st, sampler):
        st = dict(st)
        active, ray, chain0 = st["active"], st["ray"], st["chain"]
        pi = scene.ray_intersect_preliminary(ray, False, active)
        si = pi.compute_surface_interaction(ray, mi.RayFlags.All, active)
        hit = active & si.is_valid()
        bsdf = si.bsdf(ray)

        # Emission reached by the previous sample (MIS against emitter sampling there).
        ds = mi.DirectionSample3f(scene, si=si, ref=st["si_prev"])
        em_pdf = scene.pdf_emitter_direction(st["si_prev"], ds, active & ~st["delta_prev"])
        Le = st["beta"] * _mis(st["pdf_prev"], em_pdf) * ds.emitter.eval(si, active)

        bflags = bsdf.flags()
        in_chain = hit & chain0
        is_em = si.shape.is_emitter()
        st["escaped"] = st["escaped"] | (active & chain0 & ~si.is_valid())
        # The fast variant: a chain vertex without delta lobes (or an emitter) is P for sure; where the cache
        # holds P's cell, P's radiance is one lookup and the path ends there. The cache holds view-independent
        # radiance per unit diffuse albedo, so a glossy P (a highlight that moves with the view) is path traced.
        has = mi.Bool(False)
        if radiance_cache is not None:
            sure_p = in_chain & (~mi.has_flag(bflags, Delta) | is_em) & ~mi.has_flag(bflags, mi.BSDFFlags.Glossy)
            emission = si.emitter(scene).eval(si, sure_p)
            albedo = bsdf.eval_diffuse_reflectance(si, sure_p)
            L_c, has = radiance_cache.lookup(si, albedo, emission, sure_p)
            Le = dr.select(has, st["beta"] * L_c, Le)
            st["cached"] = st["cached"] | has

        # Emitter sampling and one BSDF sample in one call (as Mitsuba's path does). The lobe sample also
        # decides whether the coherent chain goes on; a lane that goes on discards its emitter sample.
        em_on = hit & ~has & (st["depth"] + 1 < op_depth) & mi.has_flag(bflags, Smooth)
        ds_e, em_w = scene.sample_emitter_direction(si, sampler.next_2d(em_on), True, em_on)
        em_on &= ds_e.pdf != 0.0
        smp = hit & ~has
        val, pdf, bs, w = bsdf.eval_pdf_sample(ctx, si, si.to_local(ds_e.d), sampler.next_1d(smp),
                                               sampler.next_2d(smp), smp)
        s_delta = mi.has_flag(bs.sampled_type, Delta) & (bs.pdf > 0)
        go_on = in_chain & s_delta & ~is_em
        at_p = in_chain & ~go_on
        mis_em = dr.select(ds_e.delta, 1.0, _mis(ds_e.pdf, pdf))
        Lr = dr.select(em_on & ~go_on, st["beta"] * mis_em * val * em_w, 0.0)

        # ---- the coherent part (float64), only in the lanes that need it (a real branch per packet) ----
        capped = go_on & (st["nd"] >= op_delta)
        st["capped"] = st["capped"] | capped
        go_on = go_on & ~capped
        deep = at_p & (st["nd"] > 0)  # an image point behind delta vertices: d from the differentials

        def coherent(D, dP, dD, frame, n_cur, nd):
            # The shading normal's derivatives (curved mirrors and lenses), only where a chain goes on.
            si_d = pi.compute_surface_interaction(ray, mi.RayFlags.All | mi.RayFlags.dNSdUV, go_on | deep)
            return _coherent(mi, si_d, bs, go_on, D, dP, dD, frame, n_cur, nd)

        def plain(D, dP, dD, frame, n_cur, nd):
            return F64(0.0), mi.Bool(False), D, dP, dD, frame, n_cur, nd

        d_deep, singular, *chain_st = dr.if_stmt(
            (st["D"], st["dP"], st["dD"], st["frame"], st["n_cur"], st["nd"]), go_on | deep, coherent, plain,
            label="delta vertex")
        st["D"], st["dP"], st["dD"], st["frame"], st["n_cur"], st["nd"] = chain_st
        # With no delta vertex before P, A = I and B = t I: d is the hit distance itself.
        st["d"] = dr.select(at_p, dr.select(deep, d_deep, F64(si.t)), st["d"])
        st["done"] = st["done"] | at_p
        if extra or surface:
            st["thr"] = dr.select(at_p, st["beta"], st["thr"])
        if extra:
            st["fin"] = dr.select(at_p, ray, st["fin"])
        if surface:
            here = {"p": si.p, "normal": si.sh_frame.n, "emission": si.emitter(scene).eval(si, at_p),
                    "albedo": bsdf.eval_diffuse_reflectance(si, at_p)}
            st["surf"] = {k: dr.select(at_p, here[k], st["surf"][k]) for k in here}
        st["bad"] = st["bad"] | singular
        go_on = go_on & ~singular
        st["chain"] = go_on

        # ---- the incoherent part, from P on ------------------------------------------------------
        # Nothing counts before P: delta vertices neither emit (the chain stops at emitters) nor sample lights.
        counts = (active & ~chain0) | at_p  # past P (escaping to an environment included) or at P
        past = ((hit & ~chain0) | at_p) & ~has
        more = past & (st["depth"] + 1 < op_depth)
        # A BSDF with delta and smooth lobes: P's radiance includes all of them, so sample afresh at P.
        if any_mixed:
            mixed = at_p & more & mi.has_flag(bflags, Delta) & mi.has_flag(bflags, Smooth)
            bs2, w2 = bsdf.sample(ctx, si, sampler.next_1d(mixed), sampler.next_2d(mixed), mixed)
            bs = dr.select(mixed, bs2, bs)
            w = dr.select(mixed, w2, w)
        st["L"] = st["L"] + dr.select(counts, Le, 0.0) + Lr

        step = go_on | more
        st["ray"] = dr.select(step, si.spawn_ray(si.to_world(bs.wo)), ray)
        st["beta"] = dr.select(step, st["beta"] * w, st["beta"])
        st["eta"] = dr.select(step, st["eta"] * bs.eta, st["eta"])
        st["si_prev"] = dr.select(step, mi.Interaction3f(si), st["si_prev"])
        st["pdf_prev"] = dr.select(step, bs.pdf, st["pdf_prev"])
        st["delta_prev"] = dr.select(step, mi.has_flag(bs.sampled_type, Delta), st["delta_prev"])
        b_max = dr.max(st["beta"])
        rr = more & (st["depth"] + 1 >= op_rr)  # Mitsuba's path: depth counted after this vertex
        rr_prob = dr.minimum(b_max * st["eta"] * st["eta"], 0.95)
        st["beta"] = dr.select(rr, st["beta"] / rr_prob, st["beta"])
        survive = ~rr | (sampler.next_1d(rr) < rr_prob)
        st["depth"] = dr.select(past, st["depth"] + 1, st["depth"])
        st["active"] = go_on | (more & survive & (b_max != 0))
        return st, sampler

    st, sampler = dr.while_loop((st, sampler), cond, body, label="wave paths")

    ok = st["done"] & ~st["bad"] & ~st["capped"] & (st["d"] > 0) & dr.isfinite(st["d"])
    L = st["L"]
    if extra:
        need = ok & ~st["cached"]
        rd = mi.RayDifferential3f(st["fin"])
        L_more = dr.zeros(mi.Color3f, R)
        for _ in range(amp_spp - 1):
            spec, valid, _aov = integrator.sample(scene, sampler, rd, None, need)
            L_more += dr.select(valid & need, spec, 0.0)
        L = dr.select(need, (L + st["thr"] * L_more) / amp_spp, L)
    finite = dr.isfinite(L[0]) & dr.isfinite(L[1]) & dr.isfinite(L[2])
    ok &= finite
    L = dr.select(ok, dr.maximum(L, 0.0), 0.0)
    d = dr.select(ok, st["d"], 0.0)
    surf = None
    if surface:
        surf = dict(st["surf"], thr=st["thr"])
    return WavePaths(valid=ok, d=d, radiance=L, n_delta=st["nd"], escaped=st["escaped"], capped=st["capped"],
                     sampled=ok & ~st["cached"], surface=surf)


def _coherent(mi, si, bs, go_on, D, dP, dD, frame, n_cur, nd):
    """At a chain vertex: the apparent distance d read from the differentials (used where the chain ends
    here), and, on ``go_on``, the differentials and the frame carried through the delta vertex (Igehy 1999),
    float64. Returns (d, singular, D, dP, dD, frame, n_cur, nd); ``singular``: the ray grazes the surface."""
    import drjit as dr

    F64, V3d = mi.Float64, mi.Vector3d
    t = F64(si.t)
    N = V3d(si.sh_frame.n)
    cosD = dr.dot(D, N)
    dPt = [dP[i] + t * dD[i] for i in range(4)]
    # The image point: 2x2 transfer blocks A (shifts) and B (angles) read along the carried frame.
    lat = [dPt[i] - dr.dot(dPt[i], D) * D for i in range(4)]
    a11, a12 = dr.dot(lat[0], frame[0]), dr.dot(lat[1], frame[0])
    a21, a22 = dr.dot(lat[0], frame[1]), dr.dot(lat[1], frame[1])
    b11, b12 = dr.dot(lat[2], frame[0]), dr.dot(lat[3], frame[0])
    b21, b22 = dr.dot(lat[2], frame[1]), dr.dot(lat[3], frame[1])
    det_b = b11 * b22 - b12 * b21
    tr = b22 * a11 - b12 * a21 - b21 * a12 + b11 * a22  # tr(adj(B) A) = det(B) tr(B^-1 A)
    d_here = 2.0 * det_b / dr.select(dr.abs(tr) > 0, tr, 1e-300)

    singular = go_on & (dr.abs(cosD) < _EPS_COS)
    go_on = go_on & ~singular
    safe_cos = dr.select(dr.abs(cosD) < _EPS_COS, 1.0, cosD)
    dPh = [dPt[i] - (dr.dot(dPt[i], N) / safe_cos) * D for i in range(4)]
    dpdu, dpdv = V3d(si.dp_du), V3d(si.dp_dv)
    dndu, dndv = V3d(si.dn_du), V3d(si.dn_dv)
    a, b, c = dr.dot(dpdu, dpdu), dr.dot(dpdu, dpdv), dr.dot(dpdv, dpdv)
    det = a * c - b * b
    det_ok = det > 1e-30
    inv_det = dr.select(det_ok, 1.0 / dr.select(det_ok, det, 1.0), 0.0)
    dN = []
    for i in range(4):
        r1, r2 = dr.dot(dPh[i], dpdu), dr.dot(dPh[i], dpdv)
        dN.append(dndu * ((c * r1 - b * r2) * inv_det) + dndv * ((a * r2 - b * r1) * inv_det))
    D_new = dr.normalize(V3d(si.to_world(bs.wo)))
    is_refl = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Reflection)
    # Reflection: D' = D - 2 (D.N) N.  Refraction (N facing the ray): D' = eta D + mu N, mu = eta c1 - c2.
    sgn = dr.select(cosD < 0, 1.0, -1.0)
    Nf = N * sgn
    eta = 1.0 / F64(dr.select(bs.eta > 0, bs.eta, 1.0))  # n1 / n2
    c1 = -dr.dot(D, Nf)
    c2 = dr.maximum(-dr.dot(D_new, Nf), 1e-9)
    mu = eta * c1 - c2
    axis = dr.cross(D, D_new)
    s_ax = dr.norm(axis)
    rot_ok = s_ax > 1e-12
    axis = axis / dr.select(rot_ok, s_ax, 1.0)
    u_old, u_new = dr.cross(axis, D), dr.cross(axis, D_new)
    dP, dD = list(dP), list(dD)
    for i in range(4):
        dDN = dr.dot(dD[i], N) + dr.dot(D, dN[i])
        refl = dD[i] - 2.0 * (cosD * dN[i] + dDN * N)
        dNf = dN[i] * sgn
        dc1 = -(dr.dot(dD[i], Nf) + dr.dot(D, dNf))
        dmu = eta * dc1 - eta * eta * c1 * dc1 / c2
        refr = eta * dD[i] + dmu * Nf + mu * dNf
        dP[i] = dr.select(go_on, dPh[i], dP[i])
        dD[i] = dr.select(go_on, dr.select(is_refl, refl, refr), dD[i])
    frame = list(frame)
    for i in range(2):
        f = frame[i]
        refl = f - 2.0 * dr.dot(f, N) * N
        rotated = dr.select(rot_ok, dr.dot(f, axis) * axis + dr.dot(f, u_old) * u_new, f)
        frame[i] = dr.select(go_on, dr.select(is_refl, refl, rotated), f)
    n_cur = dr.select(go_on & ~is_refl, n_cur * F64(bs.eta), n_cur)
    nd = dr.select(go_on, nd + 1, nd)
    D = dr.select(go_on, D_new, D)
    return d_here, singular, D, dP, dD, frame, n_cur, nd
