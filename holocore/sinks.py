"""Where a render's two fields go (:mod:`holocore.pipeline`): both in memory, or the traced one in a scratch file and
the propagated one streamed into RESULT.npz. A sink takes rows of frames of colors (``write_rows``,
``add_rows``), gives the traced field back per (frames, color) for the propagation (``read_traced``) and takes
the propagated frames in order (``write_other``)."""

from __future__ import annotations

import numpy as np

from holocore.io import ScratchArray

__all__ = ["MemorySink", "FileSink"]


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
