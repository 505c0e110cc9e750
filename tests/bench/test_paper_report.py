"""bench/paper_report.py (`holo bench paper`) at a tiny size: the equal-time bookkeeping, the convergence
normalisation, the frame-prefix shortcut the convergence map relies on, and that the tables' physics holds
(a reference scored against itself is perfect, the cue's image lies where T puts it)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def rep():
    spec = importlib.util.spec_from_file_location("holo_paper_report_test", ROOT / "bench" / "paper_report.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_equal_time_bookkeeping(rep):
    # 10 s fixed + 0.5 s per unit in a 60 s budget: 100 units fill it exactly, 101 would not fit
    assert rep.fit_count(60.0, 10.0, 0.5) == 100
    n = rep.fit_count(61.3, 7.2, 0.37)
    assert 7.2 + n * 0.37 <= 61.3 < 7.2 + (n + 1) * 0.37
    assert rep.fit_count(5.0, 10.0, 0.5, lo=4) == 4  # over budget already: the floor, not a negative count
    assert rep.fit_count(1e9, 0.0, 1.0, hi=4096) == 4096
    with pytest.raises(ValueError):
        rep.fit_count(10.0, 1.0, 0.0)


def test_convergence_ratio(rep):
    assert rep.convergence_ratio(30.0, 30.0) == 1.0
    assert rep.convergence_ratio(24.0, 30.0) == pytest.approx(0.8)
    assert math.isnan(rep.convergence_ratio(10.0, math.inf))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from holocore.display.profiles import PAPER
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.load import load_scene
    from holocore.scene.paper import write_paper_scene

    loaded = load_scene(write_paper_scene("mirror", tmp_path_factory.mktemp("mirror")))
    opt = PAPER.optics(resolution_hw=(36, 48), frames=3, z_inf_mm=4.0)
    r3 = render_loaded(loaded, opt, RenderOptions(preset="balanced", spp=4))
    r2 = render_loaded(loaded, opt.model_copy(update={"frames": 2}), RenderOptions(preset="balanced", spp=4))
    return loaded, r3, r2


@pytest.mark.slow
def test_frames_the_convergence_map_may_share(tiny):
    # The convergence map's F = 1 is the first frame of its 24-frame render: frame 0 is the same random-phase
    # frame in every bank (a 1-frame render has no random-phase bank, docs/design.md §8). Coded frame phases depend on the
    # frame count beyond frame 0, so F = 3, 8 are rendered on their own; with independent phases a prefix would do.
    loaded, r3, r2 = tiny
    from holocore.pipeline import RenderOptions, render_loaded

    tol = dict(rtol=1e-4, atol=1e-5 * np.abs(r2.slm_field).max())
    np.testing.assert_allclose(r3.slm_field[:1], r2.slm_field[:1], **tol)
    assert np.abs(r3.slm_field[1] - r2.slm_field[1]).max() > 0.1 * np.abs(r2.slm_field[1]).max()
    ind = {F: render_loaded(loaded, _optics(F, "independent"),
                            RenderOptions(preset="balanced", spp=4)).slm_field for F in (2, 3)}
    np.testing.assert_allclose(ind[3][:2], ind[2], rtol=1e-4, atol=1e-5 * np.abs(ind[2]).max())


def _optics(frames: int, frame_phases: str):
    from holocore.display.profiles import PAPER

    return PAPER.optics(resolution_hw=(36, 48), frames=frames, z_inf_mm=4.0).model_copy(
        update={"frame_phases": frame_phases})


@pytest.mark.slow
def test_reference_against_itself_and_cue_depth(rep, tiny):
    from holocore.evaluate.scoring import default_pupil_m, eye_view

    _, r3, _ = tiny
    meta = r3.meta
    focus, views = rep.cell_grid("mirror", meta, view_deg=0.5)
    names = [n for n, _ in focus]
    assert names == ["near", "middle", "far", "image"]
    z_img = dict(focus)["image"]
    # the mirror image 2.0 m away: z_inf + f^2 / 2 m = 4 mm + 1.25 mm, beyond the mirror surface (0.5 m, + 5 mm)
    assert z_img == pytest.approx(4e-3 + 0.05 ** 2 / 2.0, rel=1e-9)
    assert meta["analysis"]["z_far_holo_m"] - 1e-4 <= z_img <= meta["analysis"]["z_near_holo_m"]
    assert [e for _, e in views][0][0] == pytest.approx(-views[2][1][0])
    pupil = default_pupil_m(meta, view_deg=0.5)
    ref = eye_view(r3.slm_field, meta, focus_z_m=z_img, pupil_diameter_m=pupil)
    m = rep.margin_px(meta, (36, 48), focus_z_m=z_img, pupil_m=pupil, view=(0.0, 0.0))
    assert 0 <= m <= (36 - 16) // 2
    p, s, k = rep.score_cell(ref, ref, m)
    assert p > 60.0 and s > 0.999 and k == pytest.approx(1.0)
    # one frame against three is not perfect (speckle), and scores finite
    one = eye_view(r3.slm_field[:1], meta, focus_z_m=z_img, pupil_diameter_m=pupil)
    p1, _, _ = rep.score_cell(one, ref, m)
    assert math.isfinite(p1) and p1 < p


def test_phase_only_field(rep):
    class Enc:
        phase = np.full((2, 3, 4, 5), 0.5, dtype=np.float32)
        illumination = np.array([[1.0, 0.25, 0.0]] * 2)

    u = rep.phase_only_field(Enc())
    assert u.dtype == np.complex64 and u.shape == (2, 3, 4, 5)
    np.testing.assert_allclose(np.abs(u[0, :, 0, 0]), [1.0, 0.5, 0.0], atol=1e-6)
    np.testing.assert_allclose(np.angle(u[0, 0]), 0.5, atol=1e-6)


def test_scored_planes_are_off_the_methods_planes_and_never_twice(rep, tiny):
    from holocore.evaluate.wave_truth import layer_spacing_m

    meta = tiny[1].meta
    ana = meta["analysis"]
    own = list(np.linspace(ana["z_far_holo_m"], ana["z_near_holo_m"], 5))  # a stack's planes, its ends included
    gap = layer_spacing_m(pitch_m=meta["pitch_m"], wavelength_m=min(meta["wavelengths_m"]))
    for seed in range(5):
        focus, _ = rep.cell_grid("mirror", meta, view_deg=0.5, seed=seed, avoid_m=own)
        zs = [z for _n, z in focus]
        assert len(zs) >= 3 and min(abs(a - b) for i, a in enumerate(zs) for b in zs[i + 1:]) > 0
        drawn = [z for n, z in focus if n != "image"]
        thirds = np.linspace(ana["z_far_holo_m"], ana["z_near_holo_m"], 4)
        assert all(any(lo <= z <= hi for lo, hi in zip(thirds, thirds[1:])) for z in drawn)
        room = [z for z in drawn if min(abs(z - o) for o in own) >= gap]
        assert len(room) >= 2  # most thirds leave room between the stack's planes at this size
    assert rep.cell_grid("mirror", meta, view_deg=0.5, seed=1, avoid_m=own) != \
        rep.cell_grid("mirror", meta, view_deg=0.5, seed=2, avoid_m=own)
