"""The light-field baseline the paper compares with (Sec. 5.2, "LF"): a holographic stereogram recorded on a
ray-sampling plane (Wakunami and Yamaguchi 2011) inside the image volume.

1. Hogels. The ray-sampling (RS) plane at hologram depth z_rs (default: the middle of the image volume, which is
   the middle in dioptres, since z - z_inf = f^2 / zc) is cut into hogels of B x B pixels. A hogel's field is
   a sum of B x B plane waves, one per frequency (f_x, f_y) of a B-point grid inside the colour's
   recording cone |f| <= 1 / 2p (the renderer's passband, so direction sines up to lambda / 2p, Eq. 4); the
   grid is (k - (B-1)/2) / B p, symmetric about the axis for any B.
2. Light field from Mitsuba. The plane wave of frequency f leaves the hogel towards the eye with direction sine
   s = lambda f, hologram tan t = s / sqrt(1 - |s|^2). Straight hologram rays stay straight in the world (the
   map T is projective, docs/design.md §3), and every ray of tan t crosses the eye's plane zc = 0 at
   (f t_x, f t_y): so the radiance of that wave is what a pinhole at (f t_x, f t_y, 0) sees through the hogel's
   world image at zc = f^2 / (z_rs - z_inf). Each ray is jittered over its hogel (box in position) and its
   frequency bin (box in direction) and traced with the scene's integrator (else ``path``, 12 bounces), ``spp``
   times.
3. Field (per colour c, frame m): hogel spectrum S(f) = B^2 sqrt(L_c(f) / n) exp(i phi_m(f)) a_c, n the number
   of frequencies in the cone, so that a uniform radiance L gives mean |U|^2 = L a_c^2 over the hogel
   (Parseval); its inverse DFT is the hogel's field. phi_m is the renderer's random-phase bank laid out on the
   hogel-major grid (coded frames by default: two plane waves of one hogel that one pupil receives cancel their
   cross term in the frame average). a_c = s_c / max s, s_c = lambda_c / 2p, as for the layers (an eye's pupil
   takes the share (NA / s_c)^2 of a colour's cone).
4. The RS field goes to the WRP and the SLM by band-limited ASM (z_wrp - z_rs and -z_rs), as the layers' fields
   do; the result has the renderer's RESULT.npz format, ``meta["method"] == "light-field"``.

What it cannot do, by construction: a point away from the RS plane is rebuilt from flat hogel-wide ray bundles,
so it blurs by its distance times the cone and never comes to a sharp focus (the missing accommodation cue the
paper shows); a point on the RS plane is resolved to one hogel (B p).
"""

from __future__ import annotations

import math
import time
from typing import Any, Literal, Optional, Sequence

import numpy as np

from pydantic import Field

from holocore import validate
from holocore.baselines.adam_budget import AdamFitOptions, torch_device
from holocore.baselines.light_field_fit import optimise_light_field
from holocore.baselines.registry import Baseline, register_baseline
from holocore.display.optics import channel_of
from holocore.display.optics import OpticsConfig
from holocore.render_meta import RenderResult, result_meta
from holocore.runtime.mitsuba_env import mitsuba
from holocore.runtime.recording import recording_kernels
from holocore.scene.features import has_media, reference_integrator
from holocore.trace.reference_chain import aligned

__all__ = ["DEFAULT_HOGEL_PX", "MAX_HOGEL_PX", "MAX_SPP", "rs_plane_depth", "hogel_rays", "trace_light_field",
           "hogel_amplitudes", "stereogram_fields", "stereogram_colours",
           "render_light_field", "LightFieldOptions", "LightFieldBaseline"]

MAX_HOGEL_PX = 256
MAX_SPP = 1 << 14
DEFAULT_MAX_DEPTH = 12
_PROPAGATE_PIXELS = 1 << 23  # pixels of the frames one ASM call takes (4 frames of 1080 x 1920)
# A 3-px hogel splits each colour's cone into 3 x 3 directions, about one to two across the eye's pupil of the
# evaluation (1.6 mm at f = 50 mm: 0.4-0.57 of the cone): fine enough in angle for parallax, the finest hogel in
# space. Measured on the paper's mirror scene (135 x 240 px, 24 frames, 9 cells): 2 / 3 / 4 / 8 / 16 px hogels
# score 16.4 / 18.9 / 17.7 / 16.5 / 13.2 dB.
DEFAULT_HOGEL_PX = 3


def rs_plane_depth(*, z_inf_m: float, z_wrp_m: float, z_far_m: Optional[float], z_near_m: Optional[float]) -> float:
    """Hologram depth (m) of the ray-sampling plane: the middle of the image volume [z_far, z_near], kept
    strictly between optical infinity and the WRP (a volume at infinity or unknown: 1/4 of the way to the WRP)."""
    zi = validate.positive("z_inf_m", z_inf_m)
    zw = validate.positive("z_wrp_m", z_wrp_m)
    if zw <= zi:
        raise ValueError(f"the WRP ({zw * 1e3:.4f} mm) must lie nearer than optical infinity ({zi * 1e3:.4f} mm)")
    lo_ok, hi_ok = zi + 1e-3 * (zw - zi), zw - 1e-3 * (zw - zi)
    if z_far_m is None or z_near_m is None:
        return zi + 0.25 * (zw - zi)
    z = 0.5 * (float(z_far_m) + float(z_near_m))
    return float(min(max(z, lo_ok if z > zi else zi + 0.25 * (zw - zi)), hi_ok))


def _bin_frequencies(B: int, p: float) -> np.ndarray:
    """The hogel's B frequencies (cycles/m), (k - (B-1)/2) / (B p): symmetric about 0 for any B (an even B has no
    zero bin and no Nyquist bin, so no direction is left out on one side), all below 1 / 2p."""
    return (np.arange(B) - 0.5 * (B - 1)) / (B * p)


def _cone_mask(B: int, p: float) -> np.ndarray:
    """[B, B] bool: the hogel's frequencies inside the cone |f| <= 1 / 2p (the renderer's passband)."""
    fk = _bin_frequencies(B, p)
    return (fk[:, None] ** 2 + fk[None, :] ** 2) <= (1.0 / (2.0 * p)) ** 2 * (1.0 + 1e-12)


def _hogel_grid(shape_hw: tuple[int, int], hogel_px: int) -> tuple[int, int, int]:
    H, W = (int(s) for s in shape_hw)
    B = validate.integer("hogel_px", hogel_px, 1, MAX_HOGEL_PX)
    return -(-H // B), -(-W // B), B


def hogel_rays(shape_hw: tuple[int, int], *, hogel_px: int, pitch_m: float, wavelength_m: float,
               focal_length_m: float, z_inf_m: float, z_rs_m: float, rng: Optional[np.random.Generator] = None,
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eye-camera rays of one colour's light field (step 2 of the module docstring), float64, on the hogel-major
    grid of Hh B x Wh B entries (Hh, Wh hogels; entry (a B + u, b B + v) is hogel (a, b), frequency (u, v)):
    (origins [N, 3] on the eye's plane zc = 0, unit directions [N, 3], in-cone mask [N]).
    ``rng``: jitter each ray over its hogel and frequency bin; None: the centres."""
    Hh, Wh, B = _hogel_grid(shape_hw, hogel_px)
    H, W = (int(s) for s in shape_hw)
    p = validate.positive("pitch_m", pitch_m)
    lam = validate.positive("wavelength_m", wavelength_m)
    f = validate.positive("focal_length_m", focal_length_m)
    zi = validate.positive("z_inf_m", z_inf_m)
    zr = validate.positive("z_rs_m", z_rs_m)
    if zr <= zi:
        raise ValueError(f"the ray-sampling plane ({zr * 1e3:.4f} mm) must lie nearer than optical infinity "
                         f"({zi * 1e3:.4f} mm)")
    rows = np.arange(Hh * B)
    cols = np.arange(Wh * B)
    a, u = rows // B, rows % B
    b, v = cols // B, cols % B
    # Hogel centres on the hologram grid (x right, y up; pixel (i, j) at ((j - (W-1)/2) p, ((H-1)/2 - i) p)).
    y0 = ((H - 1) / 2.0 - (a * B + (B - 1) / 2.0)) * p
    x0 = ((b * B + (B - 1) / 2.0) - (W - 1) / 2.0) * p
    # Frequencies (cycles/m): the symmetric grid (k - (B-1)/2) / B p, k = 0..B-1 (:func:`_bin_frequencies`); a row
    # index runs along -y, so f_y = -f_row.
    fy = -_bin_frequencies(B, p)[u]
    fx = _bin_frequencies(B, p)[v]
    Y0, X0 = np.meshgrid(y0, x0, indexing="ij")
    FY, FX = np.meshgrid(fy, fx, indexing="ij")
    inside = np.tile(_cone_mask(B, p), (Hh, Wh))
    if rng is not None:
        Y0 = Y0 + (rng.random(Y0.shape) - 0.5) * B * p
        X0 = X0 + (rng.random(X0.shape) - 0.5) * B * p
        FY = FY + (rng.random(FY.shape) - 0.5) / (B * p)
        FX = FX + (rng.random(FX.shape) - 0.5) / (B * p)
    sx, sy = lam * FX, lam * FY
    sz = np.sqrt(np.clip(1.0 - sx * sx - sy * sy, 1e-12, None))
    tx, ty = sx / sz, sy / sz
    zc = f * f / (zr - zi)  # the RS plane's world depth (T^-1, docs/design.md §3)
    origin = np.stack([f * tx, f * ty, np.zeros_like(tx)], axis=-1)
    target = np.stack([X0 * zc / f, Y0 * zc / f, np.full_like(X0, zc)], axis=-1)
    d = target - origin
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return origin.reshape(-1, 3), d.reshape(-1, 3), inside.reshape(-1)


@recording_kernels()
def trace_light_field(scene: Any, hmap: Any, shape_hw: tuple[int, int], *, hogel_px: int, pitch_m: float,
                      wavelengths_m: Sequence[float], z_rs_m: float, spp: int = 16, seed: int = 0,
                      integrator: Optional[Any] = None) -> np.ndarray:
    """Linear RGB radiance float32 [C, 3, Hh B, Wb B] of each colour's hogel rays (:func:`hogel_rays`), ``spp``
    jittered rays each, traced by Mitsuba with ``integrator`` (default the scene's, else ``path``)."""
    mi = mitsuba()
    import drjit as dr

    spp = validate.integer("spp", spp, 1, MAX_SPP)
    Hh, Wh, B = _hogel_grid(shape_hw, hogel_px)
    if integrator is None:
        integrator = (mi.load_dict(reference_integrator(scene, max_depth=DEFAULT_MAX_DEPTH)) if has_media(scene)
                      else scene.integrator() or mi.load_dict({"type": "path", "max_depth": DEFAULT_MAX_DEPTH}))
    out = np.zeros((len(wavelengths_m), 3, Hh * B, Wh * B), dtype=np.float64)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x1F7D]))
    sampler = mi.load_dict({"type": "independent"})
    for c, lam in enumerate(wavelengths_m):
        acc = None
        for s in range(spp):
            o, d, _ = hogel_rays(shape_hw, hogel_px=B, pitch_m=pitch_m, wavelength_m=float(lam),
                                      focal_length_m=hmap.focal_length_m, z_inf_m=hmap.z_inf_m, z_rs_m=z_rs_m,
                                      rng=rng)
            ow, dw = hmap.camera_to_world(o), hmap.camera_dir_to_world(d)
            ray = mi.Ray3f(mi.Point3f(*[mi.Float(aligned(ow[:, i])) for i in range(3)]),
                           mi.Vector3f(*[mi.Float(aligned(dw[:, i])) for i in range(3)]))
            sampler.seed(int(seed) * 7919 + c * spp + s, len(o))
            spec, valid, _ = integrator.sample(scene, sampler, mi.RayDifferential3f(ray), None, True)
            L = dr.select(valid, spec, 0.0)
            dr.eval(L)
            rgb = np.stack([np.asarray(L[i], dtype=np.float64) for i in range(3)], axis=0)
            rgb = np.where(np.isfinite(rgb), rgb, 0.0).clip(min=0.0)  # outside the cone: hogel_amplitudes
            acc = rgb if acc is None else acc + rgb
        out[c] = (acc / spp).reshape(3, Hh * B, Wh * B)
    return out.astype(np.float32)


def stereogram_fields(radiance: np.ndarray, *, shape_hw: tuple[int, int], hogel_px: int, pitch_m: float,
                      wavelengths_m: Sequence[float], frames: int, seed: int = 0, coded: bool = True):
    """The RS-plane field complex64 torch [F, C, H, W] of :func:`trace_light_field`'s radiance (step 3 of the
    module docstring); each colour reads the RGB channel that holds its laser line."""
    import torch

    out = None
    for c, field in enumerate(stereogram_colours(radiance, shape_hw=shape_hw, hogel_px=hogel_px, pitch_m=pitch_m,
                                                 wavelengths_m=wavelengths_m, frames=frames, seed=seed, coded=coded)):
        if out is None:
            out = torch.zeros((field.shape[0], len(wavelengths_m)) + tuple(field.shape[1:]), dtype=torch.complex64)
        out[:, c] = field
    return out


def hogel_amplitudes(radiance: np.ndarray, *, shape_hw: tuple[int, int], hogel_px: int, pitch_m: float,
                     wavelengths_m: Sequence[float]) -> np.ndarray:
    """Each plane wave's amplitude, float32 [C, Hh B, Wh B] on the hogel-major grid: B^2 sqrt(L_c / n) a_c inside the
    cone, 0 outside (step 3 of the module docstring); L_c the RGB channel that holds the colour's laser line."""
    Hh, Wh, B = _hogel_grid(shape_hw, hogel_px)
    rad = np.asarray(radiance)
    if rad.shape != (len(wavelengths_m), 3, Hh * B, Wh * B):
        raise ValueError(f"radiance must be [C, 3, {Hh * B}, {Wh * B}], got {rad.shape}")
    p = validate.positive("pitch_m", pitch_m)
    inside = _cone_mask(B, p)  # the same bins as hogel_rays
    n_in = max(1, int(inside.sum()))
    cone = [min(1.0, float(lam) / (2.0 * p)) for lam in wavelengths_m]
    out = np.empty((len(wavelengths_m), Hh * B, Wh * B), dtype=np.float32)
    for c, lam in enumerate(wavelengths_m):
        amp = np.sqrt(rad[c, channel_of(float(lam))].astype(np.float64) / n_in) * (B * B) * cone[c] / max(cone)
        out[c] = amp * np.tile(inside, (Hh, Wh))  # directions outside the cone carry nothing
    return out


def stereogram_colours(radiance: np.ndarray, *, shape_hw: tuple[int, int], hogel_px: int, pitch_m: float,
                       wavelengths_m: Sequence[float], frames: int, seed: int = 0, coded: bool = True):
    """:func:`stereogram_fields` one colour at a time: yields complex64 torch [F, H, W] per wavelength, so that a
    caller holds one colour's frames, not all of them."""
    import torch

    from holocore.trace.randomfield import phase_frames

    Hh, Wh, B = _hogel_grid(shape_hw, hogel_px)
    H, W = (int(s) for s in shape_hw)
    amps = hogel_amplitudes(radiance, shape_hw=shape_hw, hogel_px=hogel_px, pitch_m=pitch_m,
                            wavelengths_m=wavelengths_m)
    frames = validate.integer("frames", frames, 1, 4096)
    p = validate.positive("pitch_m", pitch_m)
    # sum_k S_k exp(2 pi i (k - (B-1)/2) r / B) = B ifft(S)[r] exp(-i pi (B-1) r / B): the DFT and a ramp
    ramp = torch.polar(torch.ones(B), torch.from_numpy(-math.pi * (B - 1) / B * np.arange(B)).float())
    ramp2 = (ramp[:, None] * ramp[None, :]).to(torch.complex64)
    for c, lam in enumerate(wavelengths_m):
        amp = amps[c]
        field = torch.empty((frames, Hh * B, Wh * B), dtype=torch.complex64)
        for m, ph in enumerate(phase_frames(frames, (Hh * B, Wh * B), float(lam), p, seed=int(seed),
                                            coded_frames=frames if coded else None)):
            spec = torch.polar(torch.from_numpy(amp), torch.from_numpy(ph))
            # [Hh B, Wh B] -> [Hh, Wh, B, B] spectra -> hogel fields by the inverse DFT and the ramp
            spec = spec.reshape(Hh, B, Wh, B).permute(0, 2, 1, 3)
            hog = torch.fft.ifft2(spec) * ramp2  # batched, B x B: not the 2048^2 case
            field[m] = hog.permute(0, 2, 1, 3).reshape(Hh * B, Wh * B)
        yield field[:, :H, :W]


def _rs_depth(z_rs_m: Optional[float], optics: OpticsConfig, ana: Any) -> float:
    """The RS plane's hologram depth (m): :func:`rs_plane_depth` of the image volume when ``z_rs_m`` is None, else
    ``z_rs_m`` checked to lie between optical infinity and the WRP."""
    zw = ana.z_wrp_m
    if z_rs_m is None:
        return rs_plane_depth(z_inf_m=optics.z_inf_m, z_wrp_m=zw, z_far_m=ana.z_far_holo_m,
                              z_near_m=ana.z_near_holo_m)
    z_rs_m = validate.positive("z_rs_m", z_rs_m)
    if not optics.z_inf_m < z_rs_m < zw:
        raise ValueError(f"z_rs_m = {z_rs_m * 1e3:.4f} mm must lie between optical infinity "
           f"({optics.z_inf_m * 1e3:.4f} mm) and the WRP ({zw * 1e3:.4f} mm)")
    return z_rs_m


def _fields(rad: Optional[np.ndarray], res: Any, *, shape_hw: tuple[int, int], hogel_px: int, z_rs_m: float,
            z_wrp_m: float, lams: list[float], optics: OpticsConfig) -> tuple[np.ndarray, np.ndarray]:
    """(SLM field, WRP field), complex64 [F, C, H, W]: with a fit ``res``, its frames sqrt(P_c) exp(i phi)
    propagated to the WRP; else the stereogram of the light field ``rad`` on the RS plane propagated to the WRP
    and back to the SLM."""
    import torch

    from holocore.optics.propagation import asm

    H, W = shape_hw
    F = optics.frames
    wrp = np.empty((F, len(lams), H, W), dtype=np.complex64)
    slm = np.empty_like(wrp)
    step = max(1, min(F, _PROPAGATE_PIXELS // (H * W)))  # frames per ASM call: its padded workspace stays small
    if res is not None:
        power = res.illumination
        for c, lam in enumerate(lams):
            for a in range(0, F, step):
                u = torch.polar(torch.full(res.phase[a:a + step, c].shape, math.sqrt(power[c])),
                                torch.from_numpy(res.phase[a:a + step, c]))
                slm[a:a + step, c] = u.numpy()
                wrp[a:a + step, c] = asm(u, z_wrp_m, lam, optics.pitch_m).numpy()
        return slm, wrp
    # a stereogram's phases are per plane wave, not per image point: the mode says coded or independent
    for c, rs in enumerate(stereogram_colours(rad, shape_hw=(H, W), hogel_px=hogel_px, pitch_m=optics.pitch_m,
                                              wavelengths_m=lams, frames=F, seed=optics.seed,
                                              coded=optics.frame_phase_mode().stereogram_coded)):
        for a in range(0, F, step):
            chunk = rs[a:a + step].contiguous()
            wrp[a:a + step, c] = asm(chunk, z_wrp_m - z_rs_m, lams[c], optics.pitch_m).numpy()
            slm[a:a + step, c] = asm(chunk, -z_rs_m, lams[c], optics.pitch_m).numpy()
        del rs
    return slm, wrp


def render_light_field(loaded: Any, optics: OpticsConfig, *, hogel_px: int = DEFAULT_HOGEL_PX, spp: int = 16,
                       z_rs_m: Optional[float] = None, fit: str = "stereogram", iterations: int = 200,
                       lr: float = 0.05, time_limit_s: Optional[float] = None, device: str = "cpu",
                       progress: Optional[Any] = None, display: Optional[Any] = None) -> Any:
    """The light-field baseline for a loaded scene -> :class:`holocore.render_meta.RenderResult`.

    ``hogel_px`` (1..256) pixels per hogel side, ``spp`` (1..16384) jittered rays per light-field sample,
    ``z_rs_m`` the RS plane's hologram depth (m; default :func:`rs_plane_depth`); frames, colours, pitch, seed
    and the WRP come from ``optics`` and the renderer's own scene analysis. ``fit``: "stereogram" (a complex
    field, for the phase encoder) or "sgd" (phase-only frames fitted to the light field by
    :func:`holocore.baselines.light_field_fit.optimise_light_field`: ``iterations`` Adam steps at ``lr`` on
    ``device``, stopped early to keep the whole baseline within ``time_limit_s``; the SLM field is then
    sqrt(P_c) exp(i phi), P_c the colour's laser power).
    """
    from holocore.render_setup import RenderOptions, plan_scene

    hogel_px = validate.integer("hogel_px", hogel_px, 1, MAX_HOGEL_PX)
    spp = validate.integer("spp", spp, 1, MAX_SPP)
    if fit not in ("stereogram", "sgd"):
        raise ValueError(f"fit must be 'stereogram' or 'sgd', got {fit!r}")
    H, W = optics.resolution_hw
    if hogel_px > min(H, W):
        raise ValueError(f"hogel_px = {hogel_px} is larger than the SLM ({H}x{W} px)")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pl = plan_scene(loaded, optics, RenderOptions(preset="fast"))
    hmap, ana = pl.hmap, pl.analysis
    zw = ana.z_wrp_m
    z_rs_m = _rs_depth(z_rs_m, optics, ana)
    timings["analysis_s"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    lams = list(optics.wavelengths_m)
    rad = trace_light_field(loaded.scene, hmap, (H, W), hogel_px=hogel_px, pitch_m=optics.pitch_m,
                            wavelengths_m=lams, z_rs_m=z_rs_m, spp=spp, seed=optics.seed)
    timings["light_field_s"] = time.perf_counter() - t1
    if progress:
        progress("light field", 1, 1)
    t2 = time.perf_counter()
    geometry = dict(shape_hw=(H, W), hogel_px=hogel_px, z_rs_m=z_rs_m, lams=lams, optics=optics)
    fit_meta: dict[str, Any] = {"fit": fit}
    if fit == "sgd":
        target = hogel_amplitudes(rad, shape_hw=(H, W), hogel_px=hogel_px, pitch_m=optics.pitch_m,
                                  wavelengths_m=lams).astype(np.float64) ** 2
        del rad
        left = None if time_limit_s is None else max(1e-3, time_limit_s - (time.perf_counter() - t0))
        res = optimise_light_field(target, shape_hw=(H, W), hogel_px=hogel_px, z_rs_m=z_rs_m, wavelengths_m=lams,
                                   pitch_m=optics.pitch_m, frames=optics.frames, iterations=iterations, lr=lr,
                                   seed=optics.seed, device=device, time_limit_s=left)
        slm, wrp = _fields(None, res, z_wrp_m=zw, **geometry)
        fit_meta.update(iterations_done=list(res.iterations), loss_first=res.loss[0], loss_final=res.loss[-1],
                        illumination=[float(v) for v in res.illumination])
        timings["fit_s"] = res.seconds
    else:
        slm, wrp = _fields(rad, None, z_wrp_m=zw, **geometry)
        del rad
    timings["propagate_s"] = time.perf_counter() - t2
    timings["total_s"] = time.perf_counter() - t0
    if progress:
        progress("propagate", 1, 1)
    F, C = slm.shape[:2]
    summary = [f"light-field baseline: {hogel_px}x{hogel_px}-px hogels on a ray-sampling plane at "
               f"{z_rs_m * 1e3:.4f} mm, {spp} rays per sample, "
               + ("stereogram with random phase per frame, ASM RS plane -> WRP / SLM"
                  if fit == "stereogram" else "phase-only frames fitted by SGD to the light field")]
    meta = result_meta(method="light-field", preset=None, loaded=loaded, optics=optics, scene_plan=pl,
                       shape_fchw=(F, C, H, W), timings=timings, display=display, summary=summary,
                       extra={"light_field": {"hogel_px": hogel_px, "spp": spp, "z_rs_m": float(z_rs_m),
                           "hogels_hw": [-(-H // hogel_px), -(-W // hogel_px)],
                           "hogel_size_um": hogel_px * optics.pitch_m * 1e6, **fit_meta}})
    if not math.isfinite(float(np.abs(slm).max(initial=0.0))):
        raise ValueError("the light field holds non-finite radiance")
    return RenderResult(slm_field=slm, wrp_field=wrp, meta=meta)


class LightFieldOptions(AdamFitOptions):
    hogel_px: int = Field(DEFAULT_HOGEL_PX, ge=1, le=256, description="hogel side in SLM pixels")
    spp: int = Field(16, ge=1, le=16384, description="jittered Mitsuba rays per light-field sample")
    rs_mm: Optional[float] = Field(None, gt=0, lt=1e6, description="hologram depth of the ray-sampling plane (mm)")
    fit: Literal["stereogram", "sgd"] = Field("stereogram", description="stereogram: a complex field for the "
                                              "encoder; sgd: phase-only frames fitted to the light field")


@register_baseline
class LightFieldBaseline(Baseline):
    name = "light-field"
    summary = ("light field: a holographic stereogram on a ray-sampling plane (or phase-only frames fitted to it), "
               "ASM to the WRP and the SLM")
    Options = LightFieldOptions

    def describe(self, meta):
        lf = meta["light_field"]
        steps = f", {'/'.join(map(str, lf['iterations_done']))} Adam steps" if lf.get("iterations_done") else ""
        return (f"{super().describe(meta)}, {lf['hogels_hw'][0]}x{lf['hogels_hw'][1]} hogels of {lf['hogel_px']} px "
                f"at {lf['z_rs_m'] * 1e3:.4f} mm, {lf['spp']} rays per sample{steps}")

    def render(self, loaded, optics, options, *, display=None, progress=None):
        return render_light_field(loaded, optics, hogel_px=options.hogel_px, spp=options.spp,
                                  z_rs_m=None if options.rs_mm is None else options.rs_mm * 1e-3, fit=options.fit,
                                  iterations=options.iterations, lr=options.lr, time_limit_s=options.time_limit_s,
                                  device=torch_device(options.device), progress=progress, display=display)
