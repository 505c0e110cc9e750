"""The viewer-faithful score (holocore.evaluate.viewer): its eye grid, the pupil's share of the cone, the shift
estimator, and that it tells a display whose brightness steps with the eye from one whose brightness does not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from holocore.evaluate.viewer import aperture_share, eye_grid_m, image_shift_px, viewer_score
from holocore.trace.beams import beam_layout, beam_disc_sine

META = {"focal_length_m": 0.05, "z_inf_m": 4e-3, "pitch_m": 8e-6, "wavelengths_m": [640e-9, 516.5e-9, 455.4e-9]}


def test_eye_grid_is_jittered_seeded_and_spans_the_eyebox():
    g = eye_grid_m(META, n=5, seed=3)
    assert len(g) == 25 and g[0][0] == (0, 0) and g[-1][0] == (4, 4)
    span = 0.5 * 0.05 * 455.4e-9 / 16e-6  # half the blue eyebox radius
    step = 2 * span / 4
    e = np.array([v for _i, v in g])
    ideal = np.array([(-span + c * step, span - r * step) for (c, r), _v in g])
    off = np.abs(e - ideal)
    assert off.max() <= 0.3 * step + 1e-12 and off.max() > 0.1 * step  # jittered, within 0.3 of the spacing
    assert np.array_equal(e, np.array([v for _i, v in eye_grid_m(META, n=5, seed=3)]))
    assert not np.allclose(e, np.array([v for _i, v in eye_grid_m(META, n=5, seed=4)]))
    with pytest.raises(ValueError, match="eye grid"):
        eye_grid_m(META, n=0)


def test_aperture_share_is_the_overlap_of_pupil_and_the_common_eyebox():
    s_b = 455.4e-9 / 16e-6  # blue's cone: the one every colour shares
    na = 1.6e-3 / 0.1
    assert aperture_share(META, pupil_diameter_m=1.6e-3, eye_offset_m=(0, 0)) == pytest.approx((na / s_b) ** 2)
    assert aperture_share(META, pupil_diameter_m=20e-3, eye_offset_m=(1e-3, 0)) == pytest.approx(1.0)
    assert aperture_share(META, pupil_diameter_m=1e-3, eye_offset_m=(5e-3, 0)) == 0.0
    # a pupil centred on the rim holds just under half of it
    half = aperture_share(META, pupil_diameter_m=0.4e-3, eye_offset_m=(0.05 * s_b, 0))
    assert half == pytest.approx(0.5 * (0.004 / s_b) ** 2, rel=0.1)
    # a 4 mm pupil holds all of blue's eyebox (2.85 mm at f = 50 mm) and so all of the common one, although it
    # holds only part of red's own cone: one share for every colour
    assert aperture_share(META, pupil_diameter_m=4e-3, eye_offset_m=(0, 0)) == pytest.approx(1.0)


def test_image_shift_finds_a_subpixel_shift():
    rng = np.random.default_rng(0)
    from scipy.ndimage import gaussian_filter, shift

    a = gaussian_filter(rng.random((64, 96)), 2.0)
    b = shift(a, (0.0, 3.4), mode="wrap", order=3)
    si, sj = image_shift_px(a, b)
    assert abs(si) < 0.15 and sj == pytest.approx(3.4, abs=0.15)


class _Flat:
    """Ground truth of a flat white scene: the same radiance in every colour, at any focus, pupil and eye."""

    def channels(self, *, focus_z_m, pupil_diameter_m, view_offset_m):
        return np.ones((3, 48, 64))


def _cone_field(kind: str, F: int = 24, shape=(48, 64)) -> np.ndarray:
    """[F, 3, H, W] on the SLM of a flat scene: 'spread' lights the display's common eyebox (blue's cone) with
    random phases in every colour and frame (an ideal display's flat angular spectrum), 'own' each colour's own
    cone; 'beams' gives frame m one plane wave per colour towards eye position m of beam_layout (no spread)."""
    H, W = shape
    rng = np.random.default_rng(1)
    out = np.zeros((F, 3, H, W), dtype=np.complex64)
    p = META["pitch_m"]
    fy = np.fft.fftfreq(H, d=p)[:, None]
    fx = np.fft.fftfreq(W, d=p)[None, :]
    u = beam_layout(F) * beam_disc_sine(META["wavelengths_m"], p)
    for c, lam in enumerate(META["wavelengths_m"]):
        s = min(1.0, lam / (2 * p)) if kind == "own" else min(min(1.0, v / (2 * p)) for v in META["wavelengths_m"])
        cone = (fx ** 2 + fy ** 2) * lam * lam <= s * s * (1 + 1e-9)
        for m in range(F):
            spec = np.zeros((H, W), dtype=np.complex128)
            if kind in ("spread", "own"):
                spec[cone] = np.exp(2j * np.pi * rng.random(int(cone.sum()))) / math.sqrt(cone.sum())
            else:
                j = int(round(u[m, 0] / lam * W * p)) % W
                i = int(round(-u[m, 1] / lam * H * p)) % H  # rows run down
                spec[i, j] = 1.0
            out[m, c] = (np.fft.ifft2(spec) * H * W).astype(np.complex64)
    return out


@pytest.mark.slow
def test_one_scale_sees_brightness_that_steps_with_the_eye():
    # a display with a Fourier filter: without one, an eye at the eyebox's edge also takes the next diffraction
    # order's light (a real step, but of the display, not of the frames compared here)
    meta = {**META, "display": {"fourier_filter": True}}
    kw = dict(pupils_m=(2e-3, 3e-3), eye_grid=3, seed=0, focus_z_m=[4e-3])
    spread = viewer_score(_cone_field("spread"), meta, _Flat(), **kw)
    beams = viewer_score(_cone_field("beams"), meta, _Flat(), **kw)
    for p in spread.pupils:  # the share of the cone each pupil holds is divided out: flat over the eye grid
        assert p.brightness_max_over_min < 1.06, p
        assert p.colour_cast < 1.06, p
    # 24 beams: a 2 mm pupil holds a different number of them at each eye position
    assert beams.pupils[0].brightness_max_over_min > 1.15, beams.pupils[0]
    assert beams.scale_spread > spread.scale_spread
    assert not any(math.isnan(c.psnr_db) for c in spread.cells + beams.cells)  # inf: a lone beam is exactly flat


@pytest.mark.slow
def test_one_share_for_every_colour_sees_a_red_cast_through_large_pupils():
    """Each colour in its own cone: through a 6 mm pupil (wider than every eyebox) the eye gathers all of each
    colour's light, (s_c / s_blue)^2 more of red than the common eyebox's share says: a red cast that the colour
    balance at 2 mm does not have."""
    meta = {**META, "display": {"fourier_filter": True}}  # each colour's own cone passes; no other order does
    kw = dict(pupils_m=(2e-3, 6e-3), eye_grid=1, seed=0, focus_z_m=[4e-3])
    common = viewer_score(_cone_field("spread"), meta, _Flat(), **kw)
    own = viewer_score(_cone_field("own"), meta, _Flat(), **kw)
    assert all(p.colour_cast < 1.06 for p in common.pupils), common.pupils
    assert own.pupils[1].colour_cast > 1.3, own.pupils[1]


@pytest.mark.parametrize("args, words", [
    (["--pupils-mm", "2,x"], "--pupils-mm must be a comma-separated list"),
    (["--pupils-mm", "0"], "--pupils-mm must list diameters"),
    (["--eye-grid", "12"], "--eye-grid must be in 1..9"),
])
def test_holo_evaluate_viewer_options_fail_in_one_line(tmp_path, args, words):
    from typer.testing import CliRunner

    from holo.app import app

    res = CliRunner().invoke(app, ["evaluate", str(tmp_path / "none.npz"), "--scene", str(tmp_path), "--out",
                                   str(tmp_path / "o"), "--viewer", *args])
    assert res.exit_code != 0 and words in res.output and "Traceback" not in res.output, res.output
