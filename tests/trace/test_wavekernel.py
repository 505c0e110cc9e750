"""The fused wave-path kernel against the reference implementation (first hit, delta chain, then Mitsuba's
``path`` from the last chain vertex) on the cbox with its mirror and glass spheres: the project's own
(holocore.scene.demo.write_cbox_scene) and ../shared's (the cases whose id says shared)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.project_scenes import SCENE_SOURCES

pytestmark = pytest.mark.slow  # millions of rays against the reference chain; tests/trace/test_sphere_pole.py runs both on few rays

R = 128 * 128 * 32  # a 128 x 128 image, 32 rays a pixel


@pytest.fixture(scope="module", params=SCENE_SOURCES)
def both(request, bundles_of):
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.scene.load import load_scene
    from holocore.trace.kernel import trace_wave_paths
    from holocore.trace.reference_chain import aligned, trace_chain

    mi = mitsuba()
    loaded = load_scene(bundles_of(request.param).entry("cbox-mirror-glass"))
    M = np.array(loaded.sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
    rng = np.random.default_rng(0)
    tan = math.tan(math.radians(loaded.fov_x_deg) / 2)
    n = 128
    pix = np.repeat(np.arange(n * n), R // (n * n))  # pixel-major, as the tracer orders them
    x = ((pix % n + rng.random(R)) / n * 2 - 1) * tan
    y = ((pix // n + rng.random(R)) / n * 2 - 1) * tan
    d = np.stack([x, -y, np.ones(R)], axis=1) @ M[:3, :3].T
    v = d / np.linalg.norm(d, axis=1, keepdims=True)
    o = np.repeat(M[:3, 3][None], R, axis=0)
    integ = mi.load_dict({"type": "path", "max_depth": 6})
    ref = trace_chain(loaded.scene, o, v, max_delta=8, amp_spp=1, integrator=integ, seed=1)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(1, R)
    wp = trace_wave_paths(loaded.scene, mi.Point3d(*[mi.Float64(aligned(o[:, i], np.float64)) for i in range(3)]),
                          mi.Vector3d(*[mi.Float64(aligned(v[:, i], np.float64)) for i in range(3)]), sampler,
                          max_delta=8, max_depth=6)
    new = {"valid": np.asarray(wp.valid).astype(bool), "d": np.asarray(wp.d, dtype=np.float64),
           "n_delta": np.asarray(wp.n_delta).astype(np.int64),
           "radiance": np.stack([np.asarray(wp.radiance[i]) for i in range(3)], axis=1).astype(np.float64),
           "escaped": np.asarray(wp.escaped).astype(bool)}
    return ref, new


def _z(a: np.ndarray, b: np.ndarray) -> float:
    """z-score of the difference of two sample means."""
    se = math.sqrt(a.var() / len(a) + b.var() / len(b))
    return abs(a.mean() - b.mean()) / max(se, 1e-300)


def test_same_rays_end_the_same_way(both):
    ref, new = both
    assert np.all(np.isfinite(new["d"])) and np.all(np.isfinite(new["radiance"]))
    # Escaping and reaching an image point depend on the geometry, not on the random numbers (up to glass
    # paths, whose lobes are random): the rates agree to well under a percent.
    assert abs(ref.valid.mean() - new["valid"].mean()) < 2e-3
    assert abs(ref.escaped.mean() - new["escaped"].mean()) < 2e-3
    for nd in (0, 1, 2):
        a = np.mean(ref.valid & (ref.n_delta == nd))
        b = np.mean(new["valid"] & (new["n_delta"] == nd))
        assert abs(a - b) < 0.1 * a + 2e-3, (nd, a, b)


def test_the_image_point_is_the_reference_one(both):
    ref, new = both
    # No delta bounce: d is the hit distance. One bounce is a reflection (mirror, or the glass's outside),
    # whose direction is deterministic: the same d to rounding.
    for nd in (0, 1):
        m = ref.valid & new["valid"] & (ref.n_delta == nd) & (new["n_delta"] == nd)
        assert m.sum() > 1000
        rel = np.abs(ref.d[m] - new["d"][m]) / ref.d[m]
        assert np.quantile(rel, 0.999) < 1e-9, (nd, np.quantile(rel, 0.999))


def test_radiance_is_the_same_estimator(both):
    """Both estimators draw from the same distribution (the fused path re-implements Mitsuba's ``path``), so
    any statistic agrees; the mean below 1 (the light itself, 17, and the paths that see it through glass carry
    most of the variance and are cut the same way on both sides) resolves direct light to a percent."""
    ref, new = both
    for nd in (0, 1):
        a = ref.radiance[ref.valid & (ref.n_delta == nd)].astype(np.float64)
        b = new["radiance"][new["valid"] & (new["n_delta"] == nd)]
        for c in range(3):
            assert _z(np.minimum(a[:, c], 1.0), np.minimum(b[:, c], 1.0)) < 4.5, (nd, c, a[:, c].mean(), b[:, c].mean())
    a, b = ref.radiance[ref.valid].astype(np.float64).sum(1), new["radiance"][new["valid"]].sum(1)
    a, b = np.minimum(a, 3.0), np.minimum(b, 3.0)
    assert _z(a, b) < 4.5
    assert abs(a.mean() / b.mean() - 1) < 0.01
