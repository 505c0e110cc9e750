"""Measuring what a traced field does: focus curves and region brightness through the simulated eye."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch


def dot_texture(path: Path, *, n: int = 256, spacing: int = 16, radius: int = 1) -> str:
    """White dots on black (each focuses like a point), written as a PNG; returns its path."""
    from PIL import Image

    yy, xx = np.mgrid[0:n, 0:n]
    dy, dx = (yy % spacing) - spacing // 2, (xx % spacing) - spacing // 2
    img = np.where(dx * dx + dy * dy <= radius * radius, 255, 0).astype(np.uint8)
    Image.fromarray(np.stack([img] * 3, axis=-1)).save(path)
    return str(path)


def intensity(field_wrp: np.ndarray, *, z_wrp: float, z_focus: float, wavelength_m: float, pitch_m: float,
              focal_length_m: float, pupil_m: float = 8e-3, color: int = 0) -> np.ndarray:
    """Frame-averaged intensity [H, W] with the eye focused at hologram depth z_focus, from a WRP field."""
    from holocore.optics.viewing import simulate_view

    u = torch.from_numpy(np.ascontiguousarray(field_wrp[:, color:color + 1]))
    out = simulate_view(u, wavelengths_m=[wavelength_m], pitch_m=pitch_m, focal_length_m=focal_length_m,
                        pupil_diameter_m=pupil_m, distance_m=z_focus - z_wrp)
    return out[0].numpy().astype(np.float64)


def concentration(img: np.ndarray) -> float:
    """sum(I^2) / sum(I)^2 * N: 1 for a flat image, large for sharp dots."""
    s = img.sum()
    return float((img * img).sum() / max(s * s, 1e-300) * img.size)


def depth_of_field(wavelength_m: float, pitch_m: float) -> float:
    """Hologram-limited depth of field lambda / NA^2 with NA = sin(theta_max) = lambda / 2p."""
    na = min(1.0, wavelength_m / (2 * pitch_m))
    return wavelength_m / (na * na)


def best_focus(field_wrp, *, z_wrp, z_center, span, n, region=None, **kw) -> tuple[float, list]:
    """Depth (m) of maximal concentration over z_center +- span (parabolic refinement)."""
    zs = np.linspace(z_center - span, z_center + span, n)
    vals = []
    for z in zs:
        img = intensity(field_wrp, z_wrp=z_wrp, z_focus=z, **kw)
        if region is not None:
            img = img[region]
        vals.append(concentration(img))
    k = int(np.argmax(vals))
    if 0 < k < n - 1:
        y0, y1, y2 = vals[k - 1], vals[k], vals[k + 1]
        den = y0 - 2 * y1 + y2
        off = 0.5 * (y0 - y2) / den if den != 0 else 0.0
        return float(zs[k] + off * (zs[1] - zs[0])), vals
    return float(zs[k]), vals


def fov_deg(width_px: int, pitch_m: float, f_m: float) -> float:
    return 2 * math.degrees(math.atan(width_px * pitch_m / 2 / f_m))


def plate_view_colours(tilt_deg: float, *, spp: int, frames: int = 8, views_deg=(-0.5, 0.0, 0.5),
                       **render_kw) -> dict:
    """Mean R, G, B (float64 [3]) of the frame-averaged eye view of a glowing white plate (radiance 1, 0.4 m wide,
    0.5 m away, turned ``tilt_deg`` about y; it fills the view) focused on the plate, per horizontal eye offset
    (degrees), through the paper report's pupil: paper display, 135x240, z_inf 4 mm, one recording plane."""
    import math

    from holocore.display.profiles import PAPER
    from holocore.evaluate.scoring import default_pupil_m, eye_view, lit_margin_px
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.paper import paper_fov_x_deg
    from tests.trace.scenes import camera, emitting_plane, scene

    loaded = scene(sensor=camera(fov=paper_fov_x_deg()), plate=emitting_plane(-0.5, size=0.2, rotate_y_deg=tilt_deg))
    opt = PAPER.optics(resolution_hw=(135, 240), frames=frames, z_inf_mm=4.0)
    res = render_loaded(loaded, opt, RenderOptions(preset="balanced", spp=spp, wrp_planes=1, **render_kw),
                        display=PAPER)
    meta = res.meta
    f = meta["focal_length_m"]
    z = meta["z_inf_m"] + f * f / 0.5  # the plate's centre in hologram space (docs/design.md §3)
    pupil = default_pupil_m(meta, view_deg=0.5)
    out = {}
    for deg in views_deg:
        e = (f * math.tan(math.radians(deg)), 0.0)
        img = eye_view(res.slm_field, meta, focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=e)
        m = lit_margin_px(meta, focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=e)
        out[deg] = img[:, m:-m, m:-m].reshape(3, -1).mean(axis=1)
    return out
