"""`holo render` / `holo plan` end to end as a user runs them (a real subprocess), on the project's own demo
scene; RESULT.npz must open with numpy alone."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from holocore.scene.demo import write_demo_scene

HOLO = [sys.executable, "-m", "holo"]


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    return write_demo_scene(tmp_path_factory.mktemp("demo") / "scene").parent


def run(*args, **kw):
    return subprocess.run([*HOLO, *map(str, args)], capture_output=True, text=True, timeout=600, **kw)


def test_render_writes_a_numpy_readable_result(demo, tmp_path):
    out = tmp_path / "RESULT.npz"
    progress = tmp_path / "progress.jsonl"
    p = run("render", demo, "--out", out, "--preset", "fast", "--frames", 2, "--resolution", "24x32",
            "--focal-length-mm", 20, "--seed", 5, "--progress-jsonl", progress)
    assert p.returncode == 0, p.stderr
    assert "rendered" in p.stderr and " s " in p.stderr  # the summary line with the time
    with np.load(out, allow_pickle=False) as z:
        slm, wrp, meta = z["slm_field"], z["wrp_field"], json.loads(str(z["meta"]))
    assert slm.dtype == np.complex64 and wrp.dtype == np.complex64
    assert slm.shape == wrp.shape == (2, 3, 24, 32)
    assert np.isfinite(slm).all() and np.abs(wrp).max() > 0
    for key in ("focal_length_m", "z_inf_m", "z_wrp_m", "pitch_m", "wavelengths_m"):
        assert key in meta
    assert meta["wavelengths_m"] == pytest.approx([640e-9, 516.5e-9, 455.4e-9])
    assert meta["focal_length_m"] == pytest.approx(0.02)
    assert meta["display_profile"] == "paper" and meta["display"]["fourier_filter"] is True
    assert sorted(meta["display"]["overridden"]) == ["focal_length_mm", "frames", "resolution_hw"]
    assert meta["field_of_view"]["hologram_fov_x_deg"] == pytest.approx(2 * math.degrees(math.atan(32 * 8e-6 / 0.04)))
    assert meta["plan"]["summary"] and meta["timings"]["total_s"] > 0 and meta["versions"]["mitsuba"]
    assert any("mirror" in s for s in meta["plan"]["summary"])
    stages = [json.loads(line)["stage"] for line in progress.read_text().splitlines()]
    assert "trace" in stages and "propagate" in stages
    from service.jobfiles import (
        RENDER_STAGES,  # the stages the service's progress expects
    )

    assert set(stages) <= set(RENDER_STAGES), stages


@pytest.mark.slow
def test_plan_json(demo):
    p = run("plan", demo, "--json", "--resolution", "24x32")
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["inventory"]["mirrors"] == ["mirror_sphere"]
    assert doc["inventory"]["dielectrics"] == ["glass_sphere"]
    assert doc["analysis"]["z_wrp_m"] > doc["analysis"]["z_near_holo_m"]


@pytest.mark.parametrize("args, message", [
    (["--resolution", "0x10"], "resolution_hw"),
    (["--pitch-um", "nan"], "pitch_um"),
    (["--frames", "-3"], "frames"),
    (["--wavelengths-nm", "640,abc"], "wavelengths"),
    (["--preset", "turbo"], "preset"),
    pytest.param(["--time-limit-s", "0"], "--time-limit-s", marks=pytest.mark.slow),
    pytest.param(["--time-limit-s", "nan"], "--time-limit-s", marks=pytest.mark.slow),
])
def test_bad_options_are_refused_clearly(demo, tmp_path, args, message):
    p = run("render", demo, "--out", tmp_path / "x.npz", *args)
    assert p.returncode == 2
    assert message in p.stderr
    assert not (tmp_path / "x.npz").exists()


def test_missing_scene(tmp_path):
    p = run("render", tmp_path / "nope", "--out", tmp_path / "x.npz")
    assert p.returncode == 2 and "not found" in p.stderr
