"""Display profiles (docs/design.md §3): the eyepiece f is the display's, the paper's display is the
default, user profiles load from JSON or TOML with one-line errors, explicit options override the profile, and
`holo plan` takes exactly the optics options of `holo render`."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.display.profiles import (
    PAPER,
    DisplayError,
    DisplayProfile,
    display_optics,
    field_of_view_report,
    load_display,
    save_display,
)
from holocore.trace.mapping import HologramMap

HOLO = [sys.executable, "-m", "holo"]


def run(*args):
    return subprocess.run([*HOLO, *map(str, args)], capture_output=True, text=True, timeout=600)


def lab_profile(**kw) -> DisplayProfile:
    base = dict(name="lab-slm", resolution_hw=(540, 960), pitch_um=6.4, wavelengths_nm=(638.0, 520.0, 450.0),
                z_inf_mm=60.0, focal_length_mm=40.0, frames=12, fourier_filter=False, description="a lab's SLM")
    return DisplayProfile(**{**base, **kw})


# ---- the paper's display ------------------------------------------------------------------------------------
def test_paper_display_is_the_default_and_maps_depth_as_the_paper_shows_it():
    assert load_display() is PAPER and load_display("paper") is PAPER
    o = PAPER.optics()
    assert o.resolution_hw == (1080, 1920) and o.pitch_um == 8.0 and o.wavelengths_nm == (640.0, 516.5, 455.4)
    assert o.z_inf_mm == 80.0 and o.frames == 24 and PAPER.fourier_filter
    # f is the display's whatever the scene camera: a 70 degree camera does not shrink it to 11 mm
    for camera_fov in (10.0, 40.0, 70.0):
        assert o.focal_length_m(camera_fov) == pytest.approx(0.050)
    assert OpticsConfig().focal_length_m(70.0) == pytest.approx(0.050)  # the library default is the same display
    # T (holocore/trace/mapping.py): 10 m, 0.9 m and 0.5 m in front of the eye land at z_inf + 0.25, 2.8 and 5 mm
    hmap = HologramMap(cam_to_world=np.eye(4), focal_length_m=o.focal_length_m(70.0), z_inf_m=o.z_inf_m)
    q = hmap.world_to_holo(np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 0.9], [0.0, 0.0, 0.5]]))
    dz_mm = (q[:, 2] - o.z_inf_m) * 1e3
    assert dz_mm == pytest.approx([0.25, 2.78, 5.0], abs=0.01)
    # depth is linear in dioptres: 1 D = f^2 = 2.5 mm of hologram depth
    assert (dz_mm[2] - dz_mm[1]) / (1 / 0.5 - 1 / 0.9) == pytest.approx(2.5)
    # the display's field of view, 2 atan(W p / 2f) = 17.5 deg: a point at its edge lands on the SLM's edge
    fov = o.field_of_view_x_deg()
    assert fov == pytest.approx(17.46, abs=0.01) == PAPER.field_of_view_x_deg()
    half = math.tan(math.radians(fov / 2))
    edge = hmap.world_to_holo(np.array([-2.0 * half, 0.0, 2.0]))  # Mitsuba's +x is the image's left
    assert abs(edge[0]) == pytest.approx(1920 * 8e-6 / 2, rel=1e-9)


def test_fitting_the_camera_view_is_explicit_and_the_report_says_what_it_costs():
    o = PAPER.optics()
    rep = field_of_view_report(o, 70.0)
    assert rep["differs"] and rep["focal_length_source"] == "display"
    assert rep["hologram_fov_x_deg"] == pytest.approx(17.46, abs=0.01) and rep["camera_fov_x_deg"] == 70.0
    assert "narrower view" in rep["summary"] and "--fit-camera-fov" in rep["summary"]
    fit = PAPER.optics(fit_camera_fov=True)
    f_fit = fit.focal_length_m(70.0)
    assert f_fit == pytest.approx((1920 * 8e-6 / 2) / math.tan(math.radians(35.0)))  # about 11 mm
    assert f_fit == pytest.approx(0.011, abs=0.0005)
    rep = field_of_view_report(fit, 70.0)
    assert not rep["differs"] and rep["focal_length_source"] == "fit_camera_fov"
    assert rep["hologram_fov_x_deg"] == pytest.approx(70.0)
    # what fitting costs: a room from 5 to 15 m spans (f^2)(1/5 - 1/15) of hologram depth, 21x less at 11 mm
    room = lambda f: f * f * (1 / 5 - 1 / 15)  # noqa: E731
    assert room(0.05) == pytest.approx(0.333e-3, rel=0.01) and room(f_fit) < room(0.05) / 20
    assert field_of_view_report(PAPER.optics(), 17.46)["differs"] is False


# ---- user profiles ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".json", ".toml"])
def test_a_profile_file_round_trips_and_builds_its_optics(tmp_path, suffix):
    prof = lab_profile()
    path = save_display(prof, tmp_path / f"lab{suffix}")
    back = load_display(str(path))
    assert back == prof
    o = back.optics()
    assert o.focal_length_m(70.0) == pytest.approx(0.040) and o.resolution_hw == (540, 960)
    assert o.pitch_m == pytest.approx(6.4e-6) and o.z_inf_m == pytest.approx(0.060) and o.frames == 12
    assert o.wavelengths_m == pytest.approx((638e-9, 520e-9, 450e-9))


def test_a_hand_written_toml_profile_takes_its_name_from_the_file(tmp_path):
    path = tmp_path / "bench-slm.toml"
    path.write_text('resolution_hw = [1200, 1920]\npitch_um = 3.74\nwavelengths_nm = [532.0]\nz_inf_mm = 40.0\n'
                    'focal_length_mm = 75.0\nframes = 8\nfourier_filter = false\n')
    prof = load_display(path)
    assert prof.name == "bench-slm" and prof.wavelengths_nm == (532.0,) and not prof.fourier_filter
    assert prof.optics().focal_length_m() == pytest.approx(0.075)


@pytest.mark.parametrize("name, text, words", [
    ("neg.json", None, "pitch_um: Input should be greater than 0"),
    ("unit.json", None, "focal_mm: unknown field"),
    ("missing.json", '{"name": "m", "pitch_um": 8.0}', "resolution_hw: Field required"),
    ("syntax.json", '{"name": "m",', "not valid JSON"),
    ("syntax.toml", "pitch_um = = 8", "not valid TOML"),
    ("list.json", "[1, 2]", "expected an object of profile fields"),
    ("frames.toml", None, "frames: Input should be less than or equal to 256"),
    ("badname.json", None, "name must be"),
    ("profile.yaml", "pitch_um: 8", "expected a .json or .toml file"),
])
def test_bad_profile_files_are_refused_in_one_line_naming_the_file_and_field(tmp_path, name, text, words):
    good = lab_profile().model_dump(mode="json")
    if text is None:
        bad = {"neg.json": {**good, "pitch_um": -8.0}, "unit.json": {**good, "focal_mm": 50.0},
               "frames.toml": {**good, "frames": 1000}, "badname.json": {**good, "name": "my display/1"}}[name]
        if name.endswith(".toml"):
            save_display(lab_profile(), tmp_path / name)
            text = (tmp_path / name).read_text().replace("frames = 12", "frames = 1000")
        else:
            text = json.dumps(bad)
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(DisplayError) as exc:
        load_display(path)
    msg = str(exc.value)
    assert words in msg and str(path) in msg and "\n" not in msg


def test_unknown_names_and_missing_files_are_one_line(tmp_path):
    with pytest.raises(DisplayError, match="unknown display 'papr': give a built-in profile \\(paper\\)"):
        load_display("papr")
    with pytest.raises(DisplayError, match="cannot read display profile"):
        load_display(tmp_path / "absent.toml")


def test_options_override_the_profile_and_choose_the_source_of_f():
    prof = lab_profile()
    o = display_optics(prof, overrides={"frames": 3, "focal_length_mm": 25.0, "resolution_hw": None})
    assert o.frames == 3 and o.focal_length_m(70.0) == pytest.approx(0.025) and o.resolution_hw == (540, 960)
    fit = display_optics(prof, overrides={"fit_camera_fov": True})
    assert fit.focal_length_mm is None and fit.fit_camera_fov
    assert fit.focal_length_m(70.0) == pytest.approx((960 * 6.4e-6 / 2) / math.tan(math.radians(35.0)))
    with pytest.raises(DisplayError, match="not both"):
        display_optics(prof, overrides={"fit_camera_fov": True, "focal_length_mm": 25.0})
    with pytest.raises(DisplayError, match="pitch_um"):
        display_optics(prof, overrides={"pitch_um": float("nan")})


def test_a_full_optics_json_wins_over_the_profile(tmp_path):
    """The service's workers run `holo render --optics-json optics.json` with a whole OpticsConfig: the CLI
    must render exactly that, whatever the default display says (frames 24 vs the job's)."""
    from holo.common import OpticsOptions

    job = OpticsConfig(resolution_hw=(64, 64), seed=7, frames=2)
    path = tmp_path / "optics.json"
    path.write_text(job.model_dump_json())
    prof, o = OpticsOptions(optics_json=path).resolve()
    assert prof is PAPER and o == job
    fitted = OpticsConfig(resolution_hw=(64, 64), fit_camera_fov=True)
    path.write_text(fitted.model_dump_json())
    assert OpticsOptions(optics_json=path).resolve()[1] == fitted
    assert OpticsOptions(optics_json=path, focal_length_mm=30.0).resolve()[1].focal_length_mm == 30.0


# ---- the CLI ------------------------------------------------------------------------------------------------
def test_render_plan_demo_and_baseline_share_one_optics_option_set():
    import typer.main

    from holo.app import app
    from holo.common import OPTICS_OPTIONS

    cli = typer.main.get_command(app)
    shared = {"--" + name.replace("_", "-") for name, _, _ in OPTICS_OPTIONS}
    assert {"--display", "--resolution", "--pitch-um", "--wavelengths-nm", "--z-inf-mm", "--focal-length-mm",
            "--frames", "--fit-camera-fov"} <= shared

    def optics_flags(cmd) -> set[str]:
        return {o for p in cmd.params for o in p.opts if o in shared}

    render, plan, demo = (cli.commands[n] for n in ("render", "plan", "demo"))
    layers = cli.commands["baseline"].commands["layers"]
    assert optics_flags(render) == optics_flags(plan) == optics_flags(demo) == optics_flags(layers) == shared


@pytest.fixture(scope="module")
def wide_scene(tmp_path_factory) -> Path:
    """The project's demo scene seen by a 70 degree camera, as wide as a downloaded interior's."""
    from holocore.scene.demo import write_demo_scene

    return write_demo_scene(tmp_path_factory.mktemp("wide") / "scene", fov_deg=70.0)


@pytest.mark.slow
def test_plan_of_a_wide_camera_uses_the_displays_f_and_says_the_view_differs(wide_scene):
    p = run("plan", wide_scene, "--json")
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    f = doc["focal_length_m"]
    assert f == pytest.approx(0.050) and doc["display_profile"] == "paper" and doc["display"]["overridden"] == []
    fov = doc["field_of_view"]
    assert fov["differs"] and fov["camera_fov_x_deg"] == pytest.approx(70.0)
    assert fov["hologram_fov_x_deg"] == pytest.approx(17.46, abs=0.01)
    assert any("narrower view" in s for s in doc["summary"])
    # the back wall, 1.5 m away, lies at z_inf + f^2 / 1.5; the glass sphere's front (0.311 m) or its real images
    # nearer still: the scene spans at least f^2 (1/0.311 - 1/1.5) = 6.4 mm of hologram depth, many depths of field
    a, zi = doc["analysis"], doc["optics"]["z_inf_mm"] * 1e-3
    assert a["z_far_holo_m"] - zi == pytest.approx(f * f / 1.5, rel=0.02)
    assert a["z_near_holo_m"] - zi >= f * f / 0.312
    fit = run("plan", wide_scene, "--json", "--fit-camera-fov")
    assert fit.returncode == 0, fit.stderr
    fdoc = json.loads(fit.stdout)
    f_fit = fdoc["focal_length_m"]
    assert f_fit == pytest.approx((1920 * 8e-6 / 2) / math.tan(math.radians(35.0)), rel=1e-6)
    assert not fdoc["field_of_view"]["differs"] and fdoc["display"]["overridden"] == ["focal_length_mm"]
    assert fdoc["analysis"]["z_far_holo_m"] - zi == pytest.approx(f_fit ** 2 / 1.5, rel=0.02)  # 0.08 mm: no depth


@pytest.mark.slow
def test_plan_options_override_a_profile_file(wide_scene, tmp_path):
    prof = save_display(lab_profile(), tmp_path / "lab.toml")
    p = run("plan", wide_scene, "--json", "--display", prof, "--focal-length-mm", 30, "--frames", 3,
            "--resolution", "270x480")
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    o = doc["optics"]
    assert doc["display_profile"] == "lab-slm" and doc["focal_length_m"] == pytest.approx(0.030)
    assert o["frames"] == 3 and o["resolution_hw"] == [270, 480] and o["pitch_um"] == 6.4 and o["z_inf_mm"] == 60.0
    assert sorted(doc["display"]["overridden"]) == ["focal_length_mm", "frames", "resolution_hw"]
    assert doc["display"]["fourier_filter"] is False
    text = run("plan", wide_scene, "--display", prof)
    assert text.returncode == 0 and "display lab-slm" in text.stdout and "f = 40 mm" in text.stdout


@pytest.mark.parametrize("args, words", [
    (["--display", "papr"], "unknown display 'papr'"),
    (["--display", "BAD.toml"], "not valid TOML"),
    (["--fit-camera-fov", "--focal-length-mm", "20"], "not both"),
    (["--z-inf-mm", "-1"], "z_inf_mm"),
])
def test_bad_display_options_are_one_line_errors(wide_scene, tmp_path, args, words):
    (tmp_path / "BAD.toml").write_text("frames = [")
    args = [str(tmp_path / a) if a == "BAD.toml" else a for a in args]
    for cmd in (["plan", wide_scene], ["render", wide_scene, "--out", tmp_path / "x.npz"]):
        p = run(*cmd, *args)
        assert p.returncode == 2, p.stderr
        assert words in p.stderr and "Traceback" not in p.stderr
        assert len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert not (tmp_path / "x.npz").exists()


def test_display_profile_command_shows_and_writes_a_profile(tmp_path):
    p = run("display-profile", "paper", "--out", tmp_path / "mine.toml")
    assert p.returncode == 0, p.stderr
    assert "f = 50 mm" in p.stdout and "17.5 deg" in p.stdout and "80.25, 82.78, 85 mm" in p.stdout
    assert load_display(tmp_path / "mine.toml") == PAPER
    bad = run("display-profile", "nope")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and "unknown display" in bad.stderr
