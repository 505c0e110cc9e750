"""Image metrics: PSNR, SSIM (Wang et al. 2004), least-squares brightness fit, speckle contrast."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from holocore.evaluate.metrics import fit_brightness, psnr, speckle_contrast, ssim


def smooth_image(shape=(64, 80), seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[: shape[0], : shape[1]]
    img = 0.5 + 0.3 * np.sin(x / 7.0) * np.cos(y / 5.0) + 0.05 * rng.normal(size=shape)
    return img


def test_psnr_identical_is_inf_and_known_mse():
    ref = smooth_image()
    assert psnr(ref, ref) == math.inf
    rng = np.random.default_rng(1)
    noise = rng.choice([-0.1, 0.1], size=ref.shape)  # MSE exactly 0.01
    assert psnr(ref + noise, ref, data_range=1.0) == pytest.approx(20.0, abs=1e-9)
    # default range: max - min of the reference
    dr = ref.max() - ref.min()
    assert psnr(ref + noise, ref) == pytest.approx(10 * math.log10(dr**2 / 0.01), abs=1e-9)
    # torch and numpy agree; [C, H, W] uses the MSE over all channels
    t = torch.from_numpy(np.stack([ref, ref]))
    assert psnr(t + torch.from_numpy(np.stack([noise, noise])), t, data_range=1.0) == pytest.approx(20.0, abs=1e-9)
    assert psnr(np.stack([ref + noise, ref]), np.stack([ref, ref]), data_range=1.0) == pytest.approx(
        10 * math.log10(1 / 0.005), abs=1e-9)


def test_ssim_identical_noise_and_monotonic():
    ref = smooth_image()
    assert ssim(ref, ref) == pytest.approx(1.0, abs=1e-12)
    rng = np.random.default_rng(2)
    values = [ssim(ref + s * rng.normal(size=ref.shape), ref, data_range=1.0) for s in (0.02, 0.1, 0.3)]
    assert all(v < 1.0 for v in values)
    assert values[0] > values[1] > values[2]
    assert values[2] < 0.5
    # Pure noise against a structured image: low SSIM
    assert ssim(rng.uniform(size=ref.shape), ref, data_range=1.0) < 0.2
    # symmetric in its arguments for a fixed range
    a = ref + 0.1 * rng.normal(size=ref.shape)
    assert ssim(a, ref, data_range=1.0) == pytest.approx(ssim(ref, a, data_range=1.0), abs=1e-12)


def test_ssim_luminance_term_of_a_constant_shift():
    """For pred = ref + c the contrast-structure term is exactly 1, so SSIM is the mean luminance term
    (2 mu_x mu_y + C1) / (mu_x^2 + mu_y^2 + C1): for a flat reference that is a closed form."""
    ref = np.full((40, 40), 0.5)
    c, dr = 0.1, 1.0
    c1 = (0.01 * dr) ** 2
    expected = (2 * 0.5 * 0.6 + c1) / (0.5**2 + 0.6**2 + c1)
    assert ssim(ref + c, ref, data_range=dr) == pytest.approx(expected, abs=1e-9)


def test_ssim_channels_are_averaged():
    r = np.stack([smooth_image(seed=3), smooth_image(seed=4)])
    rng = np.random.default_rng(5)
    p = r + np.stack([0.02 * rng.normal(size=r.shape[1:]), 0.2 * rng.normal(size=r.shape[1:])])
    per = [ssim(p[c], r[c], data_range=1.0) for c in range(2)]
    assert ssim(p, r, data_range=1.0) == pytest.approx(np.mean(per), abs=1e-12)
    assert ssim(torch.from_numpy(p), torch.from_numpy(r), data_range=1.0) == pytest.approx(np.mean(per), abs=1e-12)


def test_channel_last_rgb_is_recognised():
    """[H, W, 3] previews (channel-last) give the same values as their [3, H, W] transpose."""
    r = np.stack([smooth_image(seed=s) for s in (3, 4, 5)])
    rng = np.random.default_rng(8)
    p = r + 0.05 * rng.normal(size=r.shape)
    r_last, p_last = np.moveaxis(r, 0, -1), np.moveaxis(p, 0, -1)
    assert ssim(p_last, r_last, data_range=1.0) == pytest.approx(ssim(p, r, data_range=1.0), abs=1e-12)
    assert psnr(p_last, r_last, data_range=1.0) == pytest.approx(psnr(p, r, data_range=1.0), abs=1e-12)
    # an explicit axis overrides the guess (a 4 x 4 x 3 image is ambiguous)
    small = rng.uniform(size=(4, 40, 3))
    assert ssim(small, small * 0.9, channel_axis=-1) == pytest.approx(
        ssim(np.moveaxis(small, -1, 0), np.moveaxis(small, -1, 0) * 0.9), abs=1e-12)
    with pytest.raises(ValueError, match="channel_axis"):
        ssim(small, small, channel_axis=1)


def test_fit_brightness_recovers_scale():
    ref = smooth_image()
    pred = ref / 3.7
    scaled, s = fit_brightness(pred, ref)
    assert s == pytest.approx(3.7, rel=1e-12)
    assert np.allclose(scaled, ref)
    rng = np.random.default_rng(6)
    noisy = pred + 0.01 * rng.normal(size=ref.shape)
    _, s2 = fit_brightness(noisy, ref)
    # least squares: s minimises ||s p - r||, so nearby scales are worse
    for ds in (-1e-3, 1e-3):
        assert np.sum((s2 * noisy - ref) ** 2) < np.sum(((s2 + ds) * noisy - ref) ** 2)
    t_scaled, t_s = fit_brightness(torch.from_numpy(pred), torch.from_numpy(ref))
    assert isinstance(t_scaled, torch.Tensor) and t_s == pytest.approx(3.7, rel=1e-12)
    _, s4 = fit_brightness(np.stack([pred] * 6).reshape(2, 3, *ref.shape), np.stack([ref] * 6).reshape(2, 3, *ref.shape))
    assert s4 == pytest.approx(3.7, rel=1e-12)  # any shape, e.g. [F, C, H, W]
    with pytest.raises(ValueError, match="shapes differ"):
        fit_brightness(pred, ref[:-1])
    zeros_scaled, s0 = fit_brightness(np.zeros_like(ref), ref)  # no division by zero
    assert s0 == 1.0 and np.all(zeros_scaled == 0)


def test_speckle_contrast():
    rng = np.random.default_rng(7)
    speckle = rng.exponential(size=200_000)  # fully developed speckle intensity: contrast 1
    assert speckle_contrast(speckle) == pytest.approx(1.0, abs=0.01)
    avg = rng.exponential(size=(16, 200_000)).mean(0)  # 16 independent looks: 1/4
    assert speckle_contrast(avg) == pytest.approx(0.25, abs=0.01)
    assert speckle_contrast(np.full(10, 3.0)) == 0.0
    img = np.ones((4, 4))
    img[0, 0] = 100.0
    mask = np.ones((4, 4), bool)
    mask[0, 0] = False
    assert speckle_contrast(img, mask=mask) == 0.0
    with pytest.raises(ValueError, match="zero"):
        speckle_contrast(np.zeros(5))


@pytest.mark.parametrize(
    "pred,ref,match",
    [
        (np.ones((4, 4)), np.ones((4, 5)), "shapes differ"),
        (np.ones(4), np.ones(4), r"\[H, W\]"),
        (np.ones((32, 32, 16)), np.ones((32, 32, 16)), "colour axis"),
        (np.full((4, 4), np.nan), np.ones((4, 4)), "NaN"),
        (np.ones((4, 4), complex), np.ones((4, 4)), "real"),
    ],
)
def test_invalid_inputs(pred, ref, match):
    with pytest.raises(ValueError, match=match):
        psnr(pred, ref)
    with pytest.raises(ValueError, match=match):
        ssim(pred, ref)


def test_invalid_data_range():
    with pytest.raises(ValueError, match="data_range"):
        psnr(np.ones((4, 4)), np.zeros((4, 4)), data_range=0.0)


def test_brightest_blob_finds_a_gaussian_spots_centre_and_half_light_radius():
    """A 2-D Gaussian of width sigma holds half its light within sigma sqrt(2 ln 2) of its centre; a dimmer
    spot elsewhere is not the brightest blob."""
    from holocore.evaluate.metrics import brightest_blob

    yy, xx = np.mgrid[0:96, 0:128].astype(np.float64)
    sigma, cy, cx = 3.0, 40.3, 71.6
    img = np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * sigma ** 2))
    img += 0.3 * np.exp(-((yy - 20) ** 2 + (xx - 20) ** 2) / 8.0)
    r50, y, x = brightest_blob(np.stack([img, 0.5 * img]))
    assert (y, x) == pytest.approx((cy, cx), abs=0.05)
    assert r50 == pytest.approx(sigma * np.sqrt(2 * np.log(2)), rel=0.08)
