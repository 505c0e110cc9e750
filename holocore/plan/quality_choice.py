"""What accuracy costs in time, before a job runs: the predicted quality-time front of a job's options, and the
options a quality target or a time limit calls for.

Each candidate is a mix of frames, rays per pixel and SGD encoder iterations (the frame-phase mode, the preset
and the recording planes stay the job's): its viewer-faithful PSNR from the quality model
(:mod:`holocore.plan.quality`) and its seconds from the time model (:mod:`holocore.plan.estimate`, render plus
encoder). The front is the candidates no other beats in both. A quality target takes the quickest candidate
predicted to reach it; a time limit, the best candidate predicted to fit in it. Frames are chosen up to the
display's own count (:func:`frames_upto`): the SLM shows that many per image; a stack of fewer repeats.
Pure Python (the service's API process calls it for every estimate).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence

from holocore.plan.quality import QualityPrediction, predict_for
from holocore.plan.estimate import features

__all__ = ["Candidate", "candidates", "frames_upto", "front", "choose_for_quality", "choose_for_time",
           "alternatives_words", "FRAME_CHOICES", "SPP_CHOICES", "ITERATION_CHOICES"]

FRAME_CHOICES = (1, 2, 4, 8, 12, 16, 24, 32, 48)
SPP_CHOICES = (None, 16, 32, 64, 128, 256, 512, 1024)  # None: the preset's choice from the scene's depth; from
# MIN_FITTED_SPP up (holocore.plan.quality)
ITERATION_CHOICES = (None, 20, 40, 80)  # the optimiser's; None: its default run (holocore.plan.encode_steps)


@dataclass(frozen=True)
class Candidate:
    frames: int
    spp: int  # rays per pixel (the preset's choice resolved)
    spp_asked: Optional[int]  # what the options say (None: the preset's)
    iterations: Optional[int]  # SGD iterations (None: the optimiser's default run)
    psnr_db: float
    seconds: float

    def words(self) -> str:
        it = "the encoder's default run" if self.iterations is None else f"{self.iterations} encoder iterations"
        return f"{self.frames} frames, {self.spp} rays per pixel, {it}: about {self.psnr_db:.0f} dB in " \
               f"{_fmt_s(self.seconds)}"


def _fmt_s(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min"


def candidates(optics, options, *, encoder: str = "sgd", optimiser: Optional[str] = None,
               seconds: Callable[[Any, Any, Optional[int]], float],
               subhologram_radius_px: Optional[float] = None, image_q: Optional[float] = None,
               refracted_share: float = 0.0, fourier_filter: bool = True, frames: Sequence[int] = FRAME_CHOICES,
               spp: Sequence[Optional[int]] = SPP_CHOICES,
               iterations: Sequence[Optional[int]] = ITERATION_CHOICES) -> list[Candidate]:
    """Every mix of ``frames`` x ``spp`` x ``iterations`` (iterations only for SGD, ``optimiser``'s: None the
    default) with its predicted PSNR and ``seconds(optics, options, iterations)``. ``options`` is copied with
    each spp (a dataclass or a pydantic model or a namespace with ``spp``), ``optics`` (an OpticsConfig) with
    each frame count."""
    out = []
    its = list(iterations) if encoder == "sgd" else [None]
    for F in frames:
        o = optics.model_copy(update={"frames": int(F)})
        for n in spp:
            opt = _with_spp(options, n)
            n_res = int(features(o, opt, subhologram_radius_px=subhologram_radius_px)["spp"])
            for it in its:
                q = predict_for(o, opt, encoder=encoder, iterations=it, optimiser=optimiser,
                                subhologram_radius_px=subhologram_radius_px, image_q=image_q,
                                refracted_share=refracted_share, fourier_filter=fourier_filter)
                out.append(Candidate(frames=int(F), spp=n_res, spp_asked=n, iterations=it, psnr_db=q.psnr_db,
                                     seconds=float(seconds(o, opt, it))))
    return out


def frames_upto(most: int) -> tuple[int, ...]:
    """The frame counts a choice may take on a display that shows ``most`` frames per image (its profile's
    frames, or what the user gave): the usual counts below it, and it."""
    return tuple(sorted({F for F in FRAME_CHOICES if F < most} | {int(most)}))


def _with_spp(options, n: Optional[int]):
    if dataclasses.is_dataclass(options):
        return dataclasses.replace(options, spp=n)
    if hasattr(options, "model_copy"):
        return options.model_copy(update={"spp": n})
    from types import SimpleNamespace

    return SimpleNamespace(**{**vars(options), "spp": n})


def front(cands: Sequence[Candidate]) -> list[Candidate]:
    """The candidates no other beats in both time and quality, quickest first."""
    best = -math.inf
    out = []
    for c in sorted(cands, key=lambda c: (c.seconds, -c.psnr_db)):
        if c.psnr_db > best + 1e-9:
            out.append(c)
            best = c.psnr_db
    return out


def choose_for_quality(cands: Sequence[Candidate], target_db: float) -> Candidate:
    """The quickest candidate predicted to reach ``target_db``; if none does, the best one."""
    ok = [c for c in cands if c.psnr_db >= target_db]
    return min(ok, key=lambda c: c.seconds) if ok else max(cands, key=lambda c: c.psnr_db)


def choose_for_time(cands: Sequence[Candidate], limit_s: float) -> Candidate:
    """The best candidate predicted to fit in ``limit_s``; if none does, the quickest."""
    ok = [c for c in cands if c.seconds <= limit_s]
    return max(ok, key=lambda c: c.psnr_db) if ok else min(cands, key=lambda c: c.seconds)


def alternatives_words(current: QualityPrediction, current_s: float, cands: Sequence[Candidate]) -> list[str]:
    """At most two lines for the user: the quickest mix that gains 3 dB or more, and the quickest that keeps
    the quality within 0.5 dB, where it saves a third of the time or more."""
    out = []
    better = [c for c in cands if c.psnr_db >= current.psnr_db + 3.0]
    if better:
        c = min(better, key=lambda c: c.seconds)
        out.append(f"{c.words()} (+{c.psnr_db - current.psnr_db:.0f} dB)")
    same = [c for c in cands if c.psnr_db >= current.psnr_db - 0.5 and c.seconds <= current_s / 1.5]
    if same:
        c = min(same, key=lambda c: c.seconds)
        out.append(f"{c.words()} (about the same quality in {c.seconds / max(current_s, 1e-9):.0%} of the time)")
    return out
