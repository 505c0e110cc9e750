"""The named render choices a user picks: the quality preset (:data:`PresetName`, its settings :class:`Preset`
in :data:`PRESETS`) and the recording method (:data:`RenderMethod`).

Rays per WRP pixel are chosen from the scene depth (docs/design.md §4 "Convergence"): the Monte Carlo noise power
relative to the signal at an image point whose sub-hologram has radius rho pixels is about
k(theta) rho^2 / N with k = 2 pi (1 - cos theta) / tan^2 theta (~ pi), so N = k rho^2 / noise, clamped
(holocore.plan.effects.choose_spp).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping, get_args

from holocore.options import MAX_WRP_PLANES, PresetName, RenderMethod

__all__ = ["PresetName", "PRESET_NAMES", "Preset", "PRESETS", "RenderMethod", "RENDER_METHODS", "MAX_WRP_PLANES"]

# the names a user picks, with the hologram's other options (holocore.options)
PRESET_NAMES: tuple[PresetName, ...] = get_args(PresetName)
RENDER_METHODS: tuple[RenderMethod, ...] = get_args(RenderMethod)


@dataclass(frozen=True)
class Preset:
    """One quality preset's settings."""

    noise_to_signal: float  # target Monte Carlo noise-to-signal power at the farthest image point
    spp_min: int  # fewest rays per WRP pixel
    spp_max: int  # most rays per WRP pixel
    amp_spp: int  # incoherent radiance samples per image point
    gi_depth: int  # global-illumination bounces at most
    use_cache: bool  # the ambient radiance cache (unless every effect is forced on)
    typical_spp: int  # what it typically picks (a scene of typical depth): estimates made without the scene's plan


PRESETS: Mapping[PresetName, Preset] = MappingProxyType({
    "fast": Preset(noise_to_signal=2.0, spp_min=4, spp_max=128, amp_spp=1, gi_depth=3, use_cache=True,
                   typical_spp=16),
    "balanced": Preset(noise_to_signal=1.0, spp_min=16, spp_max=512, amp_spp=2, gi_depth=6, use_cache=False,
                       typical_spp=128),
    "reference": Preset(noise_to_signal=0.1, spp_min=64, spp_max=8192, amp_spp=8, gi_depth=12,
                        use_cache=False, typical_spp=1024),
})
