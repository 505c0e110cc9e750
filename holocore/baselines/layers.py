"""A layer-based (RGB-D) baseline, the kind of method the paper compares against (Sec. 5.2, "RGBD").

1. RGB-D from Mitsuba: one pinhole render from the eye (the hologram's field of view, H x W) through the
   ``aov`` integrator, which returns the path-traced RGB and the ray distance t of the first hit (``dd.y``);
   the eye-camera depth is zc = t / sqrt(1 + tan_x^2 + tan_y^2) at each pixel centre.
2. N planes uniform in hologram depth z = z_inf + f^2 / zc (uniform in dioptres) from the nearest to the
   farthest pixel; every pixel goes to the nearest plane (no occlusion handling, as in plain layer methods).
3. Plane k, color c, frame m: U = sqrt(I_c) s_c / s_max on its pixels, times the frame's band-limited random
   phase (the renderer's own bank, :func:`holocore.trace.randomfield.phase_bank`: the same recording cone). The
   random phase spreads color c's light evenly over its cone of direction sines s_c = sin theta_max =
   lambda / 2p; an eye whose pupil lies inside the cone takes the fraction (NA / s_c)^2 of it, so the power
   must grow like s_c^2 for every color to look as bright as its radiance (otherwise red, with the widest
   cone, looks (s_R / s_B)^2 = 2x too dim against blue).
4. Each plane is propagated by band-limited ASM from its depth z_k to the WRP (z_wrp > z_k, towards the
   viewer), summed there, and the sum goes to the SLM by ASM over -z_wrp, as the two-stage renderer does.

The result has the renderer's RESULT.npz format and meta (same analysis, so evaluation picks the same focus
planes); ``meta["method"] == "layers"``.
"""

from __future__ import annotations

import math
import time
from typing import Any, Optional, Sequence

import numpy as np

from pydantic import Field

from holocore import validate
from holocore.baselines.registry import Baseline, BaselineOptions, register_baseline
from holocore.display.optics import channel_of
from holocore.display.optics import OpticsConfig
from holocore.render_meta import RenderResult, result_meta
from holocore.runtime.mitsuba_env import mitsuba
from holocore.runtime.recording import recording_kernels
from holocore.scene.features import reference_integrator
from holocore.trace.frame_phases import get_frame_phases

__all__ = ["MAX_PLANES", "rgbd", "plane_depths", "layer_fields", "render_layers", "LayersOptions", "LayersBaseline"]

MAX_PLANES = 256
MAX_SPP = 1 << 16


@recording_kernels()
def rgbd(scene: Any, hmap: Any, *, shape_hw: tuple[int, int], pitch_m: float, spp: int = 64, seed: int = 0,
         max_depth: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """(linear RGB float32 [3, H, W], eye-camera depth zc float64 [H, W] in m, 0 where nothing is hit).

    A pinhole camera at the eye with the hologram's pixel grid (x = f tan, docs/design.md §3), box filter,
    ``spp`` samples per pixel, Mitsuba's ``path`` integrator with ``max_depth`` inside ``aov``.
    """
    mi = mitsuba()
    H, W = (int(s) for s in shape_hw)
    spp = validate.integer("spp", spp, 1, MAX_SPP)
    p = float(pitch_m)
    if not (math.isfinite(p) and p > 0):
        raise ValueError(f"pitch_m must be finite and > 0, got {pitch_m!r}")
    f = hmap.focal_length_m
    sensor = mi.load_dict({
        "type": "perspective", "fov": 2.0 * math.degrees(math.atan(W * p / (2.0 * f))), "fov_axis": "x",
        "near_clip": 1e-3, "to_world": mi.ScalarTransform4f(np.asarray(hmap.cam_to_world).tolist()),
        "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}, "pixel_format": "rgba"},
        "sampler": {"type": "independent", "sample_count": spp},
    })
    integ = mi.load_dict({"type": "aov", "aovs": "dd.y:depth",
                          "integrator": reference_integrator(scene, max_depth=int(max_depth))})
    img = np.array(mi.render(scene, sensor=sensor, integrator=integ, spp=spp, seed=int(seed)), dtype=np.float64)
    if img.ndim != 3 or img.shape[-1] != 5:
        raise RuntimeError(f"expected R, G, B, A and depth from Mitsuba's aov integrator, got shape {img.shape}")
    # Channels of an rgba film with one AOV: R, G, B, alpha (the fraction of samples that hit), then the AOV:
    # the ray distance t averaged over all samples, misses counting 0; t / alpha averages the hits only.
    img = np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0)
    rgb = img[..., :3].clip(min=0.0)
    alpha = img[..., 3]
    t = np.where(alpha > 1e-6, img[..., 4].clip(min=0.0) / np.maximum(alpha, 1e-6), 0.0)
    cols = (np.arange(W) - (W - 1) / 2.0) * p / f
    rows = ((H - 1) / 2.0 - np.arange(H)) * p / f
    zc = hmap.camera_length(t / np.sqrt(1.0 + cols[None, :] ** 2 + rows[:, None] ** 2))  # world t -> eye frame
    return np.ascontiguousarray(np.moveaxis(rgb, -1, 0).astype(np.float32)), zc


def plane_depths(z_holo: np.ndarray, planes: int) -> np.ndarray:
    """``planes`` hologram depths (m) uniform from the smallest to the largest finite value of ``z_holo``."""
    planes = validate.integer("planes", planes, 1, MAX_PLANES)
    z = np.asarray(z_holo, dtype=np.float64)
    z = z[np.isfinite(z)]
    if z.size == 0:
        raise ValueError("no finite depth: the RGB-D image saw nothing")
    lo, hi = float(z.min()), float(z.max())
    return np.array([0.5 * (lo + hi)]) if planes == 1 or hi == lo else np.linspace(lo, hi, planes)


def layer_fields(rgb: np.ndarray, zc: np.ndarray, *, focal_length_m: float, z_inf_m: float, z_wrp_m: float,
                 pitch_m: float, wavelengths_m: Sequence[float], frames: int, planes: int = 8,
                 seed: int = 0, z_range_m: Optional[tuple[float, float]] = None, frame_phases: str = "coded",
                 eyebox_sine: Optional[float] = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(SLM field, WRP field) complex64 [F, C, H, W], plane depths (m) and pixels per plane, from RGB-D.

    ``rgb`` [3, H, W] linear radiance, ``zc`` [H, W] eye-camera depth (m; <= 0 or non-finite: nothing hit,
    put on the farthest plane). ``z_range_m`` (far, near): hologram depths outside it (pixels that mix a
    surface and the void) are clipped into it. Planes must lie below the WRP (z_k < ``z_wrp_m``). ``frame_phases``:
    the renderer's frame-phase mode (:mod:`holocore.trace.frame_phases`): its bank and amplitude, and per plane
    its depth part where it has one (directional frames' Eq. B1), one phase per frame. ``eyebox_sine``: every
    colour's WRP field cut to the directions of sine <= this
    (:meth:`holocore.display.optics.OpticsConfig.eyebox_sine`; None: not).
    """
    import torch

    from holocore.optics.propagation import asm
    img = np.asarray(rgb, dtype=np.float64)
    depth = np.asarray(zc, dtype=np.float64)
    if img.ndim != 3 or img.shape[0] != 3 or depth.shape != img.shape[1:]:
        raise ValueError(f"rgb must be [3, H, W] and zc [H, W], got {img.shape} and {depth.shape}")
    if not np.all(np.isfinite(img)) or img.min() < 0:
        raise ValueError("rgb must be finite radiance >= 0")
    frames = validate.integer("frames", frames, 1, 4096)
    mode = get_frame_phases(frame_phases)
    f, zi, zw, p = (float(v) for v in (focal_length_m, z_inf_m, z_wrp_m, pitch_m))
    H, W = depth.shape
    hit = np.isfinite(depth) & (depth > 0)
    with np.errstate(divide="ignore"):
        z_holo = np.where(hit, zi + f * f / np.where(hit, depth, 1.0), np.nan)
    if not hit.any():
        z_holo[:] = zi  # nothing seen: everything at infinity
        hit[:] = True
    if z_range_m is not None:
        lo, hi = sorted(float(v) for v in z_range_m)
        z_holo = np.where(hit, np.clip(z_holo, lo, hi), z_holo)
    zs = plane_depths(z_holo[hit], planes)
    if zs.max() >= zw:
        raise ValueError(f"a layer at {zs.max() * 1e3:.4f} mm lies at or beyond the WRP ({zw * 1e3:.4f} mm)")
    z_all = np.where(hit, z_holo, zs.min())  # nothing hit: the farthest plane (smallest hologram z)
    k = np.abs(z_all[None] - zs[:, None, None]).argmin(axis=0)
    counts = np.bincount(k.ravel(), minlength=len(zs))
    C = len(wavelengths_m)
    wrp = torch.zeros((frames, C, H, W), dtype=torch.complex64)
    slm = torch.zeros_like(wrp)
    cone = [min(1.0, float(lam) / (2.0 * p)) for lam in wavelengths_m]  # s_c, the sine of theta_max
    for c, lam in enumerate(wavelengths_m):
        amp = torch.from_numpy((np.sqrt(img[channel_of(float(lam))]) * cone[c] / max(cone)).astype(np.float32))
        amp = amp * mode.gain(float(lam), pitch_m=p, wavelengths_m=wavelengths_m)
        ph = torch.from_numpy(np.stack(list(mode.lateral_phases(frames, (H, W), float(lam), pitch_m=p,
                                                                wavelengths_m=wavelengths_m, seed=int(seed)))))
        depth_terms = mode.depth_terms(frames=frames, first_frame=0, bank_frames=frames, wavelengths_m=[lam],
                                       all_wavelengths_m=wavelengths_m, pitch_m=p)
        base = torch.polar(amp.expand(frames, H, W).contiguous(), ph)  # [F, H, W]
        for i, z in enumerate(zs):
            if counts[i] == 0:
                continue
            mask = torch.from_numpy(k == i)
            plane = base * mask
            if depth_terms is not None:  # Eq. B1's depth part: exp(i k w_m (z - z_wrp)) for each frame m
                plane = plane * depth_terms.plane_factors(float(z) - zw)[0][:, None, None]
            wrp[:, c] += asm(plane, zw - float(z), float(lam), p)
        if eyebox_sine is not None:  # a common eyebox: every colour within one disc of directions
            wrp[:, c] = asm(wrp[:, c].contiguous(), 0.0, float(lam), p, cone_sine=eyebox_sine)
        slm[:, c] = asm(wrp[:, c].contiguous(), -zw, float(lam), p)
    return slm.numpy(), wrp.numpy(), zs, counts


def render_layers(loaded: Any, optics: OpticsConfig, *, planes: int = 8, spp: int = 64,
                  progress: Optional[Any] = None, display: Optional[Any] = None) -> Any:
    """The layer baseline for a loaded scene -> :class:`holocore.render_meta.RenderResult` (RESULT.npz format).

    ``planes`` (1..256) uniform in hologram depth, ``spp`` (1..65536) Mitsuba samples per RGB-D pixel; frames,
    colors, pitch, seed and the WRP come from ``optics`` and the renderer's own scene analysis; ``display`` (a
    :class:`holocore.display.profiles.DisplayProfile`) is recorded in the meta as the renderer does.
    """
    from holocore.render_setup import RenderOptions, plan_scene

    planes = validate.integer("planes", planes, 1, MAX_PLANES)
    spp = validate.integer("spp", spp, 1, MAX_SPP)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pl = plan_scene(loaded, optics, RenderOptions(preset="fast"))
    hmap, ana = pl.hmap, pl.analysis
    timings["analysis_s"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    rgb, zc = rgbd(loaded.scene, hmap, shape_hw=optics.resolution_hw, pitch_m=optics.pitch_m, spp=spp,
                   seed=optics.seed)
    timings["rgbd_s"] = time.perf_counter() - t1
    if progress:
        progress("rgbd", 1, 1)
    t2 = time.perf_counter()
    slm, wrp, zs, counts = layer_fields(rgb, zc, focal_length_m=pl.focal_length_m, z_inf_m=optics.z_inf_m,
                                        z_wrp_m=ana.z_wrp_m, pitch_m=optics.pitch_m,
                                        wavelengths_m=optics.wavelengths_m, frames=optics.frames, planes=planes,
                                        seed=optics.seed, frame_phases=optics.frame_phases,
                                        eyebox_sine=optics.eyebox_sine(),
                                        z_range_m=None if ana.z_far_holo_m is None else (ana.z_far_holo_m,
                                                                                          ana.z_near_holo_m))
    timings["propagate_s"] = time.perf_counter() - t2
    timings["total_s"] = time.perf_counter() - t0
    if progress:
        progress("propagate", 1, 1)
    summary = [f"layer baseline: {planes} planes uniform in dioptres, RGB-D at {spp} spp, {optics.frame_phases} "
               f"frame phases, ASM plane -> WRP -> SLM, no occlusion handling"]
    meta = result_meta(method="layers", preset=None, loaded=loaded, optics=optics, scene_plan=pl,
                       shape_fchw=slm.shape, timings=timings, display=display, summary=summary,
                       extra={"layers": {"planes": planes, "spp": spp, "plane_z_m": [float(z) for z in zs],
                                         "pixels_per_plane": [int(n) for n in counts]}})
    return RenderResult(slm_field=slm, wrp_field=wrp, meta=meta)


class LayersOptions(BaselineOptions):
    planes: int = Field(8, ge=1, le=256, description="depth layers, uniform in dioptres")
    spp: int = Field(64, ge=1, le=65536, description="Mitsuba samples per pixel of the RGB-D image")


@register_baseline
class LayersBaseline(Baseline):
    name = "layers"
    summary = "RGB-D layers: sqrt(image) per depth bin with random phase per frame, ASM to the WRP and the SLM"
    Options = LayersOptions

    def describe(self, meta):
        planes = meta["layers"]["plane_z_m"]
        used = sum(1 for n in meta["layers"]["pixels_per_plane"] if n)
        return (f"{super().describe(meta)}, {len(planes)} planes ({used} hold pixels) from "
                f"{planes[0] * 1e3:.4f} to {planes[-1] * 1e3:.4f} mm")

    def render(self, loaded, optics, options, *, display=None, progress=None):
        return render_layers(loaded, optics, planes=options.planes, spp=options.spp, progress=progress,
                             display=display)
