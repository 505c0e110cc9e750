"""holocore.validate: one validator per kind of physical input, one line naming the parameter, rule and unit."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from holocore import validate


def test_scalars_from_python_numpy_and_torch_are_plain_floats():
    for v in (2, 2.0, np.float32(2.0), np.int64(2), torch.tensor(2.0, dtype=torch.float64)):
        assert validate.positive("distance_m", v) == 2.0 and type(validate.real("x", v)) is float


@pytest.mark.parametrize("value, rule", [
    (True, "real number"), ("1", "real number"), (1 + 2j, "real number"), (torch.tensor(1 + 1j), "real number"),
    (np.array([1.0, 2.0]), "real number"), (math.nan, "finite"), (math.inf, "finite"), (0.0, "> 0 m"),
    (-1e-3, "> 0 m"),
])
def test_bad_lengths_are_one_line_naming_the_parameter(value, rule):
    with pytest.raises(ValueError) as err:
        validate.positive("z_wrp_m", value)
    assert str(err.value).startswith("z_wrp_m must be") and rule in str(err.value) and "\n" not in str(err.value)


def test_pitch_pairs_and_wavelengths():
    assert validate.pitch_pair(8e-6) == (8e-6, 8e-6) and validate.pitch_pair((4e-6, 8e-6)) == (4e-6, 8e-6)
    assert validate.pitch_pair(np.array([4e-6, 8e-6])) == (4e-6, 8e-6)
    with pytest.raises(ValueError, match=r"pitch_m\[1\] \(pitch_x\) must be > 0 m"):
        validate.pitch_pair((8e-6, -1.0))
    with pytest.raises(ValueError, match="pitch_m pair"):
        validate.pitch_pair((8e-6, 8e-6, 8e-6))
    assert validate.wavelengths([640e-9, 516.5e-9], 2) == [640e-9, 516.5e-9]
    with pytest.raises(ValueError, match=r"wavelengths_m\[0\] must be > 0 and < 1e-05 m"):
        validate.wavelengths([640.0])  # nanometres given as metres
    with pytest.raises(ValueError, match="has 1 entries but the target has 3 colors"):
        validate.wavelengths([640e-9], 3)


def test_integers_refuse_bools_and_floats():
    assert validate.integer("planes", np.int32(5), 1, 64) == 5
    for bad in (True, 5.0, 0, 65):
        with pytest.raises(ValueError, match=r"planes must be an integer in 1..64"):
            validate.integer("planes", bad, 1, 64)
