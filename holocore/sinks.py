"""Where a render's two fields go (:mod:`holocore.pipeline`): both in memory, or the traced one in a scratch file and
the propagated one streamed into RESULT.npz. A sink takes rows of frames of colors (``write_rows``,
``add_rows``), gives the traced field back per (frames, color) for the propagation (``read_traced``) and takes
the propagated frames in order (``write_other``). A :class:`PassSink` holds one more pass of rays of a
time-limited render (holocore.plan.time_budget) until it is blended into the render's sink."""

from __future__ import annotations

import numpy as np

__all__ = ["MemorySink", "FileSink", "PassSink", "blend_pass"]


class MemorySink:
    """Both fields in memory (the unchunked layout: one [F, C, H, W] array each)."""

    def __init__(self, shape):
        self.traced = np.zeros(shape, dtype=np.complex64)
        self.other = np.empty(shape, dtype=np.complex64)

    def write_rows(self, f0, colors, r0, block):
        self.traced[f0:f0 + block.shape[0], colors, r0:r0 + block.shape[2]] = block

    def add_rows(self, f0, colors, r0, block):
        self.traced[f0:f0 + block.shape[0], colors, r0:r0 + block.shape[2]] += block

    def read_traced(self, f0, f1, c):
        return self.traced[f0:f1, c]

    def write_other(self, f0, block):
        self.other[f0:f0 + block.shape[0]] = block


class FileSink:
    """The traced field in a scratch file, the propagated one streamed straight into RESULT.npz."""

    def __init__(self, writer, shape, traced_name, other_name):
        from holocore.io import ScratchArray

        self.writer, self.shape, self.traced_name = writer, shape, traced_name
        self.scratch_dir = writer.path.parent
        self.scratch = ScratchArray(shape, np.complex64, dir=writer.path.parent)
        self.stream = writer.stream(other_name, shape, np.complex64)

    def write_rows(self, f0, colors, r0, block):
        self.scratch.write_rows(f0, colors, r0, block)

    def add_rows(self, f0, colors, r0, block):
        self.scratch.add_rows(f0, colors, r0, block)

    def read_traced(self, f0, f1, c):
        return self.scratch.read_fc(f0, f1, c)

    def write_other(self, f0, block):
        self.stream.write(block)

    def finish(self):
        self.stream.close()
        self.writer.copy_from(self.traced_name, self.scratch)
        self.scratch.close()


class PassSink:
    """The traced field of one extra pass of rays (frames 0..F of a pass), in memory beside a
    :class:`MemorySink`, in a scratch file beside a :class:`FileSink` (so a streamed render stays in bounded
    memory)."""

    def __init__(self, shape, like):
        from holocore.io import ScratchArray

        self.scratch_dir = getattr(like, "scratch_dir", None)
        if isinstance(like, FileSink):
            self.scratch = ScratchArray(shape, np.complex64, dir=self.scratch_dir)
            self.traced = None
        else:
            self.scratch = None
            self.traced = np.zeros(shape, dtype=np.complex64)

    def write_rows(self, f0, colors, r0, block):
        if self.scratch is not None:
            self.scratch.write_rows(f0, colors, r0, block)
        else:
            self.traced[f0:f0 + block.shape[0], colors, r0:r0 + block.shape[2]] = block

    def add_rows(self, f0, colors, r0, block):
        if self.scratch is not None:
            self.scratch.add_rows(f0, colors, r0, block)
        else:
            self.traced[f0:f0 + block.shape[0], colors, r0:r0 + block.shape[2]] += block

    def read_traced(self, f0, f1, c):
        return self.scratch.read_fc(f0, f1, c) if self.scratch is not None else self.traced[f0:f1, c]

    def close(self):
        if self.scratch is not None:
            self.scratch.close()
        self.traced = None


def blend_pass(sink, extra: PassSink, *, f0: int, n_f: int, colors, w_old: float, w_new: float, step: int) -> None:
    """sink's traced frames f0..f0+n_f of ``colors`` <- w_old * them + w_new * the extra pass's frames 0..n_f,
    ``step`` frames at a time (the spp-weighted mean of two Monte Carlo estimates; holocore.plan.time_budget)."""
    for c in colors:
        for a in range(0, n_f, step):
            e = min(n_f, a + step)
            mixed = w_old * sink.read_traced(f0 + a, f0 + e, c) + w_new * extra.read_traced(a, e, c)
            sink.write_rows(f0 + a, [c], 0, mixed.astype(np.complex64, copy=False)[:, None])
