"""Scenes with depth after the paper's figures (Figs. 1, 7), written by the project's own code: Mitsuba XML
bundles with procedurally generated textures (no third-party assets).

Every scene is seen by an eye at the world origin looking down -z (y up), through a perspective camera whose
horizontal field of view is the paper display's, 2 atan(W p / 2f) = 17.46 degrees for 1920 px of 8 µm and
f = 50 mm (docs/design.md §3), so the whole scene is in view on that display and the plan reports no field-of-view
difference there. The objects that carry the focus cues lie inside the central half of that view (|tan| <=
0.076 horizontally, 0.043 vertically): a 540 x 960 part of the SLM (the issue's figure size on a CPU) shows
all of them; a 270 x 480 part shows the middle of each.

With f = 50 mm and virtual infinity z_inf, eye-camera depth zc lands at z = z_inf + f^2 / zc: 10 m at
z_inf + 0.25 mm, 0.9 m at + 2.78 mm, 0.5 m at + 5 mm (the paper's 80 to 85 mm).

* ``depth``: textured cards at 0.5 m (a Siemens star, left) and 0.9 m (a checker, centre, partly hidden by the
  near card) in front of a textured wall at 10 m that fills the view.
* ``mirror``: a plane mirror 0.5 m away, in a textured frame, turned 12 degrees about y: it shows a poster
  1.5 m from the mirror, behind the eye and out of its view, so the mirror image lies 2.0 m away
  (z_inf + 1.25 mm) while the mirror surface is at z_inf + 5 mm.
* ``glass``: a glass sphere (n = 1.5, radius 25 cm) whose front surface is 0.5 m away, imaging a textured card
  5 m behind its centre (Fig. 1: a glass sphere imaging a far object): a ball lens of focal length
  n R / 2 (n - 1) = 37.5 cm about its centre, so the card's image is real, inverted, minified 12x and 40.5 cm in
  front of the centre: 0.345 m from the eye (z_inf + 7.25 mm), 2.25 mm of hologram depth in front of the
  sphere's surface (0.5 m, + 5 mm), more than the depth of field of an eye's 1.6 mm pupil (about 2 mm), and far
  from the card itself (5.75 m, + 0.43 mm): focusing on the surface or on the card blurs it.
* ``glossy``: a glossy textured plate (rough plastic, alpha 0.01) 0.5 m away, turned 12 degrees about y, that
  reflects a small bright sphere light 1.5 m from the plate, behind the eye: the highlight lies at the light's
  mirror image, 2 m away, so it slides over the plate's texture when the eye moves (by e (1/0.5 - 1/2.0) rad
  per metre of eye offset e).

All scenes are lit by a uniform white sky: a sphere of radius 50 m around the eye that glows inwards (rather
than Mitsuba's ``constant`` environment, so that a ray the hologram traces towards the sky, e.g. reflected by
the glass ball, ends on a surface instead of escaping and being dropped). The 10 m wall hides the sky from the
eye directly and through the mirror. :func:`scene_facts` gives each
scene's geometry (depths, the mirror and glass parameters) for tests and reports.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from holocore.display.profiles import PAPER

__all__ = ["PAPER_SCENES", "paper_fov_x_deg", "write_paper_scene", "scene_facts", "ball_lens_image_zc"]

PAPER_SCENES = ("depth", "mirror", "glass", "glossy")
ENTRY = "scene.xml"
FILM_WH = (480, 270)  # the camera's own film (16:9 as the paper's SLM); the hologram uses its own pixel grid
TILT_DEG = 12.0  # mirror and glossy plate: turned about y, so they reflect a point behind the eye on the right


def paper_fov_x_deg() -> float:
    """The paper display's horizontal field of view, 2 atan(W p / 2f), in degrees (17.46)."""
    W = PAPER.resolution_hw[1]
    return math.degrees(2.0 * math.atan(W * PAPER.pitch_um * 1e-6 / (2.0 * PAPER.focal_length_mm * 1e-3)))


def ball_lens_image_zc(*, center_zc_m: float, radius_m: float, ior: float, object_zc_m: float) -> float:
    """Eye-camera depth of the paraxial image of a point at ``object_zc_m`` behind a glass ball (thick lens:
    focal length n R / 2 (n - 1), both principal planes at the centre): 1/s_o + 1/s_i = 1/f_ball."""
    f_ball = ior * radius_m / (2.0 * (ior - 1.0))
    s_o = object_zc_m - center_zc_m
    s_i = 1.0 / (1.0 / f_ball - 1.0 / s_o)
    return center_zc_m - s_i  # s_i > 0: a real image on the eye's side of the ball


# ---- geometry (metres, eye at the origin, looking down -z) ----------------------------------------------------
_FAR_ZC = 10.0
_DEPTH = {"near": {"zc": 0.5, "tan_x": (-0.07, -0.01), "tan_y": (-0.032, 0.022), "texture": "star"},
          "mid": {"zc": 0.9, "tan_x": (-0.02, 0.05), "tan_y": (-0.036, 0.036), "texture": "checker"}}
_MIRROR = {"zc": 0.5, "half": (0.025, 0.0175), "poster_distance": 1.5, "poster_half": (0.26, 0.19)}
_GLASS = {"center_zc": 0.75, "radius": 0.25, "ior": 1.5, "card_zc": 5.75, "card_half": (0.5, 0.325),
          "card_repeat": (3.0, 2.0)}
_GLOSSY = {"zc": 0.5, "half": (0.034, 0.024), "alpha": 0.01, "light_distance": 1.5, "light_radius": 0.01,
           "light_radiance": 500.0}
_SKY = 1.0
_SKY_RADIUS = 50.0


def _reflected_dir(tilt_deg: float) -> np.ndarray:
    """Where the view ray (0, 0, -1) goes after a mirror turned by ``tilt_deg`` about y (normal (sin a, 0, cos a))."""
    a = math.radians(2.0 * tilt_deg)
    return np.array([math.sin(a), 0.0, math.cos(a)])


def scene_facts(name: str) -> dict[str, Any]:
    """The geometry of scene ``name`` in eye-camera terms: depths (m) of what carries focus cues, and the
    mirror's, the glass ball's or the glossy plate's parameters, as the writer places them."""
    if name not in PAPER_SCENES:
        raise ValueError(f"unknown paper scene {name!r}; known: {', '.join(PAPER_SCENES)}")
    far = {"far_wall_zc_m": _FAR_ZC}
    if name == "depth":
        return {**far, "depths_m": {"near": _DEPTH["near"]["zc"], "mid": _DEPTH["mid"]["zc"], "far": _FAR_ZC},
                "regions_tan": {k: {"x": v["tan_x"], "y": v["tan_y"]} for k, v in _DEPTH.items()}}
    if name == "mirror":
        m = _MIRROR
        return {**far, "mirror_zc_m": m["zc"], "mirror_half_m": m["half"], "tilt_deg": TILT_DEG,
                "reflected_dir": _reflected_dir(TILT_DEG).tolist(), "object_distance_m": m["poster_distance"],
                # a plane mirror: the image lies at the unfolded path length (for the central ray, zc = d)
                "mirror_image_zc_m": m["zc"] + m["poster_distance"]}
    if name == "glass":
        g = _GLASS
        return {**far, "sphere_center_zc_m": g["center_zc"], "sphere_radius_m": g["radius"], "ior": g["ior"],
                "sphere_front_zc_m": g["center_zc"] - g["radius"], "card_zc_m": g["card_zc"],
                "paraxial_image_zc_m": ball_lens_image_zc(center_zc_m=g["center_zc"], radius_m=g["radius"],
                                                          ior=g["ior"], object_zc_m=g["card_zc"])}
    g = _GLOSSY
    return {**far, "plate_zc_m": g["zc"], "alpha": g["alpha"], "tilt_deg": TILT_DEG,
            "light_distance_m": g["light_distance"], "light_radius_m": g["light_radius"],
            # the highlight sits at the light's mirror image: the unfolded distance from the eye
            "highlight_image_zc_m": g["zc"] + g["light_distance"]}


# ---- textures (procedural, uint8 RGB) ---------------------------------------------------------------------
def _save(img: np.ndarray, path: Path) -> str:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(img.clip(0, 255).astype(np.uint8))).save(path)
    return path.as_posix()


def _siemens_star(n: int = 512, spokes: int = 24) -> np.ndarray:
    """A Siemens star in four colours on a light ground, with a thin ring: sharp at every scale."""
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5 - n / 2) / (n / 2)
    r, th = np.hypot(xx, yy), np.arctan2(yy, xx)
    on = (np.floor(th / (2 * np.pi) * spokes * 2) % 2) == 0
    quad = ((th + np.pi) // (np.pi / 2)).astype(int) % 4
    cols = np.array([[200, 40, 40], [40, 150, 60], [40, 70, 190], [220, 170, 30]])
    img = np.full((n, n, 3), 235.0)
    inside = r < 0.92
    img[inside & on] = cols[quad[inside & on]]
    img[(np.abs(r - 0.96) < 0.015)] = 30
    return img


def _checker(n: int = 512, k: int = 12) -> np.ndarray:
    """A two-colour checker with a dark border and a diagonal stripe: edges in both directions."""
    yy, xx = np.mgrid[0:n, 0:n]
    on = ((xx * k // n) + (yy * k // n)) % 2 == 0
    img = np.where(on[..., None], np.array([240, 230, 205]), np.array([30, 90, 160])).astype(np.float64)
    img[np.abs(xx - yy) < n // 64] = [200, 60, 30]
    b = n // 40
    img[:b], img[-b:], img[:, :b], img[:, -b:] = 25, 25, 25, 25
    return img


def _bricks(n: int = 512) -> np.ndarray:
    """Brick courses with mortar and a colour per brick: the 10 m wall (repeated 5 x 3 times)."""
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:n, 0:n]
    rows, cols = 8, 4
    h, w = n // rows, n // cols
    course = yy // h
    shift = np.where(course % 2 == 1, w // 2, 0)
    bx = ((xx + shift) // w) % cols
    tint = rng.uniform(0.75, 1.15, size=(rows, cols, 1)) * np.array([170.0, 90.0, 60.0])
    img = tint[course, bx]
    mortar = ((yy % h) < max(2, h // 10)) | (((xx + shift) % w) < max(2, w // 20))
    img[mortar] = [215, 210, 200]
    return img


def _poster(n: int = 512) -> np.ndarray:
    """What the mirror shows: concentric rings, bars of three widths and a star in the middle."""
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5 - n / 2) / (n / 2)
    r = np.hypot(xx, yy)
    img = np.full((n, n, 3), 230.0)
    rings = (np.floor(r * 10) % 2 == 0) & (r > 0.35)
    img[rings] = [60, 120, 200]
    for i, (y0, wbar) in enumerate(((-0.9, 0.04), (0.8, 0.08))):
        band = (yy > y0) & (yy < y0 + 0.1)
        img[band & (np.floor((xx + 1) / wbar) % 2 == 0)] = [[180, 40, 40], [40, 140, 60]][i]
    star = _siemens_star(n, spokes=16)
    core = r < 0.33
    img[core] = star[(yy[core] / 0.33 * n / 2 + n / 2).astype(int).clip(0, n - 1),
                     (xx[core] / 0.33 * n / 2 + n / 2).astype(int).clip(0, n - 1)]
    return img


def _dots(n: int = 512, k: int = 16) -> np.ndarray:
    """Coloured dots on a grid with a cross through the middle (seen through the glass ball)."""
    yy, xx = np.mgrid[0:n, 0:n]
    c = n // k
    dy, dx = (yy % c) - c / 2, (xx % c) - c / 2
    cols = np.array([[200, 40, 40], [40, 150, 60], [40, 70, 190], [220, 170, 30]])
    idx = ((yy // c) + 2 * (xx // c)) % 4
    img = np.full((n, n, 3), 230.0)
    dot = dx * dx + dy * dy <= (0.3 * c) ** 2
    img[dot] = cols[idx[dot]]
    img[(np.abs(yy - n / 2) < n / 128) | (np.abs(xx - n / 2) < n / 128)] = 20
    return img


def _frame(n: int = 256) -> np.ndarray:
    """The mirror's frame: a fine black and white checker (focuses at the mirror's depth)."""
    yy, xx = np.mgrid[0:n, 0:n]
    on = ((xx // 8) + (yy // 8)) % 2 == 0
    return np.where(on[..., None], 235.0, 25.0) * np.ones(3)


_TEXTURES = {"star": _siemens_star, "checker": _checker, "bricks": _bricks, "poster": _poster, "dots": _dots,
             "frame": _frame}


# ---- XML ------------------------------------------------------------------------------------------------------
def _f(v: float) -> str:
    return f"{float(v):.6g}"


def _header(fov_x_deg: float, film_wh: tuple[int, int]) -> str:
    return f"""<scene version="3.0.0">
    <!-- Written by holocore.scene.paper: the eye at the origin looks down -z; the horizontal field of view
         is the paper display's (2 atan(W p / 2f), 1920 px x 8 um, f = 50 mm). -->
    <integrator type="path"><integer name="max_depth" value="8"/></integrator>
    <sensor type="perspective" id="eye">
        <float name="fov" value="{_f(fov_x_deg)}"/>
        <string name="fov_axis" value="x"/>
        <float name="near_clip" value="0.01"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, 0, -1" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="{film_wh[0]}"/><integer name="height" value="{film_wh[1]}"/>
            <rfilter type="box"/></film>
    </sensor>
    <!-- The sky: a glowing sphere 50 m around the eye, facing inwards (a constant environment at a finite
         distance, so that a ray the hologram traces towards it ends on a surface instead of escaping). -->
    <shape type="sphere" id="sky">
        <point name="center" x="0" y="0" z="0"/><float name="radius" value="{_f(_SKY_RADIUS)}"/>
        <boolean name="flip_normals" value="true"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="{_f(_SKY)}, {_f(_SKY)}, {_f(_SKY)}"/></emitter>
    </shape>
"""


def _textured_bsdf(bid: str, texture: str, *, repeat: tuple[float, float] = (1.0, 1.0)) -> str:
    uv = "" if repeat == (1.0, 1.0) else \
        f'<transform name="to_uv"><scale x="{_f(repeat[0])}" y="{_f(repeat[1])}"/></transform>'
    return f"""    <bsdf type="diffuse" id="{bid}">
        <texture type="bitmap" name="reflectance"><string name="filename" value="textures/{texture}.png"/>{uv}</texture>
    </bsdf>
"""


def _rect(sid: str, *, center: tuple[float, float, float], half: tuple[float, float], bsdf_ref: str = "",
          rotate_y_deg: float = 0.0, inner: str = "") -> str:
    rot = f'<rotate y="1" angle="{_f(rotate_y_deg)}"/>' if rotate_y_deg else ""
    ref = f'<ref id="{bsdf_ref}"/>' if bsdf_ref else ""
    return (f"""    <shape type="rectangle" id="{sid}">
        <transform name="to_world"><scale x="{_f(half[0])}" y="{_f(half[1])}"/>{rot}"""
            f"""<translate x="{_f(center[0])}" y="{_f(center[1])}" z="{_f(center[2])}"/></transform>
        {ref}{inner}
    </shape>
""")


def _far_wall() -> str:
    # 10 m away, 4.4 m x 2.8 m: past the 17.5 x 9.9 degree view (and the analysis' 15 % margin) on every side.
    return _textured_bsdf("bricks", "bricks", repeat=(5.0, 3.0)) + \
        _rect("far_wall", center=(0.0, 0.0, -_FAR_ZC), half=(2.2, 1.4), bsdf_ref="bricks")


def _card_from_tan(sid: str, bsdf: str, zc: float, tan_x: tuple[float, float], tan_y: tuple[float, float]) -> str:
    cx, cy = 0.5 * (tan_x[0] + tan_x[1]) * zc, 0.5 * (tan_y[0] + tan_y[1]) * zc
    hx, hy = 0.5 * (tan_x[1] - tan_x[0]) * zc, 0.5 * (tan_y[1] - tan_y[0]) * zc
    return _rect(sid, center=(cx, cy, -zc), half=(hx, hy), bsdf_ref=bsdf)


def _depth_xml() -> str:
    out = [_far_wall()]
    for key in ("mid", "near"):
        d = _DEPTH[key]
        out.append(_textured_bsdf(f"{key}_bsdf", d["texture"]))
        out.append(_card_from_tan(f"{key}_card", f"{key}_bsdf", d["zc"], d["tan_x"], d["tan_y"]))
    return "".join(out)


def _facing(direction: np.ndarray) -> float:
    """Rotation about y (degrees) that turns a rectangle's +z normal to ``direction`` (in the xz plane)."""
    return math.degrees(math.atan2(direction[0], direction[2]))


def _mirror_xml() -> str:
    m = _MIRROR
    r = _reflected_dir(TILT_DEG)
    c = np.array([0.0, 0.0, -m["zc"]])
    n = np.array([math.sin(math.radians(TILT_DEG)), 0.0, math.cos(math.radians(TILT_DEG))])
    frame_c = c - 0.002 * n  # 2 mm behind the glass, 1.4x its size: a border at the mirror's own depth
    poster_c = c + m["poster_distance"] * r
    return "".join([
        _far_wall(),
        '    <bsdf type="conductor" id="mirror_bsdf"/>\n',
        _rect("mirror", center=tuple(c), half=m["half"], bsdf_ref="mirror_bsdf", rotate_y_deg=TILT_DEG),
        _textured_bsdf("frame_bsdf", "frame"),
        _rect("mirror_frame", center=tuple(frame_c), half=(1.4 * m["half"][0], 1.4 * m["half"][1]),
              bsdf_ref="frame_bsdf", rotate_y_deg=TILT_DEG),
        _textured_bsdf("poster_bsdf", "poster"),
        _rect("poster", center=tuple(poster_c), half=m["poster_half"], bsdf_ref="poster_bsdf",
              rotate_y_deg=_facing(-r)),
    ])


def _glass_xml() -> str:
    g = _GLASS
    return "".join([
        _far_wall(),
        _textured_bsdf("card_bsdf", "dots", repeat=g["card_repeat"]),
        _rect("card", center=(0.0, 0.0, -g["card_zc"]), half=g["card_half"], bsdf_ref="card_bsdf"),
        f"""    <shape type="sphere" id="glass_sphere">
        <point name="center" x="0" y="0" z="{_f(-g['center_zc'])}"/><float name="radius" value="{_f(g['radius'])}"/>
        <bsdf type="dielectric"><float name="int_ior" value="{_f(g['ior'])}"/><float name="ext_ior" value="1"/></bsdf>
    </shape>
""",
    ])


def _glossy_xml() -> str:
    g = _GLOSSY
    r = _reflected_dir(TILT_DEG)
    c = np.array([0.0, 0.0, -g["zc"]])
    light = c + g["light_distance"] * r
    return "".join([
        _far_wall(),
        f"""    <bsdf type="roughplastic" id="plate_bsdf">
        <string name="distribution" value="ggx"/><float name="alpha" value="{_f(g['alpha'])}"/>
        <texture type="bitmap" name="diffuse_reflectance">"""
        """<string name="filename" value="textures/checker.png"/></texture>
    </bsdf>
""",
        _rect("glossy_plate", center=tuple(c), half=g["half"], bsdf_ref="plate_bsdf", rotate_y_deg=TILT_DEG),
        f"""    <shape type="sphere" id="light">
        <point name="center" x="{_f(light[0])}" y="{_f(light[1])}" z="{_f(light[2])}"/>"""
        f"""<float name="radius" value="{_f(g['light_radius'])}"/>
        <emitter type="area">"""
        f"""<rgb name="radiance" value="{_f(g['light_radiance'])}, {_f(g['light_radiance'])}, """
        f"""{_f(g['light_radiance'])}"/></emitter>
    </shape>
""",
    ])


_BODIES = {"depth": (_depth_xml, ("bricks", "star", "checker")),
           "mirror": (_mirror_xml, ("bricks", "frame", "poster")),
           "glass": (_glass_xml, ("bricks", "dots")),
           "glossy": (_glossy_xml, ("bricks", "checker"))}


def write_paper_scene(name: str, folder: str | Path, *, fov_x_deg: float | None = None,
                      film_wh: tuple[int, int] = FILM_WH) -> Path:
    """Write the bundle ``name`` (one of :data:`PAPER_SCENES`) into ``folder``: ``scene.xml`` and its PNG
    textures under ``textures/``. ``fov_x_deg``: the camera's horizontal field of view (default the paper
    display's, :func:`paper_fov_x_deg`); the geometry does not move with it. Returns the XML path."""
    if name not in _BODIES:
        raise ValueError(f"unknown paper scene {name!r}; known: {', '.join(PAPER_SCENES)}")
    fov = paper_fov_x_deg() if fov_x_deg is None else float(fov_x_deg)
    if not 0.0 < fov < 180.0:
        raise ValueError(f"fov_x_deg must be in (0, 180), got {fov_x_deg!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    body, textures = _BODIES[name]
    for t in textures:
        _save(_TEXTURES[t](), folder / "textures" / f"{t}.png")
    xml = folder / ENTRY
    xml.write_text(_header(fov, (int(film_wh[0]), int(film_wh[1]))) + body() + "</scene>\n")
    return xml
