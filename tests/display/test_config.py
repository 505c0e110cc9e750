"""OpticsConfig: paper defaults, SI views, and clear refusals that name the field and its range."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from holocore.display.optics import MAX_SIDE_PX, OpticsConfig


def test_paper_defaults_and_si_views():
    c = OpticsConfig()
    assert c.wavelengths_nm == (640.0, 516.5, 455.4)
    assert c.pitch_m == pytest.approx(8e-6) and c.z_inf_m == pytest.approx(0.08)
    assert c.wavelengths_m == pytest.approx((640e-9, 516.5e-9, 455.4e-9))
    assert c.theta_max(516.5e-9) == pytest.approx(math.asin(516.5e-9 / 16e-6))


def test_focal_length_is_the_displays_unless_fitting_to_the_camera_is_asked_for():
    assert OpticsConfig().focal_length_m(40.0) == pytest.approx(0.05)  # the paper display's f (docs/design.md §3)
    c = OpticsConfig(resolution_hw=(1080, 1920), fit_camera_fov=True)
    f = c.focal_length_m(40.0)
    assert f == pytest.approx((1920 * 8e-6 / 2) / math.tan(math.radians(20.0)))
    assert c.field_of_view_x_deg(40.0) == pytest.approx(40.0)
    assert OpticsConfig(focal_length_mm=25.0).focal_length_m(40.0) == pytest.approx(0.025)
    with pytest.raises(ValueError, match="focal length unknown"):
        OpticsConfig(fit_camera_fov=True).focal_length_m(None)


def test_sub_wavelength_pitch_is_legal_and_opens_the_hemisphere():
    c = OpticsConfig(pitch_um=0.2)
    assert c.theta_max(640e-9) == pytest.approx(math.pi / 2)


@pytest.mark.parametrize("field, value, words", [
    ("pitch_um", float("nan"), "pitch_um"),
    ("pitch_um", -8.0, "greater than 0"),
    ("pitch_um", 0.0, "greater than 0"),
    ("z_inf_mm", float("inf"), "z_inf_mm"),
    ("frames", 0, "frames"),
    ("frames", 10_000, "less than or equal to 256"),
    ("wavelengths_nm", (640.0, float("nan")), "wavelengths_nm"),
    ("wavelengths_nm", (50.0,), "greater than 100"),
    ("wavelengths_nm", (), "1 to 8 wavelengths"),
    ("resolution_hw", (0, 100), f"1..{MAX_SIDE_PX}"),
    ("resolution_hw", (100, 10**6), "width"),
    ("focal_length_mm", -1.0, "focal_length_mm"),
    ("fov_x_deg", 190.0, "fov_x_deg"),
    ("seed", -1, "seed"),
])
def test_nonsense_is_refused_naming_the_field(field, value, words):
    with pytest.raises(ValidationError) as exc:
        OpticsConfig(**{field: value})
    text = str(exc.value)
    assert field in text and words in text


def test_unknown_fields_and_both_f_and_fov_are_refused():
    with pytest.raises(ValidationError, match="pitch_mm"):
        OpticsConfig(pitch_mm=8.0)
    with pytest.raises(ValidationError, match="not both"):
        OpticsConfig(focal_length_mm=20.0, fov_x_deg=30.0)
    with pytest.raises(ValidationError, match="not both"):
        OpticsConfig(focal_length_mm=20.0, fit_camera_fov=True)
    with pytest.raises(ValidationError, match="focal_length_mm is null"):
        OpticsConfig(focal_length_mm=None, fit_camera_fov=False)
    # a record from before fit_camera_fov existed: a null f meant "fit the camera's view"
    assert OpticsConfig(focal_length_mm=None, fov_x_deg=None).fit_camera_fov
