"""Phase -> gray mapping: default = docs/design.md §2 (holocore.io.phase_to_u8), lookup tables, scales."""

from __future__ import annotations

import json

import numpy as np
import pytest

from display_agent.phasemap import PhaseMapping
from holocore.formats import load_lut_file, phase_levels
from holocore.io import phase_to_u8
from tests.agent.helpers import WAVELENGTHS_M, make_phase

TWO_PI = 2 * np.pi


def test_default_matches_design_rule_on_hard_values():
    ph = make_phase((2, 3, 16, 16), seed=3).astype(np.float32)
    hard = np.array([0.0, TWO_PI * 255 / 256, TWO_PI * 255.49 / 256, TWO_PI * 255.51 / 256, TWO_PI,
                     np.float32(TWO_PI), TWO_PI * 0.5 / 256, TWO_PI * 0.49 / 256, np.pi], dtype=np.float64)
    ph.reshape(-1)[: hard.size] = hard
    got = PhaseMapping().levels(ph, wavelengths_m=WAVELENGTHS_M)
    assert got.dtype == np.uint8 and got.shape == ph.shape
    np.testing.assert_array_equal(got, phase_to_u8(ph))
    lv = phase_levels(hard.reshape(1, 1, 1, -1))[0, 0, 0]
    # 2pi*255/256 -> 255; within half a level of 2pi -> 0; pi -> 128; half a level rounds (numpy: to even)
    assert list(lv[:6]) == [0, 255, 255, 0, 0, 0] and lv[8] == 128


def test_lut_json_per_wavelength_is_applied_after_default_levels(tmp_path):
    tables = [np.arange(256)[::-1], (np.arange(256) * 3) % 256, np.minimum(np.arange(256), 200)]
    doc = {"luts": [{"wavelength_nm": wl, "table": t.tolist()}
                    for wl, t in zip([455.0, 640.4, 516.9], [tables[2], tables[0], tables[1]])]}
    p = tmp_path / "lut.json"
    p.write_text(json.dumps(doc))
    m = PhaseMapping.from_options(lut=p)
    ph = make_phase((2, 3, 8, 8), seed=4)
    got = m.levels(ph, wavelengths_m=WAVELENGTHS_M)
    base = phase_to_u8(ph)
    for c in range(3):  # colours matched to the table within 1 nm whatever the file's order
        np.testing.assert_array_equal(got[:, c], tables[c][base[:, c]].astype(np.uint8))
    with pytest.raises(ValueError, match="no lookup table within 1.0 nm of 532.0"):
        m.levels(ph, wavelengths_m=[640e-9, 532e-9, 455.4e-9])


def test_lut_npy_rows_and_single_table(tmp_path):
    rows = np.stack([np.roll(np.arange(256), k) for k in (1, 2, 3)]).astype(np.uint8)
    np.save(tmp_path / "l3.npy", rows)
    np.save(tmp_path / "l1.npy", rows[0])
    ph = make_phase((1, 3, 5, 7), seed=5)
    base = phase_to_u8(ph)
    got3 = PhaseMapping.from_options(lut=tmp_path / "l3.npy").levels(ph, wavelengths_m=WAVELENGTHS_M)
    got1 = PhaseMapping.from_options(lut=tmp_path / "l1.npy").levels(ph, wavelengths_m=WAVELENGTHS_M)
    for c in range(3):
        np.testing.assert_array_equal(got3[:, c], rows[c][base[:, c]])
        np.testing.assert_array_equal(got1[:, c], rows[0][base[:, c]])
    with pytest.raises(ValueError, match="3 rows, the stack 2 colours"):
        PhaseMapping.from_options(lut=tmp_path / "l3.npy").levels(ph[:, :2], wavelengths_m=WAVELENGTHS_M[:2])


def test_scale_wraps_at_its_own_2pi_level():
    ph = np.array([0.0, np.pi, TWO_PI * 219.6 / 220, TWO_PI * 219.4 / 220, TWO_PI * (1 - 1e-12)])
    lv = phase_levels(ph, levels_per_2pi=220)
    assert list(lv) == [0, 110, 0, 219, 0]
    m = PhaseMapping.from_options(levels_per_2pi=[220, 230, 256])
    stack = make_phase((1, 3, 4, 4), seed=6)
    got = m.levels(stack, wavelengths_m=WAVELENGTHS_M)
    assert got[:, 0].max() < 220 and got[:, 1].max() < 230
    np.testing.assert_array_equal(got[:, 2], phase_to_u8(stack[:, 2]))


@pytest.mark.parametrize("bad", [1, 257, [256, 0]])
def test_bad_scales_are_refused(bad):
    with pytest.raises(ValueError, match="levels_per_2pi must be in"):
        PhaseMapping.from_options(levels_per_2pi=bad)


def test_bad_tables_and_phases_are_refused(tmp_path):
    for name, doc, msg in [("a.json", {"luts": []}, "non-empty list"),
                           ("b.json", {"luts": [{"table": list(range(255))}]}, "256 entries"),
                           ("c.json", {"luts": [{"table": [300] * 256}]}, "integers in 0..255"),
                           ("d.json", {"luts": [{"wavelength_nm": -5, "table": list(range(256))}]}, "positive")]:
        (tmp_path / name).write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=msg):
            load_lut_file(tmp_path / name)
    (tmp_path / "e.json").write_text("{not json")
    with pytest.raises(ValueError, match="cannot read lookup table"):
        load_lut_file(tmp_path / "e.json")
    ph = np.zeros((1, 1, 2, 2))
    ph[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        PhaseMapping().levels(ph, wavelengths_m=[640e-9])
    with pytest.raises(ValueError, match=r"\[F, C, H, W\]"):
        PhaseMapping().levels(np.zeros((2, 2)), wavelengths_m=[640e-9])
    with pytest.raises(ValueError, match="not both"):
        (tmp_path / "ok.json").write_text(json.dumps({"luts": [{"table": list(range(256))}]}))
        PhaseMapping.from_options(lut=tmp_path / "ok.json", levels_per_2pi=200)
