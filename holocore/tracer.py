"""Wave path tracing on the hologram side: rays from a recording plane, Monte Carlo accumulation of the
complex field for every frame and color (paper Sec. 4.2-4.4, Eq. 5; DESIGN.md §4).

For each pixel of the recording plane, N rays leave the pixel centre with directions uniform in solid
angle in the widest color's cone; they are mapped to world rays through T^-1 and traced by
:func:`holocore.wavetrace.trace_chain`, which returns the virtual image point P' and the radiance. With
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
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np
import torch

from holocore.mapping import HologramMap
from holocore.wavetrace import trace_chain

__all__ = ["TraceSettings", "TraceStats", "trace_field", "channel_of", "cone_directions", "cell_major"]

ProgressFn = Callable[[str, int, int], None]


@dataclass(frozen=True)
class TraceSettings:
    """How to trace. ``spp``: rays per recording-plane pixel in the widest cone."""

    spp: int = 16
    amp_spp: int = 1
    max_delta: int = 8
    tile_rays: int = 1 << 19
    random_phase: bool = True

    def __post_init__(self) -> None:
        if not 1 <= self.spp <= 1_000_000:
            raise ValueError(f"spp must be in 1..1e6, got {self.spp}")
        if not 1 <= self.amp_spp <= 4096:
            raise ValueError(f"amp_spp must be in 1..4096, got {self.amp_spp}")
        if not 0 <= self.max_delta <= 64:
            raise ValueError(f"max_delta must be in 0..64, got {self.max_delta}")


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


def channel_of(wavelength_m: float) -> int:
    """RGB channel holding a laser line (DESIGN §4): R from 590 nm, G 490-590 nm, B below."""
    nm = wavelength_m * 1e9
    return 0 if nm >= 590.0 else (1 if nm >= 490.0 else 2)


def cone_directions(n: int, theta_max: float, rng: np.random.Generator) -> np.ndarray:
    """n unit vectors uniform in solid angle in the cone of half-angle theta_max around -z; float64 [n, 3]."""
    cos_max = math.cos(theta_max)
    cos_t = 1.0 - rng.random(n) * (1.0 - cos_max)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * math.pi * rng.random(n)
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), -cos_t], axis=1)


def _pixel_centres(rows: np.ndarray, W: int, H: int, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """x, y (m) of pixel centres for the given rows, all columns (DESIGN §3), row-major."""
    cols = np.arange(W, dtype=np.float64)
    x = (cols - (W - 1) / 2.0) * pitch
    y = ((H - 1) / 2.0 - rows.astype(np.float64)) * pitch
    return np.tile(x, len(rows)), np.repeat(y, W)


def _bank_index(qx: np.ndarray, qy: np.ndarray, H: int, W: int, pitch: float) -> np.ndarray:
    """Flat index of the bank cell under (qx, qy), periodic wrap (DESIGN §4)."""
    j = np.rint(qx / pitch + (W - 1) / 2.0).astype(np.int64) % W
    i = np.rint((H - 1) / 2.0 - qy / pitch).astype(np.int64) % H
    return i * W + j


def cell_major(bank: torch.Tensor) -> torch.Tensor:
    """A bank [F, H, W] as [H*W, F]: the F phasors of a cell side by side. Free (a view) when the bank was
    built that way (``pipeline._banks`` does); a copy otherwise."""
    return bank.permute(1, 2, 0).reshape(-1, bank.shape[0]).contiguous()


_CHUNK_RAYS = 1 << 14  # rays per gather: the [rays, F] block stays in cache


def _accumulate_frames(cells: torch.Tensor, idx: torch.Tensor, base: torch.Tensor, n: int) -> torch.Tensor:
    """sum over each pixel's n rays of base * exp(i phi_m(Q)), for all frames m at once; complex64 [P, F].

    ``cells``: [H*W, F] (see :func:`cell_major`), ``idx``: bank cell of each ray, ``base``: complex64 [P*n]
    (pixel-major). Per chunk of pixels: gather the rays' rows [p, n, F], then a batched [1, n] x [n, F] product.
    """
    P, F = base.numel() // n, cells.shape[1]
    out = torch.empty((P, 1, F), dtype=torch.complex64)
    step = max(1, _CHUNK_RAYS // n)
    b = base.view(P, 1, n)
    for p0 in range(0, P, step):
        p1 = min(P, p0 + step)
        rows = cells.index_select(0, idx[p0 * n:p1 * n]).view(p1 - p0, n, F)
        torch.bmm(b[p0:p1], rows, out=out[p0:p1])
    return out.view(P, F)


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
) -> np.ndarray:
    """Complex field on the plane z = plane_z_m, complex64 [F, C, H, W].

    ``plane_z_m == z_wrp_m``: the two-stage method's WRP. ``plane_z_m == 0``: the direct method on the SLM.
    ``bank_phasors``: per color a complex64 tensor [F, H, W] of exp(i phi_m) (None: no random phase).
    """
    H, W = shape_hw
    C = len(wavelengths_m)
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    if bank_phasors is not None and len(bank_phasors) != C:
        raise ValueError("bank_phasors needs one bank per wavelength")
    direct = plane_z_m < z_wrp_m
    stats = stats if stats is not None else TraceStats()
    thetas = [min(math.pi / 2, math.asin(min(1.0, lam / (2 * pitch_m)))) for lam in wavelengths_m]
    # Keep rays off exactly grazing (theta = 90 deg gives cos = 0 and an infinite weight r / cos theta).
    thetas = [min(t, math.radians(89.0)) for t in thetas]
    th_max = max(thetas)
    omega = 2.0 * math.pi * (1.0 - math.cos(th_max))
    N = settings.spp
    rows_per_tile = max(1, settings.tile_rays // (N * W))
    out = torch.zeros((frames, C, H, W), dtype=torch.complex64)
    sign = -1.0 if direct else 1.0
    z_mid = hmap.z_inf_m + 0.5 * (z_wrp_m - hmap.z_inf_m)
    chans = [channel_of(lam) for lam in wavelengths_m]
    ks = [2.0 * math.pi / lam for lam in wavelengths_m]
    cos_lim = [math.cos(t) for t in thetas]

    cells = None if bank_phasors is None else [cell_major(b) for b in bank_phasors]
    tiles = [np.arange(r0, min(H, r0 + rows_per_tile)) for r0 in range(0, H, rows_per_tile)]
    for ti, rows in enumerate(tiles):
        t0 = time.perf_counter()
        rng = np.random.default_rng([seed, 7919, ti])
        px, py = _pixel_centres(rows, W, H, pitch_m)
        npix = px.size
        R = npix * N
        dirs = cone_directions(R, th_max, rng)  # around -z
        sx = np.repeat(px, N)
        sy = np.repeat(py, N)
        if direct:
            # Rays leave the SLM towards +z (u = -dirs); the world ray is the same line, traced from where it
            # crosses the WRP, back into the scene (DESIGN §4; paper Fig. 5's baseline).
            s = np.stack([sx, sy, np.full(R, plane_z_m)], axis=1)
            u = -dirs
            x = s + ((z_wrp_m - plane_z_m) / u[:, 2])[:, None] * u
        else:
            s = np.stack([sx, sy, np.full(R, z_wrp_m)], axis=1)
            x = s
        c0, vc = hmap.holo_rays_to_camera(x, dirs, z_mid=z_mid)
        o_w = hmap.camera_to_world(c0)
        v_w = hmap.camera_dir_to_world(vc)
        res = trace_chain(scene, o_w, v_w, max_delta=settings.max_delta, amp_spp=settings.amp_spp,
                          integrator=integrator, seed=int((seed * 1_000_003 + ti) % (2**31)),
                          radiance_cache=radiance_cache)
        t1 = time.perf_counter()
        # Virtual image point and its hologram position, float64 (DESIGN §2: long lengths in float64).
        c_virtual = hmap.world_to_camera(o_w + res.d[:, None] * v_w)
        zc = c_virtual[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            q = hmap.camera_to_holo(c_virtual)
        ok = res.valid & (zc > 0) & np.isfinite(q).all(axis=1) & (q[:, 2] < z_wrp_m)
        stats.behind_plane += int(np.count_nonzero(res.valid & ~ok))
        r = np.linalg.norm(q - s, axis=1)
        cos_t = -dirs[:, 2]
        weight = np.where(ok, (omega / N) * r / cos_t, 0.0)
        idx = torch.from_numpy(_bank_index(q[:, 0], q[:, 1], H, W, pitch_m)) if bank_phasors is not None else None
        for c in range(C):
            inside = ok & (cos_t >= cos_lim[c] - 1e-15)
            amp = np.sqrt(res.radiance[:, chans[c]].astype(np.float64)) * weight * inside
            phase = np.mod(sign * ks[c] * r, 2.0 * math.pi)  # wrapped in float64 before the cast
            base = torch.polar(torch.from_numpy(amp.astype(np.float32)), torch.from_numpy(phase.astype(np.float32)))
            sl = (slice(None), c, slice(int(rows[0]), int(rows[-1]) + 1), slice(None))
            if bank_phasors is None:  # one smooth-phase field, the same for every frame
                out[sl] += base.view(len(rows), W, N).sum(dim=2)[None]
            else:  # path reuse: every frame from the same rays (one gather of phi_m(Q) rows, one matmul)
                out[sl] += _accumulate_frames(cells[c], idx, base, N).t().view(frames, len(rows), W)
        stats.rays += R
        stats.valid += int(np.count_nonzero(ok))
        stats.escaped += int(np.count_nonzero(res.escaped))
        stats.capped += int(np.count_nonzero(res.capped))
        stats.path_samples += res.path_samples
        stats.delta_paths += int(np.count_nonzero(ok & (res.n_delta > 0)))
        stats.max_delta_seen = max(stats.max_delta_seen, int(res.n_delta[ok].max()) if ok.any() else 0)
        stats.seconds_trace += t1 - t0
        stats.seconds_accumulate += time.perf_counter() - t1
        if progress is not None:
            progress("trace", ti + 1, len(tiles))
    return out.numpy()
