"""Absorbing media (docs/physics.md, "Absorbing media"): a homogeneous medium with albedo 0 attenuates every
path segment inside it by Beer-Lambert, exp(-sigma_t d) in intensity per colour, along delta chains, from P
on, and on shadow rays; a scattering or heterogeneous medium is refused in one line naming where it sits."""

from __future__ import annotations

import numpy as np
import pytest

from tests.trace.scenes import T, camera, emitting_plane

SIGMA = (20.0, 8.0, 2.0)  # 1/m per colour, given as rgb (1, 0.4, 0.1) x scale 20
THICK = 0.05  # m: the slab's thickness
IOR = 1.5


def _medium(sigma=SIGMA, albedo: float = 0.0) -> dict:
    top = max(sigma)
    return {"type": "homogeneous", "albedo": albedo, "scale": top,
            "sigma_t": {"type": "rgb", "value": [s / top for s in sigma]}}


def _slab(sigma=SIGMA, **medium_kw) -> dict:
    slab = {"type": "cube", "to_world": T().translate([0, 0, -0.3]).scale([0.1, 0.1, THICK / 2]),
            "bsdf": {"type": "dielectric", "int_ior": IOR}}
    if sigma is not None:
        slab["interior"] = _medium(sigma, **medium_kw)
    return slab


def _mi_scene(sensor=None, **shapes):
    from holocore.runtime.mitsuba_env import mitsuba

    return mitsuba().load_dict({"type": "scene", "sensor": sensor or camera(fov=10), **shapes})


def _trace(scene, n: int = 20000, half_tan: float = 0.05, seed: int = 0):
    """Rays from the origin into -z within +-half_tan: (unit directions [n, 3], valid, n_delta, radiance [n, 3])."""
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.trace.kernel import trace_wave_paths
    from holocore.trace.reference_chain import aligned

    mi = mitsuba()
    rng = np.random.default_rng(seed)
    v = np.stack([(rng.random(n) * 2 - 1) * half_tan, (rng.random(n) * 2 - 1) * half_tan, -np.ones(n)], axis=1)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed + 1, n)
    wp = trace_wave_paths(scene, mi.Point3d(*[mi.Float64(aligned(np.zeros(n), np.float64)) for _ in range(3)]),
                          mi.Vector3d(*[mi.Float64(aligned(v[:, i], np.float64)) for i in range(3)]), sampler,
                          max_delta=8, max_depth=6)
    L = np.stack([np.asarray(wp.radiance[c], dtype=np.float64) for c in range(3)], axis=1)
    return v, np.asarray(wp.valid).astype(bool), np.asarray(wp.n_delta).astype(int), L


@pytest.mark.parametrize("sigma", [SIGMA, (20.0, 5.0, 0.0)])
def test_a_slab_attenuates_each_colour_by_beer_lambert(sigma):
    # An emitter of radiance 1 behind a tinted slab: a ray straight through (two refractions, n_delta = 2)
    # carries exp(-sigma_t t / cos(theta_in)) per colour, whatever the random numbers (the dielectric's lobe
    # weights are 1); a colour with sigma_t = 0 passes untouched.
    v, valid, nd, L = _trace(_mi_scene(slab=_slab(sigma), plane=emitting_plane(-0.6, size=1.0)))
    through = valid & (nd == 2)
    assert through.mean() > 0.85 and np.isfinite(L).all()
    sin_in = np.sqrt(1 - v[:, 2] ** 2) / IOR
    expect = np.exp(-np.array(sigma)[None] * THICK / np.sqrt(1 - sin_in ** 2)[:, None])
    np.testing.assert_allclose(L[through], expect[through], rtol=2e-5)
    # the paths reflected inside the slab (n_delta = 4) cross it three times
    inner = valid & (nd == 4)
    assert inner.any()
    np.testing.assert_allclose(L[inner], expect[inner] ** 3, rtol=1e-4)


def test_a_camera_inside_an_absorbing_medium_sees_through_it():
    # The sensor's own medium (an underwater camera): the segment to the emitter 0.6 m away is absorbed.
    from holocore.runtime.mitsuba_env import mitsuba

    sensor = dict(camera(fov=10), medium=mitsuba().load_dict(_medium((2.0, 1.0, 0.5))))
    v, valid, nd, L = _trace(_mi_scene(sensor=sensor, plane=emitting_plane(-0.6, size=1.0)), n=4000)
    assert valid.all() and (nd == 0).all()
    dist = 0.6 / -v[:, 2]
    np.testing.assert_allclose(L, np.exp(-np.array([2.0, 1.0, 0.5])[None] * dist[:, None]), rtol=2e-5)


def test_the_transmitted_colour_is_mitsubas_volpath():
    # Mitsuba's volpath on the same scene and view: the mean colour of the image (light through the slab and
    # beside it) agrees per colour within 1 % (measured 0.3 % at this film, as at 320 x 240); Mitsuba's path,
    # which ignores media, does not.
    from holocore.runtime.mitsuba_env import mitsuba

    mi = mitsuba()
    # a 160 x 120 film (not the default 768 x 576): every pixel sees the emitter through the slab, and 1.2 M
    # samples per render leave the mean colour's noise far under the 1 % it is held to
    sensor = dict(camera(fov=10), film={"type": "hdrfilm", "width": 160, "height": 120})
    sc = _mi_scene(sensor=sensor, slab=_slab(), plane=emitting_plane(-0.6, size=1.0))
    # the camera's 10 deg view is tan = 0.0875 half-width; the rays below cover it uniformly in tangent
    _v, valid, _nd, L = _trace(sc, n=40000, half_tan=np.tan(np.radians(5.0)))
    ours = L.mean(axis=0)
    for kind, agree in (("volpath", True), ("path", False)):
        img = np.asarray(mi.render(sc, integrator=mi.load_dict({"type": kind, "max_depth": 8}), spp=64, seed=1),
                         dtype=np.float64)[..., :3].reshape(-1, 3).mean(axis=0)
        assert (np.max(np.abs(ours / img - 1)) < 0.01) == agree, (kind, ours, img)


def test_the_whole_render_carries_the_absorption_and_says_so():
    # End to end at a small display: the WRP's energy per colour is the slab's transmittance times the
    # energy without the medium, and the plan names the medium and its sigma_t.
    from holocore.display.optics import OpticsConfig
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.load import from_mitsuba_scene
    from tests.trace.optics_probe import fov_deg

    opt = OpticsConfig(resolution_hw=(48, 64), pitch_um=8.0, frames=2, focal_length_mm=50.0)
    sensor = camera(fov=fov_deg(64, 8e-6, 0.05))
    energy, summary = [], []
    for sigma in (None, SIGMA):
        sc = from_mitsuba_scene(_mi_scene(sensor=sensor, slab=_slab(sigma), plane=emitting_plane(-0.6, size=1.0)))
        res = render_loaded(sc, opt, RenderOptions(preset="fast", spp=64))
        assert np.isfinite(res.wrp_field).all() and np.isfinite(res.slm_field).all()
        energy.append((np.abs(res.wrp_field.astype(np.complex128)) ** 2).sum(axis=(0, 2, 3)))
        summary.append(" ".join(res.meta["plan"]["summary"]))
    np.testing.assert_allclose(energy[1] / energy[0], np.exp(-np.array(SIGMA) * THICK), rtol=5e-3)
    assert "absorbing medium" not in summary[0]
    assert "absorbing medium in slab (interior): sigma_t = (20, 8, 2) /m" in summary[1]


def test_a_scattering_medium_is_refused_naming_its_shape():
    from holocore.scene.load import SceneLoadError, from_mitsuba_scene

    with pytest.raises(SceneLoadError) as err:
        from_mitsuba_scene(_mi_scene(slab=_slab(albedo=0.5), plane=emitting_plane(-0.6)), name="fog")
    msg = str(err.value)
    assert "'slab' (interior)" in msg and "albedo" in msg and "\n" not in msg


def test_a_heterogeneous_medium_is_refused_before_parsing():
    from holocore.scene.load import unsupported_reason

    assert unsupported_reason(["shape:cube", "medium:homogeneous", "phase:isotropic"]) is None
    why = unsupported_reason(["shape:cube", "medium:heterogeneous", "volume:gridvolume"])
    assert why is not None and "heterogeneous" in why and "homogeneous" in why


def test_nested_media_switch_at_each_boundary():
    # A tinted ball (sigma_b) inside a tank of another medium (sigma_a), both behind index-matched (null)
    # boundaries: a ray along the axis crosses 0.1 m of tank and the ball's 0.1 m diameter.
    sigma_a, sigma_b = (4.0, 2.0, 1.0), (1.0, 6.0, 3.0)
    tank = {"type": "cube", "to_world": T().translate([0, 0, -0.4]).scale([0.2, 0.2, 0.1]),
            "bsdf": {"type": "null"}, "interior": _medium(sigma_a)}
    ball = {"type": "sphere", "center": [0, 0, -0.4], "radius": 0.05, "bsdf": {"type": "null"},
            "interior": _medium(sigma_b), "exterior": _medium(sigma_a)}
    _v, valid, _nd, L = _trace(_mi_scene(tank=tank, ball=ball, plane=emitting_plane(-0.6, size=1.0)), n=256,
                               half_tan=1e-5)
    assert valid.all()
    expect = np.exp(-0.1 * (np.array(sigma_a) + np.array(sigma_b)))
    np.testing.assert_allclose(L, np.broadcast_to(expect, L.shape), rtol=2e-4)


def test_ground_truth_and_reference_renders_see_the_medium():
    # The evaluation's ground truth (and the baselines) render with Mitsuba's volpath where a scene holds
    # media: its centre, seen through the slab, has the slab's colour; path would show it clear.
    from holocore.evaluate.groundtruth import render_ground_truth
    from holocore.scene.features import reference_integrator

    centre = []
    for sigma in (None, SIGMA):
        sc = _mi_scene(slab=_slab(sigma), plane=emitting_plane(-0.6, size=1.0))
        M = np.array(sc.sensors()[0].world_transform().matrix, dtype=np.float64).reshape(4, 4)
        img = render_ground_truth(sc, sensor_to_world=M, focal_length_m=0.05, z_inf_m=0.08, pitch_m=8e-6,
                                  shape_hw=(16, 16), focus_z_m=0.0849, pupil_diameter_m=1e-3, spp=256, seed=3)
        centre.append(img[:, 4:12, 4:12].reshape(3, -1).mean(axis=1))
    np.testing.assert_allclose(centre[1] / centre[0], np.exp(-np.array(SIGMA) * THICK), rtol=0.02)
    assert reference_integrator(_mi_scene(plane=emitting_plane(-0.6)), max_depth=4)["type"] == "path"
    with pytest.raises(ValueError, match="sigma_t = 0 in a colour"):
        reference_integrator(_mi_scene(slab=_slab((20.0, 5.0, 0.0)), plane=emitting_plane(-0.6)), max_depth=4)
