"""Wave path tracing on the hologram side: rays from a recording plane, Monte Carlo accumulation of the
complex field for every frame and color (paper Sec. 4.2-4.4, Eq. 5; DESIGN.md §4).

For each pixel of the recording plane, N rays leave the pixel centre with directions uniform in solid
angle in the widest color's cone; they are mapped to world rays through T^-1 and traced as wave paths
(:func:`holocore.wavekernel.trace_wave_paths`), which return the virtual image point P' and the radiance.
Ray generation, T, the wave paths and each ray's complex contribution run in one Dr.Jit kernel per tile;
only the F-frame accumulation (a gather of random-phase rows, scaled and summed) runs in torch. With
Q = T P' (float64), r = |Q - x| and theta the ray's angle to the axis,

    U_m(x) = (Omega / N) sum_rays A (r / cos theta) exp(i (s k r + phi_m(Q)))          (DESIGN §4)

with s = +1 on the WRP (waves diverging from Q towards the viewer) and s = -1 on the SLM plane for the
direct method (waves converging to Q). A color only counts the rays inside its own cone (rays are shared
between colors where the cones allow it, DESIGN §4). Every quantity but phi_m is shared by all frames.

The field is sampled at pixel centres (the rays start there, not jittered within the pixel): the field of a
pixel is the field at its centre, and a jittered start would blur it by the pixel aperture.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Callable, Optional, Sequence

import numpy as np
import torch

from holocore.mapping import HologramMap
from holocore.mitsuba_env import mitsuba

__all__ = ["TraceSettings", "TraceStats", "trace_field", "channel_of", "cell_major", "combined_cells"]

ProgressFn = Callable[[str, int, int], None]


@dataclass(frozen=True)
class TraceSettings:
    """How to trace. ``spp``: rays per recording-plane pixel in the widest cone."""

    spp: int = 16
    amp_spp: int = 1
    max_delta: int = 8
    max_depth: int = 6  # incoherent path depth from the image point P (Mitsuba's convention)
    tile_rays: int = 1 << 19
    random_phase: bool = True
    stratified: bool = True  # a pixel's rays as a scrambled Hammersley set instead of independent directions

    def __post_init__(self) -> None:
        if not 1 <= self.spp <= 1_000_000:
            raise ValueError(f"spp must be in 1..1e6, got {self.spp}")
        if not 1 <= self.amp_spp <= 4096:
            raise ValueError(f"amp_spp must be in 1..4096, got {self.amp_spp}")
        if not 0 <= self.max_delta <= 64:
            raise ValueError(f"max_delta must be in 0..64, got {self.max_delta}")
        if not 1 <= self.max_depth <= 1024:
            raise ValueError(f"max_depth must be in 1..1024, got {self.max_depth}")


@dataclass
class TraceStats:
    rays: int = 0
    valid: int = 0
    escaped: int = 0
    capped: int = 0
    behind_plane: int = 0
    other_plane: int = 0  # image points that another recording plane records
    delta_paths: int = 0
    seconds_trace: float = 0.0
    seconds_accumulate: float = 0.0
    max_delta_seen: int = 0
    path_samples: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def channel_of(wavelength_m: float) -> int:
    """RGB channel holding a laser line (DESIGN §4): R from 590 nm, G 490-590 nm, B below."""
    nm = wavelength_m * 1e9
    return 0 if nm >= 590.0 else (1 if nm >= 490.0 else 2)


def cell_major(bank: torch.Tensor) -> torch.Tensor:
    """A bank [F, H, W] as [H*W, F]: the F phasors of a cell side by side (a copy unless already so stored)."""
    return bank.permute(1, 2, 0).reshape(-1, bank.shape[0]).contiguous()


def combined_cells(banks: Sequence[torch.Tensor]) -> torch.Tensor:
    """Per-color banks [F, H, W] as one table [H*W, C, F]: a view when they are color slices of one cell-major
    [H, W, C, F] tensor (``pipeline._banks`` builds them so), a copy otherwise."""
    b0 = banks[0]
    F, H, W = b0.shape
    C = len(banks)
    step = F * b0.element_size()
    if all(b.shape == b0.shape and b.dtype == b0.dtype and b.stride() == (1, W * C * F, C * F)
           and b.data_ptr() == b0.data_ptr() + c * step for c, b in enumerate(banks)):
        return torch.as_strided(b0, (H * W, C, F), (C * F, F, 1))
    return torch.stack([cell_major(b) for b in banks], dim=1)


_CHUNK_RAYS = 1 << 12  # rays per gather: the [rays, C, F] block stays in cache


def _accumulate_frames(cells: torch.Tensor, idx: torch.Tensor, base: torch.Tensor, n: int) -> torch.Tensor:
    """sum over each pixel's n rays of base * exp(i phi_m(Q)), for all colors and frames m at once; complex64
    [P, C, F].

    ``cells``: [H*W, C, F] (see :func:`combined_cells`), ``idx``: bank cell of each ray, ``base``: complex64
    [P*n, C] (pixel-major). Per chunk of pixels: gather the rays' rows [p, n, C, F], scale them by base and sum
    over n (one gather serves every color: the image point, hence the cell, is the same for all).
    """
    P, (C, F) = base.shape[0] // n, cells.shape[1:]
    out = torch.empty((P, C, F), dtype=torch.complex64, device=cells.device)
    step = max(1, _CHUNK_RAYS // n)
    b = base.view(P, n, C, 1)
    for p0 in range(0, P, step):
        p1 = min(P, p0 + step)
        rows = cells.index_select(0, idx[p0 * n:p1 * n]).view(p1 - p0, n, C, F)
        torch.sum(rows * b[p0:p1], dim=1, out=out[p0:p1])
    return out


def trace_field(
    scene,
    hmap: HologramMap,
    *,
    wavelengths_m: Sequence[float],
    pitch_m: float,
    shape_hw: tuple[int, int],
    plane_z_m: float,
    z_wrp_m: float,
    frames: int,
    settings: TraceSettings,
    integrator,
    seed: int,
    bank_phasors: Optional[Sequence[torch.Tensor]] = None,
    radiance_cache=None,
    progress: Optional[ProgressFn] = None,
    stats: Optional[TraceStats] = None,
    device: Optional[torch.device] = None,
    on_tile: Optional[Callable[[int, int, torch.Tensor], None]] = None,
    records_m: Optional[tuple[float, float]] = None,
) -> Optional[np.ndarray]:
    """Complex field on the plane z = plane_z_m, complex64 [F, C, H, W].

    ``plane_z_m == z_wrp_m``: the two-stage method's WRP. ``plane_z_m == 0``: the direct method on the SLM.
    A plane between them is one of several recording planes (:mod:`holocore.wrp_planes`): its rays start
    where they cross the WRP (in air, in front of every surface) and it records only the image points with
    hologram depth in ``records_m`` = (lo, hi] (default: everything in front of the WRP).
    ``bank_phasors``: per color a complex64 tensor [F, H, W] of exp(i phi_m) (None: no random phase).
    ``integrator``: Mitsuba's ``path`` with ``settings.max_depth``, for the radiance samples beyond the
    first (``settings.amp_spp`` > 1); the first one is traced with the wave path itself.

    ``device``: where the torch work runs (default: the banks' device, else the CPU); on CUDA the kernel's
    outputs reach torch through DLPack without leaving the GPU. ``on_tile(r0, r1, block)``: receives each tile's
    rows r0..r1 of the field as a complex64 tensor [F, C, r1 - r0, W] on ``device`` (valid during the call)
    instead of one [F, C, H, W] array being filled and returned (the caller streams them; returns None).
    """
    H, W = shape_hw
    C = len(wavelengths_m)
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    if bank_phasors is not None and len(bank_phasors) != C:
        raise ValueError("bank_phasors needs one bank per wavelength")
    stats = stats if stats is not None else TraceStats()
    geo = _Geometry.make(hmap, wavelengths_m=wavelengths_m, pitch_m=pitch_m, shape_hw=shape_hw,
                         plane_z_m=plane_z_m, z_wrp_m=z_wrp_m, spp=settings.spp, records_m=records_m,
                         bank_hw=None if bank_phasors is None else tuple(bank_phasors[0].shape[1:]))
    rows_per_tile = max(1, settings.tile_rays // (settings.spp * W))
    if device is not None:
        dev = torch.device(device)
    else:
        dev = bank_phasors[0].device if bank_phasors is not None else torch.device("cpu")
    out = None if on_tile is not None else torch.zeros((frames, C, H, W), dtype=torch.complex64, device=dev)
    cells = None if bank_phasors is None else combined_cells(bank_phasors)
    if cells is not None and cells.device != dev:
        raise ValueError(f"bank_phasors are on {cells.device}, the trace runs on {dev}")
    tiles = [(r0, min(H, r0 + rows_per_tile)) for r0 in range(0, H, rows_per_tile)]
    for ti, (r0, r1) in enumerate(tiles):
        t0 = time.perf_counter()
        tile = _trace_tile(scene, geo, r0, r1, settings, integrator, radiance_cache, cells is not None,
                           seed=int((seed * 1_000_003 + ti) % (2**31)), stats=stats, device=dev)
        _park_drjit_workers()
        t1 = time.perf_counter()
        if cells is None:  # one smooth-phase field, the same for every frame (summed in the kernel)
            block = torch.stack([tile[c].view(r1 - r0, W) for c in range(C)])[None].expand(frames, C, r1 - r0, W)
        else:  # path reuse: every frame from the same rays (one gather of phi_m(Q) rows for all colors)
            base = torch.stack([tile[c] for c in range(C)], dim=1)
            acc = _accumulate_frames(cells, tile["idx"], base, settings.spp)  # [P, C, F]
            block = acc.permute(2, 1, 0).reshape(frames, C, r1 - r0, W)
        if on_tile is not None:
            on_tile(r0, r1, block)
        else:
            out[:, :, r0:r1] += block
        del tile, block
        stats.seconds_trace += t1 - t0
        stats.seconds_accumulate += time.perf_counter() - t1
        if progress is not None:
            progress("trace", ti + 1, len(tiles))
    return None if out is None else out.cpu().numpy()


def _park_drjit_workers() -> None:
    """Let Dr.Jit's idle workers sleep now. After a kernel they spin for ~20 ms (measured: 21 ms of CPU during a
    50 ms sleep on 2 cores), which halves the speed of the torch work that follows; resizing the pool parks
    them at once (0.2 ms)."""
    import drjit as dr

    n = dr.thread_count()
    dr.set_thread_count(1)
    dr.set_thread_count(n)


@dataclass(frozen=True)
class _Geometry:
    """What every tile shares: the plane, the cones, T and its inverse as plain numbers."""

    H: int
    W: int
    pitch: float
    plane_z: float
    z_wrp: float
    z_mid: float
    direct: bool  # the plane lies behind the WRP: rays start where they cross the WRP
    bank_hw: tuple  # the random-phase bank's grid (the SLM's); a deeper plane's grid may be wider
    z_lo: float  # the image points recorded: lo < q_z <= hi (hologram z)
    z_hi: float
    sign: float  # +1: image points behind the plane (diverging waves), -1: in front (the SLM, converging)
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

    @classmethod
    def make(cls, hmap: HologramMap, *, wavelengths_m, pitch_m, shape_hw, plane_z_m, z_wrp_m, spp,
             records_m=None, bank_hw=None) -> "_Geometry":
        thetas = [min(math.pi / 2, math.asin(min(1.0, lam / (2 * pitch_m)))) for lam in wavelengths_m]
        # Keep rays off exactly grazing (theta = 90 deg gives cos = 0 and an infinite weight r / cos theta).
        thetas = [min(t, math.radians(89.0)) for t in thetas]
        th_max = max(thetas)
        lo, hi = (-1e30, z_wrp_m) if records_m is None else (max(-1e30, records_m[0]), min(z_wrp_m, records_m[1]))
        if not lo < hi:
            raise ValueError(f"empty recording slab {records_m}")
        if records_m is not None and lo < plane_z_m < hi:
            raise ValueError(f"a recording plane at {plane_z_m} m cannot record image points on both sides")
        return cls(bank_hw=tuple(bank_hw or shape_hw), z_lo=lo, z_hi=hi, sign=1.0 if plane_z_m >= hi else -1.0,H=shape_hw[0], W=shape_hw[1], pitch=pitch_m, plane_z=plane_z_m, z_wrp=z_wrp_m,
                   z_mid=hmap.z_inf_m + 0.5 * (z_wrp_m - hmap.z_inf_m), direct=plane_z_m < z_wrp_m,
                   f=hmap.focal_length_m, z_inf=hmap.z_inf_m,
                   rot=tuple(map(float, hmap._rot.ravel())), rot_inv=tuple(map(float, hmap._rot_inv.ravel())),
                   origin=tuple(map(float, hmap._origin)), cos_max=math.cos(th_max),
                   omega=2.0 * math.pi * (1.0 - math.cos(th_max)), spp=spp,
                   ks=tuple(2.0 * math.pi / lam for lam in wavelengths_m),
                   cos_lim=tuple(math.cos(t) for t in thetas), chans=tuple(channel_of(lam) for lam in wavelengths_m))


def _mat(mi, m: tuple, v):
    return mi.Vector3d(m[0] * v.x + m[1] * v.y + m[2] * v.z, m[3] * v.x + m[4] * v.y + m[5] * v.z,
                       m[6] * v.x + m[7] * v.y + m[8] * v.z)


def _holo_to_camera(mi, g, q):
    zc = g.f * g.f / (q.z - g.z_inf)
    return mi.Vector3d(q.x * zc / g.f, q.y * zc / g.f, zc)


def _opaque(mi, g: _Geometry) -> SimpleNamespace:
    """The geometry as kernel parameters rather than constants: one compiled kernel serves every resolution,
    pitch, focal length, spp and tile (a megakernel takes seconds to compile)."""
    import drjit as dr

    def f64(v):
        return dr.opaque(mi.Float64, float(v))

    o = SimpleNamespace(**{k: f64(getattr(g, k)) for k in ("pitch", "plane_z", "z_wrp", "z_mid", "f", "z_inf",
                                                            "cos_max", "omega", "z_lo", "z_hi", "sign")})
    o.Hf, o.Wf, o.W, o.N = f64(g.H), f64(g.W), dr.opaque(mi.UInt32, g.W), dr.opaque(mi.UInt32, g.spp)
    o.Hb, o.Wb, o.Wbu = f64(g.bank_hw[0]), f64(g.bank_hw[1]), dr.opaque(mi.UInt32, g.bank_hw[1])
    o.rot, o.rot_inv = tuple(map(f64, g.rot)), tuple(map(f64, g.rot_inv))
    o.origin, o.ks, o.cos_lim = tuple(map(f64, g.origin)), tuple(map(f64, g.ks)), tuple(map(f64, g.cos_lim))
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


def _to_torch(x, dev: torch.device) -> torch.Tensor:
    """A Dr.Jit array as a torch tensor on ``dev``: zero-copy through DLPack on the GPU, through numpy on the
    CPU (the tensors' values are the same)."""
    if dev.type == "cuda":
        return x.torch()
    return torch.from_numpy(np.asarray(x))


def _trace_tile(scene, g: _Geometry, r0: int, r1: int, settings: TraceSettings, integrator, radiance_cache,
                want_cells: bool, *, seed: int, stats: TraceStats, device: torch.device) -> dict:
    """Rows r0..r1 of the plane, all in Dr.Jit: ray generation, wave paths, the complex contribution of every
    ray. Returns per color a complex64 tensor (per pixel when ``want_cells`` is False, else per ray, pixel-
    major) and, with ``want_cells``, the bank cell of every ray's image point ("idx")."""
    mi = mitsuba()
    import drjit as dr

    from holocore.wavekernel import trace_wave_paths

    F64, V3d, N = mi.Float64, mi.Vector3d, settings.spp
    R = (r1 - r0) * g.W * N
    o = _opaque(mi, g)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, R)
    pix = dr.arange(mi.UInt32, R) // o.N + dr.opaque(mi.UInt32, r0 * g.W)
    s = V3d((F64(pix % o.W) - (o.Wf - 1.0) * 0.5) * o.pitch, ((o.Hf - 1.0) * 0.5 - F64(pix // o.W)) * o.pitch,
            o.plane_z)
    # Directions uniform in solid angle in the widest cone around -z: a pixel's N rays form a scrambled
    # Hammersley set (stratified; each ray still uniform on its own, so the estimate stays unbiased), or N
    # independent samples.
    u = _pixel_directions(mi, pix, o.N, seed) if settings.stratified else sampler.next_2d()
    cos_t = 1.0 - F64(u.x) * (1.0 - o.cos_max)
    sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
    sp, cp = dr.sincos(2.0 * math.pi * F64(u.y))
    dirs = V3d(sin_t * cp, sin_t * sp, -cos_t)
    if g.direct:
        # Rays leave the SLM towards +z; the world ray is the same line, traced from where it crosses the
        # WRP, back into the scene (DESIGN §4; paper Fig. 5's baseline).
        x = s - ((o.z_wrp - o.plane_z) / cos_t) * dirs
    else:
        x = s
    # T^-1 of the hologram ray (DESIGN §3): through x and the point where it reaches z_mid.
    c0 = _holo_to_camera(mi, o, x)
    c1 = _holo_to_camera(mi, o, x + ((o.z_mid - x.z) / dirs.z) * dirs)
    vc = dr.normalize(c1 - c0)
    o_w = _mat(mi, o.rot, c0) + V3d(*o.origin)
    v_w = dr.normalize(_mat(mi, o.rot, vc))
    wp = trace_wave_paths(scene, mi.Point3d(o_w), v_w, sampler, max_delta=settings.max_delta,
                          max_depth=settings.max_depth, amp_spp=settings.amp_spp, integrator=integrator,
                          radiance_cache=radiance_cache)
    # Virtual image point and its hologram position, float64 (DESIGN §2: long lengths in float64).
    cv = c0 + wp.d * _mat(mi, o.rot_inv, v_w)
    q = V3d(o.f * cv.x / cv.z, o.f * cv.y / cv.z, o.z_inf + o.f * o.f / cv.z)
    ok = wp.valid & (cv.z > 0) & dr.isfinite(q.x) & dr.isfinite(q.y) & dr.isfinite(q.z) & (q.z < o.z_wrp)
    slab = (q.z > o.z_lo) & (q.z <= o.z_hi)  # this plane's slab (several recording planes)
    elsewhere = ok & ~slab
    ok &= slab
    q = dr.select(ok, q, s)
    r = dr.norm(q - s)
    weight = dr.select(ok, (o.omega / F64(o.N)) * r / cos_t, 0.0)
    parts = []
    for c in range(len(g.ks)):
        inside = cos_t >= o.cos_lim[c] - 1e-15
        amp = mi.Float(dr.select(inside, dr.sqrt(F64(wp.radiance[g.chans[c]])) * weight, 0.0))
        kr = o.sign * o.ks[c] * r
        phase = mi.Float(kr - (2.0 * math.pi) * dr.floor(kr / (2.0 * math.pi)))  # wrapped in float64
        sn, cs = dr.sincos(phase)
        parts += [amp * cs, amp * sn]
    idx = None
    if want_cells:
        j = dr.round(q.x / o.pitch + (o.Wb - 1.0) * 0.5)
        i = dr.round((o.Hb - 1.0) * 0.5 - q.y / o.pitch)
        j, i = j - o.Wb * dr.floor(j / o.Wb), i - o.Hb * dr.floor(i / o.Hb)  # periodic wrap (DESIGN §4)
        idx = mi.UInt32(i) * o.Wbu + mi.UInt32(j)
    # Per-ray status in one word (evaluated with the rest, read once): bit 0 ok, 1 behind the plane, 2 escaped,
    # 3 capped, 4 sampled by path tracing, 5 recorded by another plane, bits 8.. delta bounces.
    status = (mi.UInt32(ok) | (mi.UInt32(wp.valid & ~ok & ~elsewhere) << 1) | (mi.UInt32(wp.escaped) << 2)
              | (mi.UInt32(wp.capped) << 3) | (mi.UInt32(wp.sampled) << 4) | (mi.UInt32(elsewhere) << 5)
              | (wp.n_delta << 8))
    dr.eval(parts, idx, status)  # the one kernel: rays, wave paths, contributions
    if not want_cells:  # sum each pixel's N rays (the rays are pixel-major)
        parts = [dr.block_sum(x, N) for x in parts]
        dr.eval(parts)
    if device.type == "cuda":
        dr.sync_thread()  # Dr.Jit's kernels run on its own stream: done before torch reads their outputs
    out = {c: torch.complex(_to_torch(parts[2 * c], device), _to_torch(parts[2 * c + 1], device))
           for c in range(len(g.ks))}
    if want_cells:
        out["idx"] = _to_torch(idx, device).to(torch.int64)
    # The ray counts, reduced where the rays are (one small read back per tile).
    st = _to_torch(status, device).to(torch.int64)
    ok_t = (st & 1).bool()
    nd = st >> 8
    counts = torch.stack([*[((st >> b) & 1).sum() for b in range(5)], (ok_t & (nd > 0)).sum(),
                          nd.masked_fill(~ok_t, 0).max() if st.numel() else st.new_zeros(()),
                          ((st >> 5) & 1).sum()]).tolist()
    stats.rays += R
    stats.valid += counts[0]
    stats.behind_plane += counts[1]
    stats.escaped += counts[2]
    stats.capped += counts[3]
    stats.path_samples += counts[4] * settings.amp_spp
    stats.delta_paths += counts[5]
    stats.max_delta_seen = max(stats.max_delta_seen, counts[6])
    stats.other_plane += counts[7]
    return out
