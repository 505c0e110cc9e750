"""Plug-ins from a package of their own (holocore.plugins): tests/plugin_package is installed into a folder of
its own and put on the path, and its frame-phase mode, baseline and SLM driver are used from the CLI and from a
service job, with nothing in the project naming them."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from holocore.io import load_result, load_stack
from holocore.scene.demo import write_demo_scene
from tests.service.helpers import REPO, Server, planned_scene, wait_state, zip_dir

pytestmark = pytest.mark.slow  # a package built and installed, three CLI runs and a service job: about a minute

SIZE = ["--resolution", "48x64", "--frames", "2", "--preset", "fast", "--spp", "4"]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """tests/plugin_package installed (without its dependencies, which are the project's) into a folder."""
    tmp = tmp_path_factory.mktemp("plugin")
    shutil.copytree(REPO / "tests/plugin_package", tmp / "src")
    target = tmp / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--no-index",
                    "--target", str(target), str(tmp / "src")], check=True, capture_output=True, timeout=300)
    return target


def _env(site: Path) -> dict:
    return dict(os.environ, PYTHONPATH=os.pathsep.join((str(REPO), str(site))))


def _holo(site: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "holo", *args], env=_env(site), capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return write_demo_scene(tmp_path_factory.mktemp("demo") / "scene")


def test_the_plugin_mode_renders_from_the_cli(site, scene, tmp_path):
    r = _holo(site, "render", str(scene), "--out", str(tmp_path / "r.npz"), "--frame-phases", "lab_repeat", *SIZE)
    assert r.returncode == 0, r.stderr
    slm = load_result(tmp_path / "r.npz")[0]
    # the plug-in's phases repeat frame 0's: the two frames are one field (every built-in mode varies them)
    assert np.abs(slm[0]).max() > 0 and np.allclose(slm[0], slm[1], atol=1e-5 * np.abs(slm[0]).max())
    unknown = _holo("/nonexistent", "render", str(scene), "--out", str(tmp_path / "x.npz"), "--frame-phases",
                    "lab_repeat", *SIZE)
    assert unknown.returncode == 2 and "unknown frame phases 'lab_repeat'" in unknown.stderr  # not installed


def test_the_plugin_baseline_and_slm_driver(site, scene, tmp_path):
    listed = _holo(site, "baseline", "list")
    assert listed.returncode == 0 and "lab-flat: a uniform field" in listed.stdout
    r = _holo(site, "baseline", "run", "lab-flat", str(scene), "--out", str(tmp_path / "b.npz"), "-o",
              "amplitude=2.5", "--resolution", "32x48", "--frames", "1")
    assert r.returncode == 0, r.stderr
    assert np.allclose(np.abs(load_result(tmp_path / "b.npz")[0]), 2.5)
    bad = _holo(site, "baseline", "run", "lab-flat", str(scene), "--out", str(tmp_path / "c.npz"), "-o",
                "amplitude=0")
    assert bad.returncode == 2 and "amplitude" in bad.stderr and "Traceback" not in bad.stderr
    code = ("import numpy as np; from display_agent.slm import open_slm, SLMError; s = open_slm('lab-counter:2'); "
            "s.load(stack_id='s', levels=np.zeros((3, 1, 2, 2), np.uint8)); s.show(0); s.show(1)\n"
            "try:\n    s.show(2)\nexcept SLMError as e:\n    print('refused:', e)")
    out = subprocess.run([sys.executable, "-c", code], env=_env(site), capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "refused: lab-counter shows at most 2 frames" in out.stdout, out.stderr


def test_a_service_job_renders_with_the_plugin_mode(site, scene, tmp_path):
    server = Server(tmp_path / "data", pythonpath=(str(site),)).start()
    try:
        sc = planned_scene(server, zip_dir(scene.parent))
        assert sc["plan_state"] == "ready", sc
        body = {"scene_id": sc["id"], "preset": "fast", "spp": 4, "encoder": "dpac",
                "optics": {"resolution_hw": [48, 64], "frames": 2, "frame_phases": "lab_repeat"}}
        with server.client("submit") as c:
            r = c.post("/v1/jobs", json=body)
            assert r.status_code == 202, r.text
            job = wait_state(c, r.json()["id"], ("succeeded", "failed", "cancelled"), timeout=300)
            assert job["state"] == "succeeded", job["error"]
            (tmp_path / "s.npz").write_bytes(c.get(f"/v1/jobs/{job['id']}/stack").content)
            refused = c.post("/v1/jobs", json={**body, "optics": {**body["optics"], "frame_phases": "lab_nope"}})
            assert refused.status_code == 422 and "lab_repeat" in refused.text  # the known modes, the plug-in's too
    finally:
        server.stop()
    phase = load_stack(tmp_path / "s.npz")[0]
    assert phase.shape[0] == 2 and np.array_equal(phase[0], phase[1])  # DPAC of one field twice
