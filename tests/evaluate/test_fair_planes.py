"""Fair focus planes (holocore.evaluate.scoring.fair_focus_planes_m): drawn per slice of the image volume from a
seed, never the same plane twice, kept off the planes a method was fitted to."""

from __future__ import annotations

import numpy as np
import pytest

from holocore.evaluate.scoring import fair_focus_planes_m

META = {"focal_length_m": 0.05, "z_inf_m": 0.08, "pitch_m": 8e-6, "wavelengths_m": [520e-9],
        "analysis": {"z_far_holo_m": 0.0802, "z_near_holo_m": 0.0852}}


def test_one_plane_a_slice_seeded_and_off_the_methods_planes():
    stack = list(np.linspace(0.0802, 0.0852, 5))  # a focal stack's 5 targets, ends included
    layers = list(np.linspace(0.0802, 0.0852, 8))
    for seed in range(20):
        zs = fair_focus_planes_m(META, 4, seed=seed, avoid_m=stack + layers, min_gap_m=0.1e-3)
        assert zs == fair_focus_planes_m(META, 4, seed=seed, avoid_m=stack + layers, min_gap_m=0.1e-3)
        edges = np.linspace(0.0802, 0.0852, 5)
        assert all(edges[i] <= z <= edges[i + 1] for i, z in enumerate(zs))  # one in each slice: never twice
        assert min(abs(z - a) for z in zs for a in stack + layers) >= 0.1e-3
    a = fair_focus_planes_m(META, 4, seed=1)
    b = fair_focus_planes_m(META, 4, seed=2)
    assert not np.allclose(a, b)


def test_a_slice_with_no_room_takes_its_point_farthest_from_the_planes():
    zs = fair_focus_planes_m(META, 1, seed=0, avoid_m=list(np.linspace(0.0802, 0.0852, 200)), min_gap_m=1e-3)
    grid = np.linspace(0.0802, 0.0852, 200)
    assert np.min(np.abs(grid - zs[0])) > 0.25 * (grid[1] - grid[0])
    with pytest.raises(ValueError, match="focus planes"):
        fair_focus_planes_m(META, 0, seed=0)
