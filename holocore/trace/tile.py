"""One tile of recording-plane rays in one Dr.Jit kernel (paper Sec. 4.2-4.4, Eq. 5; docs/design.md §3-4): the rays of
rows r0..r1 leave their pixels (stratified directions in the widest cone), go to the world through T^-1, are traced
as wave paths (:func:`holocore.trace.kernel.trace_wave_paths`), and each returns its complex contribution
A (r / cos theta) exp(i s k r) per color, its bank cell (for phi_m(Q)) and, with several recording planes, its
slot on the plane in front of its image point. :mod:`holocore.trace.hologram_rays` accumulates the tiles.

Units: metres, radians; the geometry holds T and its inverse as plain float64 numbers (:class:`TileGeometry`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace
from typing import TYPE_CHECKING, Optional

import numpy as np
import torch

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, channel_of, theta_max_rad
from holocore.runtime.mitsuba_env import mitsuba
from holocore.runtime.recording import recording_kernels
from holocore.trace.kernel import trace_wave_paths
from holocore.trace.mapping import HologramMap, camera_to_holo_xyz, holo_to_camera_xyz

if TYPE_CHECKING:
    from holocore.trace.hologram_rays import TraceSettings, TraceStats

__all__ = ["TileGeometry", "trace_tile", "image_depth_step_m"]


@dataclass(frozen=True)
class TileGeometry:
    """What every tile shares: the plane, the cones, T and its inverse as plain numbers."""

    H: int
    W: int
    pitch: float
    plane_z: float
    z_wrp: float
    z_mid: float
    direct: bool  # the plane lies behind the WRP (the SLM): rays start where they cross the WRP
    planes: Optional[tuple]  # several recording planes: (z, lo, hi, border) front to back, plane 0 the WRP
    ring_heights: tuple  # rows of each plane's ring buffer (see hologram_rays' plane bands)
    ring_offsets: tuple  # first slot of each plane's ring in the flat table
    ring_total: int
    f: float
    z_inf: float
    rot: tuple  # eye-camera -> world, 3x3 row-major
    rot_inv: tuple
    origin: tuple
    cos_max: float
    omega: float
    spp: int
    ks: tuple
    cos_lim: tuple
    chans: tuple
    depth_step: float  # m: depth grid of the phase of image points (see trace_tile), min over colors of DOF / 8

    @classmethod
    def make(cls, hmap: HologramMap, *, wavelengths_m, pitch_m, shape_hw, plane_z_m, z_wrp_m, spp,
             planes=None, ring_rows: int = 1) -> "TileGeometry":
        thetas = [theta_max_rad(lam, pitch_m) for lam in wavelengths_m]
        thetas = [min(t, MAX_CONE_HALF_ANGLE_RAD) for t in thetas]  # off grazing (an infinite r / cos theta)
        th_max = max(thetas)
        H, W = shape_hw
        pl = None if not planes else tuple((float(z), max(-1e30, float(lo)), float(hi), int(b))
                                           for z, lo, hi, b in planes)
        heights = tuple(ring_rows + 2 * b + 1 for _z, _lo, _hi, b in pl) if pl else ()
        sizes = [h * (W + 2 * b) for h, (_z, _lo, _hi, b) in zip(heights, pl or ())]
        offsets = tuple(int(v) for v in np.cumsum([0] + sizes[:-1])) if pl else ()
        return cls(planes=pl, ring_heights=heights, ring_offsets=offsets, ring_total=int(sum(sizes)),
                   H=H, W=W, pitch=pitch_m, plane_z=plane_z_m, z_wrp=z_wrp_m,
                   z_mid=hmap.z_inf_m + 0.5 * (z_wrp_m - hmap.z_inf_m), direct=plane_z_m < z_wrp_m,
                   f=hmap.focal_length_m, z_inf=hmap.z_inf_m,
                   rot=tuple(map(float, hmap.rotation.ravel())), rot_inv=tuple(map(float, hmap.rotation_inv.ravel())),
                   origin=tuple(map(float, hmap.origin)), cos_max=math.cos(th_max),
                   omega=2.0 * math.pi * (1.0 - math.cos(th_max)), spp=spp,
                   ks=tuple(2.0 * math.pi / lam for lam in wavelengths_m),
                   cos_lim=tuple(math.cos(t) for t in thetas), chans=tuple(channel_of(lam) for lam in wavelengths_m),
                   depth_step=min(image_depth_step_m(lam, t) for lam, t in zip(wavelengths_m, thetas)))


def image_depth_step_m(wavelength_m: float, theta_max_rad: float) -> float:
    """Depth grid (m) of the image points' phase (behind delta vertices; all of them with random phases): an
    eighth of the depth of field of a point seen through the recording cone, lambda / sin^2(theta_max) (axial
    extent of the focus of a cone of that numerical aperture; 0.55 mm for 455 nm at 8 µm pitch, so the grid is
    70 µm there)."""
    return wavelength_m / (8.0 * math.sin(theta_max_rad) ** 2)


def _mat(mi, m: tuple, v):
    return mi.Vector3d(m[0] * v.x + m[1] * v.y + m[2] * v.z, m[3] * v.x + m[4] * v.y + m[5] * v.z,
                       m[6] * v.x + m[7] * v.y + m[8] * v.z)


def _holo_to_camera(mi, g, q):
    return mi.Vector3d(*holo_to_camera_xyz(q.x, q.y, q.z, f=g.f, z_inf=g.z_inf))


def _opaque(mi, g: TileGeometry) -> SimpleNamespace:
    """The geometry as kernel parameters rather than constants: one compiled kernel serves every resolution,
    pitch, focal length, spp and tile (a megakernel takes seconds to compile)."""
    import drjit as dr

    def f64(v):
        return dr.opaque(mi.Float64, float(v))

    o = SimpleNamespace(**{k: f64(getattr(g, k)) for k in ("pitch", "plane_z", "z_wrp", "z_mid", "f", "z_inf",
                                                            "cos_max", "omega", "depth_step")})
    u32 = lambda v: dr.opaque(mi.UInt32, int(v))  # noqa: E731
    o.planes = tuple((f64(z), f64(lo), f64(hi), f64(g.H + 2 * b), f64(g.W + 2 * b), u32(g.W + 2 * b),
                      u32(g.ring_heights[k]), u32(g.ring_offsets[k]))
                     for k, (z, lo, hi, b) in enumerate(g.planes or ()))
    o.Hf, o.Wf, o.W, o.N = f64(g.H), f64(g.W), dr.opaque(mi.UInt32, g.W), dr.opaque(mi.UInt32, g.spp)
    o.rot, o.rot_inv = tuple(map(f64, g.rot)), tuple(map(f64, g.rot_inv))
    o.origin, o.ks, o.cos_lim = tuple(map(f64, g.origin)), tuple(map(f64, g.ks)), tuple(map(f64, g.cos_lim))
    o.tan_lim = tuple(f64(math.sqrt(max(0.0, 1.0 - c * c)) / c) for c in g.cos_lim)
    return o


def _pixel_directions(mi, pix, n, seed: int):
    """The 2D sample of each ray: ray i of its pixel's n takes (i / n + s, radinv_2(i) xor t) mod 1, with the
    rotation s and scramble t random per pixel (seeded). Every point is uniform on its own; together the n of
    a pixel cover the cone's strata evenly, so each random-phase cell of a small sub-hologram gets its share of
    rays instead of a Poisson number (far less Monte Carlo noise where n approaches the cell count)."""
    import drjit as dr

    i = dr.arange(mi.UInt32, dr.width(pix)) % n
    v0, v1 = mi.sample_tea_32(pix, dr.opaque(mi.UInt32, seed & 0xFFFFFFFF))  # opaque: one kernel for all seeds
    shift = mi.Float(v0 >> 8) * (1.0 / (1 << 24))
    x = mi.Float(i) / mi.Float(n) + shift
    x = x - dr.floor(x)
    y = mi.radical_inverse_2(i, v1)
    return mi.Point2f(dr.minimum(x, 1.0 - 2.0 ** -24), y)


def _pixel_fraction_in_cone(mi, dq, cos_max, pitch):
    """The fraction of a pixel (side ``pitch``, centred at the origin of ``dq``) from which the point dq (float64
    vector from the pixel centre, dq.z < 0) lies inside the cone of half-angle acos(cos_max) around -z. The
    cone's edge at the pixel is nearly straight (its radius is several pixels), so the fraction is the CDF at
    s = R - |dq_xy| of n.(x - c) for x uniform in the square, n the unit lateral direction: a trapezoid of
    half-widths A = p |n_x| / 2 >= B = p |n_y| / 2 (the sum of two uniform variables)."""
    import drjit as dr

    F64 = mi.Float64
    dl = dr.sqrt(dq.x * dq.x + dq.y * dq.y)
    tan_max = dr.safe_sqrt(1.0 - cos_max * cos_max) / cos_max
    s = (-dq.z) * tan_max - dl
    inv = 1.0 / dr.maximum(dl, 1e-30)
    ax, ay = dr.abs(dq.x) * inv, dr.abs(dq.y) * inv
    ax = dr.select(dl > 0, ax, F64(1.0))
    A = 0.5 * pitch * dr.maximum(ax, ay)
    B = 0.5 * pitch * dr.minimum(ax, ay)
    t = dr.abs(s)
    flat = 0.5 + t / (2.0 * A)  # |s| <= A - B: the density is 1 / 2A
    ramp = 1.0 - (A + B - t) ** 2 / dr.maximum(8.0 * A * B, 1e-300)
    upper = dr.select(t <= A - B, flat, dr.select(t < A + B, ramp, F64(1.0)))
    return dr.select(s >= 0, upper, 1.0 - upper)


def _to_torch(x, dev: torch.device) -> torch.Tensor:
    """A Dr.Jit array as a torch tensor on ``dev``: zero-copy through DLPack on the GPU, through numpy on the
    CPU (the tensors' values are the same)."""
    if dev.type == "cuda":
        return x.torch()
    return torch.from_numpy(np.asarray(x))


@recording_kernels()
def trace_tile(scene, g: TileGeometry, r0: int, r1: int, settings: TraceSettings, integrator, radiance_cache,
               want_cells: bool, *, seed: int, stats: TraceStats, device: torch.device, want_dz: bool = False,
               taper: Optional[float] = None) -> dict:
    """Rows r0..r1 of the plane, all in Dr.Jit: ray generation, wave paths, the complex contribution of every
    ray. Returns per color a complex64 tensor (per pixel when ``want_cells`` is False, else per ray, pixel-
    major) and, with ``want_cells``, the bank cell of every ray's image point ("idx"). ``want_dz`` (directional
    frames, :mod:`holocore.trace.beams`): each ray's phase also holds k (Q_z - z_wrp), the depth part of Eq. B1
    common to all frames, and "dz" returns Q_z - z_wrp (m, float32) for the part that differs between frames,
    "drec" the distance (m) from the ray's image point to the plane that records it. ``taper`` (directional
    frames): each ray's amplitude is also weighted by the rim taper (:func:`holocore.trace.beams.rim_taper`) at
    its tan(angle) over its colour's cone, which starts at this fraction of the cone: a soft-edged sub-hologram.

    The steps below build one Dr.Jit kernel, evaluated once: the helpers only name its parts."""
    mi = mitsuba()
    import drjit as dr

    N = settings.spp
    R = (r1 - r0) * g.W * N
    o = _opaque(mi, g)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, R)
    s, dirs, cos_t = _hologram_rays(mi, dr, o, g, settings, sampler, r0=r0, R=R, seed=seed)
    c0, o_w, v_w = _world_rays(mi, dr, o, g, s, dirs, cos_t)
    wp = trace_wave_paths(scene, mi.Point3d(o_w), v_w, sampler, max_delta=settings.max_delta,
                          max_depth=settings.max_depth, amp_spp=settings.amp_spp, integrator=integrator,
                          radiance_cache=radiance_cache)
    # Virtual image point and its hologram position, float64 (docs/design.md §2: long lengths in float64).
    cv = c0 + wp.d * _mat(mi, o.rot_inv, v_w)
    q = mi.Vector3d(*camera_to_holo_xyz(cv.x, cv.y, cv.z, f=o.f, z_inf=o.z_inf))
    ok = wp.valid & (cv.z > 0) & dr.isfinite(q.x) & dr.isfinite(q.y) & dr.isfinite(q.z) & (q.z < o.z_wrp)
    pos = None
    if o.planes:
        pos, s, ok = _recording_planes(mi, dr, o, s, dirs, cos_t, q, ok)
    q = dr.select(ok, q, s)
    r = dr.norm(q - s)
    weight, cos_t, ok = _ray_weights(mi, dr, o, s, q, r, cos_t, ok)
    q_ph, j, i = _phase_points(mi, dr, o, q, wp, want_cells)
    r_ph = dr.select(ok, dr.norm(q_ph - s), r)
    parts = _colour_parts(mi, dr, o, g, wp, weight=weight, cos_t=cos_t, r_ph=r_ph, q_ph=q_ph, taper=taper,
                          want_dz=want_dz)
    idx = None
    if want_cells:
        j, i = j - o.Wf * dr.floor(j / o.Wf), i - o.Hf * dr.floor(i / o.Hf)  # periodic wrap (docs/design.md §4)
        idx = mi.UInt32(i) * o.W + mi.UInt32(j)
    # Per-ray status in one word (evaluated with the rest, read once): bit 0 ok, 1 behind the plane, 2 escaped,
    # 3 capped, 4 sampled by path tracing, bits 8.. delta bounces.
    status = (mi.UInt32(ok) | (mi.UInt32(wp.valid & ~ok) << 1) | (mi.UInt32(wp.escaped) << 2)
              | (mi.UInt32(wp.capped) << 3) | (mi.UInt32(wp.sampled) << 4) | (wp.n_delta << 8))
    dz = mi.Float(q_ph.z - o.z_wrp) if want_dz else None
    drec = mi.Float(s.z - q_ph.z) if want_dz else None  # s: where the ray is recorded (its plane's z)
    dr.eval(parts, idx, status, pos, dz, drec)  # the one kernel: rays, wave paths, contributions
    if not want_cells and pos is None:  # sum each pixel's N rays (the rays are pixel-major)
        parts = [dr.block_sum(x, N) for x in parts]
        dr.eval(parts)
    if device.type == "cuda":
        dr.sync_thread()  # Dr.Jit's kernels run on its own stream: done before torch reads their outputs
    out = {c: torch.complex(_to_torch(parts[2 * c], device), _to_torch(parts[2 * c + 1], device))
           for c in range(len(g.ks))}
    for name, value in (("idx", idx), ("pos", pos)):
        if value is not None:
            out[name] = _to_torch(value, device).to(torch.int64)
    if dz is not None:
        out["dz"] = _to_torch(dz, device)
        out["drec"] = _to_torch(drec, device)
    _count(stats, _to_torch(status, device).to(torch.int64), rays=R, amp_spp=settings.amp_spp)
    return out


def _hologram_rays(mi, dr, o, g: TileGeometry, settings: TraceSettings, sampler, *, r0: int, R: int, seed: int):
    """(each ray's origin s on its recording plane, its direction, cos of its angle to -z). Directions are
    uniform in solid angle in the widest cone around -z: a pixel's N rays form a scrambled Hammersley set
    (stratified; each ray still uniform on its own, so the estimate stays unbiased), or N independent samples."""
    F64, V3d = mi.Float64, mi.Vector3d
    pix = dr.arange(mi.UInt32, R) // o.N + dr.opaque(mi.UInt32, r0 * g.W)
    s = V3d((F64(pix % o.W) - (o.Wf - 1.0) * 0.5) * o.pitch, ((o.Hf - 1.0) * 0.5 - F64(pix // o.W)) * o.pitch,
            o.plane_z)
    u = _pixel_directions(mi, pix, o.N, seed) if settings.stratified else sampler.next_2d()
    cos_t = 1.0 - F64(u.x) * (1.0 - o.cos_max)
    sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
    sp, cp = dr.sincos(2.0 * math.pi * F64(u.y))
    dirs = V3d(sin_t * cp, sin_t * sp, -cos_t)
    if g.planes:
        # Several recording planes: each ray leaves a point uniform in its WRP pixel. A ray is recorded where
        # it crosses its plane, and rays from pixel centres would cross a deeper plane on a lattice of spacing
        # (1 - alpha) p, so each pixel there would take 1..4 bundles of the rays to one image cell (a moire
        # that adds ~20% of spurious energy and does not fall with N); from spread origins they land evenly.
        jit = sampler.next_2d()
        s = s + V3d((F64(jit.x) - 0.5) * o.pitch, (F64(jit.y) - 0.5) * o.pitch, 0.0)
    return s, dirs, cos_t


def _world_rays(mi, dr, o, g: TileGeometry, s, dirs, cos_t):
    """(the ray's start in the camera's frame, its world origin, its world direction): T^-1 of the hologram
    ray (docs/design.md §3), through its start and the point where it reaches z_mid."""
    V3d = mi.Vector3d
    if g.direct:
        # Rays leave the SLM towards +z; the world ray is the same line, traced from where it crosses the
        # WRP, back into the scene (docs/design.md §4; paper Fig. 5's baseline).
        x = s - ((o.z_wrp - o.plane_z) / cos_t) * dirs
    else:
        x = s
    c0 = _holo_to_camera(mi, o, x)
    c1 = _holo_to_camera(mi, o, x + ((o.z_mid - x.z) / dirs.z) * dirs)
    vc = dr.normalize(c1 - c0)
    return c0, _mat(mi, o.rot, c0) + V3d(*o.origin), dr.normalize(_mat(mi, o.rot, vc))


def _recording_planes(mi, dr, o, s, dirs, cos_t, q, ok):
    """Several recording planes: (each ray's slot in its plane's ring buffer, the centre of the pixel that
    records it, whether a plane takes it): the plane in front of the image point, where the ray crosses it."""
    V3d = mi.Vector3d
    pos, rec, found = mi.UInt32(0), V3d(s), mi.Bool(False)
    for k, (z_k, lo, hi, Hk, Wk, Wk_u, ring, off) in enumerate(o.planes):
        xk = s + ((o.z_wrp - z_k) / cos_t) * dirs
        j = dr.clip(dr.round(xk.x / o.pitch + (Wk - 1.0) * 0.5), 0.0, Wk - 1.0)
        i = dr.clip(dr.round((Hk - 1.0) * 0.5 - xk.y / o.pitch), 0.0, Hk - 1.0)
        centre = V3d((j - (Wk - 1.0) * 0.5) * o.pitch, ((Hk - 1.0) * 0.5 - i) * o.pitch, z_k)
        here = ok & ~found & (q.z > lo) & (q.z <= hi)
        pos = dr.select(here, off + (mi.UInt32(i) % ring) * Wk_u + mi.UInt32(j), pos)
        rec = dr.select(here, centre, rec)
        found |= here
    return pos, rec, ok & found


def _ray_weights(mi, dr, o, s, q, r, cos_t, ok):
    """(each ray's weight Omega / N r / cos(theta) (docs/design.md Eq. D5), cos(theta), which rays count).

    A ray recorded on a plane crossed its pixel at a point spread over the pixel (its origin was), not at the
    centre, so near the cone's edge the image points it samples are those of a cone blurred by the pixel: keep
    those inside the centre's cone, weighted by 1 / (the pixel's fraction that sees them inside its cone), which
    makes the estimate unbiased again (docs/physics.md). Angles are then seen from the centre."""
    F64 = mi.Float64
    if not o.planes:
        return dr.select(ok, (o.omega / F64(o.N)) * r / cos_t, 0.0), cos_t, ok
    cos_t = dr.maximum((s.z - q.z) / dr.maximum(r, 1e-30), 1e-12)
    frac = _pixel_fraction_in_cone(mi, q - s, o.cos_max, o.pitch)
    ok &= frac > 0
    return dr.select(ok, (o.omega / F64(o.N)) * r / cos_t / dr.maximum(frac, 1e-3), 0.0), cos_t, ok


def _phase_points(mi, dr, o, q, wp, want_cells: bool):
    """(the image point whose distance sets each ray's phase, the column and row of its random-phase cell
    before the wrap).

    One depth per image point behind delta vertices (docs/physics.md, "Image points behind delta vertices").
    d is each ray's own apparent distance; through a glass ball it varies by ~0.4 % between the rays of one
    surface point (astigmatism of the local bundle), which moves Q along each ray by a few micrometres: a piston
    of tens of radians in k r that decorrelates the point's sub-hologram (the field's signal fell 260x). The
    phase therefore uses Q's depth rounded to a grid of depth_step, an eighth of the recording cone's depth of
    field: the rays of one point agree, and the point moves by at most 1/16 of a depth of field. Weights, the
    plane choice and the random-phase cell keep the unrounded Q. The grid is offset by a random fraction of a
    step per lateral cell: the points whose rays straddle a grid level (their phases then disagree) are
    scattered, instead of lying on the image's iso-depth contours (a glass ball's curved image field made them
    coloured rings in the view).

    With random phases (``want_cells``) every image point takes the rounded depth, not only those behind delta
    vertices (docs/physics.md, "Random-phase cells lie flat in hologram space"): the points of one random-phase
    cell share its phase, so with their own depths a cell of a surface tilted in hologram space radiated like a
    small tilted mirror, its light leaning by the tilt (a 12-degree plate at 0.5 m looked 0.68x as bright from
    the left as from the right, and red from one side, blue from the other). On the grid a cell lies flat. The
    offset uses the random-phase cell's own indices, so no point straddles a cell of one and not of the other."""
    V3d = mi.Vector3d
    j = dr.round(q.x / o.pitch + (o.Wf - 1.0) * 0.5)
    i = dr.round((o.Hf - 1.0) * 0.5 - q.y / o.pitch)
    shift = mi.sample_tea_float64(mi.UInt32(mi.Int32(j) + (1 << 24)), mi.UInt32(mi.Int32(i) + (1 << 24)), 4)
    z_grid = o.depth_step * (dr.floor(q.z / o.depth_step - shift) + 0.5 + shift)
    q_ph = V3d(q.x, q.y, z_grid) if want_cells else dr.select(wp.n_delta > 0, V3d(q.x, q.y, z_grid), q)
    return q_ph, j, i


def _colour_parts(mi, dr, o, g: TileGeometry, wp, *, weight, cos_t, r_ph, q_ph, taper: Optional[float],
                  want_dz: bool) -> list:
    """Each colour's contribution of every ray as (real, imaginary) float32 parts: amplitude sqrt(L) times the
    weight, inside that colour's cone (a raised-cosine rim from ``taper``), phase k r wrapped in float64."""
    F64 = mi.Float64
    parts = []
    for c in range(len(g.ks)):
        inside = cos_t >= o.cos_lim[c] - 1e-15
        w_c = weight
        if taper is not None:  # a soft rim: raised cosine in tan(angle) / tan(theta_c) from ``taper`` to 1
            x = dr.safe_sqrt(1.0 - cos_t * cos_t) / cos_t / o.tan_lim[c]
            t = dr.clip((x - taper) / (1.0 - taper), 0.0, 1.0)
            w_c = weight * (0.5 + 0.5 * dr.cos(math.pi * t))
        amp = mi.Float(dr.select(inside, dr.sqrt(F64(wp.radiance[g.chans[c]])) * w_c, 0.0))
        kr = (-1.0 if g.direct else 1.0) * o.ks[c] * r_ph
        if want_dz:  # Eq. B1's k (Q_z - z_ref) with the depth the phase uses (on the grid: the two agree there)
            kr = kr + o.ks[c] * (q_ph.z - o.z_wrp)
        phase = mi.Float(kr - (2.0 * math.pi) * dr.floor(kr / (2.0 * math.pi)))  # wrapped in float64
        sn, cs = dr.sincos(phase)
        parts += [amp * cs, amp * sn]
    return parts


def _count(stats: TraceStats, st: torch.Tensor, *, rays: int, amp_spp: int) -> None:
    """Add the tile's ray counts to ``stats``, reduced where the rays are (one small read back per tile)."""
    ok_t = (st & 1).bool()
    nd = st >> 8
    counts = torch.stack([*[((st >> b) & 1).sum() for b in range(5)], (ok_t & (nd > 0)).sum(),
                          nd.masked_fill(~ok_t, 0).max() if st.numel() else st.new_zeros(())]).tolist()
    stats.rays += rays
    stats.valid += counts[0]
    stats.behind_plane += counts[1]
    stats.escaped += counts[2]
    stats.capped += counts[3]
    stats.path_samples += counts[4] * amp_spp
    stats.delta_paths += counts[5]
    stats.max_delta_seen = max(stats.max_delta_seen, counts[6])
