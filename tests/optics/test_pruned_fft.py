"""FFTW's pruned window filter (holocore.optics.pruned_fft) against plain 2-D DFTs in complex128, and the ASM on
it against the ASM on torch's ``fft2``: the same numbers to rounding, on even, odd (unaligned frames) and
non-square layouts, batched, with a gain and a cone, from several threads at once."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from holocore.optics import pruned_fft
from holocore.optics.propagation import asm

pytestmark = pytest.mark.skipif(not pruned_fft.available(), reason="pyFFTW is not installed")
P = 8e-6


def _reference(x: np.ndarray, mult: np.ndarray, grid: tuple[int, int], second_forward: bool) -> np.ndarray:
    h, w = x.shape[-2:]
    pad = np.zeros(x.shape[:-2] + grid, complex)
    pad[..., :h, :w] = x
    spec = np.fft.fft2(pad) * mult
    back = np.fft.fft2(spec) if second_forward else np.fft.ifft2(spec) * (grid[0] * grid[1])
    return back[..., :h, :w]


@pytest.mark.parametrize("second_forward", [True, False])
@pytest.mark.parametrize("shape, grid", [((24, 40), (40, 64)), ((19, 31), (45, 49)), ((16, 20), (16, 36))])
def test_window_filter_is_the_padded_two_dimensional_filter(second_forward, shape, grid):
    """crop(G(M . F(pad x))) frame by frame equals numpy's 2-D DFTs of the zero-padded frames (1e-12), also where
    a frame's offset breaks FFTW's alignment (odd sizes) and where the grid adds no rows."""
    rng = np.random.default_rng(1)
    b = 3
    x = rng.standard_normal((b, *shape)) + 1j * rng.standard_normal((b, *shape))
    mult = rng.standard_normal(grid) + 1j * rng.standard_normal(grid)
    filt = pruned_fft.WindowFilter.get(shape, grid, torch.complex128, second_forward=second_forward)
    xin, out = filt.inputs(b), filt.inputs(b)
    xin[:, :, :shape[1]] = torch.from_numpy(x)
    for _ in range(2):  # the grid workspace is reused: a second call must not see the first one's rows
        got = filt(xin, torch.from_numpy(mult), out).numpy()
    ref = _reference(x, mult, grid, second_forward)
    assert np.abs(got - ref).max() < 1e-12 * np.abs(ref).max()
    assert np.abs(xin[:, :, shape[1]:].numpy()).max() == 0  # the input's padding columns stay zero


@pytest.mark.parametrize("case", ["pad2", "reach", "gain_cone", "odd", "batched"])
def test_asm_on_fftw_is_the_asm_on_torch(case):
    """asm's FFTW path equals its torch path (complex128 rounding) for the layouts the render and encoder use."""
    rng = np.random.default_rng(2)
    shape, kw, batch = (32, 48), {}, ()
    if case == "reach":
        kw = {"grid": (32, 60)}  # no padded rows: the column transforms see no zeros
    elif case == "gain_cone":
        kw = {"grid": (40, 64), "cone_sine": 0.03,
              "gain": torch.from_numpy(rng.uniform(0.5, 1.5, (40, 64)))}
    elif case == "odd":
        shape, kw = (21, 33), {"grid": (27, 45)}
    elif case == "batched":
        batch = (2, 3)
    u = torch.from_numpy(rng.standard_normal(batch + shape) + 1j * rng.standard_normal(batch + shape))
    for z in (2e-3, -5e-3):
        fast = asm(u, z, 532e-9, P, **kw)
        with pruned_fft.disabled():
            ref = asm(u, z, 532e-9, P, **kw)
        assert fast.shape == u.shape and fast.dtype == u.dtype and fast.is_contiguous()
        assert float((fast - ref).abs().max()) < 1e-12 * float(ref.abs().max())


def test_asm_from_several_threads_at_once():
    """Each thread has its own filters and workspaces: concurrent propagations give each its own answer."""
    rng = np.random.default_rng(3)
    fields = [torch.from_numpy(rng.standard_normal((64, 80)) + 1j * rng.standard_normal((64, 80))).to(torch.complex64)
              for _ in range(4)]
    with pruned_fft.disabled():
        refs = [asm(f, 3e-3, 640e-9, P) for f in fields]
    got: dict[int, list[torch.Tensor]] = {}

    def work(i: int) -> None:
        got[i] = [asm(fields[i], 3e-3, 640e-9, P) for _ in range(5)]
    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i, ref in enumerate(refs):
        for g in got[i]:
            assert float((g - ref).abs().max()) < 1e-5 * float(ref.abs().max())


def test_switched_off_means_torch():
    """``disabled()`` (and HOLO_FFTW=0 at import) makes callers take torch's path."""
    assert pruned_fft.available(torch.complex64)
    with pruned_fft.disabled():
        assert not pruned_fft.available(torch.complex64)
    assert pruned_fft.available(torch.complex64) and not pruned_fft.available(torch.float32)
