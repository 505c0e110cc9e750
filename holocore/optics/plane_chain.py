"""Several recording planes chained to the WRP by the band-limited ASM (paper Sec. 6; docs/design.md §5): one
trace records every ray on the plane in front of its image point; each deeper plane, held in a scratch file on a
grid wider than the WRP's by its border, is propagated to the plane in front of it, cropped and added, down to
the WRP. Units: metres."""

from __future__ import annotations

import time

import numpy as np

from holocore.io import ScratchArray
from holocore.optics.grids import reach_grid

__all__ = ["chain_planes"]


def _scale_wrp(sink, lams, *, f0, n_f, fp, lit_idx, scale, equalisers, optics, dev) -> None:
    """Scale and equalise the WRP's own recording in the sink's traced field (frames f0..f0+n_f), in place,
    before the deeper planes are added to it; colours that neither applies to are left as they are."""
    import torch

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


def _own(scratch, equalisers, k, a, e, ci, lam, *, scale, optics, dev):
    """Plane k's own recording, frames a..e of lit colour ci, scaled and equalised (on the device)."""
    import torch

    u = torch.from_numpy(scratch[k].read_fc(a, e, ci)).to(dev)
    if scale != 1.0:
        u = u * scale
    return equalisers[k].apply(u, ci, lam, optics.pitch_m) if equalisers is not None else u


def _add_to_front(k, planes, sink, scratch, *, lams, borders, steps, f0, n_f, lit_idx, scale, equalisers, optics,
                  dev) -> None:
    """Propagate plane k (k >= 1) by the ASM to the plane in front of it, crop it to that plane's grid and add it
    there (the sink's traced field for the WRP), a chunk of ``steps[k]`` frames at a time; the plane in front
    first gets its own recording scaled and equalised. Closes plane k's scratch file."""
    import torch

    from holocore.optics.propagation import asm, clear_cache

    H, W = optics.resolution_hw
    own = dict(scale=scale, optics=optics, dev=dev)
    d = borders[k] - borders[k - 1]
    Hn, Wn = H + 2 * borders[k - 1], W + 2 * borders[k - 1]
    if k - 1 >= 1 and (scale != 1.0 or equalisers is not None):
        # the plane in front gets its own recording scaled and equalised before this plane's field is
        # added to it: each recording is filtered by its own plane's equaliser, once
        for a in range(0, n_f, steps[k - 1]):
            e = min(n_f, a + steps[k - 1])
            for ci, lam in enumerate(lams):
                u = _own(scratch, equalisers, k - 1, a, e, ci, lam, **own)
                scratch[k - 1].write_rows(a, [ci], 0, u.cpu().numpy()[:, None])
    for a in range(0, n_f, steps[k]):
        e = min(n_f, a + steps[k])
        for ci, lam in enumerate(lams):
            if k == planes.count - 1:  # the deepest plane holds its own recording alone
                u = _own(scratch, equalisers, k, a, e, ci, lam, **own)
            else:  # done in place above, with the deeper planes' fields added since
                u = torch.from_numpy(scratch[k].read_fc(a, e, ci)).to(dev)
            dz = planes.z_m[k - 1] - planes.z_m[k]  # a few millimetres: a grid a few pixels wider, not 2x
            v = asm(u, dz, lam, optics.pitch_m, grid=reach_grid(tuple(u.shape[-2:]), dz, lam, optics.pitch_m))
            v = v[:, d:d + Hn, d:d + Wn].cpu().numpy()
            if k - 1 == 0:
                sink.add_rows(f0 + a, [lit_idx[ci]], 0, v[:, None])
            else:
                scratch[k - 1].add_rows(a, [ci], 0, v[:, None])
            del u, v
    scratch[k].close()
    clear_cache()  # this plane pair's transfer functions and padding workspaces are not used again


def chain_planes(sink, planes, trace_plane, *, f0, n_f, fp, lit_idx, optics, dev, timings,
                 equalisers=None) -> None:
    """Trace the recording planes into the sink's traced field (frames f0..f0+n_f): one trace from the WRP
    records every ray on the plane in front of its image point (holocore.trace.hologram_rays, ``planes``); each
    deeper plane, on a grid wider than the WRP's by its border and held in a scratch file, is then propagated by the
    ASM to the plane in front of it, cropped to that plane's grid and added, down to the WRP.
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
        # the WRP's own rays (scaled, equalised), before the deeper planes are added to it
        _scale_wrp(sink, lams, fp=fp, **common)
        if equalisers is not None:
            timings["equalise_s"] = timings.get("equalise_s", 0.0) + time.perf_counter() - t0
        # The chunk planner sized fp for the WRP's grid; a deeper plane's grid is wider, and the sum with the
        # plane in front is held too: fewer frames per chunk.
        steps = [max(1, fp * H * W // (2 * (H + 2 * b) * (W + 2 * b))) for b in borders]
        for k in range(planes.count - 1, 0, -1):  # the deepest first, each added to the plane in front
            _add_to_front(k, planes, sink, scratch, lams=lams, borders=borders, steps=steps, **common)
        if planes.count > 1:
            timings["planes_propagate_s"] = timings.get("planes_propagate_s", 0.0) + time.perf_counter() - t0
    finally:
        for sc in scratch[1:]:
            sc.close()
