"""Every plugin the bundle allow-list admits either renders a finite, lit hologram or is refused in one clear
line. One generated scene per plugin (a sphere, its light and its camera, plus the files the
plugin reads, all written here), through the public path a user takes: the bundle check, Mitsuba, the plan and a
32x32 render (two scenes at a time, in worker processes). The refused set is pinned, so a plugin that starts or
stops working fails the test."""

from __future__ import annotations

import multiprocessing
import struct
import zlib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from holocore.scene.bundle import ALLOWED_PLUGINS

CAMERA = ('<sensor type="perspective"><float name="fov" value="17.5"/><transform name="to_world">'
          '<lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>{film}</sensor>')
SMALL_FILM = '<film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>'
# An area light behind the camera: the background stays black, so a lit hologram means the plugin under test
# sent light to the eye.
LIGHT = ('<shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate y="1" angle="180"/>'
         '<translate z="6"/></transform><emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>')
TEX = '<texture type="bitmap" name="{name}"><string name="filename" value="tex.png"/></texture>'


def sphere(bsdf: str = '<bsdf type="diffuse"/>') -> str:
    return f'<shape type="sphere">{bsdf}</shape>'


# (tag, type) -> scene body (camera and light added unless the body brings its own "<sensor" / "<emitter")
BODIES: dict[tuple[str, str], str] = {}
for b in ("diffuse", "dielectric", "thindielectric", "roughdielectric", "conductor", "roughconductor", "plastic",
          "roughplastic", "principled", "principledthin", "hair", "pplastic", "polarizer", "retarder", "circular",
          "null"):
    BODIES[("bsdf", b)] = sphere(f'<bsdf type="{b}"/>')
BODIES[("bsdf", "twosided")] = sphere('<bsdf type="twosided"><bsdf type="diffuse"/></bsdf>')
BODIES[("bsdf", "blendbsdf")] = sphere('<bsdf type="blendbsdf"><float name="weight" value="0.3"/>'
                                       '<bsdf type="diffuse"/><bsdf type="conductor"/></bsdf>')
BODIES[("bsdf", "mask")] = sphere('<bsdf type="mask"><float name="opacity" value="0.5"/><bsdf type="diffuse"/>'
                                  '</bsdf>')
BODIES[("bsdf", "bumpmap")] = sphere(f'<bsdf type="bumpmap">{TEX.format(name="arbitrary")}<bsdf type="diffuse"/>'
                                     '</bsdf>')
BODIES[("bsdf", "normalmap")] = sphere(f'<bsdf type="normalmap">{TEX.format(name="normalmap")}'
                                       '<bsdf type="diffuse"/></bsdf>')
BODIES[("bsdf", "measured")] = sphere('<bsdf type="measured"><string name="filename" value="brdf.bsdf"/></bsdf>')
for s in ("sphere", "rectangle", "disk", "cylinder", "cube"):
    BODIES[("shape", s)] = f'<shape type="{s}"><bsdf type="diffuse"/></shape>'
for s, f in (("obj", "m.obj"), ("ply", "m.ply"), ("serialized", "m.serialized")):
    BODIES[("shape", s)] = f'<shape type="{s}"><string name="filename" value="{f}"/></shape>'
BODIES[("shape", "shapegroup")] = ('<shape type="shapegroup" id="g"><shape type="sphere"/></shape>'
                                   '<shape type="instance"><ref id="g"/></shape>')
BODIES[("shape", "instance")] = BODIES[("shape", "shapegroup")]
BODIES[("shape", "linearcurve")] = '<shape type="linearcurve"><string name="filename" value="curve.txt"/></shape>'
BODIES[("shape", "bsplinecurve")] = '<shape type="bsplinecurve"><string name="filename" value="curve.txt"/></shape>'
BODIES[("shape", "sdfgrid")] = '<shape type="sdfgrid"><string name="filename" value="sdf.vol"/></shape>'
BODIES[("shape", "ellipsoids")] = '<shape type="ellipsoids"><string name="filename" value="e.ply"/></shape>'
BODIES[("shape", "ellipsoidsmesh")] = '<shape type="ellipsoidsmesh"><string name="filename" value="e.ply"/></shape>'
BODIES[("emitter", "area")] = LIGHT + sphere()
BODIES[("emitter", "directionalarea")] = BODIES[("emitter", "area")].replace('"area"', '"directionalarea"')
for e, extra in (("point", '<point name="position" value="0,0,3"/><rgb name="intensity" value="20"/>'),
                 ("spot", '<transform name="to_world"><lookat origin="0,0,3" target="0,0,0"/></transform>'
                          '<rgb name="intensity" value="20"/>'),
                 ("directional", '<vector name="direction" value="0,0,-1"/>'),
                 ("constant", '<rgb name="radiance" value="1"/>'), ("envmap", '<string name="filename" value="tex.png"/>'),
                 ("projector", '<transform name="to_world"><lookat origin="0,0,3" target="0,0,0"/></transform>'
                               + TEX.format(name="irradiance"))):
    BODIES[("emitter", e)] = f'<emitter type="{e}">{extra}</emitter>' + sphere()
BODIES[("spectrum", "d65")] = ('<emitter type="constant"><spectrum type="d65" name="radiance"/></emitter>'
                               + sphere())  # an illuminant: Mitsuba's RGB modes take it for emitters only
BODIES[("texture", "bitmap")] = sphere(f'<bsdf type="diffuse">{TEX.format(name="reflectance")}</bsdf>')
BODIES[("texture", "checkerboard")] = sphere('<bsdf type="diffuse"><texture type="checkerboard" '
                                             'name="reflectance"/></bsdf>')
BODIES[("texture", "mesh_attribute")] = ('<shape type="ply"><string name="filename" value="colored.ply"/>'
                                         '<bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance">'
                                         '<string name="name" value="vertex_color"/></texture></bsdf></shape>')
BODIES[("texture", "volume")] = sphere('<bsdf type="diffuse"><texture type="volume" name="reflectance">'
                                       '<volume type="constvolume" name="volume"><rgb name="value" value="0.5"/>'
                                       '</volume></texture></bsdf>')
for s in ("perspective", "thinlens", "orthographic", "radiancemeter", "irradiancemeter", "batch"):
    inner = {"thinlens": '<float name="fov" value="17.5"/><float name="aperture_radius" value="0.01"/>'
                         '<float name="focus_distance" value="4"/>', "perspective": '<float name="fov" value="17.5"/>',
             "batch": '<sensor type="perspective"><float name="fov" value="17.5"/></sensor>'}.get(s, "")
    BODIES[("sensor", s)] = (f'<sensor type="{s}">{inner}<transform name="to_world"><lookat origin="0,0,4" '
                             'target="0,0,0" up="0,1,0"/></transform></sensor>' + sphere())
for f in ("hdrfilm", "specfilm"):
    BODIES[("film", f)] = "FILM:" + f'<film type="{f}"><integer name="width" value="32"/>' \
                                    f'<integer name="height" value="32"/></film>'
for r in sorted(ALLOWED_PLUGINS["rfilter"]):
    BODIES[("rfilter", r)] = (f'FILM:<film type="hdrfilm"><integer name="width" value="32"/><integer name="height" '
                              f'value="32"/><rfilter type="{r}"/></film>')
for s in sorted(ALLOWED_PLUGINS["sampler"]):
    BODIES[("sampler", s)] = f'FILM:{SMALL_FILM}<sampler type="{s}"/>'
for i in sorted(ALLOWED_PLUGINS["integrator"]):
    BODIES[("integrator", i)] = f'<integrator type="{i}"/>' + sphere()
# An absorbing homogeneous medium (albedo 0) is simulated (Beer-Lambert); the phase functions' media keep
# Mitsuba's default albedo (0.75), which scatters, and a heterogeneous one is refused.
for m, albedo in (("homogeneous", '<float name="albedo" value="0"/>'), ("heterogeneous", "")):
    BODIES[("medium", m)] = (f'<medium type="{m}" id="fog"><rgb name="sigma_t" value="0.1"/>{albedo}</medium>'
                             '<shape type="sphere"><ref name="interior" id="fog"/><bsdf type="null"/></shape>')
PHASE_PARAMS = {"blendphase": '<float name="weight" value="0.5"/><phase type="isotropic"/><phase type="hg"/>',
                "tabphase": '<string name="values" value="0.5, 1.0, 1.5"/>',
                "sggx": '<volume type="constvolume" name="S"><float name="value" value="1"/></volume>'}
for p in ("isotropic", "hg", "rayleigh", "blendphase", "tabphase", "sggx"):
    BODIES[("phase", p)] = (f'<medium type="homogeneous" id="fog"><phase type="{p}">{PHASE_PARAMS.get(p, "")}'
                            '</phase></medium>'
                            '<shape type="sphere"><ref name="interior" id="fog"/><bsdf type="null"/></shape>')
for v in ("constvolume", "gridvolume"):
    BODIES[("volume", v)] = ('<medium type="heterogeneous" id="fog"><volume type="' + v + '" name="sigma_t">'
                             + ('<string name="filename" value="sdf.vol"/>' if v == "gridvolume" else "")
                             + '</volume></medium><shape type="sphere"><ref name="interior" id="fog"/>'
                               '<bsdf type="null"/></shape>')
for s, inner in (("uniform", '<float name="value" value="0.5"/>'),
                 ("regular", '<float name="wavelength_min" value="400"/><float name="wavelength_max" value="700"/>'
                             '<string name="values" value="0.2, 0.8"/>'),
                 ("irregular", '<string name="wavelengths" value="400, 700"/><string name="values" value="0.2, 0.8"/>'),
                 ("blackbody", '<float name="temperature" value="5000"/>'), ("srgb", "")):
    if s == "srgb":
        inner = '<rgb name="color" value="0.8, 0.3, 0.1"/>'
    BODIES[("spectrum", s)] = sphere(f'<bsdf type="diffuse"><spectrum type="{s}" name="reflectance">{inner}'
                                     '</spectrum></bsdf>')

# What is refused, and the words that say why (the user's fix is in the message).
REFUSED = {
    ("shape", "ellipsoids"): "Gaussian ellipsoid", ("shape", "ellipsoidsmesh"): "Gaussian ellipsoid",
    ("sensor", "orthographic"): "perspective sensor", ("sensor", "radiancemeter"): "perspective sensor",
    ("sensor", "irradiancemeter"): "perspective sensor", ("sensor", "batch"): "perspective sensor",
    ("film", "specfilm"): "specfilm", **{("spectrum", t): "spectral Mitsuba variant" for t in ("blackbody", "regular", "irregular")},
    ("medium", "heterogeneous"): "only when homogeneous",
    **{("phase", p): "scatters (albedo > 0)" for p in ("isotropic", "hg", "rayleigh", "blendphase", "tabphase")},
    ("phase", "sggx"): "cannot be evaluated",  # its S is a 6-channel volume; a constvolume has one
    **{("volume", v): "only when homogeneous" for v in ("constvolume", "gridvolume")},
}
# Plugins whose input data the project cannot make (measured BSDFs are RGL tensor measurements): only the bundle
# check is exercised, with a tensor file.
CHECK_ONLY = {("bsdf", "measured")}



def _png(path: Path) -> None:
    from PIL import Image

    y, x = np.mgrid[0:16, 0:16]
    img = np.stack([(x * 16) % 256, (y * 16) % 256, ((x ^ y) & 1) * 255], -1).astype(np.uint8)
    Image.fromarray(img).save(path)


def _serialized(path: Path, v: np.ndarray, f: np.ndarray) -> None:
    """Mitsuba's serialized mesh format, version 4: header, a zlib stream of one mesh, the dictionary."""
    body = struct.pack("<I", 0x1000) + b"mesh\0" + struct.pack("<QQ", len(v), len(f))  # 0x1000: float32
    body += v.astype("<f4").tobytes() + f.astype("<u4").tobytes()
    data = struct.pack("<HH", 0x041C, 4) + zlib.compress(body)
    path.write_bytes(data + struct.pack("<QI", 0, 1))


def _vol(path: Path, n: int = 8) -> None:
    """A Mitsuba VOL grid (float32, 1 channel): a signed distance to a sphere of radius 0.4 in the unit cube."""
    z, y, x = np.mgrid[0:n, 0:n, 0:n] / (n - 1) - 0.5
    d = (np.sqrt(x * x + y * y + z * z) - 0.4).astype("<f4")
    head = b"VOL" + bytes([3]) + struct.pack("<iiiii", 1, n, n, n, 1) + struct.pack("<6f", 0, 0, 0, 1, 1, 1)
    path.write_bytes(head + d.tobytes())


def _write(root: Path, key: tuple[str, str]) -> Path:
    root.mkdir(parents=True)
    body = BODIES[key]
    film = SMALL_FILM
    if body.startswith("FILM:"):
        film, body = body[5:], sphere()
    if "<sensor" not in body:
        body = CAMERA.format(film=film) + body
    if "<emitter" not in body:
        body = LIGHT + body
    (root / "scene.xml").write_text(f'<scene version="3.0.0">{body}</scene>')
    tri = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], float)
    (root / "m.obj").write_text("v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n")
    head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    (root / "m.ply").write_text(head + "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                                "-1 -1 0\n1 -1 0\n0 1 0\n3 0 1 2\n")
    (root / "colored.ply").write_text(head.replace("property float z\n", "property float z\nproperty uchar red\n"
                                                   "property uchar green\nproperty uchar blue\n")
                                      + "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                                        "-1 -1 0 255 0 0\n1 -1 0 0 255 0\n0 1 0 0 0 255\n3 0 1 2\n")
    _serialized(root / "m.serialized", tri, np.array([[0, 1, 2]]))
    (root / "curve.txt").write_text("-0.5 0 0 0.05\n-0.2 0.3 0 0.05\n0.2 -0.3 0 0.05\n0.5 0 0 0.05\n")
    _vol(root / "sdf.vol")
    (root / "e.ply").write_text((root / "m.ply").read_text())
    (root / "brdf.bsdf").write_bytes(b"tensor_file\0" + bytes([1, 0]) + struct.pack("<I", 0))
    _png(root / "tex.png")
    return root


def _one_line(msg: str) -> bool:
    return bool(msg) and "\n" not in msg and "Traceback" not in msg and len(msg) <= 600


def _outcome(root: str) -> tuple:
    """Runs in a worker process: ("refused", message) for a ValueError (BundleError and SceneLoadError are
    ValueErrors: the CLI prints them in one line), else ("rendered", all fields finite, the hologram's light per
    channel, Mitsuba's path render's light per channel)."""
    from holocore.display.optics import OpticsConfig
    from holocore.pipeline import RenderOptions, render

    try:
        # the hologram sees the camera's view (fitted f), so it can be compared with Mitsuba's render of it
        result = render(Path(root), OpticsConfig(resolution_hw=(32, 32), frames=1, fit_camera_fov=True),
                        RenderOptions(preset="fast", spp=4))
    except ValueError as exc:
        return ("refused", str(exc))
    finite = all(np.isfinite(np.asarray(getattr(result, n))).all() for n in ("slm_field", "wrp_field"))
    holo = np.sum(np.abs(np.asarray(result.slm_field)) ** 2, axis=(0, 2, 3))
    return ("rendered", finite, holo, _mitsuba_path(Path(root)))


@pytest.fixture(scope="module")
def renders(request, tmp_path_factory):
    """(tag, type) -> (bundle dir, future of :func:`_outcome`) for the plugins selected to run. Two worker
    processes: each plugin's scene compiles its own kernels (seconds, one core each), most of the sweep's time."""
    base = tmp_path_factory.mktemp("sweep")
    chosen = {item.callspec.params["key"] for item in request.session.items
              if getattr(item, "originalname", "") == "test_every_admitted_plugin_renders_or_is_refused_clearly"}
    roots = {key: _write(base / f"{key[0]}-{key[1]}", key) for key in sorted(chosen)}
    with ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {key: pool.submit(_outcome, str(root)) for key, root in roots.items() if key not in CHECK_ONLY}
        yield {key: (root, futures.get(key)) for key, root in roots.items()}
        for f in futures.values():
            f.cancel()


@pytest.mark.slow  # one render per admitted plugin; tests/trace/test_emitters.py and test_hard_cases.py render the kinds
@pytest.mark.parametrize("key", sorted(BODIES), ids=lambda k: f"{k[0]}-{k[1]}")
def test_every_admitted_plugin_renders_or_is_refused_clearly(renders, key):
    from holocore.scene.bundle import validate_bundle

    root, future = renders[key]
    report = validate_bundle(root)  # every admitted plugin passes the bundle check itself
    assert f"{key[0]}:{key[1]}" in report.plugins or key[0] == "integrator"
    if key in CHECK_ONLY:
        return
    outcome = future.result(timeout=600)
    if outcome[0] == "refused":
        msg = outcome[1]
        assert key in REFUSED, f"{key} refused unexpectedly: {msg}"
        assert REFUSED[key] in msg and _one_line(msg), msg
        return
    assert key not in REFUSED, f"{key} rendered, but the test expects a refusal ({REFUSED[key]!r})"
    _, finite, holo, ref = outcome
    assert finite, key
    # lit in the colors Mitsuba's own path tracer shows light in, and dark where it shows none
    assert list(holo > 0) == list(ref > 1e-3 * max(float(ref.max()), 1e-30)), (key, holo, ref)


def _mitsuba_path(root: Path) -> np.ndarray:
    """Per-channel sum of Mitsuba's path render (64 spp, depth 8) of the scene's own camera view."""
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.scene.load import load_scene

    mi = mitsuba()
    img = np.array(mi.render(load_scene(root).scene, spp=64, integrator=mi.load_dict({"type": "path",
                                                                                       "max_depth": 8})))
    return np.nan_to_num(img[..., :3]).clip(min=0).sum(axis=(0, 1))


def test_the_sweep_covers_the_whole_allow_list():
    admitted = {(tag, t) for tag, types in ALLOWED_PLUGINS.items() for t in types}
    assert admitted == set(BODIES), sorted(admitted ^ set(BODIES))
