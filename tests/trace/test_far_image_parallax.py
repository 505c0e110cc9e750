"""Parallax of an image point far behind its recording plane (docs/design.md §3-4, §7).

A small glowing ball 1.5 m away, seen in a plane mirror 0.5 m away turned 12 degrees: its image lies 4.5 mm (in
hologram space) behind the WRP that the mirror puts in front of it, 5.7 mm in front of the SLM that the direct
method records on. Seen through a 1 mm pupil focused on it from eye positions 0.8 mm left and right, the ball must
move as the thin-lens ground truth says (-e / zc).

The traced field is a Monte Carlo estimate: each pixel's rays sample the ball's random-phase cells sparsely, and
the error is independent from pixel to pixel, a white field on the recording plane that the eye sees as a glow
*on that plane*, with its parallax. Far from the plane the rays per cell fall as 1 / d^2 and at 256 rays per pixel
the glow carries more light than the point (1.5x on one plane, 2x on the SLM), so the single render's centroid
moves towards the plane's parallax (several pixels). What the geometry must get right is the field's mean: the
eye's intensity of the mean field, estimated without the glow from K renders of independent ray seeds,
(I(sum U_k) - sum I(U_k)) / (K (K - 1)) (the eye's intensity is quadratic in the field; cross terms of independent
errors average out).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.evaluate.groundtruth import GroundTruth
from holocore.evaluate.scoring import eye_view
from holocore.pipeline import RenderOptions, render_loaded
from holocore.scene.load import from_mitsuba_scene
from tests.trace.optics_probe import fov_deg
from tests.trace.scenes import T, camera

pytestmark = pytest.mark.slow

H, W, P, F_M, Z_INF = 96, 128, 8e-6, 0.05, 4e-3
TILT_DEG = 12.0
Z_BALL = Z_INF + F_M * F_M / 1.5  # the ball's image depth in hologram space (1.5 m of path)
EYES = (-0.8e-3, 0.8e-3)
SEEDS = (44, 55, 66, 77, 88)  # five: the glow's own cross terms leave about 0.4 px of scatter (three: 0.8)
TOL_PX = 0.7
# the point behind its recording plane and in front of it (the SLM): the two signs of the plane's parallax; a
# second plane nearer the point lies between them (about 0.3 px short of the ground truth when last measured)
CASES = {"one_plane": {"wrp_planes": 1}, "direct": {"method": "direct"}}


def _scene():
    from holocore.runtime.mitsuba_env import mitsuba

    mi = mitsuba()
    ang = math.radians(2 * TILT_DEG)  # the mirror turned by TILT turns the line of sight by twice it
    return mi.load_dict({
        "type": "scene", "sensor": camera(fov=fov_deg(W, P, F_M)),
        "mirror": {"type": "rectangle", "bsdf": {"type": "conductor"},
                   "to_world": T().translate([0, 0, -0.5]).rotate([0, 1, 0], TILT_DEG).scale(0.05)},
        "ball": {"type": "sphere", "center": [math.sin(ang), 0, -0.5 + math.cos(ang)], "radius": 0.0015,
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 50.0}}},
    })


def _centroid_x(img: np.ndarray, ref: np.ndarray) -> float:
    """Column centroid of ``img`` (summed over colours) in a 49 px window about ``ref``'s brightest spot, above
    the window's 10th percentile."""
    from scipy.ndimage import gaussian_filter

    py, px = np.unravel_index(np.argmax(gaussian_filter(ref.sum(0), 2.0)), ref.shape[1:])
    y0, x0 = max(0, py - 24), max(0, px - 24)
    win = img.sum(0)[y0:py + 25, x0:px + 25]
    win = np.clip(win - np.percentile(win, 10), 0.0, None)
    return float((win.sum(0) * (x0 + np.arange(win.shape[1]))).sum() / win.sum())


OPTICS = dict(resolution_hw=(H, W), pitch_um=P * 1e6, frames=8, focal_length_mm=F_M * 1e3, z_inf_mm=Z_INF * 1e3,
              seed=1)


def _renders(loaded, **kw) -> list:
    """The renders of SEEDS at 256 rays per pixel. No cone equaliser: it fits its filter to each render's own
    spectrum, and the glow-free estimate needs the renders to differ by their rays alone."""
    return [render_loaded(loaded, OpticsConfig(**OPTICS), RenderOptions(preset="fast", spp=256, ray_seed=s,
                                                                         cone_equaliser=False, **kw))
            for s in SEEDS]


def _eye_rows(fields: list, gt) -> list[tuple]:
    """Per eye, focused on the ball through a 1 mm pupil: (the first render's view, the glow-free mean field's
    (module docstring), the ground truth's, the renders' average)."""
    meta, total, k = fields[0].meta, sum(r.slm_field for r in fields), len(fields)
    rows = []
    for e in EYES:
        kw_view = dict(focus_z_m=Z_BALL, pupil_diameter_m=1e-3, view_offset_m=(e, 0.0))
        each = [eye_view(r.slm_field, meta, **kw_view) for r in fields]
        rows.append((each[0], (eye_view(total, meta, **kw_view) - sum(each)) / (k * (k - 1)), gt.channels(**kw_view),
                     sum(each) / k))
    return rows


@pytest.fixture(scope="module")
def views():
    """Per case: :func:`_eye_rows` of the mirror scene's renders."""
    loaded = from_mitsuba_scene(_scene())
    gt, out = None, {}
    for name, kw in CASES.items():
        fields = _renders(loaded, **kw)
        if gt is None:
            gt = GroundTruth(loaded, fields[0].meta, shape_hw=(H, W), spp=64)
        out[name] = _eye_rows(fields, gt)
    return out


@pytest.mark.parametrize("case", list(CASES))
def test_mean_field_parallax_matches_ground_truth(views, case):
    """The traced field's mean shows the ball where the ground truth does from both eye positions, recorded on
    one plane 4.5 mm in front of it or on the SLM 5.7 mm behind it."""
    for e, (_single, mean_field, truth, _avg) in zip(EYES, views[case]):
        ours, want = _centroid_x(mean_field, truth), _centroid_x(truth, truth)
        assert abs(ours - want) < TOL_PX, f"{case}, eye {e * 1e3:+.1f} mm: column {ours:.2f}, ground truth {want:.2f}"


@pytest.mark.xfail(strict=True, reason="Monte Carlo glow on the recording plane: at 256 rays per pixel a point "
                                       "4.5 mm behind one plane gets more glow than signal, and a single render's "
                                       "ball moves about 2.9x as far as the ground truth's between the eyes "
                                       "(columns 73.4 / 54.4 against 66.9 / 60.3)")
def test_single_render_parallax_one_plane(views):
    for _e, (single, _mean, truth, _avg) in zip(EYES, views["one_plane"]):
        assert abs(_centroid_x(single, truth) - _centroid_x(truth, truth)) < TOL_PX


# Near-smooth surfaces (holocore/trace/near_smooth.py): the chain goes on through sampled micro-normals, so the
# ball's blurred image keeps its depth and its parallax. The mean field shows it; a single render adds the glow
# (bench/results/near_smooth_sweep.md measures alpha 0.001-0.3 for metal and glass).
NEAR_SMOOTH = {"metal_0.001": ("metal", 0.001), "glass_0.003": ("glass", 0.003)}
# On the difference between the eyes: each mean-field centroid scatters by about 0.4 px with five renders (above),
# the difference by about 0.6 px. Measured: metal -5.9 px, glass -6.6 px against the truth's -6.7; the first
# render alone -10.0 and -13.0 (its glow).
SHIFT_TOL_PX = 1.2


def _near_smooth_scene(kind: str, alpha: float):
    """The ball seen in a rough metal plate turned 12 degrees, or through a rough glass plate 5 mm thick."""
    from holocore.runtime.mitsuba_env import mitsuba

    mi = mitsuba()
    if kind == "glass":
        plate = {"type": "cube", "bsdf": {"type": "roughdielectric", "alpha": alpha, "int_ior": 1.5},
                 "to_world": T().translate([0, 0, -0.5]).scale([0.05, 0.05, 0.0025])}
        centre = [0.0, 0.0, -1.5]
    else:
        plate = {"type": "rectangle", "bsdf": {"type": "roughconductor", "alpha": alpha},
                 "to_world": T().translate([0, 0, -0.5]).rotate([0, 1, 0], TILT_DEG).scale(0.05)}
        ang = math.radians(2 * TILT_DEG)
        centre = [math.sin(ang), 0, -0.5 + math.cos(ang)]
    return mi.load_dict({
        "type": "scene", "sensor": camera(fov=fov_deg(W, P, F_M)), "plate": plate,
        "ball": {"type": "sphere", "center": centre, "radius": 0.0015,
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 50.0}}},
    })


@pytest.fixture(scope="module", params=list(NEAR_SMOOTH))
def near_smooth_views(request):
    """(the case, :func:`_eye_rows` of its renders, the plan's noise-to-signal estimate)."""
    loaded = from_mitsuba_scene(_near_smooth_scene(*NEAR_SMOOTH[request.param]))
    fields = _renders(loaded)
    gt = GroundTruth(loaded, fields[0].meta, shape_hw=(H, W), spp=64)
    return request.param, _eye_rows(fields, gt), float(fields[0].meta["plan"]["noise_to_signal"])


def test_near_smooth_image_moves_with_the_eye_as_the_ground_truth(near_smooth_views):
    """Seen in near-smooth metal and through near-smooth glass, the ball's image moves between eyes 1.6 mm apart
    as far as in Mitsuba's thin-lens render (its geometric parallax, -6.7 px), in the mean field."""
    case, row, _noise = near_smooth_views
    ours = [_centroid_x(mean, truth) for _single, mean, truth, _avg in row]
    want = [_centroid_x(truth, truth) for _single, _mean, truth, _avg in row]
    assert abs((ours[1] - ours[0]) - (want[1] - want[0])) < SHIFT_TOL_PX, (case, ours, want)
    assert all(abs(o - w) < 2 * SHIFT_TOL_PX for o, w in zip(ours, want)), (case, ours, want)


def test_the_plan_counts_the_near_smooth_glow(near_smooth_views):
    """The plan's Monte Carlo noise estimate widens the sub-hologram by the lobe's spread
    (holocore.plan.effects.lobe_spread_px): it meets the glow the eye sees within a factor 2 for metal, and errs
    high, within 3x, for glass (the spread taken as a reflection's). Measured: 1.7 and 3.0 against the smooth
    plan's 0.39 for both."""
    case, row, noise = near_smooth_views
    glow = np.mean([(avg.sum() - mean.sum()) / mean.sum() for _single, mean, _truth, avg in row])
    low, high = (0.5, 2.0) if case.startswith("metal") else (1.0, 3.0)
    assert low * glow < noise < high * glow, (case, glow, noise)
