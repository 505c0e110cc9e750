"""Wave path tracing on the hologram side: rays from a recording plane, Monte Carlo accumulation of the
complex field for every frame and color (paper Sec. 4.2-4.4, Eq. 5; docs/design.md §4).

For each pixel of the recording plane, N rays leave the pixel centre with directions uniform in solid
angle in the widest color's cone; they are mapped to world rays through T^-1 and traced as wave paths
(:func:`holocore.trace.kernel.trace_wave_paths`), which return the virtual image point P' and the radiance.
Ray generation, T, the wave paths and each ray's complex contribution run in one Dr.Jit kernel per tile;
only the F-frame accumulation (a gather of random-phase rows, scaled and summed) runs in torch. With
Q = T P' (float64), r = |Q - x| and theta the ray's angle to the axis,

    U_m(x) = (Omega / N) sum_rays A (r / cos theta) exp(i (s k r + phi_m(Q)))          (docs/design.md §4)

with s = +1 on the WRP (waves diverging from Q towards the viewer) and s = -1 on the SLM plane for the
direct method (waves converging to Q). A color only counts the rays inside its own cone (rays are shared
between colors where the cones allow it, docs/design.md §4). Every quantity but phi_m is shared by all frames.

The field is sampled at pixel centres (the rays start there, not jittered within the pixel): the field of a
pixel is the field at its centre, and a jittered start would blur it by the pixel aperture.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np
import torch

from holocore.trace.beams import BeamDepthTerms
from holocore.trace.mapping import HologramMap
from holocore.trace.tile import TileGeometry, trace_tile

__all__ = ["RecordingGrid", "TraceSettings", "TraceStats", "trace_field", "cell_major", "combined_cells"]

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
    delta_paths: int = 0
    seconds_trace: float = 0.0
    seconds_accumulate: float = 0.0
    max_delta_seen: int = 0
    path_samples: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def cell_major(bank: torch.Tensor) -> torch.Tensor:
    """A bank [F, H, W] as [H*W, F]: the F phasors of a cell side by side (a copy unless already so stored)."""
    return bank.permute(1, 2, 0).reshape(-1, bank.shape[0]).contiguous()


def combined_cells(banks: Sequence[torch.Tensor]) -> torch.Tensor:
    """Per-color banks [F, H, W] as one table [H*W, C, F]: a view when they are color slices of one cell-major
    [H, W, C, F] tensor (``pipeline.frame_banks`` builds them so), a copy otherwise."""
    b0 = banks[0]
    F, H, W = b0.shape
    C = len(banks)
    step = F * b0.element_size()
    if all(b.shape == b0.shape and b.dtype == b0.dtype and b.stride() == (1, W * C * F, C * F)
           and b.data_ptr() == b0.data_ptr() + c * step for c, b in enumerate(banks)):
        return torch.as_strided(b0, (H * W, C, F), (C * F, F, 1))
    return torch.stack([cell_major(b) for b in banks], dim=1)


_CHUNK_RAYS = 1 << 12  # rays per gather: the [rays, C, F] block stays in cache


def _accumulate_frames(cells: torch.Tensor, idx: torch.Tensor, base: torch.Tensor, n: int,
                       depth: Optional[BeamDepthTerms] = None, dz: Optional[torch.Tensor] = None,
                       drec: Optional[torch.Tensor] = None) -> torch.Tensor:
    """sum over each pixel's n rays of base * exp(i phi_m(Q)), for all colors and frames m at once; complex64
    [P, C, F]. ``depth``: directional frames' per-frame depth factor of each ray (its ``dz``), Eq. B1.

    ``cells``: [H*W, C, F] (see :func:`combined_cells`), ``idx``: bank cell of each ray, ``base``: complex64
    [P*n, C] (pixel-major). Per chunk of pixels: gather the rays' rows [p, n, C, F], scale them by base and sum
    over n (one gather serves every color: the image point, hence the cell, is the same for all).
    """
    P, (C, F) = base.shape[0] // n, cells.shape[1:]
    out = torch.empty((P, C, F), dtype=torch.complex64, device=cells.device)
    step = max(1, _CHUNK_RAYS // n)
    b = base.view(P, n, C, 1)
    terms = None if depth is None else depth.rays(base, dz, drec)
    for p0 in range(0, P, step):
        p1 = min(P, p0 + step)
        if depth is None:
            rows = cells.index_select(0, idx[p0 * n:p1 * n]).view(p1 - p0, n, C, F)
            torch.sum(rows * b[p0:p1], dim=1, out=out[p0:p1])
        else:
            a, b_ = p0 * n, p1 * n
            rows = cells.index_select(0, idx[a:b_]) * terms.factors(a, b_)
            torch.sum(rows.view(p1 - p0, n, C, F), dim=1, out=out[p0:p1])
    return out


@dataclass(frozen=True)
class RecordingGrid:
    """Where the rays are recorded (docs/design.md §3-4), in metres.

    ``plane_z_m == z_wrp_m``: the two-stage method's WRP; ``plane_z_m == 0``: the direct method on the SLM.
    ``planes``: several recording planes (:mod:`holocore.plan.wrp_planes`), (z_k, lo_k, hi_k, border_k) front to
    back, plane 0 the WRP itself: the rays still leave the WRP's pixels, and each ray's contribution is
    recorded on the plane whose slab (lo_k, hi_k] holds its image point, at the pixel where the ray crosses
    that plane, with r measured from that pixel's centre (the paper's Sec. 6); plane k's grid is the WRP's
    widened by border_k pixels on each side. None or one plane: the WRP alone.
    """

    wavelengths_m: tuple[float, ...]  # one per color (the lit ones)
    pitch_m: float  # pixel pitch of the plane (the SLM's)
    shape_hw: tuple[int, int]  # the plane's pixels (the SLM's)
    plane_z_m: float  # the plane the field is recorded on
    z_wrp_m: float  # the wave recording plane
    planes: Optional[tuple[tuple[float, float, float, int], ...]] = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "wavelengths_m", tuple(float(w) for w in self.wavelengths_m))
        object.__setattr__(self, "shape_hw", (int(self.shape_hw[0]), int(self.shape_hw[1])))
        if self.planes is not None:
            object.__setattr__(self, "planes", tuple(tuple(p) for p in self.planes))

    @property
    def several(self) -> bool:
        """Whether rays are recorded on more than one plane."""
        return self.planes is not None and len(self.planes) > 1


def trace_field(
    scene,
    hmap: HologramMap,
    grid: RecordingGrid,
    *,
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
    on_plane_rows: Optional[Callable[[int, int, torch.Tensor], None]] = None,
    depth_terms: Optional[BeamDepthTerms] = None,
) -> Optional[np.ndarray]:
    """Complex field on the plane ``grid.plane_z_m``, complex64 [F, C, H, W] (:class:`RecordingGrid`).

    With several recording planes (``grid.planes``) the rows of every plane stream out through
    ``on_plane_rows(k, r0, block)`` (block [F, C, rows, W + 2 border_k], each row once, in order).
    ``bank_phasors``: per color a complex64 tensor [F, H, W] of exp(i phi_m) (None: no random phase).
    ``integrator``: Mitsuba's ``path`` with ``settings.max_depth``, for the radiance samples beyond the
    first (``settings.amp_spp`` > 1); the first one is traced with the wave path itself.

    ``device``: where the torch work runs (default: the banks' device, else the CPU); on CUDA the kernel's
    outputs reach torch through DLPack without leaving the GPU. ``on_tile(r0, r1, block)``: receives each tile's
    rows r0..r1 of the field as a complex64 tensor [F, C, r1 - r0, W] on ``device`` (valid during the call)
    instead of one [F, C, H, W] array being filled and returned (the caller streams them; returns None).
    ``depth_terms``: directional frames (:mod:`holocore.trace.beams`): the banks hold Eq. B1's lateral part, these
    its depth part (with ``bank_phasors`` only).
    """
    H, W = grid.shape_hw
    C = len(grid.wavelengths_m)
    _check_banks(frames, bank_phasors, depth_terms, C)
    stats = stats if stats is not None else TraceStats()
    rows_per_tile = max(1, settings.tile_rays // (settings.spp * W))
    multi = grid.several
    if multi and (on_plane_rows is None or grid.plane_z_m != grid.z_wrp_m):
        raise ValueError("several recording planes need plane_z_m == z_wrp_m and on_plane_rows")
    geo = TileGeometry.make(hmap, wavelengths_m=grid.wavelengths_m, pitch_m=grid.pitch_m, shape_hw=grid.shape_hw,
                            plane_z_m=grid.plane_z_m, z_wrp_m=grid.z_wrp_m, spp=settings.spp,
                            planes=grid.planes if multi else None, ring_rows=rows_per_tile)
    dev = _trace_device(device, bank_phasors)
    out = None if on_tile is not None else torch.zeros((frames, C, H, W), dtype=torch.complex64, device=dev)
    cells = None if bank_phasors is None else combined_cells(bank_phasors)
    if cells is not None and cells.device != dev:
        raise ValueError(f"bank_phasors are on {cells.device}, the trace runs on {dev}")
    tiles = [(r0, min(H, r0 + rows_per_tile)) for r0 in range(0, H, rows_per_tile)]
    bands = _PlaneBands(geo, C, frames if cells is not None else 1, dev) if multi else None
    # Directional frames on a recording plane in front of the scene: soft-rimmed rays, each beam divided by its
    # point's spectrum there (beams.py, Eq. B2); the direct method records on the SLM, far from every point.
    taper = depth_terms.taper if depth_terms is not None and not geo.direct else None
    for ti, (r0, r1) in enumerate(tiles):
        t0 = time.perf_counter()
        tile = trace_tile(scene, geo, r0, r1, settings, integrator, radiance_cache, cells is not None,
                           seed=int((seed * 1_000_003 + ti) % (2**31)), stats=stats, device=dev,
                           want_dz=depth_terms is not None, taper=taper)
        _park_drjit_workers()
        t1 = time.perf_counter()
        block = None
        if bands is not None:  # several planes: every ray's contribution into its plane's rows
            bands.deposit(tile, cells, depth_terms)
            for k, a, blk in bands.flush(r1 if ti + 1 < len(tiles) else None):
                on_plane_rows(k, a, blk.expand(frames, *blk.shape[1:]))
        else:
            block = _tile_block(tile, cells, C=C, rows=r1 - r0, W=W, frames=frames, spp=settings.spp,
                                depth_terms=depth_terms, tapered=taper is not None)
        if block is not None and on_tile is not None:
            on_tile(r0, r1, block)
        elif block is not None:
            out[:, :, r0:r1] += block
        del tile, block
        stats.seconds_trace += t1 - t0
        stats.seconds_accumulate += time.perf_counter() - t1
        if progress is not None:
            progress("trace", ti + 1, len(tiles))
    return None if out is None else out.cpu().numpy()


def _check_banks(frames: int, bank_phasors, depth_terms: Optional[BeamDepthTerms], C: int) -> None:
    """ValueError unless there is a frame, a bank per colour (or none), and directional frames' depth terms come
    with banks and one wavenumber per colour."""
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    if bank_phasors is not None and len(bank_phasors) != C:
        raise ValueError("bank_phasors needs one bank per wavelength")
    if depth_terms is not None and (bank_phasors is None or len(depth_terms.ks) != C):
        raise ValueError("depth_terms need bank_phasors and one wavenumber per wavelength")


def _trace_device(device, bank_phasors) -> torch.device:
    """Where the torch work runs: ``device`` ("cuda" as the current GPU, which tensors call "cuda:0"), else the
    banks' device, else the CPU."""
    if device is None:
        return bank_phasors[0].device if bank_phasors is not None else torch.device("cpu")
    dev = torch.device(device)
    if dev.type == "cuda" and dev.index is None:
        dev = torch.device("cuda", torch.cuda.current_device())
    return dev


def _tile_block(tile: dict, cells, *, C: int, rows: int, W: int, frames: int, spp: int,
                depth_terms: Optional[BeamDepthTerms], tapered: bool) -> torch.Tensor:
    """A tile's rows of every frame, complex64 [F, C, rows, W]: one smooth-phase field for every frame (summed in
    the kernel), or with random phases every frame from the same rays (path reuse: one gather of phi_m(Q) rows
    for all colours)."""
    if cells is None:
        return torch.stack([tile[c].view(rows, W) for c in range(C)])[None].expand(frames, C, rows, W)
    base = torch.stack([tile[c] for c in range(C)], dim=1)
    acc = _accumulate_frames(cells, tile["idx"], base, spp, depth_terms, tile.get("dz"),
                             tile.get("drec") if tapered else None)  # [P, C, F]
    return acc.permute(2, 1, 0).reshape(frames, C, rows, W)


class _PlaneBands:
    """The rows of every recording plane that rays can still reach, as ring buffers in one flat table
    [sum_k ring_k W_k, C, F] (a ray's slot is computed in the kernel: geometry ``ring_offsets``). A WRP tile of
    rows r0..r1 reaches rows r0..r1 + 2 border_k of plane k, so after it every row below r1 is final."""

    def __init__(self, g, C: int, F: int, dev) -> None:
        self.g, self.C, self.F = g, C, F
        self.table = torch.zeros((g.ring_total, C, F), dtype=torch.complex64, device=dev)
        self.flushed = [0] * len(g.planes)

    def deposit(self, tile: dict, cells, depth: Optional[BeamDepthTerms] = None) -> None:
        base = torch.stack([tile[c] for c in range(self.C)], dim=1)  # [R, C] per ray
        pos = tile["pos"]
        terms = None if depth is None else depth.rays(base, tile["dz"], tile.get("drec"))
        # The sums run on the real and imaginary parts as float32 rows: torch's CPU index_add_ adds float rows
        # with vector instructions and complex ones element by element (half the speed; the same sums).
        table = torch.view_as_real(self.table).view(self.table.shape[0], -1)
        for a in range(0, base.shape[0], _CHUNK_RAYS):
            b = min(base.shape[0], a + _CHUNK_RAYS)
            if cells is None:
                add = base[a:b, :, None]
            else:
                add = cells.index_select(0, tile["idx"][a:b])
                add.mul_(base[a:b, :, None] if terms is None else terms.factors(a, b))
            table.index_add_(0, pos[a:b], torch.view_as_real(add).reshape(b - a, -1))

    def flush(self, upto: Optional[int]):
        """(k, first row, block [F, C, rows, W_k]) for the rows of each plane below ``upto`` (None: all)."""
        g = self.g
        for k, (_z, _lo, _hi, bord) in enumerate(g.planes):
            Hk, Wk = g.H + 2 * bord, g.W + 2 * bord
            end = Hk if upto is None else min(Hk, upto)
            ring, off = g.ring_heights[k], g.ring_offsets[k]
            view = self.table[off:off + ring * Wk].view(ring, Wk, self.C, self.F)
            while self.flushed[k] < end:
                a = self.flushed[k]
                n = min(end - a, ring - a % ring)  # up to the ring's end
                rows = view[a % ring:a % ring + n]
                yield k, a, rows.permute(3, 2, 0, 1).clone()
                rows.zero_()
                self.flushed[k] = a + n


def _park_drjit_workers() -> None:
    """Let Dr.Jit's idle workers sleep now. After a kernel they spin for ~20 ms (measured: 21 ms of CPU during a
    50 ms sleep on 2 cores), which halves the speed of the torch work that follows; resizing the pool parks
    them at once (0.2 ms)."""
    import drjit as dr

    n = dr.thread_count()
    dr.set_thread_count(1)
    dr.set_thread_count(n)
