"""What a loaded Mitsuba scene holds that the tracer, the plan and the reference renders each ask about: mixed
delta lobes, media and their extinction, how a shape is named. Cheap loops over the shapes, no pre-pass; the
scene's inventory and its plan in words are ``holocore.plan.effects``."""

from __future__ import annotations

from typing import Any, Iterator, Optional

from holocore.runtime.mitsuba_env import mitsuba

__all__ = ["shape_name", "is_mixed_delta", "has_mixed_delta", "has_media", "reference_integrator",
           "sigma_t_per_m", "absorbing_media", "NEAR_SMOOTH_MAX_ALPHA", "bsdf_alpha", "all_glossy",
           "near_smooth_shapes", "near_smooth_bsdfs"]


def shape_name(shape, i: int) -> str:
    """A shape's id, or its class and index where it has none (how the plan and the refusals name it)."""
    sid = shape.id()
    return sid if sid else f"{shape.class_name().lower()}#{i}"


def is_mixed_delta(flags) -> bool:
    """Whether BSDF flags hold delta and smooth lobes together (plastic and the like): the one test of it."""
    mi = mitsuba()
    return bool(mi.has_flag(flags, mi.BSDFFlags.Delta) and mi.has_flag(flags, mi.BSDFFlags.Smooth))


def has_mixed_delta(scene) -> bool:
    """Whether any shape's BSDF mixes delta and smooth lobes (a cheap loop over the shapes, no inventory)."""
    return any(sh.bsdf() is not None and is_mixed_delta(sh.bsdf().flags()) for sh in scene.shapes())


def has_media(scene) -> bool:
    """Whether the scene holds a medium anywhere: a shape's interior or exterior, or the first sensor."""
    sensors = scene.sensors()
    if sensors and sensors[0].get_medium() is not None:
        return True
    return any(sh.interior_medium() is not None or sh.exterior_medium() is not None for sh in scene.shapes())


def reference_integrator(scene, *, max_depth: int) -> dict:
    """Mitsuba's integrator for reference renders of ``scene`` (ground truth, baselines), as a ``load_dict``
    dict: ``path``, or ``volpath`` where the scene holds media, which ``path`` ignores. Raises ValueError for
    a medium with sigma_t = 0 in some colour and > 0 in another, where Mitsuba's ``volpath`` returns NaN in
    every pixel (the hologram's own tracer is exact there)."""
    if not has_media(scene):
        return {"type": "path", "max_depth": int(max_depth)}
    for where, sigma in absorbing_media(scene).items():
        if min(sigma) == 0 < max(sigma):
            raise ValueError(f"the medium in {where} has sigma_t = 0 in a colour, where Mitsuba's volpath (the "
                             "reference render) returns NaN: give that colour a small sigma_t (1e-6 /m)")
    return {"type": "volpath", "max_depth": int(max_depth)}


def sigma_t_per_m(medium) -> list[float]:
    """A homogeneous medium's extinction per colour (1/m; ``scale`` included), as the tracer reads it."""
    mi = mitsuba()
    import drjit as dr

    _s, _n, sigma_t = medium.get_scattering_coefficients(dr.zeros(mi.MediumInteraction3f, 1), True)
    return [float(sigma_t[c][0]) for c in range(3)]


def absorbing_media(scene) -> dict[str, list[float]]:
    """Every medium the scene's shapes and sensor hold (the scene check has made them homogeneous and
    absorbing), by where it sits."""
    out: dict[str, list[float]] = {}
    for sensor in scene.sensors()[:1]:
        if sensor.get_medium() is not None:
            out["sensor"] = sigma_t_per_m(sensor.get_medium())
    for i, sh in enumerate(scene.shapes()):
        for side, medium in (("interior", sh.interior_medium()), ("exterior", sh.exterior_medium())):
            if medium is not None:
                out[f"{shape_name(sh, i)} ({side})"] = sigma_t_per_m(medium)
    return out


NEAR_SMOOTH_MAX_ALPHA = 0.1  # GGX / Beckmann alpha up to which a surface still carries an image
"""Rough conductors and dielectrics (every lobe glossy) up to this roughness continue the coherent chain
(holocore.trace.near_smooth)."""


def bsdf_alpha(bsdf) -> Optional[float]:
    """The largest roughness alpha a BSDF declares (alpha, alpha_u, alpha_v, also inside a wrapper such as
    ``twosided``; a texture's largest texel), or None where it has none."""
    import numpy as np

    mi = mitsuba()
    names = (["alpha", "value"], ["alpha_u", "value"], ["alpha_v", "value"], ["alpha", "data"],
             ["alpha_u", "data"], ["alpha_v", "data"])
    vals = [np.asarray(v, dtype=np.float64).ravel() for k, v in mi.traverse(bsdf).items()
            if k.split(".")[-2:] in names]
    vals = [v for v in vals if v.size]
    return float(max(v.max() for v in vals)) if vals else None


def all_glossy(bsdf) -> bool:
    """Whether every lobe of a BSDF is glossy (no diffuse base, no delta lobe)."""
    F = mitsuba().BSDFFlags
    not_glossy = int(F.Diffuse) | int(F.Delta)
    lobes = [int(bsdf.flags(i)) for i in range(bsdf.component_count())]
    return bool(lobes) and all(fl & int(F.Glossy) and not fl & not_glossy for fl in lobes)


def near_smooth_shapes(scene) -> Iterator[tuple[int, Any, float]]:
    """(index, shape, alpha) of each shape whose BSDF is near-smooth (holocore.trace.near_smooth): every lobe
    glossy, alpha at most NEAR_SMOOTH_MAX_ALPHA. The one test of it, for the plan and the tracer."""
    for i, sh in enumerate(scene.shapes()):
        b = sh.bsdf()
        a = None if b is None or not all_glossy(b) else bsdf_alpha(b)
        if a is not None and a <= NEAR_SMOOTH_MAX_ALPHA:
            yield i, sh, a


def near_smooth_bsdfs(scene) -> dict[str, float]:
    """The scene's near-smooth shapes by name, with their alpha (the plan's inventory)."""
    return {shape_name(sh, i): a for i, sh, a in near_smooth_shapes(scene)}
