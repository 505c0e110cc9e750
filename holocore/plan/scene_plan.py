"""ScenePlan: everything known of a scene before it is traced (holocore.render_setup.plan_scene returns it): the
hologram's map, the scene's inventory, the pre-pass analysis, the effect plan, the focal length and view, and
the recording planes. :meth:`ScenePlan.to_dict` is the JSON `holo plan --json` prints (and the service stores)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Optional

if TYPE_CHECKING:
    from holocore.plan.analysis import SceneAnalysis
    from holocore.plan.effects import EffectPlan, SceneInventory
    from holocore.plan.focus_depth import FocusDepth
    from holocore.plan.wrp_planes import WrpPlanes
    from holocore.trace.mapping import HologramMap

__all__ = ["ScenePlan"]


@dataclass(frozen=True)
class ScenePlan:
    """A scene's plan for one display and one set of render options."""

    hmap: HologramMap  # the map from the camera's sensor to hologram space (docs/design.md §3)
    inventory: SceneInventory  # what the scene holds (shapes, primitives, delta and glossy surfaces...)
    analysis: SceneAnalysis  # the sparse pre-pass: depth range, where the WRP goes, sub-hologram radius
    plan: EffectPlan  # what the render simulates, ``summary`` in words (the view and ignored files included)
    focal_length_m: float  # the display's focal length for this scene's camera
    field_of_view: dict[str, Any]  # holocore.display.profiles.field_of_view_report: hologram vs camera view
    planes: WrpPlanes  # the wave recording planes (one for the direct method)
    focus: Optional[FocusDepth] = None  # how many depths of field the light spans, a scene scale that would help

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``plan``, ``summary``, ``analysis``, ``inventory``, ``focal_length_m``, ``field_of_view``,
        ``focus`` (the map and the planes are not in it)."""
        return {"plan": json.loads(self.plan.model_dump_json()), "summary": self.plan.summary,
                "analysis": json.loads(self.analysis.model_dump_json()),
                "inventory": json.loads(self.inventory.model_dump_json()), "focal_length_m": self.focal_length_m,
                "field_of_view": self.field_of_view,
                "focus": None if self.focus is None else json.loads(self.focus.model_dump_json())}
