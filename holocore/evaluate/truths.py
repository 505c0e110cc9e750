"""The ground truths a hologram is scored against, by name (docs/evaluation.md, "Ground truth"):

* ``wave`` (the default): :class:`holocore.evaluate.wave_truth.WaveGroundTruth`, the scene as an ideal hologram
  of this display shows it to the eye: wave-optical defocus through the pupil within the SLM's band.
* ``thinlens``: :class:`holocore.evaluate.groundtruth.GroundTruth`, Mitsuba's geometric thin-lens render
  convolved with the pupil's in-focus Airy pattern (over-blurs near focus; kept to compare with earlier scores).

Both answer ``channels(focus_z_m=, pupil_diameter_m=, view_offset_m=)`` -> [C, H, W] and keep ``seconds``.
"""

from __future__ import annotations

from typing import Any

from holocore.evaluate.groundtruth import GroundTruth
from holocore.evaluate.wave_truth import WaveGroundTruth
from holocore.formats.meta import MetaLike

__all__ = ["TRUTHS", "DEFAULT_TRUTH", "ground_truth"]

TRUTHS = {"wave": WaveGroundTruth, "thinlens": GroundTruth}
DEFAULT_TRUTH = "wave"


def ground_truth(kind: str, loaded: Any, meta: MetaLike, *, shape_hw: tuple[int, int], spp: int,
                 seed: int = 0) -> Any:
    """The ground truth ``kind`` (one of :data:`TRUTHS`) of ``loaded`` for the display ``meta`` describes."""
    if kind not in TRUTHS:
        raise ValueError(f"unknown ground truth {kind!r}; known: {', '.join(TRUTHS)}")
    return TRUTHS[kind](loaded, meta, shape_hw=shape_hw, spp=spp, seed=seed)
