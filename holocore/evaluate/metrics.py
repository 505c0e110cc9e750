"""Image quality metrics for reconstructions vs ground truth (docs/design.md §7).

Images are 2D [H, W] or 3D with a colour axis, numpy or torch, real. The colour axis is the first one
([C, H, W], the project's layout) when it has <= 8 entries, else the last one ([H, W, C], e.g. an RGB preview);
``channel_axis`` (0 or -1) overrides the guess. ``data_range`` defaults to the reference's max - min (1 when the
reference is flat).
"""

from __future__ import annotations

import math
from typing import Optional, Union

import numpy as np
from scipy.ndimage import gaussian_filter

__all__ = ["psnr", "ssim", "fit_brightness", "speckle_contrast", "white_power", "brightest_blob"]

ArrayLike = Union[np.ndarray, "torch.Tensor"]  # noqa: F821 (torch is optional here)
_MAX_CHANNELS = 8


def _to_numpy(name: str, a: object) -> np.ndarray:
    if hasattr(a, "detach") and hasattr(a, "cpu"):  # torch tensor, without importing torch
        a = a.detach().cpu().numpy()
    arr = np.asarray(a)
    if np.iscomplexobj(arr):
        raise ValueError(f"{name} must be real (an intensity image), got complex")
    if arr.dtype == bool or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be a numeric array, got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    if arr.ndim not in (2, 3):
        raise ValueError(f"{name} must be [H, W], [C, H, W] or [H, W, C], got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def _channels_first(arr: np.ndarray, channel_axis: Optional[int]) -> np.ndarray:
    """[C, H, W] view of a 3D image (2D passes through); see the module docstring for the axis rule."""
    if arr.ndim == 2:
        return arr
    if channel_axis is None:
        if arr.shape[0] <= _MAX_CHANNELS:
            channel_axis = 0
        elif arr.shape[-1] <= _MAX_CHANNELS:
            channel_axis = -1
        else:
            raise ValueError(f"cannot tell the colour axis of shape {arr.shape}: neither the first nor the last "
                             f"has <= {_MAX_CHANNELS} entries (pass channel_axis)")
    if channel_axis not in (0, -1, 2):
        raise ValueError(f"channel_axis must be 0 or -1, got {channel_axis!r}")
    return arr if channel_axis == 0 else np.moveaxis(arr, -1, 0)


def _pair(pred: object, ref: object, channel_axis: Optional[int] = None) -> tuple[np.ndarray, np.ndarray]:
    p, r = _to_numpy("pred", pred), _to_numpy("ref", ref)
    if p.shape != r.shape:
        raise ValueError(f"pred and ref shapes differ: {p.shape} vs {r.shape}")
    return _channels_first(p, channel_axis), _channels_first(r, channel_axis)


def _range(ref: np.ndarray, data_range: Optional[float]) -> float:
    if data_range is None:
        span = float(ref.max() - ref.min())
        return span if span > 0 else 1.0
    dr = float(data_range)
    if not math.isfinite(dr) or dr <= 0:
        raise ValueError(f"data_range must be finite and > 0, got {data_range!r}")
    return dr


def psnr(pred: ArrayLike, ref: ArrayLike, *, data_range: Optional[float] = None,
         channel_axis: Optional[int] = None) -> float:
    """Peak signal-to-noise ratio in dB, 10 log10(range^2 / MSE), MSE over all pixels and channels.

    Identical images give ``inf``.
    """
    p, r = _pair(pred, ref, channel_axis)
    dr = _range(r, data_range)
    mse = float(np.mean((p - r) ** 2))
    if mse == 0.0:
        return math.inf
    return 10.0 * math.log10(dr * dr / mse)


def _ssim2d(x: np.ndarray, y: np.ndarray, dr: float) -> float:
    """Mean SSIM of one channel: Gaussian window sigma 1.5 px (11 x 11), K1 0.01, K2 0.03 (Wang et al. 2004)."""
    sigma, trunc = 1.5, 3.5  # radius int(3.5 * 1.5 + 0.5) = 5 px: the paper's 11 x 11 window
    c1, c2 = (0.01 * dr) ** 2, (0.03 * dr) ** 2

    def g(a: np.ndarray) -> np.ndarray:
        return gaussian_filter(a, sigma=sigma, truncate=trunc, mode="reflect")

    mx, my = g(x), g(y)
    vxx = g(x * x) - mx * mx
    vyy = g(y * y) - my * my
    vxy = g(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * vxy + c2)) / ((mx * mx + my * my + c1) * (vxx + vyy + c2))
    pad = 5  # drop the border where the window reaches past the image (as Wang's reference code does)
    if s.shape[0] > 2 * pad and s.shape[1] > 2 * pad:
        s = s[pad:-pad, pad:-pad]
    return float(s.mean())


def ssim(pred: ArrayLike, ref: ArrayLike, *, data_range: Optional[float] = None,
         channel_axis: Optional[int] = None) -> float:
    """Structural similarity (Wang et al. 2004, Gaussian window), averaged over channels; 1 when identical."""
    p, r = _pair(pred, ref, channel_axis)
    dr = _range(r, data_range)
    if p.ndim == 2:
        return _ssim2d(p, r, dr)
    return float(np.mean([_ssim2d(p[c], r[c], dr) for c in range(p.shape[0])]))


def fit_brightness(pred: ArrayLike, ref: ArrayLike) -> tuple[ArrayLike, float]:
    """One least-squares scale s = <pred, ref> / <pred, pred> (docs/design.md §7); returns (s * pred, s).

    Any shape (pred and ref alike); ``scaled_pred`` has the input's type (numpy or torch). An all-zero ``pred``
    gives s = 1.
    """
    p, r = (np.asarray(a.detach().cpu().numpy() if hasattr(a, "detach") else a) for a in (pred, ref))
    if np.iscomplexobj(p) or np.iscomplexobj(r):
        raise ValueError("pred and ref must be real images")
    p, r = p.astype(np.float64), r.astype(np.float64)
    if p.shape != r.shape:
        raise ValueError(f"pred and ref shapes differ: {p.shape} vs {r.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(r))):
        raise ValueError("pred or ref contains NaN or infinite values")
    den = float(np.sum(p * p))
    s = float(np.sum(p * r)) / den if den > 0 else 1.0
    return pred * s, s  # type: ignore[operator]


def speckle_contrast(intensity: ArrayLike, *, mask: Optional[ArrayLike] = None) -> float:
    """Speckle contrast std(I) / mean(I) of an intensity image (optionally over a boolean ``mask``)."""
    if hasattr(intensity, "detach") and hasattr(intensity, "cpu"):
        intensity = intensity.detach().cpu().numpy()
    a = np.asarray(intensity, dtype=np.float64)
    if a.size == 0 or not np.all(np.isfinite(a)):
        raise ValueError("intensity must be a non-empty finite array")
    if mask is not None:
        m = np.asarray(mask.detach().cpu().numpy() if hasattr(mask, "detach") else mask, dtype=bool)
        if m.shape != a.shape:
            raise ValueError(f"mask shape {m.shape} differs from intensity shape {a.shape}")
        a = a[m]
        if a.size == 0:
            raise ValueError("mask selects no pixels")
    mean = float(a.mean())
    if a.min() < 0:
        raise ValueError("intensity must be >= 0")
    if mean <= 0:
        raise ValueError("intensity is zero everywhere: speckle contrast undefined")
    return float(a.std() / mean)


def white_power(image: ArrayLike, *, white_percentile: float = 99.0) -> float:
    """mean(min(I / w, 1)^2) of a linear image, w its ``white_percentile`` (the score's white, docs/design.md
    §7): the error power of speckle or noise that scales with the local intensity, in the score's units, per
    unit of relative error. A black image gives 0. The quality model (holocore.plan.quality) reads it as the
    scene's ``image_q``."""
    if hasattr(image, "detach") and hasattr(image, "cpu"):
        image = image.detach().cpu().numpy()
    a = np.asarray(image, dtype=np.float64)
    if a.size == 0 or not np.all(np.isfinite(a)) or a.min() < 0:
        raise ValueError("image must be a non-empty finite array of intensities >= 0")
    w = float(np.percentile(a, white_percentile))
    return float(np.mean(np.clip(a / w, 0.0, 1.0) ** 2)) if w > 0 else 0.0


def brightest_blob(image: ArrayLike, *, window_px: int = 24) -> tuple[float, float, float]:
    """(radius px holding half its light, centroid row, centroid column) of the brightest blob of ``image``
    ([C, H, W] summed over C, or [H, W]): found after a 2 px Gaussian blur, measured in a +-``window_px`` window
    above the window's 10th-percentile level. How sharp a highlight is at a focus, and where it lies."""
    img = np.asarray(image, dtype=np.float64)
    img = img.sum(axis=0) if img.ndim == 3 else img
    py, px = np.unravel_index(np.argmax(gaussian_filter(img, 2.0)), img.shape)
    y0, x0 = max(0, py - window_px), max(0, px - window_px)
    win = img[y0:py + window_px + 1, x0:px + window_px + 1]
    win = np.clip(win - np.percentile(win, 10), 0, None)
    yy, xx = np.mgrid[y0:y0 + win.shape[0], x0:x0 + win.shape[1]]
    s = max(float(win.sum()), 1e-300)
    cy, cx = float((win * yy).sum() / s), float((win * xx).sum() / s)
    rr = np.hypot(yy - cy, xx - cx).ravel()
    order = np.argsort(rr)
    return float(rr[order][np.searchsorted(np.cumsum(win.ravel()[order]) / s, 0.5)]), cy, cx
