"""A scene's stored plan (``ScenePlan.to_dict()``, made once at the scene's own optics) read at other optics and
options without loading the scene: the one answer to "the plan at these options" that a service gives before a
job runs (its estimate, its memory, its page).

Hologram depth is z_inf + f^2 / (s z_c) (docs/design.md §3, s the scene scale), so every depth beyond z_inf
scales with (f / f_plan)^2 s_plan / s (:func:`depth_scale`, written once here); a sub-hologram's radius in pixels
scales with that depth and with tan(theta) / pitch. Each reader returns None when the stored plan does not say
(a plan from before a field was stored, or a plan that failed).

Light: no numpy, Mitsuba or torch (the API process reads plans).
"""

from __future__ import annotations

import math
from typing import Any, Optional

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, OpticsConfig
from holocore.display.profiles import field_of_view_report
from holocore.options import HologramOptions
from holocore.plan.effects import SceneInventory, lobe_spread_px, make_plan
from holocore.plan.focus_depth import focus_depth

__all__ = ["stored", "depth_scale", "wrp_distance_m", "wrp_margin_m", "scene_depth_m", "image_depths_m",
           "subhologram_radius_px", "lobe_spread", "plan_at_options"]

_UNREADABLE = (KeyError, TypeError, ValueError, ZeroDivisionError)


def stored(scene_plan, optics: OpticsConfig) -> dict[str, Any]:
    """What is stored of a scene's plan (holocore.plan.scene_plan.ScenePlan) made at ``optics``: its dict and
    those optics, which the readers below rescale from (`holo plan --json` prints it)."""
    return {**scene_plan.to_dict(), "optics": optics.model_dump(mode="json")}


def _camera_fov(plan: dict) -> Optional[float]:
    return (plan.get("field_of_view") or {}).get("camera_fov_x_deg")


def depth_scale(plan: dict, optics: OpticsConfig) -> float:
    """(f / f_plan)^2 s_plan / s: how depths beyond z_inf in the plan scale to ``optics`` (KeyError, TypeError,
    ValueError when the plan does not hold its focal length; a plan from before the scene scale was at 1)."""
    s_plan = float((plan.get("optics") or {}).get("scene_scale", 1.0))
    return (optics.focal_length_m(_camera_fov(plan)) / float(plan["focal_length_m"])) ** 2 * s_plan / \
        optics.scene_scale


def wrp_margin_m(optics: OpticsConfig) -> float:
    """How far the WRP keeps from the nearest image point (holocore.plan.analysis): a fixed number of pixels of
    the narrowest colour's cone, so it does not scale with depth."""
    theta_min = min(optics.theta_max(lam) for lam in optics.wavelengths_m)
    return optics.wrp_margin_px * optics.pitch_m / math.tan(theta_min)


def wrp_distance_m(plan: Optional[dict], optics: OpticsConfig) -> Optional[float]:
    """The WRP's distance from the SLM with ``optics`` (m): the nearest image point's depth rescaled, plus the
    margin at these optics (a plan that saw no image point: its WRP's depth rescaled)."""
    try:
        ana, z_inf_plan = plan["analysis"], float(plan["optics"]["z_inf_mm"]) * 1e-3
        near = ana.get("z_near_holo_m")
        if near is None:
            z = optics.z_inf_m + depth_scale(plan, optics) * (float(ana["z_wrp_m"]) - z_inf_plan)
        else:
            z = optics.z_inf_m + depth_scale(plan, optics) * (float(near) - z_inf_plan) + wrp_margin_m(optics)
    except _UNREADABLE:
        return None
    return z if math.isfinite(z) and z > 0 else None


def scene_depth_m(plan: Optional[dict], optics: OpticsConfig) -> Optional[float]:
    """How far behind the WRP the scene's farthest image point lies with ``optics`` (m): the image volume's depth
    rescaled, plus the margin the WRP keeps in front of the nearest point; 0 when nothing is visible."""
    try:
        ana = plan["analysis"]
        near, far = ana["z_near_holo_m"], ana["z_far_holo_m"]
        scale = depth_scale(plan, optics)
    except _UNREADABLE:
        return None
    if near is None or far is None:  # nothing visible: one plane will do
        return 0.0
    depth = scale * abs(float(near) - float(far)) + wrp_margin_m(optics)
    return depth if math.isfinite(depth) and depth >= 0 else None


def image_depths_m(plan: Optional[dict], optics: OpticsConfig) -> Optional[list[float]]:
    """The analysis' image depth samples (hologram z, m) rescaled to ``optics``; None from a plan that stored
    none."""
    try:
        depths, z_inf_plan = plan["analysis"]["image_depths_holo_m"], float(plan["optics"]["z_inf_mm"]) * 1e-3
        if not isinstance(depths, list):
            return None
        k = depth_scale(plan, optics)
        return [optics.z_inf_m + k * (float(z) - z_inf_plan) for z in depths]
    except _UNREADABLE:
        return None


def subhologram_radius_px(plan: dict, optics: OpticsConfig, *, lobes: bool = True) -> float:
    """The farthest image point's sub-hologram radius (px) on the WRP with ``optics``: its distance from the WRP
    (:func:`scene_depth_m`) times tan(theta) / pitch; the plan's own when it does not say its depths. With
    ``lobes``, widened by the near-smooth lobes' spread (:func:`lobe_spread`) as the render's noise sees it."""
    depth = scene_depth_m(plan, optics)
    if not depth:
        radius = float((plan.get("analysis") or {}).get("subhologram_radius_px") or 0.0)
    else:
        theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
        radius = depth * math.tan(min(theta, MAX_CONE_HALF_ANGLE_RAD)) / optics.pitch_m
    return math.hypot(radius, lobe_spread(plan, optics)) if lobes else radius


def lobe_spread(plan: dict, optics: OpticsConfig) -> float:
    """``effects.lobe_spread_px`` of the stored plan's near-smooth surfaces with ``optics`` (0 when it has none or
    cannot say)."""
    try:
        alphas = ((plan.get("inventory") or {}).get("near_smooth") or {}).values()
        ana = plan.get("analysis") or {}
        return lobe_spread_px(alphas, focal_length_m=optics.focal_length_m(_camera_fov(plan)), pitch_m=optics.pitch_m,
                              zc_surface_m=ana.get("zc_first_min_m"), zc_image_m=ana.get("zc_image_max_m"))
    except _UNREADABLE:
        return 0.0


def plan_at_options(plan: Optional[dict], optics: OpticsConfig, options: HologramOptions, *,
                    max_spp: Optional[int] = None) -> Optional[dict[str, Any]]:
    """The effect plan in words that ``options`` at ``optics`` would give: the inventory and pre-pass as stored,
    the farthest sub-hologram rescaled, the options' preset, frames, colours and rays (``max_spp``: the clamp a
    service puts on the preset's choice). The recording planes are placed when the job renders (that needs the
    image points' depths), so they are only named here. None when the plan cannot be read."""
    if not isinstance(plan, dict):
        return None
    try:
        ana = plan.get("analysis") or {}
        theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
        lit = ana.get("colors_lit")
        lit = lit if isinstance(lit, list) and len(lit) == len(optics.wavelengths_nm) else None
        words = make_plan(SceneInventory(**plan["inventory"]), preset=options.preset, frames=optics.frames,
                          n_colors=len(optics.wavelengths_nm), colors_lit=lit, spp=options.spp, max_spp=max_spp,
                          max_delta_seen=ana.get("max_delta_seen"),
                          prepass_capped=int(ana.get("prepass_capped") or 0),
                          delta_bounces=_delta_bounces(ana),
                          subhologram_radius_px=subhologram_radius_px(plan, optics, lobes=False), theta_max=theta,
                          wrp_planes_asked=1, z_inf_m=optics.z_inf_m,
                          lobe_spread_px=lobe_spread(plan, optics)).summary
        words += _planes_words(options)
        if _camera_fov(plan) is not None:
            words.append(field_of_view_report(optics, float(_camera_fov(plan)))["summary"])
        words += _focus_words(plan, optics)
        words += [w for w in plan.get("summary") or [] if isinstance(w, str) and w.startswith("ignored:")]
    except _UNREADABLE:
        return None
    return {"summary": words, "source": "the scene's plan at these options"}


def _delta_bounces(ana: dict) -> Optional[list[int]]:
    """The pre-pass's rays by the delta bounces they need, as stored; None from a plan stored before it counted
    them (the cap then keeps the rule without them) or one whose counts are not such a list."""
    counts = ana.get("delta_bounces")
    if not isinstance(counts, list) or not all(isinstance(n, int) and n >= 0 for n in counts):
        return None
    return counts


def _focus_words(plan: dict, optics: OpticsConfig) -> list[str]:
    """The plan's focus line (holocore.plan.focus_depth) with its image depths rescaled to ``optics``; none from a
    plan that stored no depths."""
    depths = image_depths_m(plan, optics)
    if depths is None:
        return []
    f = optics.focal_length_m(_camera_fov(plan))
    focus = focus_depth(image_depths_holo_m=depths,
                        z_inf_m=optics.z_inf_m, focal_length_m=f, wavelengths_m=optics.wavelengths_m,
                        pitch_m=optics.pitch_m, scene_scale=optics.scene_scale)
    return [focus.summary]


def _planes_words(options: HologramOptions) -> list[str]:
    if options.method == "direct":
        return ["direct method: the rays are recorded on the SLM itself"]
    if options.wrp_planes == "auto":
        return ["wave recording planes: as many as the scene's depth calls for (auto), placed when it renders"]
    if options.wrp_planes > 1:
        return [f"{options.wrp_planes} wave recording planes (asked for), placed at the scene's depths when it "
                "renders"]
    return []
