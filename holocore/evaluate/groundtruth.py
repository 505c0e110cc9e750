"""Ground truth for simulated viewing: Mitsuba thin-lens renders of what the eye sees (docs/design.md §7).

The eye sits at the eyepiece's back focal point, so the scene camera *is* the eye (docs/design.md §3): an eye of
pupil diameter D at lateral offset e = (e_x, e_y) (m, x right, y up), focused at hologram depth z_f, sees the
scene as a Mitsuba ``thinlens`` camera with

* the scene sensor's pose translated by e in the eye-camera frame (xc = -x_camera, docs/design.md §3),
* aperture radius D / 2 (world metres: the world is in metres, and the pupil is the camera's aperture),
* focus distance f^2 / (z_f - z_inf) (the inverse of z = z_inf + f^2 / zc),
* horizontal field of view 2 atan(W p / (2 f)) on an H x W film with square pixels, box pixel filter,

so film pixel (i, j) shows the direction tan = ((j - (W-1)/2) p / f, ((H-1)/2 - i) p / f): the
reconstruction's pixel grid, without a flip. Mitsuba's film column index runs along -x_camera = +xc, its
rows downwards, as our hologram grid does.

Linear RGB radiance comes back as float32 [3, H, W]; a laser line's ground truth is the channel that holds
it (:func:`holocore.display.optics.channel_of`).

Diffraction. A thin-lens render is geometric: its pupil blurs defocused points but never limits resolution.
An eye whose pupil accepts direction sines up to NA = D / 2f resolves no better than lambda / 2NA in hologram
space, whatever the display does; a frame-averaged random-phase hologram images incoherently, so the ideal
view is the geometric image convolved with the pupil's incoherent PSF |h|^2 (h: the inverse Fourier transform
of the pupil disc of radius NA / lambda). :func:`pupil_diffraction` applies it (on by default in
:class:`GroundTruth`), so that an evaluation does not charge the hologram for the eye's own diffraction.
"""

from __future__ import annotations

import math
from typing import Any, Optional, Sequence

import numpy as np

from holocore import validate
from holocore.display.optics import channel_of
from holocore.formats.meta import MetaLike, parse_view_meta
from holocore.runtime.mitsuba_env import mitsuba
from holocore.runtime.recording import recording_kernels
from holocore.scene.features import has_media, reference_integrator
from holocore.scene.load import sensor_film_hw
from holocore.trace.mapping import HologramMap

__all__ = ["focus_distance_m", "thinlens_sensor", "render_ground_truth", "camera_picture", "channels_for_wavelengths",
           "pupil_diffraction", "GroundTruth"]

MAX_GT_SPP = 1 << 16
DEFAULT_MAX_DEPTH = 12  # path length of the ground truth when the scene names no integrator
_FAR_FOCUS_M = 1e7  # "focused at infinity": Mitsuba needs a finite focus distance


def focus_distance_m(focus_z_m: float, *, focal_length_m: float, z_inf_m: float) -> float:
    """World focus distance (m) of hologram depth z_f: f^2 / (z_f - z_inf) (docs/design.md §3, §7).

    z_f = z_inf is optical infinity (returned as 1e7 m); z_f < z_inf lies beyond infinity (ValueError).
    """
    z = validate.real("focus_z_m", focus_z_m)
    f = validate.positive("focal_length_m", focal_length_m)
    zi = validate.positive("z_inf_m", z_inf_m)
    dz = z - zi
    if dz < 0:
        raise ValueError(f"focus_z_m = {z * 1e3:.4f} mm lies beyond optical infinity (z_inf = {zi * 1e3:.4f} mm): "
                         "no thin-lens camera focuses there")
    return _FAR_FOCUS_M if dz == 0 else min(_FAR_FOCUS_M, f * f / dz)


def thinlens_sensor(hmap: HologramMap, *, shape_hw: tuple[int, int], pitch_m: float, focus_z_m: float,
                    pupil_diameter_m: float, view_offset_m: tuple[float, float] = (0.0, 0.0),
                    spp: int = 256, near_clip_m: float = 1e-3) -> Any:
    """A Mitsuba ``thinlens`` sensor for one eye (pose, pupil, focus, view; see the module docstring)."""
    mi = mitsuba()
    try:
        H, W = (int(s) for s in shape_hw)
    except (TypeError, ValueError):
        raise ValueError(f"shape_hw must be (H, W) in pixels, got {shape_hw!r}") from None
    if not (1 <= H <= 16384 and 1 <= W <= 16384):
        raise ValueError(f"shape_hw must be two sizes in 1..16384 px, got {shape_hw!r}")
    p = validate.positive("pitch_m", pitch_m)
    d = validate.positive("pupil_diameter_m", pupil_diameter_m)
    if len(view_offset_m) != 2:
        raise ValueError(f"view_offset_m must be (e_x, e_y) in m, got {view_offset_m!r}")
    ex, ey = (validate.real(f"view_offset_m[{i}]", v) for i, v in enumerate(view_offset_m))
    if not 1 <= int(spp) <= MAX_GT_SPP:
        raise ValueError(f"spp must be in 1..{MAX_GT_SPP}, got {spp!r}")
    f = hmap.focal_length_m
    focus = focus_distance_m(focus_z_m, focal_length_m=f, z_inf_m=hmap.z_inf_m)
    fov_deg = 2.0 * math.degrees(math.atan(W * p / (2.0 * f)))
    # The eye moved by e in the eye-camera frame (x right, y up): a world translation, rotation unchanged. The
    # pupil and the focus are eye-frame lengths: 1 / scene_scale of them in the world Mitsuba renders.
    m = np.array(hmap.cam_to_world, dtype=np.float64)
    m[:3, 3] = hmap.camera_to_world(np.array([ex, ey, 0.0]))
    to_world = 1.0 / hmap.scene_scale
    return mi.load_dict({
        "type": "thinlens",
        "fov": fov_deg,
        "fov_axis": "x",
        "aperture_radius": d / 2.0 * to_world,
        "focus_distance": focus * to_world,
        "near_clip": float(near_clip_m) * min(1.0, to_world),
        "to_world": mi.ScalarTransform4f(m.tolist()),
        "sampler": {"type": "independent", "sample_count": int(spp)},
        "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"},
                 "pixel_format": "rgb", "component_format": "float32"},
    })


@recording_kernels()
def render_ground_truth(scene: Any, *, sensor_to_world: np.ndarray, focal_length_m: float, z_inf_m: float,
                        pitch_m: float, shape_hw: tuple[int, int], focus_z_m: float, pupil_diameter_m: float,
                        view_offset_m: tuple[float, float] = (0.0, 0.0), spp: int = 256, seed: int = 0,
                        integrator: Optional[Any] = None, scene_scale: float = 1.0) -> np.ndarray:
    """Linear RGB radiance float32 [3, H, W] an eye sees (docs/design.md §7), rendered by Mitsuba.

    ``scene``: a Mitsuba scene; ``sensor_to_world``: its perspective sensor's 4x4 to_world matrix (the eye's
    pose); ``focal_length_m``, ``z_inf_m``, ``pitch_m`` (m) and ``shape_hw`` describe the display (a render's
    meta); focus at hologram depth ``focus_z_m`` (m), pupil ``pupil_diameter_m`` (m), eye offset
    ``view_offset_m`` (m). ``integrator``: default the scene's own (else ``path`` with 12 bounces). ``spp``
    samples per pixel (1..65536). ``scene_scale``: the render's (docs/design.md §3), from its meta.
    """
    mi = mitsuba()
    hmap = HologramMap(cam_to_world=np.asarray(sensor_to_world, dtype=np.float64),
                       focal_length_m=validate.positive("focal_length_m", focal_length_m),
                       z_inf_m=validate.positive("z_inf_m", z_inf_m),
                       scene_scale=validate.positive("scene_scale", scene_scale))
    sensor = thinlens_sensor(hmap, shape_hw=shape_hw, pitch_m=pitch_m, focus_z_m=focus_z_m,
                             pupil_diameter_m=pupil_diameter_m, view_offset_m=view_offset_m, spp=spp)
    if not 0 <= int(seed) < 2**31:
        raise ValueError(f"seed must be in 0..2^31-1, got {seed!r}")
    if integrator is None and (scene.integrator() is None or has_media(scene)):
        # a scene without one: Mitsuba's path tracer; with media, volpath (path ignores them)
        integrator = mi.load_dict(reference_integrator(scene, max_depth=DEFAULT_MAX_DEPTH))
    img = mi.render(scene, sensor=sensor, integrator=integrator, spp=int(spp), seed=int(seed))
    rgb = np.array(img, dtype=np.float32)[..., :3]  # [H, W, 3]
    rgb = np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0).clip(min=0.0)
    return np.ascontiguousarray(np.moveaxis(rgb, -1, 0))


_PICTURE_MAX_ASPECT = 4  # the picture's height is at most this many times its widest


@recording_kernels()
def camera_picture(loaded: Any, *, max_width_px: int = 320, spp: int = 32, seed: int = 0) -> np.ndarray:
    """What the scene's own camera sees, small: linear RGB float32 [3, h, w], at most ``max_width_px`` wide and
    4 ``max_width_px`` tall, with the camera's aspect (its film's h / w, square pixels) and its horizontal field
    of view, from its pose, as a pinhole; Mitsuba's path tracer (volpath where the scene holds media) at ``spp``
    samples per pixel.
    A picture a person recognises the scene by, not a ground truth: the display's optics play no part, so the
    hologram's view can be drawn over it (holocore.display.profiles.field_of_view_box)."""
    mi = mitsuba()
    if not 8 <= int(max_width_px) <= 4096:
        raise ValueError(f"max_width_px must be in 8..4096, got {max_width_px!r}")
    if not 1 <= int(spp) <= 4096:
        raise ValueError(f"spp must be in 1..4096, got {spp!r}")
    film_h, film_w = sensor_film_hw(loaded.sensor)
    w = min(int(max_width_px), film_w)
    h = max(1, round(w * film_h / film_w))
    if h > _PICTURE_MAX_ASPECT * int(max_width_px):  # a tall film: the height is bounded too, the aspect kept
        h = _PICTURE_MAX_ASPECT * int(max_width_px)
        w = max(1, round(h * film_w / film_h))
    sensor = {
        "type": "perspective", "fov": float(loaded.fov_x_deg), "fov_axis": "x", "near_clip": 1e-3,
        "to_world": mi.ScalarTransform4f(
            np.array(loaded.sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4).tolist()),
        "sampler": {"type": "independent", "sample_count": int(spp)},
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                 "pixel_format": "rgb", "component_format": "float32"},
    }
    if loaded.sensor.get_medium() is not None:  # a camera inside a medium sees through it
        sensor["medium"] = loaded.sensor.get_medium()
    # The scene's own integrator may be anything (an AOV, a depth of 100): the picture takes the reference one.
    integrator = mi.load_dict(reference_integrator(loaded.scene, max_depth=DEFAULT_MAX_DEPTH))
    img = mi.render(loaded.scene, sensor=mi.load_dict(sensor), integrator=integrator, spp=int(spp), seed=int(seed))
    rgb = np.nan_to_num(np.array(img, dtype=np.float32)[..., :3], nan=0.0, posinf=0.0, neginf=0.0).clip(min=0.0)
    return np.ascontiguousarray(np.moveaxis(rgb, -1, 0))


def channels_for_wavelengths(rgb: np.ndarray, wavelengths_m: Sequence[float]) -> np.ndarray:
    """[C, H, W]: for each laser line the RGB channel that holds it (R >= 590 nm, G 490-590 nm, B below)."""
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[0] != 3:
        raise ValueError(f"rgb must be [3, H, W], got shape {a.shape}")
    lams = [validate.positive("wavelengths_m", v) for v in wavelengths_m]
    if not lams:
        raise ValueError("wavelengths_m needs at least one wavelength")
    return np.stack([a[channel_of(lam)] for lam in lams], axis=0)


def pupil_diffraction(img: np.ndarray, *, wavelengths_m: Sequence[float], pitch_m: float,
                      numerical_aperture: float) -> np.ndarray:
    """Each channel [C, H, W] convolved with the incoherent PSF of a pupil of ``numerical_aperture`` (sine)
    at its wavelength (m), on the grid of ``pitch_m`` (m); float64, same sum. Edges are padded by reflection."""
    a = np.asarray(img, dtype=np.float64)
    lams = [validate.positive("wavelengths_m", v) for v in wavelengths_m]
    if a.ndim != 3 or a.shape[0] != len(lams):
        raise ValueError(f"img must be [C, H, W] with one channel per wavelength, got {a.shape} for {len(lams)}")
    p = validate.positive("pitch_m", pitch_m)
    na = validate.positive("numerical_aperture", numerical_aperture)
    C, H, W = a.shape
    ph, pw = H // 2 + 1, W // 2 + 1
    out = np.empty_like(a)
    for c, lam in enumerate(lams):
        big = np.pad(a[c], ((ph, ph), (pw, pw)), mode="reflect")
        fy = np.fft.fftfreq(big.shape[0], d=p)
        fx = np.fft.fftfreq(big.shape[1], d=p)
        pupil = (fx[None, :] ** 2 + fy[:, None] ** 2) <= (na / lam) ** 2
        psf = np.abs(np.fft.ifft2(pupil)) ** 2
        otf = np.fft.fft2(psf / psf.sum())
        blurred = np.fft.ifft2(np.fft.fft2(big) * otf).real
        out[c] = blurred[ph:ph + H, pw:pw + W].clip(min=0.0)
    return out


class GroundTruth:
    """Thin-lens renders of one scene for one display, cached by (focus, pupil, view).

    ``loaded``: a :class:`holocore.scene.load.LoadedScene` (its first sensor is the eye); ``meta``: a render's meta
    (``focal_length_m``, ``z_inf_m``, ``pitch_m``, ``wavelengths_m``) with ``shape_hw`` the display's pixels.
    """

    def __init__(self, loaded: Any, meta: MetaLike, *, shape_hw: tuple[int, int], spp: int = 256, seed: int = 0,
                 integrator: Optional[Any] = None, diffraction: bool = True) -> None:
        meta = parse_view_meta(meta, what="the ground truth (it needs the display's geometry)")
        if not 1 <= int(spp) <= MAX_GT_SPP:
            raise ValueError(f"spp must be in 1..{MAX_GT_SPP}, got {spp!r}")
        self.scene = loaded.scene
        self.sensor_to_world = np.array(loaded.sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        self.focal_length_m = meta.focal_length_m
        self.z_inf_m = meta.z_inf_m
        self.scene_scale = meta.scene_scale
        self.pitch_m = float(meta.pitch_m)
        self.wavelengths_m = list(meta.wavelengths_m)
        self.shape_hw = (int(shape_hw[0]), int(shape_hw[1]))
        self.spp = int(spp)
        self.seed = int(seed)
        self.integrator = integrator
        self.diffraction = bool(diffraction)
        self.seconds = 0.0  # time spent rendering
        self._cache: dict[tuple, np.ndarray] = {}

    def rgb(self, *, focus_z_m: float, pupil_diameter_m: float,
            view_offset_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """Linear RGB float32 [3, H, W] (cached)."""
        import time

        key = (round(float(focus_z_m), 12), round(float(pupil_diameter_m), 12),
               round(float(view_offset_m[0]), 12), round(float(view_offset_m[1]), 12))
        if key not in self._cache:
            t0 = time.perf_counter()
            self._cache[key] = render_ground_truth(
                self.scene, sensor_to_world=self.sensor_to_world, focal_length_m=self.focal_length_m,
                z_inf_m=self.z_inf_m, pitch_m=self.pitch_m, shape_hw=self.shape_hw, focus_z_m=focus_z_m,
                pupil_diameter_m=pupil_diameter_m, view_offset_m=view_offset_m, spp=self.spp, seed=self.seed,
                integrator=self.integrator, scene_scale=self.scene_scale)
            self.seconds += time.perf_counter() - t0
        return self._cache[key]

    def channels(self, *, focus_z_m: float, pupil_diameter_m: float,
                 view_offset_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """[C, H, W]: the channel of each laser line (docs/design.md §4 colors), diffraction-limited by the pupil
        unless the instance was made with ``diffraction=False``."""
        img = channels_for_wavelengths(self.rgb(focus_z_m=focus_z_m, pupil_diameter_m=pupil_diameter_m,
                                                view_offset_m=view_offset_m), self.wavelengths_m)
        if not self.diffraction:
            return img
        return pupil_diffraction(img, wavelengths_m=self.wavelengths_m, pitch_m=self.pitch_m,
                                 numerical_aperture=float(pupil_diameter_m) / (2.0 * self.focal_length_m))
