"""Sub-wavelength and extreme pitches: the recording cone is clamped off grazing (sin theta = lambda / 2p > 1 is a
full hemisphere), the field stays finite, and the deeper recording planes' grids, which grow as tan(theta) / p, are
admitted against the memory budget before anything is allocated (fewer planes with ``auto``, a one-line refusal
with the figure for a count asked for)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions, plan_scene, render_loaded
from holocore.plan.memory_estimate import recording_planes_bytes
from tests.trace.scenes import T, camera, emitting_plane, scene

# Two emitters far apart in depth: auto places a deeper recording plane, whose border at a fine pitch is huge.
DEEP = dict(sensor=camera(fov=10.0), near=emitting_plane(-0.3, size=0.01, x=-0.01),
            far={**emitting_plane(-3.0, size=2.0), "to_world": T().translate([0, 0, -3.0]).scale(2.0)})


def _optics(pitch_um: float, resolution_hw=(16, 24)) -> OpticsConfig:
    return OpticsConfig(resolution_hw=resolution_hw, wavelengths_nm=(640.0, 455.4), pitch_um=pitch_um, frames=2,
                        focal_length_mm=20.0)


@pytest.mark.parametrize("pitch_um", [0.05, 0.2, 0.25, 0.5, 100.0])
def test_sub_wavelength_pitch_renders_finite(pitch_um):
    res = render_loaded(scene(**DEEP), _optics(pitch_um), RenderOptions(preset="fast", spp=2))
    for arr in (res.slm_field, res.wrp_field):
        assert np.isfinite(arr).all()
    assert np.abs(res.wrp_field).max() > 0
    assert len(res.meta["plan"]["wrp_planes_m"]) >= 1


@pytest.mark.parametrize("pitch_um", [0.05, 100.0])
def test_extreme_pitch_plans_without_nan(pitch_um):
    pl = plan_scene(scene(**DEEP), _optics(pitch_um), RenderOptions(preset="fast"))
    assert pl.plan.spp >= 1 and np.isfinite(pl.plan.noise_to_signal)


def test_equaliser_spectrum_with_one_near_point_among_far_ones():
    # at 0.2 um every distance quantile lies beyond the Fresnel limit although the nearest point does not
    from holocore.optics.cone_equaliser import mean_sheet_spectrum

    assert mean_sheet_spectrum([1e-9] + [1e-3] * 99, 455e-9, 0.2e-6) is None


def test_auto_planes_at_quarter_micron_fit_the_budget():
    budget = 1 << 30
    opt = _optics(0.25, resolution_hw=(1080, 1920))
    pl = plan_scene(scene(**DEEP), opt, RenderOptions(preset="fast"), memory_budget_bytes=budget)
    theta = max(opt.theta_max(lam) for lam in opt.wavelengths_m)
    borders = [pl.planes.border_px(k, pitch_m=opt.pitch_m, theta_max=theta) for k in range(pl.planes.count)]
    need = recording_planes_bytes(1080, 1920, borders, colors=2, frames=2, ring_rows=1080)
    assert need <= budget
    unbounded = plan_scene(scene(**DEEP), opt, RenderOptions(preset="fast"), memory_budget_bytes=1 << 62)
    assert unbounded.planes.count > pl.planes.count  # the scene's depth asks for planes the budget cannot hold
    assert any("cut to" in s and "memory budget" in s for s in pl.plan.summary)
    assert pl.plan.wrp_planes_m == list(pl.planes.z_m)


def test_planes_asked_for_that_cannot_fit_are_refused_with_the_figure():
    with pytest.raises(ValueError, match=r"need about .* GB.*memory budget"):
        plan_scene(scene(**DEEP), _optics(0.25), RenderOptions(preset="fast", wrp_planes=2),
                   memory_budget_bytes=1 << 30)


def test_cli_refuses_in_one_line_with_status_2(tmp_path):
    from holo.app import app
    from holocore.scene.paper import write_paper_scene

    xml = write_paper_scene("mirror", tmp_path / "mirror")
    r = CliRunner().invoke(app, ["render", str(xml), "--out", str(tmp_path / "r.npz"), "--pitch-um", "0.25",
                                 "--wrp-planes", "2", "--resolution", "16x24", "--frames", "1", "--spp", "1"])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "GB" in lines[0], r.output
    assert not (tmp_path / "r.npz").exists()


@pytest.mark.slow
def test_cli_estimate_at_quarter_micron_gives_a_finite_figure(tmp_path):
    import re

    from holo.app import app
    from holocore.scene.paper import write_paper_scene

    xml = write_paper_scene("mirror", tmp_path / "mirror")
    r = CliRunner().invoke(app, ["render", str(xml), "--out", str(tmp_path / "r.npz"), "--pitch-um", "0.25",
                                 "--resolution", "16x24", "--frames", "1", "--estimate"],
                           env={"HOLO_MEMORY_BUDGET_MB": "1024"})
    assert r.exit_code == 0, r.output
    m = re.search(r"estimated peak memory: render ([0-9.]+) GB", r.output)
    assert m and float(m.group(1)) < 2.0, r.output
