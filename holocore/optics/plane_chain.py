"""Several recording planes chained to the WRP by the band-limited ASM (paper Sec. 6; DESIGN.md §5): one trace
records every ray on the plane in front of its image point; each deeper plane, held in a scratch file on a grid
wider than the WRP's by its border, is propagated to the plane in front of it, cropped and added, down to the
WRP. Units: metres."""

from __future__ import annotations

import time

import numpy as np

__all__ = ["chain_planes"]


def chain_planes(sink, planes, trace_plane, *, f0, n_f, fp, lit_idx, optics, dev, timings,
                 equalisers=None) -> None:
    """Trace the recording planes into the sink's traced field (frames f0..f0+n_f): one trace from the WRP
    records every ray on the plane in front of its image point (holocore.trace.hologram_rays, ``planes``); each deeper
    plane, on a grid wider than the WRP's by its border and held in a scratch file, is then propagated by the
    ASM to the plane in front of it, cropped to that plane's grid and added, down to the WRP.
    ``trace_plane(spec, on_plane_rows)`` runs the trace. ``equalisers``: one
    :class:`holocore.optics.cone_equaliser.PlaneEqualiser` per plane (None: none), applied to each plane's own
    recording before anything is added to it."""
    import torch

    from holocore.io import ScratchArray
    from holocore.optics.propagation import asm, clear_cache

    H, W = optics.resolution_hw
    lams = [optics.wavelengths_m[c] for c in lit_idx]
    theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    borders = [planes.border_px(k, pitch_m=optics.pitch_m, theta_max=theta) for k in range(planes.count)]
    spec = [(planes.z_m[k], *planes.slab(k), borders[k]) for k in range(planes.count)]
    scratch = [None] + [ScratchArray((n_f, len(lams), H + 2 * b, W + 2 * b), np.complex64,
                                     dir=getattr(sink, "scratch_dir", None)) for b in borders[1:]]
    try:
        def on_plane_rows(k, r0, block):
            rows = block.cpu().numpy()  # the one transfer to the host per block
            if k == 0:
                sink.write_rows(f0, lit_idx, r0, rows)
            else:
                scratch[k].write_rows(0, range(len(lams)), r0, rows)

        trace_plane(spec if planes.count > 1 else None, on_plane_rows)
        t0 = time.perf_counter()
        if equalisers is not None:  # the WRP's own rays, before the deeper planes are added to it
            for ci, lam in enumerate(lams):
                if not equalisers[0].active(ci):
                    continue
                for a in range(0, n_f, fp):
                    e = min(n_f, a + fp)
                    u = torch.from_numpy(np.ascontiguousarray(sink.read_traced(f0 + a, f0 + e, lit_idx[ci]))).to(dev)
                    v = equalisers[0].apply(u, ci, lam, optics.pitch_m)
                    sink.write_rows(f0 + a, [lit_idx[ci]], 0, v.cpu().numpy()[:, None])
                    del u, v
            timings["equalise_s"] = timings.get("equalise_s", 0.0) + time.perf_counter() - t0
        for k in range(planes.count - 1, 0, -1):  # the deepest first, each added to the plane in front
            d = borders[k] - borders[k - 1]
            Hn, Wn = H + 2 * borders[k - 1], W + 2 * borders[k - 1]
            # The chunk planner sized fp for the WRP's grid; this plane's grid is wider, and the sum with the
            # plane in front is held too: fewer frames per chunk.
            step = max(1, fp * H * W // (2 * (H + 2 * borders[k]) * (W + 2 * borders[k])))
            for a in range(0, n_f, step):
                e = min(n_f, a + step)
                for ci, lam in enumerate(lams):
                    u = torch.from_numpy(scratch[k].read_fc(a, e, ci)).to(dev)
                    if equalisers is not None:
                        u = equalisers[k].apply(u, ci, lam, optics.pitch_m)
                    v = asm(u, planes.z_m[k - 1] - planes.z_m[k], lam, optics.pitch_m)
                    v = v[:, d:d + Hn, d:d + Wn].cpu().numpy()
                    if k - 1 == 0:
                        sink.add_rows(f0 + a, [lit_idx[ci]], 0, v[:, None])
                    else:
                        scratch[k - 1].add_rows(a, [ci], 0, v[:, None])
                    del u, v
            scratch[k].close()
            clear_cache()  # this plane pair's transfer functions and padding workspaces are not used again
        if planes.count > 1:
            timings["planes_propagate_s"] = timings.get("planes_propagate_s", 0.0) + time.perf_counter() - t0
    finally:
        for sc in scratch[1:]:
            sc.close()
