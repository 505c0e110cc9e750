"""The recording planes a job would render with, read from its scene's stored plan (holocore.plan.stored_plan)
at the job's optics: placed on the stored image depths, rescaled, as the render places them
(holocore.plan.wrp_planes), and admitted against the render's memory budget by the render's own rule
(holocore.plan.memory_estimate.admit_planes). A service asks this before a job runs, so that it keeps and
refuses the planes the CLI would.
"""

from __future__ import annotations

from typing import Optional, Union

from holocore.display.optics import OpticsConfig
from holocore.plan.memory_estimate import DEFAULT_TILE_RAYS, PlaneAdmission, admit_placed_planes
from holocore.plan.stored_plan import image_depths_m, wrp_distance_m, wrp_margin_m
from holocore.plan.wrp_planes import choose_planes, place_planes

__all__ = ["admitted_planes"]


def admitted_planes(plan: Optional[dict], optics: OpticsConfig, *, wrp_planes: Union[int, str], budget_bytes: int,
                    tile_rays: int = DEFAULT_TILE_RAYS) -> Optional[PlaneAdmission]:
    """The recording planes ``wrp_planes`` (a count, or ``auto``) gives the scene of ``plan`` at ``optics`` within
    ``budget_bytes`` (:func:`admit_planes`: ``auto`` keeps those that fit; a count asked for that does not fit is
    a ValueError with the figure). None when the plan stored no image depths (a plan from before they were)."""
    depths, z_wrp = image_depths_m(plan, optics), wrp_distance_m(plan, optics)
    if depths is None or z_wrp is None:
        return None
    margin = wrp_margin_m(optics)
    if wrp_planes == "auto":
        planes = choose_planes(depths, z_wrp_m=z_wrp, margin_m=margin)
    else:
        planes = place_planes(depths, z_wrp_m=z_wrp, margin_m=margin, count=int(wrp_planes))
    return admit_placed_planes(planes, optics, auto=wrp_planes == "auto", budget_bytes=budget_bytes,
                               tile_rays=tile_rays)[1]
