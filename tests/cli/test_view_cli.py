"""`holo encode` and `holo view` end to end on a small RESULT.npz made here: two luminous points at different
hologram depths (a field whose focus we know). The pictures open with Pillow, have the right size, and the
point in focus is the bright one."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from holo.app import app
from holocore.io import load_stack, phase_to_u8, save_result

P = 8e-6
LAMS = [640e-9, 520e-9]
H, W = 64, 64
Z_INF, F_EYE, Z_WRP = 2e-3, 5e-3, 4.5e-3
# (x, y, z) in hologram space (m): x right, y up; z from the SLM. The far point lies nearer to z_inf.
# Both far enough from the SLM that their light covers 10+ px there: a phase-only SLM cannot concentrate light
# into a few pixels, so an image point hugging the SLM would come out dim.
POINTS = [(9 * P, 6 * P, 2.0e-3), (-8 * P, -5 * P, 3.4e-3)]
PUPIL_MM = 0.3  # NA 0.03: inside both recording cones (0.04, 0.0325); 1.4 mm of depth blurs ~5 px

runner = CliRunner()


def _pixel(x: float, y: float) -> tuple[int, int]:
    """(row, col) of a hologram-space point (docs/design.md §3: x = (j - (W-1)/2) p, y = ((H-1)/2 - i) p)."""
    return round((H - 1) / 2 - y / P), round(x / P + (W - 1) / 2)


def _point_field(frames: int = 2) -> np.ndarray:
    """WRP field [F, C, H, W] of POINTS: spherical waves within each color's recording cone, a random phase
    per point and frame (so frames average the interference between the points away)."""
    rng = np.random.default_rng(4)
    yy, xx = np.mgrid[0:H, 0:W]
    x = (xx - (W - 1) / 2) * P
    y = ((H - 1) / 2 - yy) * P
    out = np.zeros((frames, len(LAMS), H, W), np.complex128)
    for c, lam in enumerate(LAMS):
        k = 2 * np.pi / lam
        sin_max = lam / (2 * P)
        for px, py, pz in POINTS:
            dz = Z_WRP - pz
            r = np.sqrt((x - px) ** 2 + (y - py) ** 2 + dz ** 2)
            cone = np.hypot(x - px, y - py) / r <= 0.95 * sin_max
            wave = np.where(cone, np.exp(1j * np.mod(k * r, 2 * np.pi)) / r, 0.0)
            for f in range(frames):
                out[f, c] += wave * np.exp(2j * np.pi * rng.random())
    return out.astype(np.complex64)


@pytest.fixture(scope="module")
def result_npz(tmp_path_factory):
    from holocore.encode.encoder import ideal_slm_field

    wrp = _point_field()
    slm = ideal_slm_field(wrp, z_wrp_m=Z_WRP, wavelengths_m=LAMS, pitch_m=P).numpy()
    meta = {"focal_length_m": F_EYE, "z_inf_m": Z_INF, "z_wrp_m": Z_WRP, "pitch_m": P, "wavelengths_m": LAMS,
            "analysis": {"z_near_holo_m": POINTS[1][2], "z_far_holo_m": POINTS[0][2]}, "scene": "two points"}
    path = tmp_path_factory.mktemp("result") / "RESULT.npz"
    save_result(path, slm_field=slm, wrp_field=wrp, meta=meta)
    return path


@pytest.fixture(scope="module")
def stack_npz(result_npz, tmp_path_factory):
    out = tmp_path_factory.mktemp("stack") / "STACK.npz"
    progress = out.parent / "progress.jsonl"
    r = runner.invoke(app, ["encode", str(result_npz), "--out", str(out), "--iterations", "200",
                            "--progress-jsonl", str(progress)])
    assert r.exit_code == 0, r.output
    assert "complex-field error" in r.output
    stages = [json.loads(line)["stage"] for line in progress.read_text().splitlines()]
    assert stages[0] == "load" and "encode" in stages and stages[-1] == "save"
    return out


def _window_sum(img: np.ndarray, rc: tuple[int, int], r: int = 1) -> float:
    i, j = rc
    return float(img[i - r:i + r + 1, j - r:j + r + 1].astype(np.float64).sum())


@pytest.mark.slow
def test_encode_writes_a_numpy_readable_stack(stack_npz):
    with np.load(stack_npz, allow_pickle=False) as z:
        phase, u8, meta = z["phase"], z["frames_u8"], json.loads(str(z["meta"]))
    assert phase.dtype == np.float32 and phase.shape == (2, 2, H, W) and u8.dtype == np.uint8
    assert phase.min() >= 0 and phase.max() < 2 * np.pi and np.array_equal(u8, phase_to_u8(phase))
    assert meta["scene"] == "two points" and meta["z_wrp_m"] == Z_WRP  # the render's meta carried forward
    e = meta["encoder"]
    assert e["method"] == "sgd" and 0 < e["iterations"] <= 200 and e["lut"] is None
    assert e["loss_mean"] < e["loss_init_mean"] and np.asarray(e["illumination"]).shape == (2, 2)


def test_encode_with_lbfgs_steps(result_npz, tmp_path):
    enc = {}
    for opt in ("lbfgs", "adam"):
        out = tmp_path / f"{opt}.npz"
        r = runner.invoke(app, ["encode", str(result_npz), "--out", str(out), "--optimiser", opt, "--iterations",
                                "30", "--stop-db", "0"])
        assert r.exit_code == 0, r.output
        with np.load(out, allow_pickle=False) as z:
            enc[opt] = json.loads(str(z["meta"]))["encoder"]
    e = enc["lbfgs"]
    assert e["optimiser"] == "lbfgs" and enc["adam"]["optimiser"] == "adam" and e["iterations"] == 30
    assert e["loss_mean"] < 0.5 * e["loss_init_mean"], e
    assert e["loss_mean"] < enc["adam"]["loss_mean"], (e["loss_mean"], enc["adam"]["loss_mean"])  # in as many steps


@pytest.mark.parametrize("method", ["dpac", "naive"])
def test_encode_baselines_with_a_lookup_table(result_npz, tmp_path, method):
    lut = tmp_path / "cal.json"
    tables = [{"wavelength_nm": 640.0, "table": list(range(255, -1, -1))},
              {"wavelength_nm": 520.0, "table": [min(255, 2 * v) for v in range(256)]}]
    lut.write_text(json.dumps({"luts": tables}))
    out = tmp_path / "S.npz"
    r = runner.invoke(app, ["encode", str(result_npz), "--out", str(out), "--method", method, "--lut", str(lut)])
    assert r.exit_code == 0, r.output
    phase, u8, meta = load_stack(out)
    levels = phase_to_u8(phase)
    assert np.array_equal(u8[:, 0], 255 - levels[:, 0])
    assert np.array_equal(u8[:, 1], np.minimum(255, 2 * levels[:, 1].astype(int)))
    assert meta["encoder"]["method"] == method and meta["encoder"]["lut"]["source"] == "cal.json"


@pytest.mark.parametrize("source", [pytest.param("result", marks=pytest.mark.slow), "stack"])
def test_view_focuses_on_the_right_point(result_npz, stack_npz, tmp_path, source):
    src = result_npz if source == "result" else stack_npz
    near_px, far_px = _pixel(*POINTS[1][:2]), _pixel(*POINTS[0][:2])
    sums = {}
    for name, z in (("far", POINTS[0][2]), ("near", POINTS[1][2])):
        out = tmp_path / f"{name}.png"
        r = runner.invoke(app, ["view", str(src), "--focus-mm", f"{z * 1e3:.4f}", "--pupil-mm", str(PUPIL_MM),
                                "--white-percentile", "100", "--out", str(out)])
        assert r.exit_code == 0, r.output
        img = Image.open(out)
        assert img.size == (W, H) and img.mode == "RGB"
        lum = ((np.asarray(img, dtype=np.float64) / 255.0) ** 2.2).sum(axis=-1)  # linear intensity
        sums[name] = (_window_sum(lum, far_px), _window_sum(lum, near_px))
    # Focused on the far point, it is the brighter one; focused on the near point, the near one is.
    assert sums["far"][0] > 2.0 * sums["far"][1], sums
    assert sums["near"][1] > 2.0 * sums["near"][0], sums


def _centroid(lum: np.ndarray, rc: tuple[int, int], r: int = 8) -> np.ndarray:
    i, j = rc
    win = lum[i - r:i + r + 1, j - r:j + r + 1].astype(np.float64)
    ii, jj = np.mgrid[i - r:i + r + 1, j - r:j + r + 1]
    return np.array([(win * ii).sum(), (win * jj).sum()]) / win.sum()


@pytest.mark.parametrize("offset_mm", [(0.1, 0.0), (0.0, 0.1)])
def test_view_offset_gives_parallax(result_npz, tmp_path, offset_mm):
    """Focused on the far point, an eye moved by e sees the near point shift by -(e/f)(z_near - z_far) in the
    focus plane (the pupil takes its rays of direction sine e/f), against the eye's motion; the far point
    stays."""
    lum = {}
    for name, view in (("centre", "0,0"), ("moved", f"{offset_mm[0]},{offset_mm[1]}")):
        out = tmp_path / f"{name}.png"
        r = runner.invoke(app, ["view", str(result_npz), "--focus-mm", f"{POINTS[0][2] * 1e3:.4f}", "--pupil-mm",
                                "0.1", "--view-mm", view, "--white-percentile", "100", "--out", str(out)])
        assert r.exit_code == 0, r.output
        lum[name] = ((np.asarray(Image.open(out), dtype=np.float64) / 255.0) ** 2.2).sum(axis=-1)  # linear
    far_px, near_px = _pixel(*POINTS[0][:2]), _pixel(*POINTS[1][:2])
    shift_xy = -np.array(offset_mm) * 1e-3 / F_EYE * (POINTS[1][2] - POINTS[0][2]) / P  # pixels, x right, y up
    expected = np.array([-shift_xy[1], shift_xy[0]])  # (rows, cols): rows run down
    near = _centroid(lum["moved"], near_px) - _centroid(lum["centre"], near_px)
    far = _centroid(lum["moved"], far_px) - _centroid(lum["centre"], far_px)
    # The shift is a few pixels; the sampled point's angular spectrum is not quite flat, so allow 60-110%.
    k = int(np.argmax(np.abs(expected)))
    assert 0.6 < near[k] / expected[k] < 1.1 and abs(near[1 - k]) < 0.3, (near, expected)
    assert np.abs(far).max() < 0.15 * np.abs(expected).max(), far  # measured: 0.36 px against 3.5 px


def test_sweep_contact_sheet_and_gif(stack_npz, tmp_path):
    sheet = tmp_path / "sheet.png"
    r = runner.invoke(app, ["view", str(stack_npz), "--sweep", "5", "--pupil-mm", str(PUPIL_MM), "--out",
                            str(sheet)])
    assert r.exit_code == 0, r.output
    assert "5 views" in r.output
    cols, rows = math.ceil(math.sqrt(5)), 2
    assert Image.open(sheet).size == (cols * W, rows * (H + 14))
    gif = tmp_path / "sweep.gif"
    r = runner.invoke(app, ["view", str(stack_npz), "--sweep", "4", "--pupil-mm", str(PUPIL_MM), "--quantized",
                            "--out", str(gif)])
    assert r.exit_code == 0, r.output
    im = Image.open(gif)
    assert im.format == "GIF" and im.n_frames == 4 and im.size == (W, H + 14)
    frames = []
    for k in range(im.n_frames):
        im.seek(k)
        frames.append(np.asarray(im.convert("RGB"), dtype=float)[14:])
    assert np.abs(frames[0] - frames[-1]).mean() > 1.0  # focus really changes across the sweep


def test_black_stack_views_black(tmp_path):
    meta = {"focal_length_m": F_EYE, "z_inf_m": Z_INF, "z_wrp_m": Z_WRP, "pitch_m": P, "wavelengths_m": LAMS}
    zero = np.zeros((1, 2, 16, 16), np.complex64)
    save_result(tmp_path / "R.npz", slm_field=zero, wrp_field=zero, meta=meta)
    r = runner.invoke(app, ["encode", str(tmp_path / "R.npz"), "--out", str(tmp_path / "S.npz")])
    assert r.exit_code == 0, r.output
    assert "black" in r.output
    r = runner.invoke(app, ["view", str(tmp_path / "S.npz"), "--focus-mm", "2", "--out", str(tmp_path / "v.png")])
    assert r.exit_code == 0, r.output
    img = np.asarray(Image.open(tmp_path / "v.png"))
    assert img.shape == (16, 16, 3) and img.max() == 0  # the laser is off for a black target


@pytest.mark.parametrize("args, message", [
    (["view", "{r}", "--out", "{t}/x.png"], "exactly one of --focus-mm"),
    (["view", "{r}", "--focus-mm", "1", "--sweep", "3", "--out", "{t}/x.png"], "exactly one of --focus-mm"),
    (["view", "{r}", "--sweep", "3", "--out", "{t}/x.jpg"], ".png (contact sheet) or .gif"),
    (["view", "{r}", "--focus-mm", "1", "--view-mm", "1;2", "--out", "{t}/x.png"], "X,Y"),
    (["view", "{r}", "--focus-mm", "1", "--pupil-mm", "-1", "--out", "{t}/x.png"], "--pupil-mm"),
    (["view", "{r}", "--focus-mm", "1", "--quantized", "--out", "{t}/x.png"], "STACK.npz only"),
    (["view", "{t}/missing.npz", "--focus-mm", "1", "--out", "{t}/x.png"], "not found"),
    (["encode", "{r}", "--out", "{t}/s.npz", "--method", "gs"], "--method"),
    (["encode", "{r}", "--out", "{t}/s.npz", "--lr", "0"], "lr"),
    (["encode", "{r}", "--out", "{t}/s.npz", "--optimiser", "newton"], "--optimiser: Input should be 'lbfgs' or 'adam'"),
    (["encode", "{r}", "--out", "{t}/s.npz", "--lut", "{t}/nolut.json"], "not found"),
])
def test_bad_input_exits_2_with_a_message(result_npz, tmp_path, args, message):
    argv = [a.format(r=result_npz, t=tmp_path) for a in args]
    r = runner.invoke(app, argv)
    assert r.exit_code == 2, r.output
    assert message in r.output


@pytest.mark.slow
def test_service_preview_is_what_holo_view_writes_and_a_failed_preview_keeps_the_pictures(stack_npz, tmp_path,
                                                                                          capsys):
    # The job driver's preview step (service.workers.pictures --preview) makes the preview and the pictures in
    # one process; its preview must be the picture `holo view --focus-mm` writes.
    from service.workers.pictures import main as pictures_main

    focus_mm = f"{POINTS[0][2] * 1e3:.6f}"
    r = runner.invoke(app, ["view", str(stack_npz), "--focus-mm", focus_mm, "--pupil-mm", str(PUPIL_MM),
                            "--out", str(tmp_path / "cli.png")])
    assert r.exit_code == 0, r.output
    assert pictures_main([str(stack_npz), "--out", str(tmp_path / "pics"), "--pupil-mm", str(PUPIL_MM),
                          "--preview", str(tmp_path / "job.png"), "--preview-focus-mm", focus_mm]) == 0
    a, b = (np.asarray(Image.open(tmp_path / n)) for n in ("cli.png", "job.png"))
    assert a.shape == (H, W, 3) and np.array_equal(a, b)
    assert (tmp_path / "pics" / "index.json").is_file()
    # a preview that cannot be written is reported, and the pictures are still made
    capsys.readouterr()
    assert pictures_main([str(stack_npz), "--out", str(tmp_path / "pics2"), "--pupil-mm", str(PUPIL_MM),
                          "--preview", str(tmp_path / "no" / "such" / "dir.png"), "--preview-focus-mm", focus_mm]) == 0
    assert "error: no preview:" in capsys.readouterr().err
    assert (tmp_path / "pics2" / "index.json").is_file()
    assert pictures_main([str(stack_npz), "--out", str(tmp_path / "pics3"), "--preview", str(tmp_path / "x.png")]) == 2
