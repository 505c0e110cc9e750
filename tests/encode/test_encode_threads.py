"""The SGD encoder runs small problems on one torch thread (their ops are too small to split, and split ones
stall behind other work on a shared CPU: a service job's 96x128 encode took 20x its estimate) and gives the
thread count back after."""

from __future__ import annotations

import torch

from holocore.encode.encoder import SMALL_OPS_ELEMENTS, encode_sgd, small_ops_on_one_thread


def test_a_small_sgd_encode_runs_on_one_thread_and_restores_the_count():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        g = torch.Generator().manual_seed(0)
        target = torch.polar(torch.rand((2, 1, 32, 48), generator=g), 6.3 * torch.rand((2, 1, 32, 48), generator=g))
        seen: list[int] = []
        encode_sgd(target, z_wrp_m=1e-3, wavelengths_m=[520e-9], pitch_m=8e-6, iterations=20, stop_db=0.0,
                   progress=lambda stage, done, total: seen.append(torch.get_num_threads()))
        assert seen and set(seen) == {1}
        assert torch.get_num_threads() == 2
        with small_ops_on_one_thread("sgd", "cpu", SMALL_OPS_ELEMENTS):  # a large grid keeps its threads
            assert torch.get_num_threads() == 2
        with small_ops_on_one_thread("dpac", "cpu", 16):
            assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
