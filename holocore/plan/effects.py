"""EffectPlan: simulate only what a scene calls for (docs/design.md §8).

From the scene's BSDFs, emitters and geometry the plan decides: whether the coherent delta loop runs and
its depth cap, whether radiance is view-dependent (glossy), the global-illumination depth, whether the
ambient cache is exact, which colors carry light, and whether a random-phase bank is needed. Every decision
can be forced on (``force_all``) for comparison. The plan travels in every result, in plain words.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Iterable, Optional

from pydantic import BaseModel, Field

from holocore.display.optics import MAX_CONE_HALF_ANGLE_RAD
from holocore.plan.presets import PRESETS, PresetName
from holocore.runtime.mitsuba_env import mitsuba
from holocore.scene.features import absorbing_media, is_mixed_delta, near_smooth_bsdfs, shape_name

__all__ = ["SceneInventory", "EffectPlan", "inventory", "make_plan", "choose_spp", "noise_factor", "lobe_spread_px"]

MAX_DELTA_CAP = 16  # the delta-bounce cap the surfaces' count may ask for, and a forced plan's
DELTA_CAP_LIMIT = 32  # the most a pre-pass that sees longer chains (a mirror hall) raises it to; also its probe cap
DELTA_LOSS_OK = 0.005  # share of rays a cap may drop before it is raised: each bounce more costs only the rays
# still bouncing, so the cap goes up until the pre-pass's loss is below this

def noise_factor(theta_max: float) -> float:
    """k(theta) = Omega / tan^2(theta): noise-to-signal = k rho^2 / N (rho in pixels, N rays per pixel)."""
    t = min(theta_max, MAX_CONE_HALF_ANGLE_RAD)
    return 2.0 * math.pi * (1.0 - math.cos(t)) / math.tan(t) ** 2


def lobe_spread_px(alphas: Iterable[float], *, focal_length_m: float, pitch_m: float,
                   zc_surface_m: Optional[float], zc_image_m: Optional[float]) -> float:
    """How far a near-smooth surface's lobe spreads, over the recording plane, the rays that reach one image point
    behind it (px; docs/physics.md, "Near-smooth surfaces"). Each ray leaves along its own micro-normal: a tilt of
    about 2 alpha (a reflection's; refraction through a plate deviates about half as much), magnified z_s / f in
    hologram space, over the f^2 (1 / z_s - 1 / z_i) between the surface's image and the point's, is
    2 alpha f (1 - z_s / z_i) / p. Its Monte Carlo noise is the sub-hologram's of radius hypot(rho, spread).
    Conservative: the roughest surface, the nearest surface depth and the farthest image point (camera distances,
    m). 0 without near-smooth surfaces or depths."""
    a = max((float(v) for v in alphas), default=0.0)
    if a <= 0.0 or not zc_surface_m or not zc_image_m or zc_image_m <= zc_surface_m:
        return 0.0
    return 2.0 * a * float(focal_length_m) * (1.0 - float(zc_surface_m) / float(zc_image_m)) / float(pitch_m)


def choose_spp(preset: PresetName, subhologram_radius_px: float, theta_max: float,
               max_spp: Optional[int] = None) -> int:
    """Rays per WRP pixel for a preset (holocore.plan.presets), from the farthest image point's sub-hologram
    radius: N = k(theta) rho^2 / the preset's noise-to-signal target, within its bounds and at most ``max_spp``
    (a service's cap on rays per pixel, which may be below the preset's own spp_max)."""
    p = PRESETS[preset]
    n = math.ceil(noise_factor(theta_max) * subhologram_radius_px ** 2 / p.noise_to_signal)
    top = p.spp_max if max_spp is None else max(1, min(p.spp_max, int(max_spp)))
    return int(min(top, max(min(p.spp_min, top), n)))


class SceneInventory(BaseModel):
    """What the scene holds, read from Mitsuba's objects (no tracing)."""

    shapes: int
    primitives: int
    mirrors: list[str] = Field(default_factory=list)  # shapes with a delta reflection-only BSDF
    dielectrics: list[str] = Field(default_factory=list)  # shapes with delta transmission
    glossy: list[str] = Field(default_factory=list)  # shapes with glossy lobes where the image point can sit
    # rough conductors and dielectrics that keep an image: the chain goes on through them (holocore.trace.near_smooth)
    near_smooth: dict[str, float] = Field(default_factory=dict)  # name -> roughness alpha
    mixed_delta: list[str] = Field(default_factory=list)  # delta and non-delta lobes together (plastic...)
    emitters: list[str] = Field(default_factory=list)
    environment: bool = False
    bsdf_types: dict[str, int] = Field(default_factory=dict)
    # Homogeneous absorbing media: where (shape interior / exterior, or the sensor) -> sigma_t per colour (1/m)
    absorbing_media: dict[str, list[float]] = Field(default_factory=dict)


class EffectPlan(BaseModel):
    """Decisions for one render; ``summary`` says them in words."""

    coherent_delta: bool
    max_delta: int
    # share of the pre-pass rays whose delta chain runs past max_delta (dropped: their light never reaches P)
    delta_capped_share: float = 0.0
    view_dependent: bool
    gi_depth: int
    use_cache: bool
    cache_exact: bool
    colors_lit: list[bool]
    random_phase: bool
    spp: int
    amp_spp: int
    noise_to_signal: float = 0.0
    wrp_planes_m: list[float] = Field(default_factory=list)  # recording planes front to back (hologram z, m)
    forced: bool = False
    summary: list[str] = Field(default_factory=list)


def inventory(scene) -> SceneInventory:
    mi = mitsuba()
    F = mi.BSDFFlags
    inv = SceneInventory(shapes=0, primitives=0, near_smooth=near_smooth_bsdfs(scene))
    types: Counter = Counter()
    for i, sh in enumerate(scene.shapes()):
        inv.shapes += 1
        inv.primitives += int(sh.primitive_count())
        name = shape_name(sh, i)
        if sh.is_emitter():
            inv.emitters.append(name)
        b = sh.bsdf()
        if b is None:
            continue
        types[b.class_name()] += 1
        fl = b.flags()
        has = lambda flag: mi.has_flag(fl, flag)  # noqa: E731
        if has(F.DeltaTransmission):
            inv.dielectrics.append(name)
        elif has(F.DeltaReflection) and not has(F.Smooth):
            inv.mirrors.append(name)
        if is_mixed_delta(fl):
            inv.mixed_delta.append(name)
        if has(F.Glossy) and name not in inv.near_smooth:
            inv.glossy.append(name)
    inv.environment = scene.environment() is not None
    inv.absorbing_media = absorbing_media(scene)
    inv.bsdf_types = dict(types)
    return inv


def make_plan(
    inv: SceneInventory,
    *,
    preset: PresetName,
    frames: int,
    n_colors: int,
    colors_lit: Optional[list[bool]] = None,
    spp: Optional[int] = None,
    max_spp: Optional[int] = None,
    force_all: bool = False,
    max_delta_seen: Optional[int] = None,
    prepass_capped: int = 0,
    delta_bounces: Optional[list[int]] = None,
    subhologram_radius_px: float = 0.0,
    theta_max: float = 0.05,
    wrp_planes_m: Optional[list[float]] = None,
    wrp_planes_asked: object = 1,
    z_inf_m: float = 0.0,
    lobe_spread_px: float = 0.0,
) -> EffectPlan:
    """Decide what to simulate. ``max_delta_seen``: the deepest delta chain the pre-pass met; ``delta_bounces``:
    its rays by the delta bounces they needed (holocore.plan.analysis), from which the cap's loss is told."""
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {preset!r}")
    p = PRESETS[preset]
    coherent, cap, words = _delta_chain(inv, force_all=force_all, max_delta_seen=max_delta_seen,
                                        prepass_capped=prepass_capped)
    lost = capped_share(delta_bounces, cap) if coherent else 0.0
    if coherent and delta_bounces and not force_all:
        cap, lost, line = _raise_cap(delta_bounces, cap)
        words.append(line)
    # Mitsuba's integrators cannot continue a path that sits inside a medium where the kernel found P: the
    # extra radiance samples are the kernel's own one sample then.
    amp_spp = 1 if inv.absorbing_media else p.amp_spp
    view_dep = force_all or bool(inv.glossy) or bool(inv.mixed_delta)
    if inv.glossy:
        words.append(f"glossy, view-dependent radiance traced per ray: {', '.join(inv.glossy[:4])}")
    elif not view_dep:
        words.append("all rough surfaces diffuse: radiance is view-independent")

    gi = p.gi_depth
    words.append(f"global illumination: up to {gi} bounces")
    use_cache = p.use_cache and not force_all
    cache_exact = not view_dep
    if use_cache:
        words.append("ambient radiance cache: " + ("exact here (view-independent radiance)" if cache_exact
                                                    else "used on diffuse surfaces; glossy surfaces are path "
                                                         "traced (their highlights move with the view)"))
    lit = list(colors_lit) if colors_lit is not None else [True] * n_colors
    if force_all:
        lit = [True] * n_colors
    if not all(lit):
        dark = [str(i) for i, v in enumerate(lit) if not v]
        words.append(f"color channel(s) {', '.join(dark)} carry no light: skipped")
    if not any(lit):
        words.append("the scene is black: the fields are zero")
    random_phase = force_all or frames > 1
    words.append(f"{frames} frame(s): " + ("band-limited random-phase bank, paths shared by all frames"
                                           if random_phase else "one frame, no random-phase bank (smooth phase)"))
    planes = list(wrp_planes_m or [])
    words += _planes_words(planes, wrp_planes_asked=wrp_planes_asked, z_inf_m=z_inf_m)
    radius = math.hypot(subhologram_radius_px, lobe_spread_px)  # near-smooth lobes widen it (lobe_spread_px)
    n = spp if spp is not None else choose_spp(preset, radius, theta_max, max_spp)
    ratio = noise_factor(theta_max) * radius ** 2 / n
    widened = f", {radius:.1f} px with the near-smooth lobes' spread" if lobe_spread_px > 0 else ""
    words.append(f"{n} rays per WRP pixel ({'given' if spp is not None else 'chosen from the scene depth'}): the "
                 f"farthest image point's sub-hologram on its plane has a radius of {subhologram_radius_px:.1f} px"
                 f"{widened}, "
                 f"Monte Carlo noise about {ratio:.2g}x its signal power; {amp_spp} radiance sample(s) per "
                 f"image point" + (" (absorbing media: the tracer's own)" if amp_spp < p.amp_spp else ""))
    return EffectPlan(coherent_delta=coherent, max_delta=cap, delta_capped_share=lost, view_dependent=view_dep,
                      gi_depth=gi,
                      use_cache=use_cache, cache_exact=cache_exact, colors_lit=lit, random_phase=random_phase,
                      spp=n, amp_spp=amp_spp, noise_to_signal=ratio, forced=force_all,
                      wrp_planes_m=[float(z) for z in planes],
                      summary=words)


def _delta_chain(inv: SceneInventory, *, force_all: bool, max_delta_seen: Optional[int],
                 prepass_capped: int) -> tuple[bool, int, list[str]]:
    """(whether the coherent delta loop runs, its cap on delta bounces, the plan's words on mirrors, glass, coated
    surfaces and absorbing media)."""
    words: list[str] = []
    n_delta_shapes = len(inv.mirrors) + len(inv.dielectrics) + len(inv.mixed_delta) + len(inv.near_smooth)
    n_delta_shapes += int(bool(max_delta_seen))
    coherent = force_all or n_delta_shapes > 0
    if force_all:
        cap = MAX_DELTA_CAP
    elif n_delta_shapes == 0:
        cap = 0
    else:
        # Each dielectric: entry, exit and up to two internal reflections; each mirror: a couple of visits.
        cap = 4 * (len(inv.dielectrics) + len(inv.near_smooth)) + 2 * (len(inv.mirrors) + len(inv.mixed_delta))
        if max_delta_seen is not None:
            cap = max(cap, max_delta_seen + 1)  # Mitsuba merges meshes that share a BSDF: trust the pre-pass
        if prepass_capped:
            cap = MAX_DELTA_CAP
        cap = min(MAX_DELTA_CAP, cap)
    if inv.mirrors:
        words.append(f"mirror reflection: {len(inv.mirrors)} surface(s) ({', '.join(inv.mirrors[:4])})")
    if inv.dielectrics:
        words.append(f"refraction: {', '.join(inv.dielectrics[:4])}, up to {cap} delta interfaces per path")
    if inv.mixed_delta:
        words.append(f"coated surfaces with a delta layer: {', '.join(inv.mixed_delta[:4])}")
    if inv.near_smooth:
        named = ", ".join(f"{k} (alpha {a:.2g})" for k, a in list(inv.near_smooth.items())[:4])
        words.append(f"near-smooth surfaces carry the coherent chain through sampled micro-normals (a blurred image "
                     f"at the apparent depth of what they show): {named}")
    for where, sig in inv.absorbing_media.items():
        words.append(f"absorbing medium in {where}: sigma_t = ({', '.join(f'{x:.3g}' for x in sig)}) /m per "
                     "colour, every path segment inside it attenuated by exp(-sigma_t d / 2) in amplitude "
                     "(Beer-Lambert)")
    if not coherent:
        words.append("no mirror or glass: coherent delta loop off, the first hit is the image point")
    elif force_all and n_delta_shapes == 0:
        words.append(f"coherent delta loop forced on (cap {cap}) although the scene has no delta surface")
    return coherent, cap, words


def capped_share(delta_bounces: Optional[list[int]], cap: int) -> float:
    """The share of the pre-pass rays a delta cap ``cap`` drops: those that needed more bounces (0 unknown)."""
    n = sum(delta_bounces or [])
    return float(sum(delta_bounces[cap + 1:]) / n) if n else 0.0


def _raise_cap(delta_bounces: list[int], cap: int) -> tuple[int, float, str]:
    """(the cap, the share of rays it drops, the plan's line): the cap is raised while the pre-pass shows it
    dropping more than DELTA_LOSS_OK of the rays, up to DELTA_CAP_LIMIT."""
    lost0 = capped_share(delta_bounces, cap)
    new = cap
    while new < DELTA_CAP_LIMIT and capped_share(delta_bounces, new) > DELTA_LOSS_OK:
        new += 1
    lost = capped_share(delta_bounces, new)
    raised = f" (raised from {cap}, which drops {lost0:.1%})" if new > cap else ""
    tail = f"{lost:.1%} of the rays still bounce past it and are dropped (their light is lost)" if lost > 0 else \
        "no pre-pass ray runs past it"
    return new, lost, f"delta chains capped at {new} bounces{raised}: {tail}"


def _planes_words(planes: list[float], *, wrp_planes_asked: object, z_inf_m: float) -> list[str]:
    """The plan's words on the recording planes."""
    if len(planes) > 1:
        at = ", ".join(f"{(z - z_inf_m) * 1e3:.2f}" for z in planes)
        why = "chosen from the scene depth (auto)" if wrp_planes_asked == "auto" else "asked for"
        return [f"{len(planes)} wave recording planes at z_inf + {at} mm ({why}): each ray's contribution is "
                f"recorded where it crosses the plane just in front of its image point, the planes chained "
                f"to the WRP by the ASM"]
    if wrp_planes_asked == "auto":
        return ["one wave recording plane (auto: more planes would not lower the noise much at this depth)"]
    return []
