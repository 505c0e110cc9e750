"""The quality model (holocore/plan/quality.py) and the choices built on it (holocore/plan/quality_choice.py,
service/quality.py): what a job's options buy, before it runs.

The model's accuracy against measured jobs is bench/quality_fit.py's (bench/results/quality/); here, that the
fitted model keeps the physics it was built on: speckle and encoder error average over frames, Monte Carlo
noise falls with rays, the parts add as powers, a brighter-on-average scene has more to lose, and that the
choices take the quickest options predicted to reach a target.
"""

from __future__ import annotations

import math

import pytest

from holocore.display.profiles import PAPER
from holocore.plan.effects import noise_factor
from holocore.plan.quality import PARTS, UNRECOGNISABLE_DB, predict_for, predict_quality, quality_model
from holocore.plan.quality_choice import Candidate, choose_for_quality, choose_for_time, front
from holocore.render_setup import RenderOptions

BASE = dict(frame_phases="coded", noise_to_signal=1.0, encoder="sgd")


def _p(**kw) -> float:
    return predict_quality(**{**BASE, "frames": 24, **kw}).psnr_db


def test_more_frames_more_rays_and_more_iterations_predict_more_db():
    frames = [_p(frames=F) for F in (2, 4, 8, 16, 24, 48)]
    assert all(b > a for a, b in zip(frames, frames[1:])), frames
    rays = [_p(noise_to_signal=v) for v in (16.0, 4.0, 1.0, 0.25)]
    assert all(b >= a for a, b in zip(rays, rays[1:])) and rays[-1] > rays[0], rays
    its = [_p(iterations=n) for n in (5, 20, 80)]
    assert its[0] <= its[1] <= its[2], its
    assert _p(encoder="dpac") < _p(encoder="sgd") - 3  # DPAC's checkerboard lands in a full-band cone


def test_speckle_averages_over_frames_at_the_fitted_rate():
    """Coded frames: the speckle part's power falls as F^-a with a between 1/2 and 1 (1: independent speckle
    patterns; the fit says how close the frames come)."""
    a = quality_model()["coefficients"]["a_coded"]
    assert 0.5 <= a <= 1.0
    p8 = predict_quality(**BASE, frames=8).error_power["speckle"]
    p32 = predict_quality(**BASE, frames=32).error_power["speckle"]
    assert p8 / p32 == pytest.approx(4 ** a, rel=1e-9)


def test_the_parts_add_as_powers_and_each_says_what_it_costs():
    q = predict_quality(**BASE, frames=8)
    total = sum(q.error_power.values())
    assert q.psnr_db == pytest.approx(-10 * math.log10(total))
    assert set(q.error_power) == set(PARTS)
    for part, db in q.parts_db.items():
        assert db == pytest.approx(10 * math.log10(total / (total - q.error_power[part])))
    # a scene whose light is spread brighter over the picture (larger image statistic) loses more dB
    assert predict_quality(**BASE, frames=8, image_q=0.4).psnr_db < predict_quality(**BASE, frames=8,
                                                                                    image_q=0.1).psnr_db


def test_one_frame_at_sixteen_rays_is_warned_as_unrecognisable():
    theta = max(PAPER.optics().theta_max(lam) for lam in PAPER.optics().wavelengths_m)
    nsr = noise_factor(theta) * 10.0 ** 2 / 16
    q = predict_quality(frames=1, frame_phases="coded", noise_to_signal=nsr, encoder="sgd")
    assert q.psnr_db < UNRECOGNISABLE_DB and any("below 12 dB" in w for w in q.warnings), q
    assert not predict_quality(**BASE, frames=24).warnings


def test_predict_for_uses_the_presets_rays_and_the_plans_noise():
    optics = PAPER.optics(resolution_hw=(135, 240), frames=8)
    q = predict_for(optics, RenderOptions(spp=64), subhologram_radius_px=12.0)
    theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    direct = predict_quality(frames=8, frame_phases=optics.frame_phases, encoder="sgd",
                             noise_to_signal=noise_factor(theta) * 144.0 / 64)
    assert q.psnr_db == pytest.approx(direct.psnr_db)


@pytest.mark.parametrize("bad", [dict(frames=0), dict(frames=2.5), dict(noise_to_signal=-1.0),
                                 dict(noise_to_signal=float("nan")), dict(encoder="gs"), dict(image_q=0.0),
                                 dict(image_q=1.5), dict(iterations=-3)])
def test_bad_input_is_one_clear_error(bad):
    with pytest.raises(ValueError):
        predict_quality(**{**BASE, "frames": 8, **bad})


def test_choices_take_the_quickest_that_reaches_and_the_best_that_fits():
    c = [Candidate(frames=F, spp=16, spp_asked=None, iterations=None, psnr_db=db, seconds=s)
         for F, db, s in [(2, 9.0, 5.0), (8, 14.0, 12.0), (16, 16.5, 30.0), (24, 18.0, 40.0), (24, 17.0, 60.0)]]
    assert choose_for_quality(c, 15.0).frames == 16
    assert choose_for_quality(c, 30.0).psnr_db == 18.0  # none reaches it: the best
    assert choose_for_time(c, 35.0).frames == 16
    assert choose_for_time(c, 1.0).seconds == 5.0  # none fits: the quickest
    f = front(c)
    assert [x.seconds for x in f] == [5.0, 12.0, 30.0, 40.0]  # the 60 s, 17 dB mix is beaten by 40 s, 18 dB


def test_the_recording_radius_gives_back_the_plans_noise():
    """Predictions read the noise as the plan set it: the radius recovered from a plan's noise-to-signal at its
    rays gives that noise-to-signal again at those rays, and the preset's choice of rays from it."""
    from holocore.plan.effects import choose_spp
    from holocore.plan.quality import recording_radius_px

    optics = PAPER.optics(resolution_hw=(135, 240), frames=8)
    theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    for rho, n in ((7.5, 16), (24.0, 100), (40.0, 512)):
        nsr = noise_factor(theta) * rho ** 2 / n
        assert recording_radius_px(noise_to_signal=nsr, spp=n, theta_max=theta) == pytest.approx(rho)
    rho = 12.0
    n = choose_spp("balanced", rho, theta)
    q = predict_for(optics, RenderOptions(), subhologram_radius_px=rho)
    assert q.psnr_db == pytest.approx(predict_quality(frames=8, frame_phases=optics.frame_phases, encoder="sgd",
                                                      noise_to_signal=noise_factor(theta) * rho ** 2 / n).psnr_db)
