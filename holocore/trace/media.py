"""Homogeneous absorbing media on a wave path (docs/physics.md, "Absorbing media"): Beer-Lambert attenuation of
each segment by the medium it travels in, per colour, for the wave kernel (:mod:`holocore.trace.kernel`).

Mitsuba tells which medium a ray is in: the sensor's (a ``<sensor>`` holding a ``<medium>``) at the start, then
the side of the last boundary the ray left into (``target_medium``). Only homogeneous media with albedo 0
reach the tracer (the scene check refuses scattering and heterogeneous ones), so sigma_t is one constant per
colour and a segment of length t keeps exp(-sigma_t t) of its intensity (its amplitude the square root).

Units: metres, 1/m (Mitsuba's ``scale`` included in sigma_t).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from holocore.runtime.mitsuba_env import mitsuba

if TYPE_CHECKING:  # annotations only: the variant's array types come from mitsuba() at run time
    import mitsuba as mi

__all__ = ["sensor_medium", "extinction", "transmittance", "absorb"]


def sensor_medium(scene: mi.Scene, width: int) -> mi.MediumPtr:
    """The medium the ``width`` rays start in: the scene's first sensor's; null pointers (vacuum) when it has
    none."""
    mi = mitsuba()
    import drjit as dr

    sensors = scene.sensors()
    medium = sensors[0].get_medium() if sensors else None
    none = dr.zeros(mi.MediumPtr, width)
    return none if medium is None else dr.select(dr.full(mi.Bool, True, width), mi.MediumPtr(medium), none)


def extinction(medium: Any, ray: mi.Ray3f, si: mi.SurfaceInteraction3f, active: mi.Bool) -> mi.Color3f:
    """sigma_t per colour (1/m) of ``medium`` (a pointer per lane) for the segment of ``ray``: one constant per
    colour, so it is read at the ray's origin; 0 where ``active`` is off or the pointer is null. ``si`` gives the
    lanes' wavelengths."""
    mi = mitsuba()
    import drjit as dr

    mei = dr.zeros(mi.MediumInteraction3f)
    mei.p, mei.wi, mei.t, mei.wavelengths = ray.o, -ray.d, 0.0, si.wavelengths
    _sigma_s, _sigma_n, sigma_t = medium.get_scattering_coefficients(mei, active)
    return dr.select(active, sigma_t, 0.0)


def transmittance(sigma_t: mi.Color3f, t: mi.Float) -> mi.Color3f:
    """Beer-Lambert, exp(-sigma_t t) per colour over t (m), in intensity; exactly 1 where sigma_t = 0, also over
    an infinite t (no 0 * inf)."""
    import drjit as dr

    return dr.select(sigma_t > 0, dr.exp(-sigma_t * t), 1.0)


def absorb(state: Any, vertex: Any) -> None:
    """The kernel's step 1': the segment just traced (``state.ray``, from ``state.si_prev`` to ``vertex.si``)
    crossed ``state.medium``, so the throughput ``state.beta`` takes its transmittance. The length is measured
    from the previous vertex, not from the spawned ray's origin, which Mitsuba offsets by ~1e-4 m; a segment
    that leaves the scene inside a medium is fully absorbed."""
    import drjit as dr

    inside = state.active & (state.medium != None)  # noqa: E711 (Dr.Jit compares pointers lane by lane)
    t = dr.select(vertex.si.is_valid(), dr.norm(vertex.si.p - state.si_prev.p), dr.inf)
    state.beta = state.beta * transmittance(extinction(state.medium, state.ray, vertex.si, inside), t)
