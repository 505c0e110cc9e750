"""bench/device_check.sh --dry-run: the GPU check's whole sequence (plan, render to a convergence, encode, view,
figures) at 96x128 x 2 frames on the CPU, so the script a GPU machine runs is known to work before it gets one."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_device_check_dry_run(tmp_path):
    out = tmp_path / "figures.json"
    r = subprocess.run(["bash", str(REPO / "bench" / "device_check.sh"), "--dry-run", "--python", sys.executable,
                        "--", "--work", str(tmp_path / "work"), "--out-json", str(out)],
                       capture_output=True, text=True, timeout=600, cwd=REPO)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    doc = json.loads(out.read_text())
    assert doc["dry_run"] and doc["device"] == "cpu" and doc["size"] == [96, 128, 3, 2]
    assert [s["stage"] for s in doc["stages"]] == ["render", "encode", "view"]
    assert all(s["seconds"] > 0 and s["peak_rss_mb"] > 0 for s in doc["stages"])
    render = doc["stages"][0]
    assert render["variant"].startswith("llvm") and render["device"] == "cpu"
    assert render["rays"] == 96 * 128 * doc["spp"]  # the rays per pixel the convergence asked for (capped)
    assert 0 < doc["convergence"] < 0.8
    with np.load(tmp_path / "work" / "STACK.npz") as z:
        ph = z["phase"]
    assert ph.shape == (2, 3, 96, 128) and float(ph.min()) >= 0 and float(ph.max()) < 2 * np.pi
    assert "CPU / this" in r.stdout and "total" in r.stdout


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_full_display_figure_dry_run(tmp_path):
    """bench/full_display.py, the full-display figure's script, at 64x96 x 2 frames on the CPU: it writes the
    figure, the figures' JSON and the ladder; the encoder's loss falls with its iterations and every score is
    finite."""
    r = subprocess.run([sys.executable, str(REPO / "bench" / "full_display.py"), "--device", "cpu", "--resolution",
                        "64x96", "--frames", "2", "--spp", "8", "--ladder", "3,12", "--default-rule", "0",
                        "--gt-spp", "4", "--out", str(tmp_path)], capture_output=True, text=True, timeout=600,
                       cwd=REPO)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    doc = json.loads((tmp_path / "full_display_mirror.json").read_text())
    assert doc["size"] == [64, 96, 3, 2] and doc["render"]["variant"].startswith("llvm")
    assert [row["iterations"] for row in doc["ladder"]] == [3, 12]
    assert doc["ladder"][1]["loss_mean"] < doc["ladder"][0]["loss_mean"]
    assert [f["name"] for f in doc["focus"]] == ["mirror frame", "mirror image"]
    scores = [s["psnr_db"] for row in doc["ladder"] for s in row["scores"].values()]
    assert all(np.isfinite(scores))
    assert (tmp_path / "full_display_mirror.jpg").stat().st_size > 1000
    assert (tmp_path / "encode_ladder_mirror.md").read_text().count("|") > 20
