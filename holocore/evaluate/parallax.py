"""The motion parallax of the viewer-faithful score (:mod:`holocore.evaluate.viewer`): the image shift between two
views of one focus plane, by phase correlation, for the outer eyes of each row of the eye grid."""

from __future__ import annotations

import numpy as np

__all__ = ["image_shift_px", "parallax_shifts"]


def image_shift_px(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(rows, cols) shift of image ``b`` against ``a`` (float [H, W]), b(x) = a(x - shift): the peak of their
    cross-correlation (means removed, a Hann window against the borders, both smoothed by a 1-px Gaussian so that
    speckle and Monte Carlo noise do not make the peak), refined by a parabola through its neighbours."""
    from scipy.ndimage import gaussian_filter

    a = gaussian_filter(np.asarray(a, dtype=np.float64), 1.0)
    b = gaussian_filter(np.asarray(b, dtype=np.float64), 1.0)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"images must be [H, W] of one shape, got {a.shape} and {b.shape}")
    win = np.outer(np.hanning(a.shape[0]), np.hanning(a.shape[1]))
    A = np.fft.fft2((a - a.mean()) * win)
    B = np.fft.fft2((b - b.mean()) * win)
    corr = np.fft.ifft2(B * np.conj(A)).real
    i, j = np.unravel_index(int(np.argmax(corr)), corr.shape)
    H, W = corr.shape

    def sub(c_m, c_0, c_p):
        den = c_m - 2 * c_0 + c_p
        return 0.0 if abs(den) < 1e-30 else float(np.clip(0.5 * (c_m - c_p) / den, -0.5, 0.5))

    di = sub(corr[(i - 1) % H, j], corr[i, j], corr[(i + 1) % H, j])
    dj = sub(corr[i, (j - 1) % W], corr[i, j], corr[i, (j + 1) % W])
    return float((i + H // 2) % H - H // 2 + di), float((j + W // 2) % W - W // 2 + dj)


def _centre_crop(x: np.ndarray, h: int, w: int) -> np.ndarray:
    """The centred h x w part of a 2-D image."""
    return x[(x.shape[0] - h) // 2:(x.shape[0] - h) // 2 + h, (x.shape[1] - w) // 2:(x.shape[1] - w) // 2 + w]


def parallax_shifts(lumimg: dict, n_pupils: int, n_focus: int, eye_grid: int) -> dict[int, list[tuple[float, float]]]:
    """Motion parallax, pupil index -> [(recon, truth) column shift px]: the outer eyes of each grid row at each
    focus, on the part both views score."""
    n = int(eye_grid)
    pairs = [(row * n, row * n + n - 1) for row in range(n)] if n > 1 else []
    par: dict[int, list[tuple[float, float]]] = {pi_: [] for pi_ in range(n_pupils)}
    for pi_ in range(n_pupils):
        for zi in range(n_focus):
            for a, b in pairs:
                (ra, ga), (rb, gb) = lumimg[(pi_, zi, a)], lumimg[(pi_, zi, b)]
                h, w = min(ra.shape[0], rb.shape[0]), min(ra.shape[1], rb.shape[1])
                sr = image_shift_px(_centre_crop(ra, h, w), _centre_crop(rb, h, w))[1]
                sg = image_shift_px(_centre_crop(ga, h, w), _centre_crop(gb, h, w))[1]
                par[pi_].append((sr, sg))
    return par
