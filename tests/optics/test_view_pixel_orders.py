"""An SLM's square pixels as the eye sees them without a Fourier filter (holocore.optics.viewing, pixel_orders):
each diffraction order carries the sampled field's spectrum times the pixel's sinc (relative to the zeroth
order's), and a ghost of the image sits where that order's tilted light lands."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from holocore.optics.viewing import orders_factor, simulate_view

P, LAM, F = 8e-6, 520e-9, 0.05


def _see(field: np.ndarray, *, e_x_m: float, pupil_m: float, distance_m: float = 0.0,
         pixel_orders: bool = True, fourier_filter: bool = False) -> np.ndarray:
    u = torch.tensor(field, dtype=torch.complex64)[None, None]
    return simulate_view(u, wavelengths_m=[LAM], pitch_m=P, focal_length_m=F, pupil_diameter_m=pupil_m,
                         distance_m=distance_m, view_offset_m=(e_x_m, 0.0), pixel_orders=pixel_orders,
                         fourier_filter=fourier_filter)[0].numpy().astype(np.float64)


def _ramp(nu_per_pitch: float, shape=(64, 128)) -> np.ndarray:
    h, w = shape
    x = (np.arange(w) - (w - 1) / 2) * P
    return np.repeat(np.exp(2j * np.pi * (nu_per_pitch / P) * x)[None, :], h, axis=0)


@pytest.mark.parametrize("order_nu", [-0.75, 1.25, -1.75])
def test_each_order_of_a_tilted_wave_carries_the_pixels_sinc(order_nu):
    # a plane wave at 0.25 / p: the pixel grid sends copies to 0.25 / p + n / p with amplitude sinc(p nu)
    u = _ramp(0.25)
    base = _see(u, e_x_m=LAM * F * 0.25 / P, pupil_m=1e-3)[8:-8, 16:-16].mean()
    ghost = _see(u, e_x_m=LAM * F * order_nu / P, pupil_m=1e-3)[8:-8, 16:-16].mean()
    want = (np.sinc(order_nu) / np.sinc(0.25)) ** 2
    assert ghost / base == pytest.approx(want, rel=0.05)
    assert base == pytest.approx(1.0, rel=0.05)  # the zeroth order as with point-like pixels
    # a display with a filter (or a model of point-like pixels) shows none of it
    assert _see(u, e_x_m=LAM * F * order_nu / P, pupil_m=1e-3, pixel_orders=False).max() < 1e-6 * base
    assert _see(u, e_x_m=LAM * F * order_nu / P, pupil_m=1e-3, fourier_filter=True).max() < 1e-6 * base


def test_a_uniform_field_fills_the_pixels_without_ghosts():
    # pixels of fill factor 1 showing one value are a uniform plane: all orders but the zeroth vanish
    u = np.ones((64, 96), dtype=np.complex128)
    seen = _see(u, e_x_m=0.0, pupil_m=6e-3)
    assert orders_factor(LAM, P, focal_length_m=F, pupil_diameter_m=6e-3) == 3
    assert seen[16:-16, 16:-16].mean() == pytest.approx(1.0, abs=3e-3)
    # where the first order sits only the SLM's edges diffract (the finite field), not its pixels
    assert _see(u, e_x_m=LAM * F / P, pupil_m=1e-3)[16:-16, 16:-16].max() < 1e-3


def test_the_first_orders_ghost_lands_where_its_tilted_light_goes():
    # a wave converging to a point z0 in front of the SLM; an eye looking along the +1 order sees the point
    # displaced by z0 tan(theta), sin(theta) = lambda / p
    h, w, z0 = 64, 160, 5e-3
    y = ((h - 1) / 2 - np.arange(h))[:, None] * P
    x = (np.arange(w) - (w - 1) / 2)[None, :] * P
    r2 = x * x + y * y
    u = np.exp(-2j * np.pi / LAM * np.sqrt(r2 + z0 * z0)) * np.exp(-r2 / (12 * P) ** 2)
    on_axis = _see(u, e_x_m=0.0, pupil_m=2e-3, distance_m=z0)
    ghost = _see(u, e_x_m=LAM * F / P, pupil_m=2e-3, distance_m=z0)

    def spot_col(img):
        row = img.sum(axis=0)
        j = int(np.argmax(row))
        return j - (w - 1) / 2

    s = LAM / P
    assert abs(spot_col(on_axis)) <= 1
    assert spot_col(ghost) == pytest.approx(z0 * s / math.sqrt(1 - s * s) / P, abs=1.5)
    assert np.isfinite(ghost).all() and ghost.max() < on_axis.max()


def test_orders_factor_spans_the_pupils_reach():
    # the refined grid covers sines up to k lambda / 2p (k odd: the orders -n..n, symmetric about the axis)
    band = LAM / (2 * P)
    assert orders_factor(LAM, P, focal_length_m=F, pupil_diameter_m=2 * F * band * 0.99) == 1
    assert orders_factor(LAM, P, focal_length_m=F, pupil_diameter_m=2 * F * band * 1.01) == 3
    assert orders_factor(LAM, P, focal_length_m=F, pupil_diameter_m=2 * F * band * 0.5,
                         view_offset_m=(F * band * 2.6, 0.0)) == 5
    assert orders_factor(LAM, P, focal_length_m=F, pupil_diameter_m=6e-3, fourier_filter=True) == 1


def test_the_eyes_content_shift_moves_the_view_with_its_orders():
    # U'[i, j] = U[i + a_row, j + a_col]: an integer shift moves the whole view, ghosts included
    rng = np.random.default_rng(3)
    u = np.exp(2j * np.pi * rng.random((48, 64)))
    t = torch.tensor(u, dtype=torch.complex64)[None, None]
    kw = dict(wavelengths_m=[LAM], pitch_m=P, focal_length_m=F, pupil_diameter_m=4e-3, distance_m=1e-3,
              view_offset_m=(1e-3, 0.0), pixel_orders=True, pad_factor=4)
    still = simulate_view(t, **kw)[0].numpy()
    moved = simulate_view(t, shift_px=(2.0, -3.0), **kw)[0].numpy()
    a, b = moved[16:-16, 16:-16], still[18:-14, 13:-19]
    # what is left comes from the field's edges, padded otherwise (the same 1 % without the orders)
    assert np.linalg.norm(a - b) < 0.015 * np.linalg.norm(b)
    wrong = still[14:-18, 19:-13]  # the opposite shift
    assert np.linalg.norm(a - wrong) > 0.5 * np.linalg.norm(b)
