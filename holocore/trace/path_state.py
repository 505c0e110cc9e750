"""The loop state of the wave-path kernel (holocore.trace.kernel): what every ray carries from one iteration to
the next (:class:`PathState`, named and commented like the locals of Mitsuba's integrators), the kernel's fixed
settings, one iteration's vertex and lobes, the kernel's result (:class:`WavePaths`), and the state a ray starts
with (:func:`start_state`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from holocore.runtime.mitsuba_env import mitsuba
from holocore.trace.media import sensor_medium

if TYPE_CHECKING:  # annotations only: the variant's array types come from mitsuba() at run time
    import mitsuba as mi

    from holocore.trace.radiance_cache import RadianceCache

__all__ = ["WavePaths", "PathState", "KernelSettings", "Vertex", "Lobes", "start_state"]


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
    surface: dict | None = None  # with ``surface=True``: p, normal (shading), emission, albedo at P and the
    # chain's throughput ``thr`` (radiance leaving P = radiance / thr)


@dataclass
class PathState:
    """The loop state: one lane per wave path. Dr.Jit traverses the fields in this order (a ``None`` field is
    not part of the loop) and evaluates their annotations, hence ``object`` and the array type in the comment."""

    # The incoherent path, as in Mitsuba's ``path`` integrator.
    ray: object  # mi.Ray3f: the segment traced next (float32, world)
    active: object  # mi.Bool: the lane is still tracing
    beta: object  # mi.Color3f throughput: the chain's Fresnel weights, then BSDF weight / pdf, / RR survival
    L: object  # mi.Color3f: radiance gathered so far, towards the ray's origin
    eta: object  # mi.Float: product of the sampled relative indices of refraction (for Russian roulette)
    depth: object  # mi.UInt32: vertices counted from P on (Mitsuba's depth for a ray arriving at P; 0 before P)
    si_prev: object  # mi.Interaction3f: the previous vertex, for MIS of the emission the BSDF sample reaches
    pdf_prev: object  # mi.Float: solid-angle pdf (sr^-1) of the BSDF sample that left it
    delta_prev: object  # mi.Bool: that sample was a delta lobe (its emission takes no MIS)
    # The coherent chain (Sec. 4.2), float64: differentials per unit shift of O (m/m) or per radian of v.
    chain: object  # mi.Bool: still on delta vertices: P not reached yet
    D: object  # mi.Vector3d: unit direction of the current segment
    dP: object  # 4 x mi.Vector3d: position differentials (shift along e1, e2; angle along e1, e2)
    dD: object  # 4 x mi.Vector3d: direction differentials (same order)
    frame: object  # 2 x mi.Vector3d: the lateral frame (e1, e2) of v, carried through the delta vertices
    n_cur: object  # mi.Float64: index of refraction of the current medium relative to the start
    medium: object  # mi.MediumPtr: the medium the current segment travels in (null: vacuum; None: no media)
    nd: object  # mi.UInt32: delta bounces so far
    # The outcome.
    d: object  # mi.Float64: apparent distance of P along v (m, world), set at P
    done: object  # mi.Bool: P reached
    bad: object  # mi.Bool: a grazing delta vertex made the transfer singular: the ray is dropped
    capped: object  # mi.Bool: still on delta lobes after max_delta bounces
    escaped: object  # mi.Bool: left the scene before P
    cached: object  # mi.Bool: P's radiance came from the ambient cache
    # What the caller asked to keep of P.
    thr: object | None = None  # mi.Color3f: the chain's throughput at P (amp_spp > 1, or surface)
    fin: object | None = None  # mi.Ray3f: the segment that reached P (amp_spp > 1: more samples from it)
    surf: object | None = None  # dict (surface=True): p (m), shading normal, emission, albedo at P


class KernelSettings(NamedTuple):
    """What the loop body reads besides its state. The depths are kernel parameters (opaque), not constants:
    one compiled kernel serves every setting; the Python switches each select their own kernel."""

    ctx: mi.BSDFContext
    max_delta: mi.UInt32  # delta bounces allowed before P
    max_depth: mi.UInt32  # path depth counted from P (1: emission at P only)
    rr_depth: mi.UInt32  # Russian roulette from this depth on
    any_mixed: bool  # the scene has a BSDF with delta and smooth lobes
    media: bool  # the scene holds absorbing media (a shape's interior or exterior, or the sensor's)
    cache: RadianceCache | None  # the fast variant's ambient cache
    keep_thr: bool  # record the chain's throughput at P
    keep_ray: bool  # record the segment that reached P
    keep_surface: bool  # record P's surface
    near_smooth: object | None = None  # mi.Bool by BSDF registry id (holocore.trace.near_smooth); None: none here


class Vertex(NamedTuple):
    """What one iteration knows of the vertex its segment reached."""

    ray: mi.Ray3f  # the segment that reached it
    pi: mi.PreliminaryIntersection3f
    si: mi.SurfaceInteraction3f
    hit: mi.Bool  # an active lane that hit a surface
    bsdf: mi.BSDFPtr
    flags: mi.UInt32  # the BSDF's lobes (mi.BSDFFlags)
    chain0: mi.Bool  # the path was still coherent on this segment
    in_chain: mi.Bool  # a coherent path hit a surface here: a delta vertex or P
    is_emitter: mi.Bool  # the surface emits (the chain stops at emitters)


class Lobes(NamedTuple):
    """The vertex's samples (:func:`_sample_lobes`)."""

    bs: mi.BSDFSample3f  # the BSDF sample (direction wo in the local frame, pdf, lobe, relative eta)
    w: mi.Color3f  # its weight f cos / pdf
    Lr: mi.Color3f  # the emitter sample's radiance, MIS-weighted, times the throughput (0 where unused)
    go_on: mi.Bool  # a delta lobe on a chain: the chain goes on (before the max_delta cap)
    at_p: mi.Bool  # the chain ends here: this vertex is P
    micro: mi.Bool | None = None  # the chain goes on through a near-smooth surface's sampled micro-normal


def start_state(scene: mi.Scene, o64: mi.Point3d, v64: mi.Vector3d, s: KernelSettings) -> PathState:
    """The loop state of every ray at its start, with what ``s`` asks to keep (throughput, the ray that reaches P,
    P's surface)."""
    mi = mitsuba()
    import drjit as dr

    F64, V3d = mi.Float64, mi.Vector3d
    R = dr.width(o64)
    # The chain starts with A = I, B = 0 (docs/design.md §4): two lateral shifts of O along e1, e2 (dP = e_i, dD = 0)
    # and two angular perturbations of v along them (dP = 0, dD = e_i).
    helper = dr.select(dr.abs(v64.z) < 0.9, V3d(0, 0, 1), V3d(1, 0, 0))
    e1 = dr.normalize(dr.cross(v64, helper))
    e2 = dr.cross(v64, e1)
    zero3 = dr.zeros(V3d, R)
    p = PathState(
        ray=mi.Ray3f(mi.Point3f(o64), mi.Vector3f(v64)), active=dr.full(mi.Bool, True, R),
        beta=dr.full(mi.Color3f, 1.0, R), L=dr.zeros(mi.Color3f, R), eta=dr.full(mi.Float, 1.0, R),
        depth=dr.zeros(mi.UInt32, R), si_prev=dr.zeros(mi.Interaction3f, R), pdf_prev=dr.full(mi.Float, 1.0, R),
        delta_prev=dr.full(mi.Bool, True, R),
        chain=dr.full(mi.Bool, True, R), D=V3d(v64), dP=[V3d(e1), V3d(e2), V3d(zero3), V3d(zero3)],
        dD=[V3d(zero3), V3d(zero3), V3d(e1), V3d(e2)], frame=[V3d(e1), V3d(e2)], n_cur=dr.full(F64, 1.0, R),
        medium=sensor_medium(scene, R) if s.media else None, nd=dr.zeros(mi.UInt32, R),
        d=dr.zeros(F64, R), done=dr.full(mi.Bool, False, R), bad=dr.full(mi.Bool, False, R),
        capped=dr.full(mi.Bool, False, R), escaped=dr.full(mi.Bool, False, R), cached=dr.full(mi.Bool, False, R))
    if s.media:
        p.si_prev.p = mi.Point3f(o64)  # the first segment's start, for its length in a medium (MIS ignores it)
    if s.keep_thr:
        p.thr = dr.full(mi.Color3f, 1.0, R)
    if s.keep_ray:
        p.fin = mi.Ray3f(mi.Point3f(o64), mi.Vector3f(v64))
    if s.keep_surface:
        p.surf = {"p": dr.zeros(mi.Point3f, R), "normal": dr.zeros(mi.Vector3f, R),
                  "emission": dr.zeros(mi.Color3f, R), "albedo": dr.zeros(mi.Color3f, R)}
    return p
