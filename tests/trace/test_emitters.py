"""Every emitter kind Mitsuba ships lights the hologram as it lights Mitsuba's own render.

Each scene is written by the test (XML and images in tmp_path, no third-party assets): a white diffuse wall
1 m in front of the eye, lit by one emitter of one kind whose light has only some of the three colors. The
hologram goes through the public :func:`holocore.pipeline.render`, and Mitsuba's ``path`` integrator renders
the same scene file; the colors the scene analysis calls lit, the colors that carry energy in the hologram
and the colors Mitsuba's image shows must be the same three booleans, and the fields must be finite.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions, render

WAVELENGTHS_NM = (640.0, 516.5, 455.4)  # channels 0, 1, 2 (tracer.channel_of)
OPTICS = OpticsConfig(resolution_hw=(32, 32), wavelengths_nm=WAVELENGTHS_NM, frames=1, focal_length_mm=20.0)
OPTIONS = RenderOptions(preset="fast", spp=4)
FILM_PX = 16
MITSUBA_SPP = 16

_WALL = """
    <shape type="rectangle" id="wall">
        <transform name="to_world"><scale x="0.6" y="0.6"/><translate z="-1"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf>
    </shape>"""
# A panel behind the eye (z = +0.5) facing the wall (-z): never in view, it lights the wall head-on.
_PANEL = """
    <shape type="rectangle" id="panel">
        <transform name="to_world"><scale x="0.5" y="0.5"/><rotate y="1" angle="180"/><translate z="0.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        {emitter}
    </shape>"""
_CHECKER_RED = """<texture type="checkerboard" name="{name}">
            <rgb name="color0" value="{c0}"/><rgb name="color1" value="{c1}"/>
            <transform name="to_uv"><scale x="4" y="4"/></transform>
        </texture>"""


def _scene_xml(body: str, *, wall: bool = True) -> str:
    return f"""<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="10"/><string name="fov_axis" value="x"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, 0, -1" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="{FILM_PX}"/><integer name="height" value="{FILM_PX}"/></film>
    </sensor>{_WALL if wall else ""}
    {body}
</scene>
"""


def _write_image(path: Path, rgb: tuple[float, float, float], *, hw: tuple[int, int] = (8, 16)) -> None:
    """A small image of one color, every second pixel dark (a spatially varying texture)."""
    from holocore.runtime.mitsuba_env import mitsuba

    mi = mitsuba()
    img = np.zeros((*hw, 3), dtype=np.float32)
    img[:, :] = np.asarray(rgb, dtype=np.float32)
    img[::2, ::2] *= 0.25
    mi.Bitmap(img).write(str(path))


def _area(radiance: str) -> str:
    return _PANEL.format(emitter=f'<emitter type="area">{radiance}</emitter>')


# kind -> (scene body, the files it needs: name -> rgb of the image, the colors its light carries)
CASES: dict[str, tuple[str, dict[str, tuple[float, float, float]], tuple[bool, bool, bool]]] = {
    "area-rgb": (_area('<rgb name="radiance" value="0, 3, 0"/>'), {}, (False, True, False)),
    "area-bitmap": (_area('<texture type="bitmap" name="radiance"><string name="filename" value="glow.exr"/>'
                          '</texture>'), {"glow.exr": (0.0, 0.0, 4.0)}, (False, False, True)),
    "area-checkerboard": (_area(_CHECKER_RED.format(name="radiance", c0="0.2, 0, 0", c1="0.05, 0, 0")), {},
                          (True, False, False)),
    "point": ("""<emitter type="point"><point name="position" x="0" y="0.2" z="0.2"/>
        <rgb name="intensity" value="2, 0, 2"/></emitter>""", {}, (True, False, True)),
    "spot": ("""<emitter type="spot"><float name="cutoff_angle" value="30"/>
        <transform name="to_world"><lookat origin="0, 0.2, 0.3" target="0, 0, -1" up="0, 1, 0"/></transform>
        <rgb name="intensity" value="0, 3, 3"/></emitter>""", {}, (False, True, True)),
    "spot-texture": ("""<emitter type="spot"><float name="cutoff_angle" value="30"/>
        <transform name="to_world"><lookat origin="0, 0.2, 0.3" target="0, 0, -1" up="0, 1, 0"/></transform>
        """ + _CHECKER_RED.format(name="texture", c0="1, 0, 0", c1="0.3, 0, 0") + "</emitter>", {},
                     (True, False, False)),
    "directional": ("""<emitter type="directional"><vector name="direction" x="0" y="-0.3" z="-1"/>
        <rgb name="irradiance" value="1, 1, 0"/></emitter>""", {}, (True, True, False)),
    "envmap": ("""<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>""",
               {"sky.exr": (0.0, 0.5, 0.0)}, (False, True, False)),
    "constant": ("""<emitter type="constant"><rgb name="radiance" value="0, 0, 0.5"/></emitter>""", {},
                 (False, False, True)),
    "projector": ("""<emitter type="projector"><float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 0.3" target="0, 0, -1" up="0, 1, 0"/></transform>
        <texture type="bitmap" name="irradiance"><string name="filename" value="slide.exr"/></texture>
        </emitter>""", {"slide.exr": (3.0, 0.0, 0.0)}, (True, False, False)),
    # Emits along the panel's normal only: a path tracer never connects to it (Mitsuba's docs: particle tracer
    # only), so Mitsuba's path shows the wall dark, and so must the hologram be: black, not an error.
    "directionalarea": (_PANEL.format(emitter='<emitter type="directionalarea">'
                                              '<rgb name="radiance" value="0, 2, 0"/></emitter>'), {},
                        (False, False, False)),
}


def _write_case(folder: Path, kind: str) -> Path:
    body, images, _colors = CASES[kind]
    folder.mkdir(parents=True, exist_ok=True)
    for name, rgb in images.items():
        _write_image(folder / name, rgb)
    xml = folder / "scene.xml"
    xml.write_text(_scene_xml(body))
    return xml


def _mitsuba_lit(xml: Path) -> tuple[bool, bool, bool]:
    """Which RGB channels Mitsuba's own path tracer shows light in."""
    from holocore.runtime.mitsuba_env import mitsuba

    mi = mitsuba()
    scene = mi.load_file(str(xml))
    img = np.asarray(mi.render(scene, integrator=mi.load_dict({"type": "path", "max_depth": 6}),
                               spp=MITSUBA_SPP, seed=1), dtype=np.float64)
    assert np.isfinite(img).all()
    energy = img[..., :3].reshape(-1, 3).sum(axis=0)
    return tuple(bool(e > 0) for e in energy)


def _channel_energy(field: np.ndarray) -> np.ndarray:
    """|U|^2 summed over frames and pixels, per color: [C]."""
    return (np.abs(field.astype(np.complex128)) ** 2).sum(axis=(0, 2, 3))


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(CASES))
def test_every_emitter_kind_lights_the_hologram_like_mitsubas_render(kind: str, tmp_path: Path) -> None:
    xml = _write_case(tmp_path / kind, kind)
    expected = CASES[kind][2]
    assert _mitsuba_lit(xml) == expected, "the test scene does not show the colors it was built to show"

    res = render(tmp_path / kind, OPTICS, OPTIONS)
    assert np.isfinite(res.wrp_field).all() and np.isfinite(res.slm_field).all()
    assert tuple(res.meta["analysis"]["colors_lit"]) == expected
    assert tuple(res.meta["plan"]["colors_lit"]) == expected
    wrp, slm = _channel_energy(res.wrp_field), _channel_energy(res.slm_field)
    for c, lit in enumerate(expected):
        if lit:
            assert wrp[c] > 0 and slm[c] > 0, f"channel {c} carries light in Mitsuba's render, none in the hologram"
        else:
            assert wrp[c] == 0 and slm[c] == 0, f"channel {c} is dark in Mitsuba's render, lit in the hologram"
    assert res.meta["stats"]["valid"] > 0 or not any(expected)


@pytest.mark.slow
def test_a_textured_area_light_in_view_is_imaged(tmp_path: Path) -> None:
    """The case of the issue: the emitter seen directly has a red-only checkerboard radiance; the hologram
    images its squares (red only) and the analysis no longer raises Texture::sample_spectrum()."""
    body = f"""<shape type="rectangle">
        <transform name="to_world"><scale x="0.6" y="0.6"/><translate z="-1"/></transform>
        <emitter type="area">{_CHECKER_RED.format(name="radiance", c0="0.2, 0, 0", c1="0.05, 0, 0")}</emitter>
    </shape>"""
    folder = tmp_path / "glow"
    folder.mkdir()
    (folder / "scene.xml").write_text(_scene_xml(body, wall=False))
    assert _mitsuba_lit(folder / "scene.xml") == (True, False, False)
    res = render(folder, OPTICS, OPTIONS)
    assert res.meta["analysis"]["colors_lit"] == [True, False, False]
    wrp = _channel_energy(res.wrp_field)
    assert wrp[0] > 0 and wrp[1] == 0 and wrp[2] == 0
    # Every ray reaches the glowing plane: an image point 1 m away on each, nothing escapes.
    assert res.meta["stats"]["escaped"] == 0
    assert res.meta["stats"]["valid"] == res.meta["stats"]["rays"]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["point", "area-checkerboard"])
def test_field_amplitude_goes_as_the_square_root_of_the_emitted_power(kind: str, tmp_path: Path) -> None:
    """Four times the emitter's intensity: the same paths carry four times the radiance, so every sample's
    amplitude (sqrt of radiance) doubles and the field's energy is four times larger."""
    body, _images, _colors = CASES[kind]
    brighter = body.replace('value="2, 0, 2"', 'value="8, 0, 8"').replace(
        'name="color0" value="0.2, 0, 0"/><rgb name="color1" value="0.05, 0, 0"',
        'name="color0" value="0.8, 0, 0"/><rgb name="color1" value="0.2, 0, 0"')
    assert brighter != body
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "scene.xml").write_text(_scene_xml(body))
    (tmp_path / "b" / "scene.xml").write_text(_scene_xml(brighter))
    e1 = _channel_energy(render(tmp_path / "a", OPTICS, OPTIONS).wrp_field)
    e4 = _channel_energy(render(tmp_path / "b", OPTICS, OPTIONS).wrp_field)
    lit = e1 > 0
    assert lit[0]
    np.testing.assert_allclose(e4[lit] / e1[lit], 4.0, rtol=1e-3)
