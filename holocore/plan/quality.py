"""Predicting a hologram's quality before it runs: the viewer-faithful PSNR a job's options buy.

The score predicted is the one ``holocore.evaluate.viewer.viewer_score`` measures (docs/evaluation.md): the eye's
views through pupils of 2-6 mm from a jittered grid of eye positions, one brightness per colour, against the wave
ground truth, on a display with a Fourier filter. Its error power, in units of the score's white squared, is a
sum of parts, each from what a job's options and the scene's plan say before anything is traced:

    speckle   q s_m / F^a_m           F frames of independent random phase average the eye's speckle; s_m and a_m
                                      per frame-phase mode (coded frames average close to 1/F; one frame has no
                                      random phase, and its own error s_1: coherent defocus blur and ringing)
    noise     q c_mc nsr (1 + d r) / F^b  Monte Carlo noise: nsr = k(theta) rho^2 / N, the plan's noise-to-signal of
                                      N rays per pixel at the farthest image point (sub-hologram radius rho px,
                                      holocore.plan.effects.noise_factor); frames re-phase the same rays, which
                                      decorrelates part of their noise (b). r: the share of the light that reaches
                                      the eye through glass (the plan's ``refracted_share``): at each glass
                                      surface a ray goes on by reflection or by refraction, drawn by their
                                      Fresnel weights, a binary choice whose variance a mirror's one path lacks
    encoder   q e(method, it) / F^a   the phase-only encoder's error: SGD e_sgd (1 + i_half / it) after it
                                      Adam iterations (its stop rule: ``TYPICAL_STOP_ITERATIONS``; another
                                      optimiser's counted as the Adam iterations that reach its field error,
                                      ``holocore.plan.encode_steps``: L-BFGS's 28 as 39), averaging over
                                      frames as speckle does (a = a_m); DPAC e_dpac / F^a_dpac: its checkerboard
                                      puts the light the amplitude does not need back into the recording cone
                                      wherever that cone fills the SLM's band, much the same in every frame
    floor     f                       what remains with endless rays, frames and iterations: the recording planes'
                                      approximations and the ground truth's own Monte Carlo noise

q is the scene's image statistic mean(min(I / w, 1)^2), w its 99th percentile (the score's white): speckle,
encoder error and noise all scale with the local intensity, so a dark scene with small bright objects scores
higher for the same hologram. The PSNR is -10 log10 of the sum. The coefficients are fitted by
``bench/quality_fit.py`` to measured jobs on the paper's display (``bench/results/quality/``) and stored in
``data/quality_model.json`` with the fit's cross-validated residual, which is the ± of every prediction.

Pure Python, like the time model (``holocore.plan.estimate``): the service's API process predicts with it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Optional

from holocore.plan.effects import noise_factor
from holocore.plan.encode_steps import rule
from holocore.plan.estimate import TYPICAL_STOP_ITERATIONS, features

__all__ = ["QualityPrediction", "predict_quality", "predict_for", "recording_radius_px", "MIN_FITTED_SPP",
           "quality_model", "MODEL_PATH", "UNRECOGNISABLE_DB", "DEFAULT_IMAGE_Q", "PARTS"]

MODEL_PATH = Path(__file__).resolve().parent / "data" / "quality_model.json"
# Below this viewer-faithful PSNR a hologram is speckle and bands, not the scene (the threshold a warning names).
UNRECOGNISABLE_DB = 12.0
# The image statistic q of a typical scene (the median of the fitted scenes') when the scene's own is unknown.
DEFAULT_IMAGE_Q = 0.2
PARTS = ("speckle", "noise", "encoder", "floor")
# The fewest rays per pixel of the fitted jobs' range (the balanced preset's least): below it the cone equaliser
# filters the signal with the noise, a loss the noise term does not model.
MIN_FITTED_SPP = 16
# The frame count a speckle warning compares with: the paper's display shows 24 frames per image.
SPECKLE_FRAMES = 24


@lru_cache(maxsize=4)
def _load(path: str) -> dict:
    return json.loads(Path(path).read_text())


def quality_model(path: Optional[str | Path] = None) -> dict:
    """The fitted coefficients (``data/quality_model.json`` unless ``path``)."""
    doc = _load(str(path or MODEL_PATH))
    if not isinstance(doc.get("coefficients"), dict):
        raise ValueError(f"{path or MODEL_PATH} is not a quality model (needs 'coefficients')")
    return doc


@dataclass(frozen=True)
class QualityPrediction:
    """A predicted viewer-faithful PSNR (dB), its ± (the model's cross-validated residual), and what each part
    costs: ``parts_db[p]`` is how many dB the prediction would gain without part p."""

    psnr_db: float
    uncertainty_db: float
    parts_db: dict[str, float]
    error_power: dict[str, float]
    warnings: list[str] = field(default_factory=list)

    @property
    def largest_part(self) -> str:
        return max(self.error_power, key=self.error_power.get)

    def as_dict(self) -> dict:
        return {"psnr_db": round(self.psnr_db, 1), "uncertainty_db": round(self.uncertainty_db, 1),
                "parts_db": {k: round(v, 1) for k, v in self.parts_db.items()},
                "largest_part": self.largest_part, "warnings": list(self.warnings)}

    def words(self) -> str:
        parts = ", ".join(f"{k} {v:.1f} dB" for k, v in sorted(self.parts_db.items(), key=lambda kv: -kv[1]))
        return (f"expected about {self.psnr_db:.0f} dB viewer-faithful PSNR, ±{self.uncertainty_db:.1f} "
                f"(what each part costs: {parts})")


def _check_count(name: str, v, low: int = 1) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
    return v


def _error_power(c: dict, *, F: int, mode: str, nsr: float, encoder: str, it: float, q: float,
                 refracted: float) -> dict[str, float]:
    """The parts' error powers (module docstring) with coefficients ``c``."""
    q_dpac = q ** c["k_dpac"]  # DPAC's checkerboard spreads its error over the picture, not with the light
    q = q ** c["k_q"]
    per_frame = 1.0 if F == 1 else F ** -c[f"a_{mode}"]
    speckle = q * (c["s_one"] if F == 1 else c[f"s_{mode}"] * per_frame)
    noise = q * c["c_mc"] * nsr * (1.0 + c["d_split"] * refracted) * F ** -c["b_mc"]
    if encoder == "sgd":
        enc = c["e_sgd"] * (1.0 + c["i_half"] / max(it, 1)) if it > 0 else c["e_naive"]
    else:
        enc = c[f"e_{encoder}"]
    # SGD's residual differs frame to frame like speckle; DPAC's checkerboard error is much the same in every frame
    enc_frames = F ** -c[f"a_{encoder}"] if f"a_{encoder}" in c else per_frame
    return {"speckle": speckle, "noise": noise, "encoder": (q_dpac if encoder == "dpac" else q) * enc * enc_frames,
            "floor": c["floor"]}


def _psnr(power: dict[str, float]) -> float:
    return -10.0 * math.log10(sum(power.values()))


def predict_quality(*, frames: int, frame_phases: str, noise_to_signal: float, encoder: str,
                    iterations: Optional[int] = None, optimiser: Optional[str] = None, image_q: Optional[float] = None,
                    refracted_share: float = 0.0, fourier_filter: bool = True,
                    model: Optional[dict] = None) -> QualityPrediction:
    """Predicted viewer-faithful PSNR of a job (module docstring). ``noise_to_signal``: the plan's Monte Carlo
    noise-to-signal power of its rays per pixel (:func:`holocore.plan.effects.noise_factor` rho^2 / N);
    ``iterations``: the SGD encoder's (None: its ``optimiser``'s default run; None: the default optimiser);
    ``image_q``: the scene's image statistic (None: a typical scene's); ``refracted_share``: the share of the
    light seen through glass (the plan's analysis)."""
    F = _check_count("frames", frames)
    if not (isinstance(noise_to_signal, (int, float)) and math.isfinite(noise_to_signal) and noise_to_signal >= 0):
        raise ValueError(f"noise_to_signal must be finite and >= 0, got {noise_to_signal!r}")
    if encoder not in ("sgd", "dpac", "naive"):
        raise ValueError(f"encoder must be sgd, dpac or naive, got {encoder!r}")
    steps = rule(optimiser)
    if iterations is None:
        it = TYPICAL_STOP_ITERATIONS if steps.stops_early else steps.max_iterations * steps.adam_equivalent
    else:
        it = _check_count("iterations", iterations, 0) * steps.adam_equivalent
    q = DEFAULT_IMAGE_Q if image_q is None else float(image_q)
    if not (math.isfinite(q) and 0 < q <= 1):
        raise ValueError(f"image_q must be in (0, 1], got {image_q!r}")
    if not (isinstance(refracted_share, (int, float)) and 0.0 <= refracted_share <= 1.0):
        raise ValueError(f"refracted_share must be in [0, 1], got {refracted_share!r}")
    doc = model if model is not None else quality_model()
    c = doc["coefficients"]
    kw = dict(mode=frame_phases if f"s_{frame_phases}" in c else "coded", nsr=float(noise_to_signal),
              encoder=encoder, it=it, q=q, refracted=float(refracted_share))
    power = _error_power(c, F=F, **kw)
    total, psnr = sum(power.values()), _psnr(power)
    parts = {k: 10.0 * math.log10(total / max(total - v, 1e-30)) for k, v in power.items() if k != "floor"}
    warnings = []
    if psnr < UNRECOGNISABLE_DB:
        warnings.append(f"expected about {psnr:.0f} dB: below {UNRECOGNISABLE_DB:.0f} dB a hologram shows speckle and "
                        f"bands more than the scene ({max(parts, key=parts.get)} costs the most)")
    more = _psnr(_error_power(c, F=SPECKLE_FRAMES, **kw)) - psnr
    if F < SPECKLE_FRAMES and more >= 3.0:
        warnings.append(f"the eye's speckle dominates at {F} frame(s): {SPECKLE_FRAMES} frames would give about "
                        f"{more:.0f} dB more")
    if encoder == "dpac":
        warnings.append("DPAC on a display whose recording cone fills the SLM's band puts its checkerboard's light "
                        "back into the cone (docs/quality.md): SGD does far better")
    if not fourier_filter:
        warnings.append("predicted for a display with a Fourier filter; without one the pixels' diffraction "
                        "orders and the encoder's out-of-cone light cost more")
    return QualityPrediction(psnr_db=psnr, uncertainty_db=float(doc.get("uncertainty_db", 1.5)), parts_db=parts,
                             error_power=power, warnings=warnings)


def recording_radius_px(*, noise_to_signal: float, spp: int, theta_max: float) -> float:
    """The sub-hologram radius (px) a plan's noise target was set by: that of the farthest image point on the
    recording plane that records it (with several planes, smaller than the analysis' farthest point from the
    WRP), from the plan's noise-to-signal at its spp (holocore.plan.effects.make_plan's nsr = k rho^2 / N).
    Predictions read the noise as the jobs they were fitted on rendered it."""
    return math.sqrt(max(0.0, float(noise_to_signal)) * max(1, int(spp)) / noise_factor(theta_max))


def predict_for(optics, options, *, encoder: str = "sgd", iterations: Optional[int] = None,
                optimiser: Optional[str] = None, subhologram_radius_px: Optional[float] = None,
                image_q: Optional[float] = None, refracted_share: float = 0.0, fourier_filter: bool = True,
                model: Optional[dict] = None) -> QualityPrediction:
    """:func:`predict_quality` for a render's optics and options (``holocore.render_setup.RenderOptions`` or
    anything with ``preset``, ``spp``, ``max_spp``): the rays per pixel the preset picks for the scene's depth
    (its farthest sub-hologram radius, px; unknown: a shallow scene's, as the time estimate assumes) and their
    noise-to-signal, the optics' frames and frame-phase mode."""
    x = features(optics, options, subhologram_radius_px=subhologram_radius_px)
    radius = optics.wrp_margin_px + 2.0 if subhologram_radius_px is None else float(subhologram_radius_px)
    theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    nsr = noise_factor(theta) * radius ** 2 / max(1, int(x["spp"]))
    pred = predict_quality(frames=optics.frames, frame_phases=optics.frame_phases, noise_to_signal=nsr,
                           encoder=encoder, iterations=iterations, optimiser=optimiser, image_q=image_q,
                           refracted_share=refracted_share, fourier_filter=fourier_filter, model=model)
    if int(x["spp"]) < MIN_FITTED_SPP:
        pred.warnings.append(f"{int(x['spp'])} rays per pixel is below the {MIN_FITTED_SPP} the prediction was "
                             "fitted from: expect less than predicted")
    return pred
