"""Scene analysis: a sparse pre-pass that finds the depth range of the first surfaces and of the image
points (through a mirror the image lies behind it), which colors carry light, and where the WRP goes
(docs/design.md §3 Eq. D3: on the viewer's side of every surface and image point, with a margin)."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from pydantic import BaseModel

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD, channel_of, theta_max_rad
from holocore.plan.effects import DELTA_CAP_LIMIT as DELTA_PROBE_CAP
from holocore.runtime.mitsuba_env import mitsuba
from holocore.runtime.recording import recording_kernels
from holocore.trace.mapping import HologramMap, camera_grid
from holocore.trace.reference_chain import aligned, trace_chain

__all__ = ["SceneAnalysis", "analyze", "SceneDoesNotFit"]


class SceneDoesNotFit(ValueError):
    """The scene needs a WRP farther from z_inf than allowed."""


class SceneAnalysis(BaseModel):
    rays: int
    hit_fraction: float
    zc_first_min_m: Optional[float]
    zc_first_max_m: Optional[float]
    zc_image_min_m: Optional[float]
    zc_image_max_m: Optional[float]
    image_points_behind_viewer: int
    max_delta_seen: int
    prepass_capped: int  # pre-pass rays still in a delta chain at the probe cap (a mirror hall)
    # pre-pass rays by the delta bounces their chain needed (index k: k bounces; the last: still bouncing at the probe
    # cap): the share a delta cap c drops is the rays past index c (holocore.plan.effects)
    delta_bounces: list[int] = []
    colors_lit: list[bool]
    z_wrp_m: float
    z_near_holo_m: Optional[float]  # hologram depth of the nearest surface or image point
    z_far_holo_m: Optional[float]  # ... of the farthest
    subhologram_radius_px: float  # of the farthest image point on the WRP, widest cone
    # the light's share (luminance-weighted over the pre-pass rays with an image point) that reaches the eye
    # through a refracting medium (its optical path differs from its apparent distance): each glass surface is a
    # Fresnel choice between reflection and refraction, a Monte Carlo noise a mirror's one path does not have
    refracted_share: float = 0.0
    margin_m: float
    # Hologram depths of the image points, luminance-weighted quantiles (front to back): where the light is,
    # for placing several recording planes (holocore.plan.wrp_planes).
    image_depths_holo_m: list[float] = []


def _emitted_rgb(scene, seed: int, n: int = 256) -> np.ndarray:
    """Total RGB weight of light sampled from every emitter: which channels carry any light at all.

    Mitsuba's ``sample_ray`` needs the emitter's spectrum to be sampleable, which spatially varying radiance
    (a checkerboard or bitmap on an area light, a spot's or projector's texture) is not in every variant
    ("Texture::sample_spectrum(): not implemented"). What the path integrator uses of an emitter is
    ``eval`` (seen directly) and ``sample_direction`` (emitter sampling), so where ``sample_ray`` is not
    implemented the same quantities are measured with those two: emitted radiance at points sampled on the
    emitter's shape, and direct light arriving at points sampled on the scene's shapes. A surface that emits
    in one direction only (``directionalarea``) is measured that way too: a path tracer never connects to it
    (Mitsuba renders it with a particle tracer only), so it lights neither Mitsuba's ``path`` nor the hologram.
    """
    mi = mitsuba()
    total = np.zeros(3)
    sampler = mi.load_dict({"type": "independent"})
    for em in scene.emitters():
        sampler.seed(seed, n)
        if em.get_shape() is not None and mi.has_flag(em.flags(), mi.EmitterFlags.DeltaDirection):
            total += _emitter_rgb_by_eval(mi, scene, em, sampler, seed, n)
            continue
        try:
            _ray, weight = em.sample_ray(0.0, sampler.next_1d(), sampler.next_2d(), sampler.next_2d())
            total += _positive_rgb_sum(weight)
        except RuntimeError:  # the spectrum cannot be sampled: measure it as the path integrator sees it
            total += _emitter_rgb_by_eval(mi, scene, em, sampler, seed, n)
    return total


def _positive_rgb_sum(color) -> np.ndarray:
    """Per-channel sum of a Color3f's finite, positive lanes."""
    w = np.stack([np.asarray(color[k], dtype=np.float64).reshape(-1) for k in range(3)], axis=1)
    return np.nan_to_num(w, nan=0.0, posinf=0.0, neginf=0.0).clip(min=0).sum(axis=0)


def _emitter_rgb_by_eval(mi, scene, em, sampler, seed: int, n: int) -> np.ndarray:
    """An emitter's RGB weight from ``eval`` on its own shape (if any) and from ``sample_direction`` towards
    points sampled on every shape of the scene (both sides, just off the surface)."""
    import drjit as dr

    total = np.zeros(3)
    shape = em.get_shape()
    if shape is not None:
        sampler.seed(seed + 1, n)
        ps = shape.sample_position(0.0, sampler.next_2d())
        si = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
        si.wi = mi.Vector3f(0.0, 0.0, 1.0)  # leaving along the normal: the side an area light emits from
        total += _positive_rgb_sum(em.eval(si))
    for k, ref_shape in enumerate(scene.shapes()):
        for side in (1.0, -1.0):
            sampler.seed(seed + 2 + 2 * k + (side < 0), n)
            ps = ref_shape.sample_position(0.0, sampler.next_2d())
            scale = 1e-4 * max(1e-3, float(dr.norm(ref_shape.bbox().extents())))
            it = dr.zeros(mi.Interaction3f, n)
            it.p = ps.p + ps.n * (side * scale)
            it.n = ps.n * side
            _ds, weight = em.sample_direction(it, sampler.next_2d(), True)
            total += _positive_rgb_sum(weight)
    return total


def _small_shape_depths(scene, hmap: HologramMap, dirs_c: np.ndarray, n_side: int) -> np.ndarray:
    """Nearest eye-camera depth of every shape that the sparse grid could miss: its bounding box lies in front
    of the eye, spans less than two grid steps and is seen inside the grid's field of view. (A point-like
    emitter between the grid's rays would otherwise leave the WRP behind it, and its light would be dropped.)"""
    x = dirs_c[:, 0] / dirs_c[:, 2]
    y = dirs_c[:, 1] / dirs_c[:, 2]
    tx, ty = float(np.abs(x).max()), float(np.abs(y).max())
    step = 2.0 * tx / max(1, n_side)
    out = []
    for shape in scene.shapes():
        bb = shape.bbox()
        lo = np.array([bb.min[k] for k in range(3)], dtype=np.float64)
        hi = np.array([bb.max[k] for k in range(3)], dtype=np.float64)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            continue
        corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                            for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        c = hmap.world_to_camera(corners)
        if np.any(c[:, 2] <= 0):
            continue
        u, v = c[:, 0] / c[:, 2], c[:, 1] / c[:, 2]
        if max(u.max() - u.min(), v.max() - v.min()) >= 2.0 * step:
            continue  # big enough for the grid to hit
        if u.max() < -tx or u.min() > tx or v.max() < -ty or v.min() > ty:
            continue  # outside the view
        out.append(float(c[:, 2].min()))
    return np.asarray(out, dtype=np.float64)


@recording_kernels()
def analyze(
    scene,
    hmap: HologramMap,
    *,
    wavelengths_m: list[float],
    pitch_m: float,
    shape_hw: tuple[int, int],
    margin_px: float,
    max_wrp_distance_m: float,
    max_delta: int = DELTA_PROBE_CAP,
    n_side: int = 64,
    seed: int = 0,
) -> SceneAnalysis:
    """Sparse pre-pass from the eye point; places the WRP or raises :class:`SceneDoesNotFit`."""
    mi = mitsuba()
    rng = np.random.default_rng([seed, 31337])
    dirs_c = camera_grid(hmap, shape_hw, pitch_m, n_side, rng)
    R = dirs_c.shape[0]
    eye_w = hmap.camera_to_world(np.zeros((1, 3)))
    o = np.repeat(eye_w, R, axis=0)
    v = hmap.camera_dir_to_world(dirs_c)

    zc_first, hit = _first_surfaces(mi, scene, o, v, dirs_c)
    zc_first = hmap.camera_length(zc_first)  # world lengths along the rays -> eye-camera depths
    integ = mi.load_dict({"type": "path", "max_depth": 4})
    res = trace_chain(scene, o, v, max_delta=max_delta, amp_spp=4, integrator=integ, seed=seed + 17)
    zc_img_all = hmap.camera_length(res.d) * dirs_c[:, 2]
    good = res.valid
    behind = int(np.count_nonzero(good & (zc_img_all <= 0)))
    zc_img = zc_img_all[good & (zc_img_all > 0)]
    lum = res.radiance[res.valid].sum(axis=0) if res.valid.any() else np.zeros(3)
    lum = lum + _emitted_rgb(scene, seed)
    colors_lit = [bool(lum[channel_of(lam)] > 0) for lam in wavelengths_m]

    theta_min = min(theta_max_rad(lam, pitch_m) for lam in wavelengths_m)
    theta_max = max(theta_max_rad(lam, pitch_m) for lam in wavelengths_m)
    margin = margin_px * pitch_m / math.tan(theta_min)
    depths = np.concatenate([zc_first, zc_img, _small_shape_depths(scene, hmap, dirs_c, n_side)])
    zc_min, z_near, z_far, z_wrp = _wrp_place(hmap, depths[np.isfinite(depths) & (depths > 0)], margin,
                                              max_wrp_distance_m)
    depth_q = _weighted_quantiles(hmap.holo_depth_m(zc_img), res.radiance[good & (zc_img_all > 0)].sum(axis=1))
    ok = good & (zc_img_all > 0)
    w_lum = res.radiance[ok].sum(axis=1).astype(np.float64)
    bent = np.abs(res.opl_m[ok] - res.d[ok]) > 1e-6 * np.maximum(np.abs(res.d[ok]), 1e-9)
    refracted = float(w_lum[bent].sum() / w_lum.sum()) if w_lum.sum() > 0 else 0.0
    radius_px = 0.0 if z_far is None else (z_wrp - z_far) * math.tan(min(theta_max, MAX_CONE_HALF_ANGLE_RAD)) / pitch_m
    return SceneAnalysis(
        rays=R,
        hit_fraction=float(hit.mean()) if R else 0.0,
        zc_first_min_m=float(zc_first.min()) if zc_first.size else None,
        zc_first_max_m=float(zc_first.max()) if zc_first.size else None,
        zc_image_min_m=float(zc_img.min()) if zc_img.size else None,
        zc_image_max_m=float(zc_img.max()) if zc_img.size else None,
        image_points_behind_viewer=behind,
        max_delta_seen=int(res.n_delta[res.valid].max()) if res.valid.any() else 0,
        prepass_capped=int(np.count_nonzero(res.capped)),
        delta_bounces=_delta_bounces(res, max_delta),
        colors_lit=colors_lit,
        z_wrp_m=float(z_wrp),
        z_near_holo_m=z_near,
        z_far_holo_m=z_far,
        subhologram_radius_px=float(radius_px),
        refracted_share=refracted,
        margin_m=float(margin),
        image_depths_holo_m=depth_q,
    )


def _delta_bounces(res, cap: int) -> list[int]:
    """Pre-pass rays by delta bounces needed, the rays still bouncing at ``cap`` in the last bin (index cap + 1)."""
    k = np.where(res.capped, cap + 1, np.minimum(res.n_delta, cap)).astype(np.int64)
    return [int(v) for v in np.bincount(k, minlength=cap + 2)]


def _first_surfaces(mi, scene, o: np.ndarray, v: np.ndarray, dirs_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(camera depth of each ray's first surface of any BSDF, which rays hit one): the WRP must stay in air, in
    front of them."""
    import drjit as dr

    ray = mi.Ray3f(mi.Point3f(*[mi.Float(aligned(o[:, i])) for i in range(3)]),
                   mi.Vector3f(*[mi.Float(aligned(v[:, i])) for i in range(3)]))
    si = scene.ray_intersect(ray)
    dr.eval(si.t)
    hit = np.asarray(si.is_valid(), dtype=bool)
    t = np.asarray(si.t, dtype=np.float64)
    return (t * dirs_c[:, 2])[hit], hit


def _wrp_place(hmap: HologramMap, depths: np.ndarray, margin: float, max_wrp_distance_m: float):
    """(the nearest camera depth, the image volume's near and far hologram depths, the WRP's: docs/design.md
    Eq. D3) from the visible depths; :class:`SceneDoesNotFit` when the WRP would lie past the limit."""
    if depths.size:
        zc_min = float(depths.min())
        z_near = float(hmap.holo_depth_m(zc_min))
        z_far = float(hmap.holo_depth_m(float(depths.max())))
        z_wrp = z_near + margin
    else:  # nothing visible: a black scene; any plane will do
        zc_min = z_near = z_far = None
        z_wrp = hmap.z_inf_m + margin
    if z_wrp - hmap.z_inf_m > max_wrp_distance_m:
        raise SceneDoesNotFit(
            f"the nearest surface or image point is {zc_min:.4g} m from the eye, which maps to "
            f"{(z_wrp - hmap.z_inf_m) * 1e3:.1f} mm in front of z_inf with the eyepiece f = "
            f"{hmap.focal_length_m * 1e3:.2f} mm; the limit (max_wrp_distance_mm) is "
            f"{max_wrp_distance_m * 1e3:.1f} mm: move the camera away, shorten f, or raise the limit"
        )
    return zc_min, z_near, z_far, z_wrp


def _weighted_quantiles(z: np.ndarray, lum: np.ndarray, n: int = 64) -> list[float]:
    """n quantiles of z weighted by luminance (plus 5% of the mean, so that dim lit parts count too), front
    (largest z) to back."""
    z = np.asarray(z, dtype=np.float64)
    w = np.nan_to_num(np.asarray(lum, dtype=np.float64), nan=0.0, posinf=0.0).clip(min=0)
    ok = np.isfinite(z)
    z, w = z[ok], w[ok]
    if z.size == 0:
        return []
    w = w + 0.05 * (w.mean() if w.sum() > 0 else 1.0)
    order = np.argsort(-z)
    z, cw = z[order], np.cumsum(w[order])
    pos = (np.arange(n) + 0.5) / n * cw[-1]
    return [float(v) for v in z[np.minimum(np.searchsorted(cw, pos), z.size - 1)]]
