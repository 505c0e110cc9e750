"""``lab-flat``: a uniform field on the SLM, its amplitude an option (a demonstration of a baseline's cost)."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from holocore.baselines.registry import Baseline, BaselineOptions


class FlatOptions(BaselineOptions):
    amplitude: float = Field(1.0, gt=0, le=100, description="the field's amplitude")


class FlatBaseline(Baseline):
    name = "lab-flat"
    summary = "a uniform field of the given amplitude (a lab's plug-in)"
    Options = FlatOptions

    def render(self, loaded, optics, options, *, display=None, progress=None):
        from holocore.pipeline import RenderOptions, plan_scene
        from holocore.render_meta import RenderResult, result_meta

        F, C, (H, W) = optics.frames, len(optics.wavelengths_m), optics.resolution_hw
        field = np.full((F, C, H, W), options.amplitude, dtype=np.complex64)
        pl = plan_scene(loaded, optics, RenderOptions())
        meta = result_meta(method=self.name, preset=None, loaded=loaded, optics=optics, scene_plan=pl,
                           shape_fchw=(F, C, H, W), timings={}, display=display, summary=[self.summary])
        return RenderResult(slm_field=field, wrp_field=field, meta=meta)
