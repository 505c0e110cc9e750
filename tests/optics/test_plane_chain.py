"""The recording-plane chain (holocore.optics.plane_chain): each plane's own recording is filtered by its own
plane's equaliser exactly once, and a trace's factor (a time-limited render's 1 / rays) is applied once, whatever
plane the light was recorded on."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from holocore.display.optics import OpticsConfig
from holocore.optics.plane_chain import chain_planes
from holocore.plan.wrp_planes import WrpPlanes
from holocore.sinks import MemorySink


class Gain:
    """A stand-in equaliser: multiplies a plane's field by a constant (the chain is linear, so a plane's
    contribution to the WRP carries the product of every gain applied to it)."""

    def __init__(self, g):
        self.g = g

    def active(self, color):
        return True

    def apply(self, u, color, wavelength_m, pitch_m):
        return u * self.g

    def own_grid(self, shape_hw):
        return tuple(shape_hw)

    def gain(self, u, color, wavelength_m, pitch_m, grid):
        return torch.full(tuple(grid), float(self.g))


def _chain(source_plane, gains, scale=None):
    optics = OpticsConfig(resolution_hw=(24, 32), frames=1, wavelengths_nm=(640.0,))
    planes = WrpPlanes(z_m=(0.0900, 0.0895, 0.0890), margin_m=1e-4)
    theta = optics.theta_max(optics.wavelengths_m[0])
    borders = [planes.border_px(k, pitch_m=optics.pitch_m, theta_max=theta) for k in range(3)]
    rng = np.random.default_rng(3)
    b = borders[source_plane]
    shape = (1, 1, 24 + 2 * b, 32 + 2 * b)
    block = torch.from_numpy((rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64))
    sink = MemorySink((1, 1, 24, 32))

    def trace_plane(spec, on_plane_rows):
        for k in range(3):  # every plane gets rows (zeros but on the source plane), as a trace gives them
            bk = borders[k]
            on_plane_rows(k, 0, block if k == source_plane else torch.zeros((1, 1, 24 + 2 * bk, 32 + 2 * bk),
                                                                             dtype=torch.complex64))
        return scale

    chain_planes(sink, planes, trace_plane, f0=0, n_f=1, fp=1, lit_idx=[0], optics=optics, dev=torch.device("cpu"),
                 timings={}, equalisers=None if gains is None else [Gain(g) for g in gains])
    return sink.traced.copy()


@pytest.mark.parametrize("source_plane", [0, 1, 2])
def test_each_recording_is_equalised_by_its_own_plane_once(source_plane):
    plain = _chain(source_plane, None)
    assert np.abs(plain).max() > 0
    gains = (2.0, 3.0, 5.0)
    got = _chain(source_plane, gains)
    # light recorded on plane k reaches the WRP with gain g_k alone (the deepest plane's field passes plane 1 on
    # its way: a chain that equalised plane 1's sum would give it 3 x 5)
    np.testing.assert_allclose(got, gains[source_plane] * plain, rtol=0, atol=1e-5 * np.abs(plain).max() * 5)


@pytest.mark.parametrize("source_plane", [0, 2])
def test_the_traces_factor_is_applied_once(source_plane):
    plain = _chain(source_plane, (2.0, 3.0, 5.0))
    got = _chain(source_plane, (2.0, 3.0, 5.0), scale=0.125)
    np.testing.assert_allclose(got, 0.125 * plain, rtol=0, atol=1e-6 * np.abs(plain).max())
