"""The wave-optical ground truth (holocore.evaluate.wave_truth) against the exact field of a flat card.

A flat checker card on one plane of hologram space, as an ideal hologram shows it: its field sqrt(L) with a new
random phase each frame, propagated to the SLM, seen through the simulated eye (``eye_view``) and averaged over
frames. The ground truth of that card must be what that eye sees, at every pupil (2-6 mm, past the SLM's band
included) and defocus (0 and +-0.4 D), for a centred and an off-centre eye: within +-0.02 of checker contrast,
and pixel by pixel within the frames' speckle. The geometric ground truth it replaces (the pupil's defocus disc
convolved with the in-focus Airy pattern) over-blurs there by far more; that is checked too, so that the test
shows the difference the wave-optical truth makes. The SLM here is an ideal one of point-like pixels: the
ground truth is what the display should show, and a real SLM's square pixels add their diffraction orders'
ghosts on top (tests/optics/test_view_pixel_orders.py), an error of the display, not of the truth.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from holocore.evaluate.groundtruth import pupil_diffraction
from holocore.evaluate.scoring import eye_view
from holocore.evaluate.wave_truth import band_share, layer_spacing_m, wave_view
from holocore.optics.propagation import asm

LAM, P, F_EYE, Z_INF = 520e-9, 8e-6, 0.05, 4e-3
Z_CARD = 6e-3  # 2 mm past virtual infinity: zc = f^2 / 2 mm = 1.25 m
N, SQUARE, FRAMES = 192, 4, 48
META = {"focal_length_m": F_EYE, "z_inf_m": Z_INF, "pitch_m": P, "wavelengths_m": [LAM]}
# the scored middle: light from it reaches the SLM and comes back well inside the grid
MID = slice(N // 2 - 40, N // 2 + 40)


def _checker() -> np.ndarray:
    i = np.arange(N)
    return (((i[:, None] // SQUARE) + (i[None, :] // SQUARE)) % 2).astype(np.float64) * 0.9 + 0.1


def _contrast(img: np.ndarray, card: np.ndarray) -> float:
    a, m = img[MID, MID], card[MID, MID] > 0.5
    w, b = a[m].mean(), a[~m].mean()
    return float((w - b) / (w + b))


@pytest.fixture(scope="module")
def slm_field() -> np.ndarray:
    """The card's exact field on the SLM: [F, 1, N, N], a fresh full-band random phase each frame."""
    g = torch.Generator().manual_seed(1)
    amp = torch.from_numpy(np.sqrt(_checker())).to(torch.complex64)
    phase = torch.rand((FRAMES, N, N), generator=g) * (2 * math.pi)
    card = amp * torch.polar(torch.ones_like(phase), phase)
    slm = asm(card, -Z_CARD, LAM, P)  # to the SLM at z = 0
    return slm.numpy()[:, None]


@pytest.mark.parametrize("defocus_m", [-1e-3, 0.0, 1e-3])
@pytest.mark.parametrize("pupil_mm", [2.0, 3.0, 4.0, 6.0])
def test_the_card_is_imaged_as_its_exact_field_is_seen(slm_field, pupil_mm, defocus_m):
    card = _checker()
    z_f, D = Z_CARD + defocus_m, pupil_mm * 1e-3
    seen = eye_view(slm_field, META, focus_z_m=z_f, pupil_diameter_m=D, fourier_filter=False, pixel_orders=False)[0]
    truth = wave_view(card[None, None], [Z_CARD], wavelengths_m=[LAM], pitch_m=P, focal_length_m=F_EYE,
                      z_inf_m=Z_INF, focus_z_m=z_f, pupil_diameter_m=D)[0]
    assert _contrast(truth, card) == pytest.approx(_contrast(seen, card), abs=0.02)
    # pixel by pixel: 2 x 2 blocks, after the one brightness scale a score applies, within the speckle left
    blocks = lambda a: a[MID, MID].reshape(40, 2, 40, 2).mean(axis=(1, 3))  # noqa: E731
    s, t = blocks(seen), blocks(truth)
    scale = float((s * t).sum() / (t * t).sum())
    assert np.sqrt(np.mean((s - scale * t) ** 2)) / s.mean() < 0.12
    # and the brightness: the truth is in the card's radiance; a full-band random field passes the eye in the
    # share of the band the pupil takes
    from holocore.optics.propagation import padded_shape
    from holocore.optics.viewing import pupil_mask

    mask = pupil_mask(padded_shape((N, N)), LAM, P, focal_length_m=F_EYE, pupil_diameter_m=D)
    assert scale == pytest.approx(float(mask.float().mean()), rel=0.05)
    assert truth[MID, MID].mean() == pytest.approx(card[MID, MID].mean(), rel=0.02)


def test_an_off_centre_eye_sees_each_depth_shifted_as_the_viewer_shifts_it(slm_field):
    card = _checker()
    for eye in ((0.8e-3, 0.0), (0.0, -0.6e-3), (0.5e-3, 0.5e-3)):
        z_f = Z_CARD + 1e-3
        seen = eye_view(slm_field, META, focus_z_m=z_f, pupil_diameter_m=2e-3, view_offset_m=eye,
                        fourier_filter=False, pixel_orders=False)[0]
        truth = wave_view(card[None, None], [Z_CARD], wavelengths_m=[LAM], pitch_m=P, focal_length_m=F_EYE,
                          z_inf_m=Z_INF, focus_z_m=z_f, pupil_diameter_m=2e-3, view_offset_m=eye)[0]
        s = seen[MID, MID].ravel()
        corr = {(dy, dx): np.corrcoef(s, np.roll(truth, (dy, dx), (0, 1))[MID, MID].ravel())[0, 1]
                for dy in (-1, 0, 1) for dx in (-1, 0, 1)}
        # the speckle of 48 frames keeps the correlation near 0.88 even where the two agree; a pixel off drops
        # it to 0.6 (and the eye's parallax at 0.8 mm and 1 mm of defocus is 2 px)
        assert max(corr, key=corr.get) == (0, 0) and corr[(0, 0)] > 0.8, (eye, corr)


def test_the_geometric_truth_over_blurs_near_focus(slm_field):
    """What the thin-lens truth did: the defocus disc of the pupil (radius |dz| NA / p px) convolved with the
    in-focus Airy pattern. At 0.4 D and a 3 mm pupil it loses most of the checker's contrast that the eye
    keeps."""
    card = _checker()
    z_f, D = Z_CARD + 1e-3, 3e-3
    seen = eye_view(slm_field, META, focus_z_m=z_f, pupil_diameter_m=D, fourier_filter=False, pixel_orders=False)[0]
    r = 1e-3 * D / (2 * F_EYE) / P
    yy, xx = np.mgrid[-8:9, -8:9]
    disc = ((xx ** 2 + yy ** 2) <= r * r).astype(np.float64)
    disc /= disc.sum()
    spec = np.fft.fft2(card) * np.fft.fft2(np.roll(np.pad(disc, ((0, N - 17), (0, N - 17))), (-8, -8), (0, 1)))
    geometric = pupil_diffraction(np.fft.ifft2(spec).real[None], wavelengths_m=[LAM], pitch_m=P,
                                  numerical_aperture=D / (2 * F_EYE))[0]
    assert _contrast(geometric, card) < _contrast(seen, card) - 0.05


def test_band_share_is_the_pupils_area_the_display_can_fill():
    half = LAM * F_EYE / (2 * P)  # 1.625 mm: the SLM's band, in the pupil's plane
    assert band_share(wavelength_m=LAM, pitch_m=P, focal_length_m=F_EYE, pupil_diameter_m=2e-3) == 1.0
    six = band_share(wavelength_m=LAM, pitch_m=P, focal_length_m=F_EYE, pupil_diameter_m=6e-3)
    assert six == pytest.approx((2 * half) ** 2 / (math.pi * 9e-6), rel=0.01)
    cone = band_share(wavelength_m=LAM, pitch_m=P, focal_length_m=F_EYE, pupil_diameter_m=6e-3, fourier_filter=True)
    assert cone == pytest.approx(half ** 2 / 9e-6, rel=0.01)
    assert layer_spacing_m(pitch_m=P, wavelength_m=LAM) == pytest.approx(2 * P * P / LAM)
