"""The quality side of `holo render`: what `--estimate` predicts, and the options `--quality-db` chooses.

Both read the scene's plan (the radius its noise target was set by gives the rays' noise), a small picture
through its camera (its image statistic, holocore.evaluate.metrics.white_power) and the time model, and assume
the phase-only encoding `holo encode` gives next (SGD).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Optional

__all__ = ["QualityContext", "quality_context", "estimate_lines", "choose_options", "frames_for_time"]


@dataclass(frozen=True)
class QualityContext:
    radius_px: float
    image_q: Optional[float]
    refracted_share: float
    fourier_filter: bool
    seconds: Any  # (optics, options, iterations, encode=True) -> predicted seconds of render (plus encode)


def quality_context(loaded, pl, profile, optics, *, probe=None, calibration=None) -> QualityContext:
    """What the predictions need of a loaded scene and its plan ``pl`` (holocore.pipeline.plan_scene) at
    ``optics``: the radius its noise target was set by (on the recording plane of its farthest image point,
    from which the preset chooses its rays), the picture's image statistic, the light seen through glass."""
    from holocore.evaluate.groundtruth import camera_picture
    from holocore.evaluate.metrics import white_power
    from holocore.plan.estimate import encode_iterations, estimate_breakdown
    from holocore.plan.estimate_probe import estimate_with_probe

    try:
        q = white_power(camera_picture(loaded, max_width_px=64, spp=16)) or None
    except (ValueError, RuntimeError):
        q = None  # no picture: a typical scene's statistic
    from holocore.plan.quality import recording_radius_px

    theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    radius = recording_radius_px(noise_to_signal=pl.plan.noise_to_signal, spp=pl.plan.spp, theta_max=theta)
    prims = pl.inventory.primitives

    def seconds(o, opt, it, encode: bool = True) -> float:
        iters = encode_iterations(o.height, o.width, iterations=it) if encode else 0  # the default optimiser's
        stages = estimate_breakdown(o, opt, scene_primitives=prims, subhologram_radius_px=radius,
                                    encode_iterations=iters, z_wrp_m=pl.analysis.z_wrp_m, calibration=calibration)
        if probe is None:
            return stages["total"]
        render = estimate_with_probe(o, opt, probe, scene_primitives=prims, subhologram_radius_px=radius,
                                     calibration=calibration)
        return render["total"] + stages.get("encode", 0.0)

    return QualityContext(radius_px=radius, image_q=q, refracted_share=float(pl.analysis.refracted_share),
                          fourier_filter=bool(profile.fourier_filter), seconds=seconds)


def estimate_lines(ctx: QualityContext, optics, options, *, most_frames: int) -> list[str]:
    """What `holo render --estimate` says of quality: the prediction, its parts, warnings and two alternatives
    (with up to ``most_frames`` frames, what the display shows)."""
    from holocore.plan.quality import predict_for
    from holocore.plan.quality_choice import alternatives_words, candidates, frames_upto

    pred = predict_for(optics, options, subhologram_radius_px=ctx.radius_px, image_q=ctx.image_q,
                       refracted_share=ctx.refracted_share, fourier_filter=ctx.fourier_filter)
    now_s = ctx.seconds(optics, options, None)
    lines = [f"predicted quality (with `holo encode`'s default: SGD, 28 L-BFGS steps): {pred.words()}; render and "
             f"encode about {now_s:.0f} s"]
    lines += [f"warning: {w}" for w in pred.warnings]
    cands = candidates(optics, options, seconds=ctx.seconds, subhologram_radius_px=ctx.radius_px,
                       image_q=ctx.image_q, refracted_share=ctx.refracted_share, fourier_filter=ctx.fourier_filter,
                       frames=frames_upto(most_frames))
    lines += [f"instead: {w}" for w in alternatives_words(pred, now_s, cands)]
    return lines


def choose_options(ctx: QualityContext, optics, options, target_db: float):
    """(optics, options, the chosen candidate) that reach ``target_db`` in the least predicted time: frames (up
    to the optics' own), rays per pixel and the encoder's iterations (the rest as given)."""
    from holocore.plan.quality_choice import candidates, choose_for_quality, frames_upto

    cands = candidates(optics, options, seconds=ctx.seconds, subhologram_radius_px=ctx.radius_px,
                       image_q=ctx.image_q, refracted_share=ctx.refracted_share, fourier_filter=ctx.fourier_filter,
                       frames=frames_upto(optics.frames))
    best = choose_for_quality(cands, target_db)
    return (optics.model_copy(update={"frames": best.frames}),
            dataclasses.replace(options, spp=best.spp_asked), best)


def frames_for_time(ctx: QualityContext, optics, options, limit_s: float):
    """(frames, predicted dB, rays per pixel expected) of the mix a render of ``limit_s`` seconds does best with:
    for each frame count up to the optics' own, the rays that fill the time (the time model, doubling rays from
    the preset's least) and the quality they predict; the best. A time limit then buys frames as well as rays."""
    from holocore.plan.presets import PRESETS
    from holocore.plan.quality import predict_for
    from holocore.plan.quality_choice import frames_upto

    best = None
    for F in frames_upto(optics.frames):
        o = optics.model_copy(update={"frames": F})
        n, spp = None, max(1, PRESETS[options.preset].spp_min // 4)
        while spp <= 1 << 16:
            opt = dataclasses.replace(options, spp=spp, time_limit_s=None)
            if ctx.seconds(o, opt, None, encode=False) > limit_s:
                break
            n, spp = spp, spp * 2
        if n is None:
            continue
        q = predict_for(o, dataclasses.replace(options, spp=n, time_limit_s=None), subhologram_radius_px=ctx.radius_px,
                        image_q=ctx.image_q, refracted_share=ctx.refracted_share,
                        fourier_filter=ctx.fourier_filter).psnr_db
        if best is None or q > best[1]:
            best = (F, q, n)
    return best
