"""What every method's result says of itself (the RESULT.npz ``meta``; holocore.formats.meta reads it): one builder,
:func:`result_meta`, for the renderer and every baseline, so a field every reader needs is written in one place.

Common fields: the display geometry (f, z_inf, z_wrp, pitch, wavelengths, shape), the method and preset, the scene
(bundle-relative name and sha256: no server path), the optics and the scene analysis, the plan's summary, the
field of view, the display profile, stats, timings (s) and the software versions; each method adds its own under
``extra`` (the renderer's plan, sampling and memory, a baseline's settings under its own key).
"""

from __future__ import annotations

import json
import platform
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from holocore import __version__
from holocore.runtime.mitsuba_env import variant
from holocore.display.profiles import display_meta

__all__ = ["RenderResult", "result_meta", "delta_capped_meta", "display_meta_fields", "software_versions"]


@dataclass
class RenderResult:
    slm_field: np.ndarray  # complex64 [F, C, H, W]
    wrp_field: np.ndarray  # complex64 [F, C, H, W]
    meta: dict


def result_meta(*, method: str, preset: Optional[str], loaded: Any, optics: Any, scene_plan: Any,
                shape_fchw, timings: dict, display: Any = None, plan: Optional[dict] = None,
                summary: Optional[list[str]] = None, stats: Optional[dict] = None,
                extra: Optional[dict] = None) -> dict:
    """The meta of one result. ``scene_plan``: the :class:`holocore.plan.scene_plan.ScenePlan` the method used;
    ``plan``: the renderer's EffectPlan as JSON, or None for a baseline, whose ``summary`` lines (the field of view
    line appended) stand for it; ``extra``: the method's own fields, added last."""
    ana = scene_plan.analysis
    if plan is None:
        plan = {"summary": [*(summary or []), scene_plan.field_of_view["summary"]]}
    meta: dict[str, Any] = {
        "focal_length_m": scene_plan.focal_length_m,
        "scene_scale": float(scene_plan.hmap.scene_scale),
        "z_inf_m": optics.z_inf_m,
        "z_wrp_m": ana.z_wrp_m,
        "pitch_m": optics.pitch_m,
        "wavelengths_m": list(optics.wavelengths_m),
        "shape_fchw": [int(v) for v in shape_fchw],
        "method": method,
        "preset": preset,
        "scene": loaded.entry.name,  # bundle-relative (the loader's root is the XML's folder): no server path
        "scene_sha256": getattr(loaded.bundle, "sha256", None),
        "optics": json.loads(optics.model_dump_json()),
        "plan": plan,
        "analysis": json.loads(ana.model_dump_json()),
        "field_of_view": scene_plan.field_of_view,
        "focus": None if scene_plan.focus is None else json.loads(scene_plan.focus.model_dump_json()),
        **display_meta_fields(display, optics),
        "stats": stats or {},
        "delta_capped": delta_capped_meta(stats or {}, plan),
        "timings": timings,
        "versions": software_versions(variant()),
    }
    meta.update(extra or {})
    return meta


def delta_capped_meta(stats: dict, plan: dict) -> Optional[dict]:
    """The rays whose delta chain (mirrors, glass) ran past the cap and were dropped: their count and share of the
    traced rays, and the share the plan's pre-pass predicted at its cap (None: a method without the trace's
    counts). Their share of the radiance is not known: a dropped chain never reaches the surface that lights it."""
    if "capped" not in stats:
        return None
    rays = int(stats.get("rays") or 0)
    return {"max_delta": plan.get("max_delta"), "rays_capped": int(stats["capped"]),
            "rays_capped_share": float(stats["capped"]) / rays if rays else 0.0,
            "prepass_capped_share": plan.get("delta_capped_share")}


def display_meta_fields(display: Any, optics: Any) -> dict:
    """``display_profile`` (None: optics given directly, no profile) and ``display`` for a result's meta."""
    if display is None:
        return {"display_profile": None, "display": None}
    return display_meta(display, optics)


def software_versions(mi_variant: str) -> dict:
    import drjit
    import mitsuba
    import torch

    return {"holocore": __version__, "mitsuba": mitsuba.__version__, "drjit": drjit.__version__,
            "torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version(),
            "variant": mi_variant}
