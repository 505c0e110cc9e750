"""A job's predicted quality, shown with every estimate and stored with the job, and a quality target resolved
into the options that reach it (``quality_db``).

The prediction is holocore.plan.quality's, from what the scene's plan says (the radius its noise target was set
by gives the noise of the rays; its picture's image statistic the weight of speckle and noise); the times
beside it are the job estimate's own (:func:`service.cost.hologram_seconds`), so "24 frames would give about
20 dB in 3 min" and the estimate above it never disagree.
"""

from __future__ import annotations

from typing import Any, Optional

from holocore.display.optics import OpticsConfig
from holocore.plan.quality import UNRECOGNISABLE_DB, predict_for, recording_radius_px
from holocore.plan.quality_choice import alternatives_words, candidates, choose_for_quality, frames_upto
from service.models import effective_optics
from service.untrusted import read_job_json

__all__ = ["job_quality", "recording_radius", "resolve_quality_target", "measured_psnr", "quality_flag",
           "CANDIDATE_SPP", "CANDIDATE_ITERATIONS"]

# Fewer than the CLI's (holocore.plan.quality_choice): every estimate of the page's form, one per keystroke, prices
# each candidate with the job estimate's time model.
CANDIDATE_SPP = (None, 32, 128, 512)
CANDIDATE_ITERATIONS = (None, 40)


def _scene_facts(scene_plan: Optional[dict]) -> tuple[Optional[float], Optional[float], float]:
    """(the radius the plan's noise target was set by in px, the picture's image statistic, the share of light
    seen through glass) from a scene's plan, None (0) where the plan lacks them."""
    plan = scene_plan or {}
    r = (plan.get("analysis") or {}).get("refracted_share")
    refracted = float(r) if isinstance(r, (int, float)) and 0 <= r <= 1 else 0.0
    radius = recording_radius(plan)
    q = (plan.get("picture") or {}).get("image_q")
    radius = float(radius) if isinstance(radius, (int, float)) and radius >= 0 else None
    q = float(q) if isinstance(q, (int, float)) and 0 < q <= 1 else None
    return radius, q, refracted


def recording_radius(plan: dict) -> Optional[float]:
    """The radius the plan's noise target was set by (holocore.plan.quality.recording_radius_px), from its
    noise-to-signal and rays at the plan's optics; the analysis' farthest point where the plan lacks them. It
    sets the preset's rays per pixel: with several recording planes it is smaller than the farthest point's."""
    ep = plan.get("plan") or {}
    try:
        o = OpticsConfig(**plan["optics"])
        return recording_radius_px(noise_to_signal=float(ep["noise_to_signal"]), spp=int(ep["spp"]),
                                   theta_max=max(o.theta_max(lam) for lam in o.wavelengths_m))
    except (KeyError, TypeError, ValueError):
        return (plan.get("analysis") or {}).get("subhologram_radius_px")


def _options(req, max_spp: Optional[int]):
    from types import SimpleNamespace

    return SimpleNamespace(preset=req.preset, spp=req.spp, method=req.method, max_spp=max_spp)


def _candidates(req, *, facts: tuple, max_spp: Optional[int], seconds_of) -> list:

    radius, q, diel = facts

    def seconds(o, opt, it) -> float:
        return seconds_of(req.model_copy(update={"frames": o.frames, "spp": opt.spp, "iterations": it}))

    # the most frames a choice takes: those given with a target, else what the display's optics show
    most = req.frames if req.quality_db is not None and req.frames is not None else req.optics.frames
    return candidates(effective_optics(req), _options(req, max_spp), encoder=req.encoder, optimiser=req.optimiser,
                      seconds=seconds,
                      subhologram_radius_px=radius, image_q=q, refracted_share=diel, frames=frames_upto(most),
                      spp=CANDIDATE_SPP, iterations=CANDIDATE_ITERATIONS)


def job_quality(req, *, scene_plan: Optional[dict], max_spp: Optional[int], seconds: float, seconds_of,
                target_db: Optional[float] = None) -> dict[str, Any]:
    """The estimate's ``quality``: the predicted viewer-faithful PSNR, its ±, what each part costs, warnings,
    and at most two other mixes of frames, rays and encoder iterations worth knowing (``seconds_of(req)``:
    the estimate's seconds of a request)."""

    facts = radius, q, diel = _scene_facts(scene_plan)
    pred = predict_for(effective_optics(req), _options(req, max_spp), encoder=req.encoder,
                       iterations=req.iterations, optimiser=req.optimiser, subhologram_radius_px=radius, image_q=q,
                       refracted_share=diel)
    out = pred.as_dict()
    out["words"] = pred.words()
    out["scene_facts"] = "the scene's plan" if radius is not None else "a shallow, typical scene (its plan is pending)"
    if target_db is not None:
        out["target_db"] = float(target_db)
        if pred.psnr_db < target_db:
            out["warnings"].append(f"the target of {target_db:g} dB is beyond what the service's limits predict "
                                   f"({pred.psnr_db:.1f} dB at best)")
    if req.render_time_limit_s is None:
        out["instead"] = alternatives_words(pred, seconds, _candidates(req, facts=facts, max_spp=max_spp,
                                                                        seconds_of=seconds_of))
    return out


def resolve_quality_target(req, *, scene_plan: Optional[dict], max_spp: Optional[int], seconds_of, allowed):
    """``req`` with the frames, rays per pixel and encoder iterations predicted to reach its ``quality_db``
    soonest among those ``allowed(req)`` admits (the service's limits), else the best of those, and
    ``quality_db`` cleared (the estimate keeps the target); ``req`` itself without a target."""
    if req.quality_db is None:
        return req
    cands = _candidates(req, facts=_scene_facts(scene_plan), max_spp=max_spp, seconds_of=seconds_of)

    def as_req(c):
        return req.model_copy(update={"frames": c.frames, "spp": c.spp_asked, "iterations": c.iterations,
                                      "quality_db": None})

    ok = [c for c in cands if allowed(as_req(c))]
    if not ok:
        return req.model_copy(update={"quality_db": None})
    return as_req(choose_for_quality(ok, req.quality_db))


def measured_psnr(row: dict) -> tuple[Optional[float], Optional[str]]:
    """(PSNR dB, "viewer" or "mean") of a succeeded job's evaluation: its viewer-faithful mean, else its mean;
    (None, None) without one (or with one made for another stack)."""
    spec = row["spec"] if isinstance(row["spec"], dict) else {}
    if row["state"] != "succeeded" or not spec.get("evaluate") or not row["artifact_dir"]:
        return None, None
    try:
        doc = read_job_json(row["artifact_dir"], "evaluation/index.json")
    except (OSError, ValueError):
        return None, None
    if not isinstance(doc, dict) or doc.get("stack_sha256") != row["stack_sha256"]:
        return None, None
    viewer = doc.get("viewer") if isinstance(doc.get("viewer"), dict) else {}
    for kind, value in (("viewer", viewer.get("mean_psnr_db")), ("mean", doc.get("mean_psnr_db"))):
        if isinstance(value, (int, float)):
            return float(value), kind
    return None, None


def quality_flag(row: dict) -> Optional[dict[str, Any]]:
    """A job's quality against the level below which a hologram shows speckle and bands rather than the scene
    (holocore.plan.quality.UNRECOGNISABLE_DB, the level the estimate's own warning names): the measured
    viewer-faithful PSNR once evaluated, else the estimate's prediction; None for a job stopped before its
    result (failed, cancelled) or without either number."""
    if row["state"] not in ("queued", "running", "succeeded"):
        return None
    psnr, source = measured_psnr(row)
    if psnr is None:
        est = row["estimate"] if isinstance(row["estimate"], dict) else {}
        q = est.get("quality") if isinstance(est.get("quality"), dict) else {}
        psnr, source = (q.get("psnr_db"), "predicted") if isinstance(q.get("psnr_db"), (int, float)) else (None, None)
    if psnr is None:
        return None
    return {"psnr_db": round(float(psnr), 2), "source": "measured" if source != "predicted" else "predicted",
            "floor_db": UNRECOGNISABLE_DB, "too_low": bool(psnr < UNRECOGNISABLE_DB)}
