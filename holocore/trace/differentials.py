"""The ray-differential transfer through a delta vertex (Igehy 1999), in float64, shared by the fused kernel
(:mod:`holocore.trace.kernel`) and the reference chain (:mod:`holocore.trace.reference_chain`).

A coherent chain carries four differentials of its ray (two lateral shifts of the origin, two angular
perturbations of the direction) and an orthonormal frame. At a mirror or a smooth dielectric they are carried
through the vertex (Igehy's Eq. 10 for the transfer to the surface, Eq. 12 for the change of t there, then the
reflection or refraction of the direction differentials); where the chain ends, at the image point P, the
apparent distance d = 2 / tr(B^-1 A) is read from them (docs/design.md §4, docs/physics.md). Units: metres,
unit direction vectors.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from holocore.runtime.mitsuba_env import mitsuba
from holocore.trace.near_smooth import micro_normal

if TYPE_CHECKING:  # annotations only: the variant's array types come from mitsuba() at run time
    import mitsuba as mi

__all__ = ["igehy_transfer"]

_EPS_COS = 1e-7  # |cos| below this at a delta vertex: the differential transfer is singular, drop the ray


def _normal_differentials(si: mi.SurfaceInteraction3f, N: mi.Vector3d, dPh: list) -> list:
    """dN for each surface differential dP' (float64): the shape operator applied to dP'.

    Where the (u, v) chart is regular: dN = dn/du du + dn/dv dv, (du, dv) from dP' in the tangent basis
    (dp_du, dp_dv) by the normal equations. Where its metric is singular, at a pole of the parametrisation
    (Mitsuba's sphere on its local z axis: dp_du = 0 there, dp_dv still a unit tangent times pi r), those
    equations have no solution, and dropping dN made a ball lens a flat slab for the ray on its axis (5.58 m
    instead of 0.345 m). There the shape operator comes from the tangent that survives, t: its normal curvature
    k = (dn_t . t) / |t|^2 and twist tau along the orthogonal tangent N x t; it is symmetric, and the second
    principal curvature is the limit at such a pole, equal to k (a pole of a surface of revolution is an
    umbilic point; on a sphere every point is). Both tangents gone (no differential geometry): dN = 0.
    """
    mi = mitsuba()
    import drjit as dr

    V3d = mi.Vector3d
    dpdu, dpdv = V3d(si.dp_du), V3d(si.dp_dv)
    dndu, dndv = V3d(si.dn_du), V3d(si.dn_dv)
    a, b, c = dr.dot(dpdu, dpdu), dr.dot(dpdu, dpdv), dr.dot(dpdv, dpdv)
    det = a * c - b * b
    # relative to the metric's size, so a chart whose one tangent shrinks to nothing (float32 rounding next to
    # a pole) counts as singular too; there the limit below is accurate to (|dp_du| / |dp_dv|)^2 ~ 1e-10
    regular = (det > 1e-10 * (a + c) * (a + c)) & (det > 1e-30)
    inv_det = dr.select(regular, 1.0 / dr.select(regular, det, 1.0), 0.0)
    use_u = a >= c  # the longer tangent survives
    t = dr.select(use_u, dpdu, dpdv)
    dn_t = dr.select(use_u, dndu, dndv)
    len2 = dr.select(use_u, a, c)
    have = ~regular & (len2 > 1e-30)
    inv_len = dr.select(have, dr.rsqrt(dr.select(have, len2, 1.0)), 0.0)
    e1 = t * inv_len
    e1 = dr.normalize(e1 - dr.dot(e1, N) * N)  # tangent to the shading normal's plane
    e2 = dr.cross(N, e1)
    k = dr.dot(dn_t, e1) * inv_len
    tau = dr.dot(dn_t, e2) * inv_len
    dN = []
    for i in range(4):
        r1, r2 = dr.dot(dPh[i], dpdu), dr.dot(dPh[i], dpdv)
        chart = dndu * ((c * r1 - b * r2) * inv_det) + dndv * ((a * r2 - b * r1) * inv_det)
        x1, x2 = dr.dot(dPh[i], e1), dr.dot(dPh[i], e2)
        pole = e1 * (k * x1 + tau * x2) + e2 * (tau * x1 + k * x2)
        dN.append(dr.select(regular, chart, dr.select(have, pole, V3d(0.0))))
    return dN


def igehy_transfer(si: mi.SurfaceInteraction3f, bs: mi.BSDFSample3f, go_on: mi.Bool, D: mi.Vector3d,
                    dP: list, dD: list, frame: list, n_cur: mi.Float64, nd: mi.UInt32, micro: mi.Bool | None = None
                    ) -> tuple:
    """At a chain vertex, in float64: the apparent distance d (m) read from the differentials (used where the
    chain ends here, at P), and, on ``go_on``, the differentials and the frame carried through the delta
    vertex (Igehy 1999). Returns (d, singular, D, dP, dD, frame, n_cur, nd); ``singular``: the ray grazes the
    surface (|cos| < 1e-7), the transfer does not exist and the ray is dropped. ``micro``: lanes whose vertex is
    a near-smooth surface (holocore.trace.near_smooth): the direction and its differentials turn about the
    sampled micro-normal, while the differentials still land on the surface's own tangent plane."""
    mi = mitsuba()
    import drjit as dr

    F64, V3d = mi.Float64, mi.Vector3d
    t = F64(si.t)
    N = V3d(si.sh_frame.n)
    cosD = dr.dot(D, N)
    # Transfer along the segment to the surface (Igehy Eq. 10 without dt, which the projection below adds).
    dPt = [dP[i] + t * dD[i] for i in range(4)]
    # The image point: 2x2 transfer blocks A (shifts) and B (angles) read along the carried frame, perpendicular
    # to the last segment; d = 2 / tr(B^-1 A) = 2 det(B) / tr(adj(B) A) (docs/physics.md).
    lat = [dPt[i] - dr.dot(dPt[i], D) * D for i in range(4)]
    a11, a12 = dr.dot(lat[0], frame[0]), dr.dot(lat[1], frame[0])
    a21, a22 = dr.dot(lat[0], frame[1]), dr.dot(lat[1], frame[1])
    b11, b12 = dr.dot(lat[2], frame[0]), dr.dot(lat[3], frame[0])
    b21, b22 = dr.dot(lat[2], frame[1]), dr.dot(lat[3], frame[1])
    det_b = b11 * b22 - b12 * b21
    tr = b22 * a11 - b12 * a21 - b21 * a12 + b11 * a22  # tr(adj(B) A) = det(B) tr(B^-1 A)
    d_here = 2.0 * det_b / dr.select(dr.abs(tr) > 0, tr, 1e-300)

    singular = go_on & (dr.abs(cosD) < _EPS_COS)
    go_on = go_on & ~singular
    safe_cos = dr.select(dr.abs(cosD) < _EPS_COS, 1.0, cosD)
    # dP on the surface: dt = -(dPt . N) / (D . N) (Igehy Eq. 12), dP' = dPt + dt D.
    dPh = [dPt[i] - (dr.dot(dPt[i], N) / safe_cos) * D for i in range(4)]
    dN = _normal_differentials(si, N, dPh)
    D_new = dr.normalize(V3d(si.to_world(bs.wo)))
    is_refl = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Reflection)
    if micro is not None:  # the micro-normal turns the ray; the surface's curvature turns the micro-normal
        N = dr.select(micro, micro_normal(D, D_new, F64(bs.eta), is_refl), N)
        cosD = dr.dot(D, N)
    # Reflection: D' = D - 2 (D.N) N.  Refraction (N facing the ray): D' = eta D + mu N, mu = eta c1 - c2.
    sgn = dr.select(cosD < 0, 1.0, -1.0)
    Nf = N * sgn
    eta = 1.0 / F64(dr.select(bs.eta > 0, bs.eta, 1.0))  # n1 / n2
    c1 = -dr.dot(D, Nf)
    c2 = dr.maximum(-dr.dot(D_new, Nf), 1e-9)
    mu = eta * c1 - c2
    axis = dr.cross(D, D_new)
    s_ax = dr.norm(axis)
    rot_ok = s_ax > 1e-12
    axis = axis / dr.select(rot_ok, s_ax, 1.0)
    u_old, u_new = dr.cross(axis, D), dr.cross(axis, D_new)
    dP, dD = list(dP), list(dD)
    for i in range(4):  # the derivatives of D' (Igehy's reflection and refraction differentials)
        dDN = dr.dot(dD[i], N) + dr.dot(D, dN[i])
        refl = dD[i] - 2.0 * (cosD * dN[i] + dDN * N)
        dNf = dN[i] * sgn
        dc1 = -(dr.dot(dD[i], Nf) + dr.dot(D, dNf))
        dmu = eta * dc1 - eta * eta * c1 * dc1 / c2
        refr = eta * dD[i] + dmu * Nf + mu * dNf
        dP[i] = dr.select(go_on, dPh[i], dP[i])
        dD[i] = dr.select(go_on, dr.select(is_refl, refl, refr), dD[i])
    frame = list(frame)
    for i in range(2):  # the frame: mirrored (reflection) or rotated about D x D' (refraction)
        f = frame[i]
        refl = f - 2.0 * dr.dot(f, N) * N
        rotated = dr.select(rot_ok, dr.dot(f, axis) * axis + dr.dot(f, u_old) * u_new, f)
        frame[i] = dr.select(go_on, dr.select(is_refl, refl, rotated), f)
    n_cur = dr.select(go_on & ~is_refl, n_cur * F64(bs.eta), n_cur)
    nd = dr.select(go_on, nd + 1, nd)
    D = dr.select(go_on, D_new, D)
    return d_here, singular, D, dP, dD, frame, n_cur, nd
