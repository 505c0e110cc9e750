"""Typed RESULT/STACK metadata (holocore.formats.meta): the numbers every reader needs are checked once, in SI
units, with one line naming the field; what the model does not know is kept, so older and newer files load and
are written back with the keys they had."""

from __future__ import annotations

import json

import numpy as np
import pytest

from holocore.formats import (
    MetaError,
    load_result,
    load_stack,
    parse_result_meta,
    parse_stack_meta,
    parse_view_meta,
    save_result,
    save_stack,
)

GEOMETRY = {"focal_length_m": 0.05, "z_inf_m": 0.08, "z_wrp_m": 0.0816, "pitch_m": 8e-6,
            "wavelengths_m": [640e-9, 516.5e-9, 455.4e-9]}


def test_a_file_with_keys_this_version_does_not_know_round_trips_unchanged(tmp_path):
    meta = {**GEOMETRY, "analysis": {"z_near_holo_m": 0.084}, "from_a_newer_version": {"x": [1, 2]},
            "pitch_m": [8e-6, 8e-6]}
    f = np.zeros((1, 3, 4, 4), np.complex64)
    save_result(tmp_path / "r.npz", slm_field=f, wrp_field=f, meta=meta)
    raw = json.loads(str(np.load(tmp_path / "r.npz")["meta"]))
    assert raw == meta
    _, _, m = load_result(tmp_path / "r.npz")
    assert m.z_wrp_m == 0.0816 and m.pitch_yx_m == (8e-6, 8e-6) and m.wavelengths_m == (640e-9, 516.5e-9, 455.4e-9)
    assert m["from_a_newer_version"] == {"x": [1, 2]} and m.to_dict() == meta and {**m} == meta
    stack_meta = m.with_fields(encoder={"method": "sgd"})
    save_stack(tmp_path / "s.npz", phase=np.zeros((1, 3, 4, 4)), meta=stack_meta)
    _, _, s = load_stack(tmp_path / "s.npz")
    assert s.encoder == {"method": "sgd"} and s.to_dict() == {**meta, "encoder": {"method": "sgd"}}
    assert parse_result_meta(s).z_inf_m == 0.08  # a stack from a render carries the render's geometry


@pytest.mark.parametrize("change, field", [
    ({"z_wrp_m": None}, "z_wrp_m"),
    ({"focal_length_m": -0.05}, "focal_length_m"),
    ({"pitch_m": 0.0}, "pitch_m"),
    ({"wavelengths_m": [640.0, 516.5, 455.4]}, "wavelengths_m"),  # nanometres where metres belong
    ({"wavelengths_m": []}, "wavelengths_m"),
])
def test_a_wrong_field_is_one_line_naming_it(change, field):
    meta = {k: v for k, v in {**GEOMETRY, **change}.items() if v is not None}
    with pytest.raises(MetaError) as err:
        parse_result_meta(meta, what="result r.npz")
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"result r.npz: meta.{field}")


def test_what_each_reader_needs():
    assert parse_stack_meta({"wavelengths_m": [5e-7]}).z_wrp_m is None  # the SLM needs only the wavelengths
    view = parse_view_meta({k: v for k, v in GEOMETRY.items() if k != "z_wrp_m"})  # a viewer needs no WRP
    assert view.focal_length_m == 0.05
    with pytest.raises(MetaError, match="meta.focal_length_m"):
        parse_view_meta({"wavelengths_m": [5e-7]}, what="stack s.npz")
    with pytest.raises(MetaError, match="must be a JSON object"):
        parse_stack_meta(["not", "an", "object"])


def test_a_stack_whose_wavelengths_do_not_match_its_colors_is_not_written(tmp_path):
    with pytest.raises(ValueError, match="3 wavelengths for 2 colors"):
        save_stack(tmp_path / "s.npz", phase=np.zeros((1, 2, 4, 4)), meta=GEOMETRY)
    assert list(tmp_path.iterdir()) == []
