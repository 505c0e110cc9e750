"""The baseline registry (holocore.baselines.registry): the built-in methods by name, one options model that
checks every option (a refusal names it), and a new baseline as one class: registered in a test, it runs
through `holo baseline run` and writes a RESULT.npz that the project's readers accept."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import Field
from typer.testing import CliRunner

from holocore.baselines.registry import (
    Baseline,
    BaselineOptions,
    BaselineOptionsError,
    baseline_names,
    get_baseline,
    register_baseline,
)


def test_the_built_in_baselines_are_registered():
    # found by their entry points (pyproject.toml, group holocore.baselines), as a lab's package would be
    from holocore.plugins import BASELINES, discovered

    assert {name for name, _ in discovered(BASELINES)} >= {"layers", "focal-stack", "light-field"}
    assert set(baseline_names()[:3]) == {"layers", "focal-stack", "light-field"}
    with pytest.raises(ValueError, match="unknown baseline 'nope': one of focal-stack, layers, light-field"):
        get_baseline("nope")


@pytest.mark.parametrize("name, values, field", [
    ("layers", {"planes": 0}, "planes"), ("layers", {"spp": 70000}, "spp"), ("layers", {"colour": 1}, "colour"),
    ("focal-stack", {"time_limit_s": float("nan")}, "time_limit_s"), ("focal-stack", {"lr": 0}, "lr"),
    ("light-field", {"fit": "best"}, "fit"), ("light-field", {"device": "tpu"}, "device"),
])
def test_each_option_is_checked_by_its_model(name, values, field):
    with pytest.raises(BaselineOptionsError) as err:
        get_baseline(name).options(**values)
    assert err.value.field == field and "\n" not in str(err.value)


def test_defaults_come_from_the_model():
    o = get_baseline("focal-stack").options()
    assert (o.iterations, o.lr, o.planes, o.spacing_mm, o.device) == (200, 0.05, None, None, "cpu")
    assert get_baseline("layers").options(planes="3").planes == 3  # the CLI's NAME=VALUE strings


class _FlatOptions(BaselineOptions):
    amplitude: float = Field(1.0, gt=0, description="the field's amplitude")


class FlatBaseline(Baseline):
    """A trivial method: a uniform field at the SLM, to show what a new baseline costs."""

    name = "flat-test"
    summary = "a uniform field (test only)"
    Options = _FlatOptions

    def render(self, loaded, optics, options, *, display=None, progress=None):
        from holocore.render_meta import RenderResult, result_meta
        from holocore.render_setup import RenderOptions, plan_scene

        F, C, (H, W) = optics.frames, len(optics.wavelengths_m), optics.resolution_hw
        field = np.full((F, C, H, W), options.amplitude, dtype=np.complex64)
        pl = plan_scene(loaded, optics, RenderOptions())
        meta = result_meta(method="flat-test", preset=None, loaded=loaded, optics=optics, scene_plan=pl,
                           shape_fchw=(F, C, H, W), timings={}, display=display, summary=[self.summary])
        return RenderResult(slm_field=field, wrp_field=field, meta=meta)


def test_a_new_baseline_is_one_class(tmp_path):
    from holo.app import app
    from holocore.io import load_result
    from holocore.scene.demo import write_demo_scene

    register_baseline(FlatBaseline)
    register_baseline(FlatBaseline)  # the same class again is harmless
    assert "flat-test" in baseline_names()
    with pytest.raises(ValueError, match="registered already"):
        register_baseline(type("Other", (FlatBaseline,), {}))
    scene = write_demo_scene(tmp_path / "demo")
    runner = CliRunner()
    listed = runner.invoke(app, ["baseline", "list"])
    assert listed.exit_code == 0 and "flat-test: a uniform field" in listed.output and "amplitude=1.0" in listed.output
    out = tmp_path / "R.npz"
    r = runner.invoke(app, ["baseline", "run", "flat-test", str(scene), "--out", str(out), "--resolution", "16x24",
                            "--frames", "2", "-o", "amplitude=0.5"])
    assert r.exit_code == 0, r.output
    slm, wrp, meta = load_result(out)
    assert slm.shape == (2, 3, 16, 24) and np.allclose(np.abs(slm), 0.5) and meta["method"] == "flat-test"
    bad = runner.invoke(app, ["baseline", "run", "flat-test", str(scene), "--out", str(tmp_path / "x.npz"),
                              "-o", "amplitude=-1"])
    assert bad.exit_code == 2 and "--amplitude:" in bad.output and "Traceback" not in bad.output
    assert not (tmp_path / "x.npz").exists()
