"""Wave paths in one Dr.Jit loop: the delta chain and the incoherent radiance of its image point traced as
one path (paper Sec. 4.2, docs/design.md §4; what a ray adds: Eq. D5).

A wave path starts like any path of a path tracer. While its vertices are delta vertices (mirrors, smooth
dielectrics) it is *coherent*: it carries the four float64 ray differentials of :mod:`holocore.trace.reference_chain`
(two lateral shifts of O, two angular perturbations of v) and its optical path. The first non-delta vertex
(or an emitter) is the real image point P; there the differentials give the apparent distance d, and from
then on the same path goes on as an ordinary incoherent path (emitter sampling with MIS, Russian roulette
from ``rr_depth``), whose radiance is the radiance leaving P times the chain's throughput. The path depth is
counted from P, so the radiance equals what Mitsuba's ``path`` integrator returns for a ray arriving at P.

Fusing the two traces P once, not twice, in one kernel; :func:`holocore.trace.reference_chain.trace_chain`
(a first hit, a chain, then ``integrator.sample``) is the reference the tests compare with. A BSDF that mixes
delta and smooth lobes (plastic) decides chain or image point with one sample; at an image point it draws a
fresh sample for the incoherent path, so that P's radiance includes all its lobes, as the reference does.

One iteration of the loop (:func:`trace_wave_paths`) is five named steps, in this order:

1. :func:`_intersect`: the vertex the current segment reaches, and :func:`holocore.trace.media.absorb`: Beer-Lambert
   attenuation of the segment by the homogeneous absorbing medium it travels in (docs/physics.md);
2. :func:`_emission`: the emission found there by the previous BSDF sample, MIS-weighted (paper Eq. 1, L_e),
   or, in the fast variant, :func:`_cached_radiance`: P's radiance from the ambient cache;
3. :func:`_sample_lobes`: emitter sampling and one BSDF sample; the lobe decides chain or P (Sec. 4.2);
4. :func:`_coherent_step`: on a delta lobe, the float64 ray-differential transfer (Igehy 1999,
   :func:`holocore.trace.differentials.igehy_transfer`); at P behind delta vertices, the apparent distance d
   (docs/design.md §4, docs/physics.md);
5. :func:`_incoherent_step`: from P on, Eq. 1's Monte Carlo estimate as Mitsuba's ``path`` (radiance, next ray, RR).

Units: world metres (positions, distances, d), unit direction vectors, radiance in the scene's units.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from holocore.scene.features import has_media, has_mixed_delta
from holocore.runtime.mitsuba_env import mitsuba
from holocore.trace.differentials import igehy_transfer
from holocore.trace.media import absorb, extinction, transmittance
from holocore.trace.near_smooth import is_near_smooth, near_smooth_table
from holocore.trace.path_state import KernelSettings, Lobes, PathState, Vertex, WavePaths, start_state

if TYPE_CHECKING:  # annotations only: the variant's array types come from mitsuba() at run time
    import mitsuba as mi

    from holocore.trace.radiance_cache import RadianceCache

__all__ = ["WavePaths", "trace_wave_paths"]


def trace_wave_paths(
    scene: mi.Scene,
    o64: mi.Point3d,
    v64: mi.Vector3d,
    sampler: mi.Sampler,
    *,
    max_delta: int,
    max_depth: int,
    rr_depth: int = 5,
    amp_spp: int = 1,
    integrator: mi.Integrator | None = None,
    radiance_cache: RadianceCache | None = None,
    surface: bool = False,
) -> WavePaths:
    """Trace world rays (``o64``, ``v64``: mi.Point3d in m / unit mi.Vector3d of one width) as wave paths.

    ``max_depth``: path depth counted from P (Mitsuba's convention: 1 = emission at P only). ``amp_spp`` > 1
    adds ``amp_spp - 1`` samples of ``integrator`` from the ray that reached P. ``radiance_cache``: the fast
    variant's ambient cache; where it holds the cell of P, P's radiance is one lookup and the path ends.
    ``surface``: also record what the cache's pre-pass needs of P (see :class:`WavePaths`).
    """
    mi = mitsuba()
    import drjit as dr

    if max_depth < 1:
        raise ValueError(f"max_depth must be >= 1, got {max_depth}")
    extra = amp_spp > 1 and integrator is not None
    any_mixed, media = has_mixed_delta(scene), has_media(scene)
    # Kernel parameters, not constants: one compiled kernel for every depth setting.
    op_delta, op_depth, op_rr = (dr.opaque(mi.UInt32, v) for v in (max_delta, max_depth, rr_depth))
    s = KernelSettings(ctx=mi.BSDFContext(), max_delta=op_delta, max_depth=op_depth, rr_depth=op_rr,
                  any_mixed=any_mixed, media=media, cache=radiance_cache, keep_thr=extra or surface, keep_ray=extra,
                  keep_surface=surface, near_smooth=near_smooth_table(scene))

    p = start_state(scene, o64, v64, s)

    def body(p: PathState, sampler: mi.Sampler) -> tuple[PathState, mi.Sampler]:
        v = _intersect(scene, p)  # 1. the vertex this segment reaches
        if s.media:
            absorb(p, v)  # 1'. Beer-Lambert along the segment, before anything it carries is counted
        p.escaped |= p.active & v.chain0 & ~v.si.is_valid()  # a coherent path that leaves the scene
        Le = _emission(scene, p, v)  # 2. Eq. 1's L_e reached by the previous BSDF sample, MIS-weighted
        cached = mi.Bool(False)
        if s.cache is not None:  # 2'. fast variant: P's radiance from the ambient cache (Sec. 4.2)
            Le, cached = _cached_radiance(scene, p, v, Le, s.cache)
        lobes = _sample_lobes(scene, p, v, sampler, s, cached)  # 3. emitter + BSDF sample; chain or P (Sec. 4.2)
        go_on = _coherent_step(p, v, lobes, s)  # 4. Igehy transfer, or d at P (docs/design.md §4)
        _record_image_point(scene, p, v, lobes.at_p, s)
        _incoherent_step(p, v, lobes, Le, go_on, cached, sampler, s)  # 5. Eq. 1 from P on, Russian roulette
        return p, sampler

    p, sampler = dr.while_loop((p, sampler), lambda p, sampler: p.active, body, label="wave paths")

    ok = p.done & ~p.bad & ~p.capped & (p.d > 0) & dr.isfinite(p.d)
    L = _more_radiance(scene, p, ok, sampler, integrator, amp_spp) if extra else p.L
    ok &= dr.isfinite(L[0]) & dr.isfinite(L[1]) & dr.isfinite(L[2])
    L = dr.select(ok, dr.maximum(L, 0.0), 0.0)
    d = dr.select(ok, p.d, 0.0)
    surf = dict(p.surf, thr=p.thr) if surface else None
    return WavePaths(valid=ok, d=d, radiance=L, n_delta=p.nd, escaped=p.escaped, capped=p.capped,
                     sampled=ok & ~p.cached, surface=surf)


def _more_radiance(scene: mi.Scene, p: PathState, ok, sampler: mi.Sampler, integrator: mi.Integrator,
                   amp_spp: int):
    """P's radiance averaged with ``amp_spp - 1`` more samples of Mitsuba's integrator from the segment that
    reached P (where P's radiance did not come from the cache)."""
    mi = mitsuba()
    import drjit as dr

    need = ok & ~p.cached
    rd = mi.RayDifferential3f(p.fin)
    L_more = dr.zeros(mi.Color3f, dr.width(ok))
    for _ in range(amp_spp - 1):
        spec, valid, _aov = integrator.sample(scene, sampler, rd, None, need)
        L_more += dr.select(valid & need, spec, 0.0)
    return dr.select(need, (p.L + p.thr * L_more) / amp_spp, p.L)


# ---- the steps of one iteration ------------------------------------------------------------------------------


def _intersect(scene: mi.Scene, p: PathState) -> Vertex:
    """Step 1: the vertex the current segment reaches, and what kind of vertex it is for the chain."""
    mi = mitsuba()

    pi = scene.ray_intersect_preliminary(p.ray, False, p.active)
    si = pi.compute_surface_interaction(p.ray, mi.RayFlags.All, p.active)
    hit = p.active & si.is_valid()
    bsdf = si.bsdf(p.ray)
    return Vertex(ray=p.ray, pi=pi, si=si, hit=hit, bsdf=bsdf, flags=bsdf.flags(), chain0=p.chain,
                   in_chain=hit & p.chain, is_emitter=si.shape.is_emitter())


def _emission(scene: mi.Scene, p: PathState, v: Vertex) -> mi.Color3f:
    """Step 2: the emitted radiance L_e of Eq. 1 that the previous BSDF sample reached (an area light or the
    environment), times the throughput, MIS-weighted (power heuristic) against emitter sampling at the
    previous vertex. Whether it counts (from P on only) is the incoherent step's decision."""
    ds = mitsuba().DirectionSample3f(scene, si=v.si, ref=p.si_prev)
    em_pdf = scene.pdf_emitter_direction(p.si_prev, ds, p.active & ~p.delta_prev)
    return p.beta * _mis(p.pdf_prev, em_pdf) * ds.emitter.eval(v.si, p.active)


def _cached_radiance(scene: mi.Scene, p: PathState, v: Vertex, Le: mi.Color3f,
                     cache: RadianceCache) -> tuple[mi.Color3f, mi.Bool]:
    """Step 2, fast variant (Sec. 4.2, the ambient cache): a chain vertex without delta lobes (or an emitter)
    is P for sure; where the cache holds P's cell, P's radiance is one lookup and the path ends there. The
    cache holds view-independent radiance per unit diffuse albedo, so a glossy P (a highlight that moves with
    the view) is path traced. Returns (Le, cached): Le replaced by the throughput times the cached radiance."""
    mi = mitsuba()
    import drjit as dr

    sure_p = (v.in_chain & (~mi.has_flag(v.flags, mi.BSDFFlags.Delta) | v.is_emitter)
              & ~mi.has_flag(v.flags, mi.BSDFFlags.Glossy))
    emission = v.si.emitter(scene).eval(v.si, sure_p)
    albedo = v.bsdf.eval_diffuse_reflectance(v.si, sure_p)
    L_c, cached = cache.lookup(v.si, albedo, emission, sure_p)
    p.cached |= cached
    return dr.select(cached, p.beta * L_c, Le), cached


def _sample_lobes(scene: mi.Scene, p: PathState, v: Vertex, sampler: mi.Sampler, s: KernelSettings,
                  cached: mi.Bool) -> Lobes:
    """Step 3: emitter sampling and one BSDF sample in one call (as Mitsuba's ``path`` does), the two halves
    of Eq. 1's integral combined by MIS. The BSDF sample's lobe also decides the chain (Sec. 4.2): a delta
    lobe goes on coherently, anything else (or an emitter) makes this vertex the real image point P. A lane
    whose chain goes on discards its emitter sample (delta vertices neither emit nor sample lights)."""
    mi = mitsuba()
    import drjit as dr

    Delta = mi.BSDFFlags.Delta
    em_on = v.hit & ~cached & (p.depth + 1 < s.max_depth) & mi.has_flag(v.flags, mi.BSDFFlags.Smooth)
    ds, em_w = scene.sample_emitter_direction(v.si, sampler.next_2d(em_on), True, em_on)
    em_on &= ds.pdf != 0.0
    smp = v.hit & ~cached
    val, pdf, bs, w = v.bsdf.eval_pdf_sample(s.ctx, v.si, v.si.to_local(ds.d), sampler.next_1d(smp),
                                             sampler.next_2d(smp), smp)
    chain_lobe = mi.has_flag(bs.sampled_type, Delta)
    micro = None
    if s.near_smooth is not None:  # a near-smooth surface's glossy lobe carries the chain too (its micro-normal)
        micro = (v.in_chain & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Glossy)
                 & is_near_smooth(s.near_smooth, v.bsdf, v.in_chain))
        chain_lobe |= micro
    go_on = v.in_chain & chain_lobe & (bs.pdf > 0) & ~v.is_emitter
    at_p = v.in_chain & ~go_on
    mis_em = dr.select(ds.delta, 1.0, _mis(ds.pdf, pdf))
    if s.media:  # the shadow segment's own medium: the side of a medium boundary it leaves into, else the ray's
        shadow = dr.select(v.si.is_medium_transition(), v.si.target_medium(ds.d), p.medium)
        em_w = em_w * transmittance(extinction(shadow, p.ray, v.si, em_on & (shadow != None)), ds.dist)  # noqa: E711
    Lr = dr.select(em_on & ~go_on, p.beta * mis_em * val * em_w, 0.0)
    return Lobes(bs=bs, w=w, Lr=Lr, go_on=go_on, at_p=at_p, micro=micro)


def _coherent_step(p: PathState, v: Vertex, lobes: Lobes, s: KernelSettings) -> mi.Bool:
    """Step 4, the coherent part (Sec. 4.2, docs/design.md §4 "Virtual image point"), float64 and only in the lanes
    that need it (a real branch per packet): through a delta vertex, the differentials and the frame are
    carried on (:func:`igehy_transfer`); at a P behind delta vertices, d = 2 / tr(B^-1 A) is read from them
    (docs/physics.md); at a P with no delta vertex before it (A = I, B = t I), d is the hit distance t (m).
    Chains past ``max_delta`` bounces are capped, grazing ones dropped. Returns where the chain goes on."""
    mi = mitsuba()
    import drjit as dr

    capped = lobes.go_on & (p.nd >= s.max_delta)
    p.capped |= capped
    go_on = lobes.go_on & ~capped
    deep = lobes.at_p & (p.nd > 0)

    def transfer(D, dP, dD, frame, n_cur, nd):
        # The shading normal's derivatives (curved mirrors and lenses), only where a chain goes on or ends.
        si_d = v.pi.compute_surface_interaction(v.ray, mi.RayFlags.All | mi.RayFlags.dNSdUV, go_on | deep)
        return igehy_transfer(si_d, lobes.bs, go_on, D, dP, dD, frame, n_cur, nd, micro=lobes.micro)

    def keep(D, dP, dD, frame, n_cur, nd):
        return mi.Float64(0.0), mi.Bool(False), D, dP, dD, frame, n_cur, nd

    d_deep, singular, p.D, p.dP, p.dD, p.frame, p.n_cur, p.nd = dr.if_stmt(
        (p.D, p.dP, p.dD, p.frame, p.n_cur, p.nd), go_on | deep, transfer, keep, label="delta vertex")
    p.d = dr.select(lobes.at_p, dr.select(deep, d_deep, mi.Float64(v.si.t)), p.d)
    p.done |= lobes.at_p
    p.bad |= singular
    go_on &= ~singular
    p.chain = go_on
    return go_on


def _record_image_point(scene: mi.Scene, p: PathState, v: Vertex, at_p: mi.Bool, s: KernelSettings) -> None:
    """At P, keep what the caller asked for: the chain's throughput, the segment that reached P, P's surface."""
    import drjit as dr

    if s.keep_thr:
        p.thr = dr.select(at_p, p.beta, p.thr)
    if s.keep_ray:
        p.fin = dr.select(at_p, v.ray, p.fin)
    if s.keep_surface:
        here = {"p": v.si.p, "normal": v.si.sh_frame.n, "emission": v.si.emitter(scene).eval(v.si, at_p),
                "albedo": v.bsdf.eval_diffuse_reflectance(v.si, at_p)}
        p.surf = {k: dr.select(at_p, here[k], p.surf[k]) for k in here}


def _incoherent_step(p: PathState, v: Vertex, lobes: Lobes, Le: mi.Color3f, go_on: mi.Bool,
                     cached: mi.Bool, sampler: mi.Sampler, s: KernelSettings) -> None:
    """Step 5, the incoherent part from P on: Eq. 1 by Monte Carlo, as Mitsuba's ``path`` (depth counted
    from P). Nothing counts before P: delta vertices neither emit (the chain stops at emitters) nor sample
    lights. Adds this vertex's emission and emitter sample, follows the BSDF sample (or the chain), and plays
    Russian roulette from ``rr_depth``."""
    mi = mitsuba()
    import drjit as dr

    counts = (p.active & ~v.chain0) | lobes.at_p  # past P (escaping to an environment included) or at P
    past = ((v.hit & ~v.chain0) | lobes.at_p) & ~cached
    more = past & (p.depth + 1 < s.max_depth)
    bs, w = lobes.bs, lobes.w
    if s.any_mixed:  # delta and smooth lobes: P's radiance includes all of them, so sample afresh at P
        mixed = (lobes.at_p & more & mi.has_flag(v.flags, mi.BSDFFlags.Delta)
                 & mi.has_flag(v.flags, mi.BSDFFlags.Smooth))
        bs2, w2 = v.bsdf.sample(s.ctx, v.si, sampler.next_1d(mixed), sampler.next_2d(mixed), mixed)
        bs = dr.select(mixed, bs2, bs)
        w = dr.select(mixed, w2, w)
    p.L = p.L + dr.select(counts, Le, 0.0) + lobes.Lr

    step = go_on | more
    wo = v.si.to_world(bs.wo)
    p.ray = dr.select(step, v.si.spawn_ray(wo), p.ray)
    # Mitsuba's media: a boundary that carries media switches the ray's medium to the side it leaves into.
    if s.media:
        p.medium = dr.select(step & v.si.is_medium_transition(), v.si.target_medium(wo), p.medium)
    p.beta = dr.select(step, p.beta * w, p.beta)
    p.eta = dr.select(step, p.eta * bs.eta, p.eta)
    p.si_prev = dr.select(step, mi.Interaction3f(v.si), p.si_prev)
    p.pdf_prev = dr.select(step, bs.pdf, p.pdf_prev)
    # a chain step is a delta step for MIS: its vertex sampled no light, so what the chain reaches counts whole
    p.delta_prev = dr.select(step, mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta) | go_on, p.delta_prev)
    # Russian roulette, Mitsuba's ``path``: depth counted after this vertex, survival max(beta) eta^2 <= 0.95.
    b_max = dr.max(p.beta)
    rr = more & (p.depth + 1 >= s.rr_depth)
    rr_prob = dr.minimum(b_max * p.eta * p.eta, 0.95)
    p.beta = dr.select(rr, p.beta / rr_prob, p.beta)
    survive = ~rr | (sampler.next_1d(rr) < rr_prob)
    p.depth = dr.select(past, p.depth + 1, p.depth)
    p.active = go_on | (more & survive & (b_max != 0))


def _mis(a: mi.Float, b: mi.Float) -> mi.Float:
    """Power heuristic a^2 / (a^2 + b^2) of two pdfs (same measure); 0 where a = 0 (keeps 0/0 out)."""
    import drjit as dr

    a2 = a * a
    return dr.select(a > 0, a2 / (a2 + b * b), 0.0)
