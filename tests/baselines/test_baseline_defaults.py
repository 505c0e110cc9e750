"""Every baseline (layers, focal stack, light field) runs with its own defaults on every project scene and on the
plugin sweep's scenes, its planes chosen from the scene's image volume as the renderer's analysis knows it; at a
tiny size (32 x 48 px, 2 frames) and few samples / Adam steps, since what is checked is where the planes go and
that the fields are finite, not their quality. Before, the focal stack's fixed 5 planes 1.25 mm apart did not
fit on any scene shallower than that (most of them at this size) and it stopped with an error."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig

OPTICS = OpticsConfig(resolution_hw=(32, 48), frames=2)
PROJECT_SCENES = ["demo", "cbox", "paper-depth", "paper-mirror", "paper-glass", "paper-glossy", "veach-bidir",
                  "veach-mis"]


def _write_scene(name: str, folder: Path) -> Path:
    from holocore.scene.demo import write_cbox_scene, write_demo_scene
    from holocore.scene.paper import write_paper_scene
    from tests.project_scenes import write_project_scene

    if name == "demo":
        return write_demo_scene(folder)
    if name == "cbox":
        return write_cbox_scene(folder)
    if name.startswith("paper-"):
        return write_paper_scene(name[len("paper-"):], folder)
    return write_project_scene(name, folder)


def _in_volume(z: np.ndarray, ana: dict) -> bool:
    far, near = ana["z_far_holo_m"], ana["z_near_holo_m"]
    tol = 1e-9
    return bool(np.all(z >= far - tol) and np.all(z <= near + tol))


def _check_all_baselines(scene_path: Path) -> None:
    """Each baseline with its planes, spacing and ranges left to their defaults; finite fields, planes inside
    the image volume."""
    from holocore.baselines.focal_stack import depth_of_focus_m, render_focal_stack
    from holocore.baselines.layers import render_layers
    from holocore.baselines.light_field import render_light_field
    from holocore.scene.load import load_scene

    loaded = load_scene(scene_path)
    results = {"layers": render_layers(loaded, OPTICS, spp=2),
               "focal-stack": render_focal_stack(loaded, OPTICS, iterations=2, gt_spp=2),
               "light-field": render_light_field(loaded, OPTICS, spp=1)}
    for name, res in results.items():
        F, C, H, W = res.meta["shape_fchw"]
        assert (F, H, W) == (2, 32, 48) and C == len(OPTICS.wavelengths_m), name
        for arr in (res.slm_field, res.wrp_field):
            assert arr.shape == (F, C, H, W) and np.isfinite(arr).all(), name
    ana = results["focal-stack"].meta["analysis"]
    fs = results["focal-stack"].meta["focal_stack"]
    zs = np.asarray(fs["plane_z_m"])
    zw = results["focal-stack"].meta["z_wrp_m"]
    assert np.all(zs >= OPTICS.z_inf_m) and np.all(zs < zw)
    if ana["z_far_holo_m"] is not None:
        assert _in_volume(zs, ana), (zs, ana["z_far_holo_m"], ana["z_near_holo_m"])
        # as many planes as the volume holds at the pupil's depth of focus for red, the paper's 5 at most
        step = depth_of_focus_m(wavelength_m=max(OPTICS.wavelengths_m), focal_length_m=OPTICS.focal_length_m(),
                                pupil_diameter_m=fs["pupil_diameter_m"])
        depth = ana["z_near_holo_m"] - ana["z_far_holo_m"]
        assert len(zs) == min(5, 1 + math.floor(depth / step + 1e-9))
        if len(zs) > 1:
            assert np.all(np.diff(zs) >= step * (1 - 1e-9))
        z_rs = results["light-field"].meta["light_field"]["z_rs_m"]
        assert _in_volume(np.array([z_rs]), ana) or ana["z_far_holo_m"] <= OPTICS.z_inf_m
        assert _in_volume(np.asarray(results["layers"].meta["layers"]["plane_z_m"]), ana)


# every scene but paper-depth is slow: paper-depth keeps the check in the quick tier
@pytest.mark.parametrize("name", [n if n == "paper-depth" else pytest.param(n, marks=pytest.mark.slow)
                                  for n in PROJECT_SCENES])
def test_every_baseline_runs_with_its_defaults_on_each_project_scene(name, tmp_path):
    _check_all_baselines(_write_scene(name, tmp_path / name))


@pytest.mark.slow
@pytest.mark.scenes
@pytest.mark.parametrize("name", ["cbox-mirror-glass", "veach-bidir", "veach-mis"])
def test_every_baseline_runs_with_its_defaults_on_the_shared_bundles(name, shared_scenes):
    from tests.project_scenes import ENTRIES

    _check_all_baselines(shared_scenes / name / ENTRIES[name])


def test_default_planes_span_the_volume_at_the_pupils_depth_of_focus():
    from holocore.baselines.focal_stack import default_stack_planes, depth_of_focus_m, stack_plane_depths

    # red (640 nm) through a 1.6 mm pupil at f = 50 mm focuses over 1.25 mm of hologram depth: the paper's spacing
    step = depth_of_focus_m(wavelength_m=640e-9, focal_length_m=0.05, pupil_diameter_m=1.6e-3)
    assert step == pytest.approx(1.25e-3)
    zi = 0.08
    for depth, planes in ((5e-3, 5), (20e-3, 5), (2.5e-3, 3), (1.0e-3, 1), (0.0, 1)):
        n = default_stack_planes(z_far_m=zi + 0.25e-3, z_near_m=zi + 0.25e-3 + depth, min_spacing_m=step)
        assert n == planes, (depth, n)
    assert default_stack_planes(z_far_m=None, z_near_m=None, min_spacing_m=step) == 1  # a black scene
    # spread uniformly from the far to the near end: the paper's own stack on its 80.25..85.25 mm volume
    zs = stack_plane_depths(z_inf_m=zi, z_far_m=zi + 0.25e-3, z_near_m=zi + 5.25e-3, planes=5, spacing_m=None)
    np.testing.assert_allclose(np.diff(zs), 1.25e-3, rtol=1e-9)


def test_the_cli_focal_stack_runs_with_its_own_defaults_on_a_shallow_scene(tmp_path):
    """The command the report was about: `holo baseline focal-stack SCENE --out ...`, nothing else but the size."""
    from typer.testing import CliRunner

    from holo.app import app

    scene = _write_scene("demo", tmp_path / "demo")
    out = tmp_path / "RESULT.npz"
    r = CliRunner().invoke(app, ["baseline", "focal-stack", str(scene), "--out", str(out), "--resolution", "32x48",
                                 "--frames", "2", "--gt-spp", "4", "--iterations", "3"])
    assert r.exit_code == 0, r.output
    with np.load(out, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        assert np.isfinite(z["slm_field"]).all()
    fs = meta["focal_stack"]
    ana = meta["analysis"]
    assert _in_volume(np.asarray(fs["plane_z_m"]), ana)
    r = CliRunner().invoke(app, ["baseline", "focal-stack", str(scene), "--out", str(out), "--resolution", "32x48",
                                 "--frames", "2", "--spacing-mm", "1.25", "--planes", "5", "--iterations", "1"])
    assert r.exit_code == 2 and "do not fit" in r.output  # an explicit spacing is kept, and refused in one line
    assert "Traceback" not in r.output and len(r.output.strip().splitlines()) == 1


# The baselines build their own film, reconstruction filter and sampler (holocore/baselines/layers.py, the ground
# truth's and the light field's sensors), so the sweep's scenes that differ only in those run the same code: one of
# each kind stays (a baseline that starts reading the scene's own would meet it), the hdrfilm scene is every other
# scene's film. tests/scene/test_plugin_sweep.py renders every one of them.
SENSOR_SIDE_KEPT = {"film": None, "rfilter": "gaussian", "sampler": "multijitter"}


def _sweep_keys() -> list:
    from tests.scene.test_plugin_sweep import BODIES, CHECK_ONLY, REFUSED

    return [k for k in sorted(BODIES) if k not in REFUSED and k not in CHECK_ONLY
            and (k[0] not in SENSOR_SIDE_KEPT or SENSOR_SIDE_KEPT[k[0]] == k[1])]


@pytest.mark.slow
@pytest.mark.parametrize("key", _sweep_keys(), ids=lambda k: f"{k[0]}-{k[1]}")
def test_every_baseline_runs_with_its_defaults_on_the_plugin_sweeps_scenes(key, tmp_path):
    from tests.scene.test_plugin_sweep import _write

    _check_all_baselines(_write(tmp_path / "scene", key) / "scene.xml")
