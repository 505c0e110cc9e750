"""What a loaded Mitsuba scene holds that the tracer, the plan and the reference renders each ask about: mixed
delta lobes, media and their extinction, how a shape is named. Cheap loops over the shapes, no pre-pass; the
scene's inventory and its plan in words are ``holocore.plan.effects``."""

from __future__ import annotations

from holocore.runtime.mitsuba_env import mitsuba

__all__ = ["shape_name", "is_mixed_delta", "has_mixed_delta", "has_media", "reference_integrator",
           "sigma_t_per_m", "absorbing_media"]


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
