"""Several recording planes chained to the WRP by the band-limited ASM (paper Sec. 6; docs/design.md §5): one
trace records every ray on the plane in front of its image point; each deeper plane, held in a scratch file on a
grid wider than the WRP's by its border, is equalised, propagated to the WRP, cropped to its window and added.

Why straight to the WRP rather than plane by plane: the ASM is linear and a plane's grid is wider than the WRP's
by exactly the reach from it to the WRP, so the sum is the same, and each plane then costs one FFT pair for its
equaliser and its propagation together (on one grid holding both paddings), with no read-add-write of the planes
in between. Units: metres."""

from __future__ import annotations

import time

import numpy as np
import torch

from holocore.io import ScratchArray
from holocore.optics.grids import reach_grid, smooth_at_least
from holocore.optics.propagation import asm, clear_cache
from holocore.runtime.heap import heap_reuse

__all__ = ["chain_planes"]


def _scale_wrp(sink, lams, *, f0, n_f, fp, lit_idx, scale, equalisers, optics, dev) -> None:
    """Scale and equalise the WRP's own recording in the sink's traced field (frames f0..f0+n_f), in place,
    before the deeper planes are added to it; colours that neither applies to are left as they are."""
    for ci, lam in enumerate(lams):
        active = equalisers is not None and equalisers[0].active(ci)
        if not active and scale == 1.0:
            continue
        for a in range(0, n_f, fp):
            e = min(n_f, a + fp)
            u = torch.from_numpy(np.ascontiguousarray(sink.read_traced(f0 + a, f0 + e, lit_idx[ci]))).to(dev)
            if scale != 1.0:
                u = u * scale
            v = equalisers[0].apply(u, ci, lam, optics.pitch_m) if active else u
            sink.write_rows(f0 + a, [lit_idx[ci]], 0, v.cpu().numpy()[:, None])
            del u, v


def _add_to_wrp(k, planes, sink, scratch, *, lams, border, step, f0, n_f, lit_idx, scale, equalisers, optics,
                dev) -> None:
    """Plane k's own recording (k >= 1), scaled, equalised and propagated by the ASM to the WRP in one transform
    pair (the equaliser's gain and the transfer function on one grid: :func:`_to_wrp`), cropped to the WRP's
    window and added to the sink's traced field, a chunk of ``step`` frames at a time. Closes plane k's scratch
    file."""
    H, W = optics.resolution_hw
    dz = planes.z_m[0] - planes.z_m[k]
    for a in range(0, n_f, step):
        e = min(n_f, a + step)
        for ci, lam in enumerate(lams):
            u = torch.from_numpy(scratch[k].read_fc(a, e, ci)).to(dev)
            if scale != 1.0:
                u = u * scale
            eq = None if equalisers is None or not equalisers[k].active(ci) else equalisers[k]
            v = _to_wrp(u, dz, lam, optics.pitch_m, eq, ci)[:, border:border + H, border:border + W]
            sink.add_rows(f0 + a, [lit_idx[ci]], 0, v.cpu().numpy()[:, None])
            del u, v
    scratch[k].close()
    clear_cache()  # this plane's transfer functions and padding workspaces are not used again


def _to_wrp(u, dz, lam, pitch_m, eq, ci):
    """u [n, Hk, Wk] equalised by ``eq`` (None: not) and propagated by dz, on a grid that pads by the filter's
    border and the distance's reach together (docs/design.md §5): one FFT pair for both."""
    reach = reach_grid(tuple(u.shape[-2:]), dz, lam, pitch_m)
    if eq is None:
        return asm(u, dz, lam, pitch_m, grid=reach)
    own = eq.own_grid(tuple(u.shape[-2:]))
    grid = tuple(smooth_at_least(r + o - n) for r, o, n in zip(reach, own, u.shape[-2:]))
    return asm(u, dz, lam, pitch_m, grid=grid, gain=eq.gain(u, ci, lam, pitch_m, grid))


def chain_planes(sink, planes, trace_plane, *, f0, n_f, fp, lit_idx, optics, dev, timings,
                 equalisers=None) -> None:
    """Trace the recording planes into the sink's traced field (frames f0..f0+n_f): one trace from the WRP
    records every ray on the plane in front of its image point (holocore.trace.hologram_rays, ``planes``); each
    deeper plane, on a grid wider than the WRP's by its border and held in a scratch file, is then equalised,
    propagated by the ASM to the WRP, cropped to its window and added.
    ``trace_plane(spec, on_plane_rows)`` runs the trace: ``on_plane_rows(k, r0, block, add=False)`` writes (or
    adds) rows of plane k; it returns a factor for every recording (None: 1), applied once after all the trace's
    passes (a time-limited render adds its passes' sums and divides by their rays here). ``equalisers``: one
    :class:`holocore.optics.cone_equaliser.PlaneEqualiser` per plane (None: none), applied to each plane's own
    recording before anything is added to it."""
    H, W = optics.resolution_hw
    lams = [optics.wavelengths_m[c] for c in lit_idx]
    theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    borders = planes.borders_px(pitch_m=optics.pitch_m, theta_max=theta)
    spec = [(planes.z_m[k], *planes.slab(k), borders[k]) for k in range(planes.count)]
    scratch = [None] + [ScratchArray((n_f, len(lams), H + 2 * b, W + 2 * b), np.complex64,
                                     dir=getattr(sink, "scratch_dir", None)) for b in borders[1:]]
    try:
        def on_plane_rows(k, r0, block, add=False):
            rows = block.cpu().numpy()  # the one transfer to the host per block
            if k == 0:
                (sink.add_rows if add else sink.write_rows)(f0, lit_idx, r0, rows)
            else:
                (scratch[k].add_rows if add else scratch[k].write_rows)(0, range(len(lams)), r0, rows)

        scale = trace_plane(spec if planes.count > 1 else None, on_plane_rows)
        scale = 1.0 if scale is None else float(scale)
        t0 = time.perf_counter()
        common = dict(f0=f0, n_f=n_f, lit_idx=lit_idx, scale=scale, equalisers=equalisers, optics=optics, dev=dev)
        with heap_reuse(torch.device(dev).type == "cpu"):  # the transforms' outputs on reused pages
            # the WRP's own rays (scaled, equalised), before the deeper planes are added to it
            _scale_wrp(sink, lams, fp=fp, **common)
            if equalisers is not None:
                timings["equalise_s"] = timings.get("equalise_s", 0.0) + time.perf_counter() - t0
            # The chunk planner sized fp for the WRP's grid; a deeper plane's grid is wider: fewer frames a chunk.
            for k in range(planes.count - 1, 0, -1):  # each deeper plane straight to the WRP
                step = max(1, fp * H * W // (2 * (H + 2 * borders[k]) * (W + 2 * borders[k])))
                _add_to_wrp(k, planes, sink, scratch, lams=lams, border=borders[k], step=step, **common)
        if planes.count > 1:
            timings["planes_propagate_s"] = timings.get("planes_propagate_s", 0.0) + time.perf_counter() - t0
    finally:
        for sc in scratch[1:]:
            sc.close()
