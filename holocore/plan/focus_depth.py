"""Whether an eye can focus through the scene: its depth in depths of field, and the scene scale that would help
(docs/design.md §3, "Scene scale").

Depth in hologram space is f^2 / zc (dioptres times f^2), so a scene modelled metres from its camera lies within a
fraction of one depth of field of the display's eye: the focal sweep shows no change at any focus. The plan says
how many depths of field the light spans for a pupil of :data:`PUPIL_M`, and below one suggests the scale that
brings the near content to :data:`NEAR_TARGET_M` from the eye, where accommodation works (the paper placed its
scenes' cues at 0.5-2 m), or nearer, down to the eye's near point :data:`NEAR_POINT_M`, where 0.5 m is not enough.

The depth of field is lambda / NA^2 with NA the smaller of the pupil's D / 2f and the display's cone sine
lambda / 2p (the light an eye takes from one point is what the hologram sends it): on the paper's display the cone
limits it (0.032 against 0.04 for a 4 mm pupil), and with an eyepiece fitted to a wide camera (a small f) depth in
hologram space shrinks as f^2 while the depth of field does not.
"""

from __future__ import annotations

import math
from statistics import median
from typing import Optional, Sequence

from pydantic import BaseModel

from holocore.display.optics import MAX_SCENE_SCALE, MIN_SCENE_SCALE, common_cone_sine

__all__ = ["FocusDepth", "focus_depth", "PUPIL_M", "NEAR_TARGET_M", "NEAR_POINT_M"]

PUPIL_M = 4e-3  # the eye the plan speaks for: the viewer-faithful score's pupil (docs/evaluation.md)
NEAR_TARGET_M = 0.5  # where a suggested scale puts the near content, from the eye
NEAR_POINT_M = 0.25  # ... where 0.5 m leaves it under one depth of field: the nearest an eye accommodates
NEAR_QUANTILE = 0.05  # the light's near edge: this share of it (luminance-weighted) is nearer
_SUGGEST_BELOW = 0.8  # suggest only a scale that brings the scene at least this much nearer


class FocusDepth(BaseModel):
    """How deep the scene's light is for an eye, in its depths of field."""

    pupil_mm: float
    depth_of_field_mm: float  # hologram space: lambda / NA^2, NA = min(D / 2f, the common cone's sine) (green)
    span_mm: float  # hologram depth from the light's near edge to its far edge (5 % .. 95 %, luminance-weighted)
    depths_of_field: float  # span / depth of field
    near_m: Optional[float]  # eye distance of the light's near edge, at the present scale (m)
    scene_scale: float  # the present scale
    suggested_scene_scale: Optional[float]  # None: no scale needed, or none helps
    summary: str


def _edges(depths: Sequence[float], lo: float) -> tuple[float, float]:
    """(near, far) hologram depths of the light: the quantiles ``lo`` and ``1 - lo`` of the luminance-weighted
    quantile list (front to back)."""
    n = len(depths)
    k = min(n - 1, int(round(lo * n)))
    return float(depths[k]), float(depths[n - 1 - k])


def focus_depth(*, image_depths_holo_m: Sequence[float], z_inf_m: float, focal_length_m: float,
                wavelengths_m: Sequence[float], pitch_m: float, scene_scale: float,
                pupil_m: float = PUPIL_M) -> FocusDepth:
    """The scene's depth for an eye of pupil ``pupil_m`` (m), from the plan's luminance-weighted image depths
    (hologram z, front to back, ``holocore.plan.analysis``)."""
    lam = float(median(wavelengths_m))
    f = float(focal_length_m)
    na = min(pupil_m / (2.0 * f), common_cone_sine(wavelengths_m, pitch_m))
    dof = lam / na ** 2
    words = f"for a {pupil_m * 1e3:g} mm pupil"
    if not image_depths_holo_m:
        return FocusDepth(pupil_mm=pupil_m * 1e3, depth_of_field_mm=dof * 1e3, span_mm=0.0, depths_of_field=0.0,
                          near_m=None, scene_scale=scene_scale, suggested_scene_scale=None,
                          summary="focus: no light reaches the eye, nothing to focus on")
    near, far = _edges(image_depths_holo_m, NEAR_QUANTILE)
    span = max(0.0, near - far)
    n_dof = span / dof
    near_m = f * f / (near - z_inf_m) if near > z_inf_m else math.inf
    head = (f"focus: the scene's light spans {n_dof:.2g} depths of field ({span * 1e3:.3g} mm in hologram space, "
            f"{dof * 1e3:.2g} mm each {words})")
    suggested = None
    if n_dof < 1.0 and math.isfinite(near_m) and NEAR_TARGET_M / near_m < _SUGGEST_BELOW:
        for target in (NEAR_TARGET_M, NEAR_POINT_M):
            s = _round2(min(MAX_SCENE_SCALE, max(MIN_SCENE_SCALE, scene_scale * target / near_m)))
            then = n_dof * scene_scale / s  # hologram depths go as 1 / scale
            if then >= 1.0:
                break
        suggested = s
        tail = (f": an eye sees no focus change; scene scale {s:g} (--scene-scale) brings the near content from "
                f"{near_m:.3g} m to {target:g} m, where it spans {then:.2g} depths of field"
                + ("" if then >= 1.0 else " (still under one: the scene is nearly flat for this display; a "
                   "longer eyepiece f shows depth as f^2)"))
    elif n_dof < 1.0:
        tail = ": the scene is nearly flat for the eye, and no scale brings it nearer than it is"
    else:
        tail = ""
    return FocusDepth(pupil_mm=pupil_m * 1e3, depth_of_field_mm=dof * 1e3, span_mm=span * 1e3,
                      depths_of_field=n_dof, near_m=near_m if math.isfinite(near_m) else None,
                      scene_scale=scene_scale, suggested_scene_scale=suggested, summary=head + tail)


def _round2(x: float) -> float:
    """x to two significant digits (a scale a person types)."""
    return float(f"{x:.2g}")
