"""Where the hologram's view lies in the scene's picture (the planner's ``holo plan --picture``): the rectangle
the hologram covers, as fractions of the camera's image, for given optics (docs/design.md §3: the hologram shows
2 atan(W p / 2f) around the camera's axis). The one formula is holocore.display.profiles.field_of_view_box;
this module reads the camera's numbers from a scene's stored plan and words the answer. Light imports only
(pydantic and math): the API answers with it."""

from __future__ import annotations

from typing import Any, Optional

from pydantic import BaseModel, Field

from holocore.display.optics import OpticsConfig
from holocore.display.profiles import field_of_view_box

__all__ = ["FieldOfViewBox", "field_of_view_box_for", "scene_field_of_view_box"]


class FieldOfViewBox(BaseModel):
    """The hologram's view in the scene camera's image at some optics. Fractions of the image's width and
    height from its top-left corner; outside 0..1 when the display sees more than the camera did."""

    x0: float = Field(description="Left edge, a fraction of the camera image's width (< 0: beyond it).")
    y0: float = Field(description="Top edge, a fraction of its height.")
    x1: float = Field(description="Right edge (> 1: beyond the image).")
    y1: float = Field(description="Bottom edge.")
    hologram_fov_x_deg: float = Field(description="The hologram's horizontal view, 2 atan(W p / 2f).")
    hologram_fov_y_deg: float = Field(description="Its vertical view, 2 atan(H p / 2f).")
    camera_fov_x_deg: float = Field(description="The scene camera's horizontal view.")
    camera_fov_y_deg: float = Field(description="The scene camera's vertical view (square pixels).")
    camera_film_hw_px: tuple[int, int] = Field(description="The camera's film, rows x columns.")
    beyond_camera: bool = Field(description="The hologram sees more than the camera on some side: its edges "
                                            "show what the camera never rendered.")
    summary: str = Field(description="In words, for a caption.")


def _deg(v: float) -> str:
    return f"{v:.3g}°"


def field_of_view_box_for(optics: OpticsConfig, plan: Any) -> Optional[FieldOfViewBox]:
    """The box at ``optics`` for the scene whose stored plan is ``plan``; None when the plan does not give the
    camera's view and film (pending, failed, or from before the plan recorded the film)."""
    try:
        fov = plan["field_of_view"]
        cam_fov = float(fov["camera_fov_x_deg"])
        film_h, film_w = (int(v) for v in fov["camera_film_hw_px"])
        box = field_of_view_box(optics, cam_fov, (film_h, film_w))
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return None
    holo = f"{_deg(box['hologram_fov_x_deg'])} x {_deg(box['hologram_fov_y_deg'])}"
    cam = f"{_deg(box['camera_fov_x_deg'])} x {_deg(box['camera_fov_y_deg'])}"
    words = f"the hologram shows {holo} of the camera's {cam}"
    if box["beyond_camera"]:
        eps = 1e-9
        wider, taller = box["x0"] < -eps or box["x1"] > 1 + eps, box["y0"] < -eps or box["y1"] > 1 + eps
        how = "wider and taller" if wider and taller else "wider" if wider else "taller"
        edges = "every edge" if wider and taller else "its left and right" if wider else "its top and bottom"
        words += (f": {how} than the camera's view, so the box reaches past {edges}, where the camera rendered "
                  "nothing")
    return FieldOfViewBox(**box, summary=words)


def scene_field_of_view_box(scene: dict, optics: Optional[OpticsConfig] = None) -> Optional[dict]:
    """The box as JSON for a scene row at ``optics`` (default: the optics its plan was made with, the
    default display's); None unless the plan is ready and says the camera's view."""
    plan = scene.get("plan") if scene.get("plan_state") == "ready" else None
    if not isinstance(plan, dict):
        return None
    if optics is None:
        try:
            optics = OpticsConfig(**plan["optics"])
        except (KeyError, TypeError, ValueError):
            return None
    box = field_of_view_box_for(optics, plan)
    return None if box is None else box.model_dump(mode="json")
