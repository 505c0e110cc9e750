"""Wave-optical ground truth: what an ideal hologram of the scene would show an eye (docs/evaluation.md).

The thin-lens ground truth (:mod:`holocore.evaluate.groundtruth`) is geometric: its pupil blurs a defocused
point into a disc, and the disc convolved with the in-focus Airy pattern stands in for diffraction. Near focus,
at the Fresnel numbers of a near-eye display (1-2 within a dioptre), that over-blurs: the defocused pupil
function's PSF is narrower than disc * Airy. And a pupil wider than the display's eyebox gathers light the
display can never send. Both penalise a hologram that is right.

Here the scene is imaged as an ideal diffuse hologram would image it, through the same optics the simulated eye
uses (:func:`holocore.evaluate.scoring.eye_view`):

1. **Depth layers** (:func:`depth_layers`, Mitsuba). From the centre of the eye a pinhole sees the scene on the
   hologram's pixel grid (x = f tan, docs/design.md §3: hologram space seen orthographically). Each sample follows its
   chain of delta surfaces (mirrors, smooth glass), sampling each surface's lobe, to the first surface that
   scatters (or to the sky); its *image distance* is the unfolded path length, each segment inside a medium of
   index n counted as d / n (the paraxial apparent depth); the radiance it brings is the reference path tracer's
   along that last segment. The sample's hologram depth z = z_inf + f^2 / zc (zc: the image distance along the
   camera axis; the sky at z_inf) splits its radiance between the two nearest of K layers uniform in z (uniform
   in dioptres), linearly. So a mirror's image lies at the mirror image's depth and glass shows both its images,
   each at its own depth.
2. **Incoherent imaging per layer** (:func:`wave_view`). A rough surface's field has random phase, so the eye
   adds intensities: layer k contributes L_k (*) |IFFT(M H(z_f - z_k))|^2, with M the plane waves the eye
   accepts (its pupil disc at sine e / f; the SLM's own band, |sine| <= lambda / 2p on each axis, which the
   pixel grid itself imposes; and the recording cone where the display has a Fourier filter) and H the band-
   limited angular-spectrum transfer function, on the same padded grid, with the same off-axis shift as
   ``eye_view``. That is exactly the frame average of an ideal random-phase field of each layer viewed by
   ``eye_view``: the hologram is charged for what it gets wrong, not for the eye's or the display's own limits.

What it leaves out: occlusion edges between layers (a layer is blurred as if the ones in front were not
there) and the parallax of disocclusion (one render, from the centre of the eye, serves every eye position;
the depth-dependent shift of each layer for an off-centre eye is exact). For the pupils of 2-6 mm and the
scene distances of a near-eye display both are a fraction of a pixel.

:class:`WaveGroundTruth` renders the layers once and answers ``channels(focus_z_m=, pupil_diameter_m=,
view_offset_m=)`` as :class:`holocore.evaluate.groundtruth.GroundTruth` does.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np
import torch

from holocore import validate
from holocore.evaluate.groundtruth import MAX_GT_SPP, channels_for_wavelengths
from holocore.evaluate.scoring import view_shift_px
from holocore.formats.meta import MetaLike, parse_view_meta
from holocore.optics.propagation import ifft2, padded_shape, transfer_function
from holocore.optics.viewing import eye_mask
from holocore.runtime.mitsuba_env import mitsuba
from holocore.runtime.recording import recording_kernels
from holocore.scene.features import reference_integrator

__all__ = ["DepthLayers", "depth_layers", "layer_spacing_m", "wave_view", "band_share", "WaveGroundTruth",
           "MAX_LAYERS"]

MAX_LAYERS = 64
MAX_DELTA_BOUNCES = 8  # mirrors and smooth glass followed before the chain counts as lost
_PASS_SAMPLES = 1 << 19  # samples traced at once: Dr.Jit holds some 400 bytes of chain and path state for each


@dataclass(frozen=True)
class DepthLayers:
    """Linear RGB radiance ``rgb`` float32 [K, 3, H, W] split over K hologram depths ``z_m`` [K] (m, increasing:
    far to near), from one pinhole render at the eye's centre; ``lost`` the share of samples whose chain of
    delta surfaces ran past :data:`MAX_DELTA_BOUNCES` (their radiance is missing)."""

    rgb: np.ndarray
    z_m: np.ndarray
    lost: float
    spp: int


def layer_spacing_m(*, pitch_m: float, wavelength_m: float) -> float:
    """Depth step (m) between layers: 2 p^2 / lambda, over which defocus at the SLM band's edge (sine
    lambda / 2p) grows by a quarter wave; between two layers a point is split linearly, so a step this size
    shifts no PSF by more than a small fraction of that."""
    p = validate.positive("pitch_m", pitch_m)
    lam = validate.positive("wavelength_m", wavelength_m)
    return 2.0 * p * p / lam


@recording_kernels()
def depth_layers(scene: Any, *, sensor_to_world: np.ndarray, focal_length_m: float, z_inf_m: float,
                 pitch_m: float, shape_hw: tuple[int, int], spacing_m: float, z_max_m: Optional[float] = None,
                 spp: int = 64, seed: int = 0, max_depth: int = 12, scene_scale: float = 1.0) -> DepthLayers:
    """The scene's radiance split over depth layers (module docstring, step 1). Layers start at z_inf and are
    ``spacing_m`` apart up to the nearest image found (or ``z_max_m``; at most :data:`MAX_LAYERS`, the spacing
    widened to fit). ``scene_scale``: the render's (docs/design.md §3): world lengths times it for the eye."""
    import drjit as dr

    mi = mitsuba()
    H, W = (int(s) for s in shape_hw)
    if not (1 <= H <= 16384 and 1 <= W <= 16384):
        raise ValueError(f"shape_hw must be two sizes in 1..16384 px, got {shape_hw!r}")
    p = validate.positive("pitch_m", pitch_m)
    f = validate.positive("focal_length_m", focal_length_m)
    zi = validate.positive("z_inf_m", z_inf_m)
    scale = validate.positive("scene_scale", scene_scale)
    dz = validate.positive("spacing_m", spacing_m)
    spp = validate.integer("spp", spp, 1, MAX_GT_SPP)
    sensor = mi.load_dict({
        "type": "perspective", "fov": 2.0 * math.degrees(math.atan(W * p / (2.0 * f))), "fov_axis": "x",
        "near_clip": 1e-3, "to_world": mi.ScalarTransform4f(np.asarray(sensor_to_world, dtype=np.float64).tolist()),
        "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}},
    })
    integrator = mi.load_dict(reference_integrator(scene, max_depth=int(max_depth)))
    per_pass = max(1, min(spp, _PASS_SAMPLES // (H * W)))
    out: Optional[np.ndarray] = None  # [K, 3, H * W] sums, once the first pass has set the layers
    z_layers = np.zeros(0)
    lost = 0
    for first in range(0, spp, per_pass):
        n = min(per_pass, spp - first)
        z, rgb, pix, n_lost = _trace_pass(mi, dr, scene, sensor, integrator, H=H, W=W, n=n, p=p, f=f, zi=zi,
                                          seed=int(seed) * 7919 + first, scale=scale)
        lost += n_lost
        if out is None:  # the layers span z_inf to the nearest image the first pass saw (later ones clamp, and
            # so does the nearest 0.05 % of its samples: a grazing pencil's stray depth must not stretch the layers)
            near = float(np.quantile(z, 0.9995)) if z.size else zi
            if z_max_m is not None:
                near = min(near, float(z_max_m))
            k = int(math.floor((near - zi) / dz + 1e-9)) + 2
            if k > MAX_LAYERS:
                k = MAX_LAYERS
                dz = (near - zi) / (k - 1)
            z_layers = zi + dz * np.arange(k)
            out = np.zeros((k, 3, H * W), dtype=np.float32)
        k = len(z_layers)
        b = np.clip((z - zi) / dz, 0.0, k - 1.0)
        b0 = np.minimum(np.floor(b).astype(np.int64), max(k - 2, 0))
        w1 = b - b0 if k > 1 else np.zeros_like(b)
        lo, hi = b0 * (H * W) + pix, np.minimum(b0 + 1, k - 1) * (H * W) + pix
        for ch in range(3):
            acc = np.bincount(lo, weights=rgb[ch] * (1.0 - w1), minlength=k * H * W)
            acc += np.bincount(hi, weights=rgb[ch] * w1, minlength=k * H * W)
            out[:, ch] += acc.reshape(k, H * W).astype(np.float32)
            del acc
    assert out is not None
    out /= spp
    return DepthLayers(rgb=out.reshape(len(z_layers), 3, H, W), z_m=z_layers, lost=lost / (spp * H * W), spp=spp)


_STEP = 1e-4  # finite-difference step of the pencil: a direction step in rad, an origin step of that times t


def _chain(mi, dr, scene, ray, active, key):
    """Follow ``ray`` through delta surfaces (module docstring); the lobe of bounce b is chosen by a hash of
    (``key``, b), so neighbouring rays of one sample take the same lobes. Returns the last ray, where it ends
    (the scattering point, or far along the ray for the sky), the shape it ends on, its bounce count, whether it
    ended (not lost), whether it saw the sky, the chain's weight and the unfolded length (each segment over its
    medium's index)."""
    apparent, index = mi.Float(0.0), mi.Float(1.0)
    throughput = mi.Spectrum(1.0)
    chasing, ended, sky = mi.Bool(active), mi.Bool(False), mi.Bool(False)
    bounces = mi.UInt32(0)
    end = mi.Point3f(ray.o + ray.d)
    shape = dr.zeros(mi.ShapePtr, dr.width(key))
    ctx = mi.BSDFContext()
    for b in range(MAX_DELTA_BOUNCES + 1):
        si = scene.ray_intersect(ray, chasing)
        hit = chasing & si.is_valid()
        missed = chasing & ~si.is_valid()
        bsdf = si.bsdf(ray)
        flags = bsdf.flags()
        # mirrors, smooth glass and pass-through (null) surfaces; a surface with any rough lobe scatters
        delta = (mi.has_flag(flags, mi.BSDFFlags.Delta) | mi.has_flag(flags, mi.BSDFFlags.Null)) & \
            ~mi.has_flag(flags, mi.BSDFFlags.Smooth)
        follow = hit & delta
        stop = hit & ~delta
        apparent = dr.select(hit, apparent + si.t / index, apparent)
        end = dr.select(stop, si.p, dr.select(missed, ray.o + ray.d * 1e6, end))
        shape = dr.select(stop, si.shape, shape)
        sky |= missed
        ended |= missed | stop
        u1 = mi.sample_tea_float32(key, mi.UInt32(3 * b))
        u2 = mi.Point2f(mi.sample_tea_float32(key, mi.UInt32(3 * b + 1)),
                        mi.sample_tea_float32(key, mi.UInt32(3 * b + 2)))
        bs, weight = bsdf.sample(ctx, si, u1, u2, follow)
        follow &= dr.any(mi.unpolarized_spectrum(weight) > 0.0)
        throughput = dr.select(follow, throughput * weight, throughput)
        index = dr.select(follow, index * bs.eta, index)
        ray = dr.select(follow, si.spawn_ray(si.to_world(bs.wo)), ray)
        bounces = dr.select(follow, bounces + 1, bounces)
        chasing = follow
        if not dr.any(chasing):
            break
    return ray, end, shape, bounces, ended, sky, throughput, apparent


def _trace_pass(mi, dr, scene, sensor, integrator, *, H: int, W: int, n: int, p: float, f: float, zi: float,
                seed: int, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """One pass of ``n`` samples per pixel: (hologram depth [S], linear RGB [3, S], pixel index [S], lost).

    A sample's image distance s along its first ray is where the pencil of rays that ends on its scattering
    point seems to come from: with J_o and J_d the changes of the end point (across the last ray) per step of
    the first ray's origin and of its direction, rays from o + delta a aimed at o + s d (direction step
    -delta / s) end on the same point when J_o = J_d / s, so 1 / s is the mean of the eigenvalues of
    J_d^-1 J_o (the circle of least confusion where the chain is astigmatic). Where the pencil's rays end on
    another shape, take other lobes, or give no finite s, the unfolded length stands in."""
    count = H * W * n
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, count)
    # sizes and seeds enter the kernels as opaque values: a literal would compile the kernels again (seconds
    # each) for every size, sample count and seed
    n_o, w_o = dr.opaque(mi.UInt32, n), dr.opaque(mi.UInt32, W)
    wf, hf, pf = dr.opaque(mi.Float, W), dr.opaque(mi.Float, H), dr.opaque(mi.Float, p / f)
    idx = dr.arange(mi.UInt32, count)
    key = idx + dr.opaque(mi.UInt32, (seed * 2654435761) & 0xFFFFFFFF)
    pix = idx // n_o
    u = mi.Float(pix % w_o) + sampler.next_1d()
    v = mi.Float(pix // w_o) + sampler.next_1d()
    ray, _ = sensor.sample_ray(0.0, sampler.next_1d(), mi.Point2f(u / wf, v / hf), mi.Point2f(0.5, 0.5))
    ray = mi.Ray3f(ray)
    # the eye-camera depth of a point at distance s along this ray: s / sqrt(1 + tan_x^2 + tan_y^2)
    tan_x, tan_y = (u - 0.5 * wf) * pf, (v - 0.5 * hf) * pf
    to_axis = dr.rsqrt(1.0 + tan_x * tan_x + tan_y * tan_y)
    last, end, shape, bounces, ended, sky, throughput, apparent = _chain(mi, dr, scene, ray, mi.Bool(True), key)
    lost = int(np.count_nonzero(np.array(~ended)))
    li, _, _ = integrator.sample(scene, sampler, mi.RayDifferential3f(last), None, ended)
    rgb = dr.select(ended, throughput * li, 0.0)

    # the pencil, for the samples that met a delta surface (the others' image is the point they hit, at the
    # distance they travelled), gathered together so that the four extra chains trace only those: two origin
    # steps and two direction steps across the first ray
    bent = ended & ~sky & (bounces > 0)
    zc = apparent * to_axis
    far = mi.Bool(sky)
    sel = dr.compress(bent)
    if dr.width(sel) > 0:
        g = lambda v: dr.gather(type(v), v, sel)  # noqa: E731
        ray_s = mi.Ray3f(g(ray.o), g(ray.d))
        last_d, end_s, shape_s, bounces_s, key_s = g(last.d), g(end), g(shape), g(bounces), g(key)
        e1, e2 = mi.coordinate_system(ray_s.d)
        q1, q2 = mi.coordinate_system(last_d)  # across the last ray
        probe = dr.full(mi.Bool, True, dr.width(sel))
        first_t = dr.maximum(scene.ray_intersect(ray_s, probe).t, 1e-6)
        delta = _STEP * dr.select(dr.isfinite(first_t), first_t, 1.0)
        cols = []
        for shift in (e1, e2):
            moved = mi.Ray3f(ray_s.o + shift * delta, ray_s.d)
            turned = mi.Ray3f(ray_s.o, dr.normalize(ray_s.d + shift * _STEP))
            for r, step in ((moved, delta), (turned, mi.Float(_STEP))):
                _, end_k, shape_k, bounces_k, ended_k, sky_k, _, _ = _chain(mi, dr, scene, r, probe, key_s)
                probe &= ended_k & ~sky_k & (shape_k == shape_s) & (bounces_k == bounces_s)
                dv = (end_k - end_s) / step
                cols.append((dr.dot(dv, q1), dr.dot(dv, q2)))
        (o1x, o1y), (d1x, d1y), (o2x, o2y), (d2x, d2y) = cols
        # J_o = [[o1x, o2x], [o1y, o2y]], J_d likewise; trace(J_d^-1 J_o) / 2
        det = d1x * d2y - d2x * d1y
        vergence = 0.5 * (d2y * o1x - d2x * o1y - d1y * o2x + d1x * o2y) / det
        pencil = probe & dr.isfinite(vergence)
        zc_s = dr.select(pencil, g(to_axis) / dr.maximum(vergence, 1e-30), g(zc))
        # a pencil converging at the eye (vergence <= 0) images beyond optical infinity: as near it as can be
        far_s = pencil & (vergence <= 0.0)
        dr.scatter(zc, zc_s, sel)
        dr.scatter(far, far_s, sel)
    zi_o, f2 = dr.opaque(mi.Float, zi), dr.opaque(mi.Float, f * f / scale)  # zc is in world lengths here
    z = dr.select(far | (zc <= 0.0), zi_o, zi_o + f2 / dr.maximum(zc, 1e-30))
    dr.eval(rgb, z)
    rgb_np = np.array(rgb, dtype=np.float64)  # Dr.Jit gives the colour axis first: [3, S]
    rgb_np = np.nan_to_num(rgb_np if rgb_np.shape[0] == 3 else rgb_np.T, nan=0.0, posinf=0.0, neginf=0.0)
    z_np = np.nan_to_num(np.array(z, dtype=np.float64), nan=zi, posinf=zi, neginf=zi)
    return np.maximum(z_np, zi), rgb_np.clip(min=0.0), np.array(pix, dtype=np.int64), lost


def band_share(*, wavelength_m: float, pitch_m: float, focal_length_m: float, pupil_diameter_m: float,
               view_offset_m: tuple[float, float] = (0.0, 0.0), fourier_filter: bool = False,
               samples: int = 512) -> float:
    """Share of the pupil's area that the display can fill: inside the SLM's band (the square of half-side
    lambda f / 2p about the axis, in the pupil's plane) and, with a Fourier filter, the recording cone. The rest
    of a wider pupil is an etendue deficit of the display, reported beside a score, not charged in it."""
    lam = validate.positive("wavelength_m", wavelength_m)
    p = validate.positive("pitch_m", pitch_m)
    f = validate.positive("focal_length_m", focal_length_m)
    d = validate.positive("pupil_diameter_m", pupil_diameter_m)
    ex, ey = (float(v) for v in view_offset_m)
    t = (np.arange(samples) + 0.5) / samples * d - d / 2.0
    x, y = np.meshgrid(ex + t, ey + t)
    inside = (x - ex) ** 2 + (y - ey) ** 2 <= (d / 2.0) ** 2
    half = lam * f / (2.0 * p)
    ok = inside & (np.abs(x) <= half) & (np.abs(y) <= half)
    if fourier_filter:
        ok &= x * x + y * y <= half * half
    return float(ok.sum() / max(1, inside.sum()))


def wave_view(layers: np.ndarray, z_m: Sequence[float], *, wavelengths_m: Sequence[float], pitch_m: float,
              focal_length_m: float, z_inf_m: float, focus_z_m: float, pupil_diameter_m: float,
              view_offset_m: tuple[float, float] = (0.0, 0.0), fourier_filter: bool = False,
              pad_factor: float = 2) -> np.ndarray:
    """What an eye sees of intensity layers ``layers`` [K, C, H, W] at hologram depths ``z_m`` [K], imaged
    incoherently (module docstring, step 2): float64 [C, H, W] on ``eye_view``'s grid, in the layers' radiance
    (each PSF sums to 1): the brightness an ideal display gives every pupil, as the scores take a ground truth
    (``eye_view`` of an ideal full-band random-phase field is this times the share of the band the pupil takes,
    which the viewer score divides out)."""
    a = np.asarray(layers, dtype=np.float32)
    zs = [validate.real("z_m", z) for z in z_m]
    lams = [validate.positive("wavelengths_m", v) for v in wavelengths_m]
    if a.ndim != 4 or a.shape[0] != len(zs) or a.shape[1] != len(lams):
        raise ValueError(f"layers must be [K, C, H, W] with K = {len(zs)} depths and C = {len(lams)} colours, "
                         f"got {a.shape}")
    p = validate.positive("pitch_m", pitch_m)
    f = validate.positive("focal_length_m", focal_length_m)
    z_f = validate.real("focus_z_m", focus_z_m)
    ex, ey = (validate.real("view_offset_m", v) for v in view_offset_m)
    D = validate.positive("pupil_diameter_m", pupil_diameter_m)
    _, C, H, W = a.shape
    a_row, a_col = view_shift_px({"focal_length_m": f, "z_inf_m": validate.positive("z_inf_m", z_inf_m),
                                  "pitch_m": p, "wavelengths_m": lams}, focus_z_m=z_f, view_offset_m=(ex, ey))
    hp, wp = padded_shape((H, W), pad_factor)
    ky = torch.fft.fftfreq(hp, dtype=torch.float64)
    kx = torch.fft.rfftfreq(wp, dtype=torch.float64)
    ramp = torch.polar(torch.ones(hp, wp // 2 + 1, dtype=torch.float64),
                       2 * math.pi * (ky[:, None] * a_row + kx[None, :] * a_col)).to(torch.complex64)
    out = np.empty((C, H, W), dtype=np.float64)
    for c, lam in enumerate(lams):
        mask = eye_mask((hp, wp), lam, p, focal_length_m=f, pupil_diameter_m=D, view_offset_m=(ex, ey),
                        fourier_filter=fourier_filter)
        acc = torch.zeros((hp, wp // 2 + 1), dtype=torch.complex64)
        for k, z in enumerate(zs):
            img = torch.from_numpy(np.ascontiguousarray(a[k, c]))
            if not bool(img.any()):
                continue
            ctf = transfer_function((hp, wp), z_f - z, lam, p, dtype=torch.complex64) * mask
            psf = ifft2(ctf)
            psf = psf.real.square() + psf.imag.square()
            total = float(psf.sum())
            if total <= 0.0:
                continue
            acc += torch.fft.rfft2(img, s=(hp, wp)) * torch.fft.rfft2(psf / total)
        view = torch.fft.irfft2(acc * ramp, s=(hp, wp))[:H, :W].to(torch.float64)
        out[c] = view.numpy().clip(min=0.0)
    return out


class WaveGroundTruth:
    """The wave-optical ground truth of one scene for one display (module docstring): the depth layers are
    rendered once (``spp`` samples per pixel), each view is computed from them and cached by (focus, pupil,
    view). Same interface as :class:`holocore.evaluate.groundtruth.GroundTruth`."""

    kind = "wave"

    def __init__(self, loaded: Any, meta: MetaLike, *, shape_hw: tuple[int, int], spp: int = 64, seed: int = 0,
                 fourier_filter: Optional[bool] = None, max_depth: int = 12) -> None:
        m = parse_view_meta(meta, what="the ground truth (it needs the display's geometry)")
        self.scene = loaded.scene
        self.sensor_to_world = np.array(loaded.sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        self.focal_length_m, self.z_inf_m, self.pitch_m = m.focal_length_m, m.z_inf_m, float(m.pitch_m)
        self.scene_scale = m.scene_scale
        self.wavelengths_m = list(m.wavelengths_m)
        self.shape_hw = (int(shape_hw[0]), int(shape_hw[1]))
        self.spp = validate.integer("spp", spp, 1, MAX_GT_SPP)
        self.seed = int(seed)
        self.max_depth = int(max_depth)
        self.fourier_filter = m.fourier_filter if fourier_filter is None else bool(fourier_filter)
        self.seconds = 0.0
        self._layers: Optional[DepthLayers] = None
        self._per_colour: Optional[np.ndarray] = None  # the layers' channel of each laser line, [K, C, H, W]
        self._cache: dict[tuple, np.ndarray] = {}

    @property
    def layers(self) -> DepthLayers:
        if self._layers is None:
            t0 = time.perf_counter()
            self._layers = depth_layers(
                self.scene, sensor_to_world=self.sensor_to_world, focal_length_m=self.focal_length_m,
                z_inf_m=self.z_inf_m, pitch_m=self.pitch_m, shape_hw=self.shape_hw,
                spacing_m=layer_spacing_m(pitch_m=self.pitch_m, wavelength_m=min(self.wavelengths_m)),
                spp=self.spp, seed=self.seed, max_depth=self.max_depth, scene_scale=self.scene_scale)
            self.seconds += time.perf_counter() - t0
        return self._layers

    def channels(self, *, focus_z_m: float, pupil_diameter_m: float,
                 view_offset_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """[C, H, W]: for each laser line its RGB channel's layers, imaged through the eye (float64)."""
        key = (round(float(focus_z_m), 12), round(float(pupil_diameter_m), 12),
               round(float(view_offset_m[0]), 12), round(float(view_offset_m[1]), 12))
        if key not in self._cache:
            lay = self.layers
            t0 = time.perf_counter()
            if self._per_colour is None:
                self._per_colour = np.stack([channels_for_wavelengths(lay.rgb[k], self.wavelengths_m)
                                             for k in range(lay.rgb.shape[0])])
            self._cache[key] = wave_view(self._per_colour, lay.z_m, wavelengths_m=self.wavelengths_m,
                                         pitch_m=self.pitch_m, focal_length_m=self.focal_length_m,
                                         z_inf_m=self.z_inf_m, focus_z_m=focus_z_m,
                                         pupil_diameter_m=pupil_diameter_m, view_offset_m=view_offset_m,
                                         fourier_filter=self.fourier_filter)
            self.seconds += time.perf_counter() - t0
        return self._cache[key]
