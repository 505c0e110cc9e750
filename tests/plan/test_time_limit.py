"""A render with a time limit (``RenderOptions.time_limit_s``, ``holo render --time-limit-s``): passes of rays
until the budget is spent (holocore.plan.time_budget), added into the recording planes as the estimate of all
their rays."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.plan.time_budget import MAX_PASSES, SppSchedule
from holocore.scene.demo import write_demo_scene

# Costs of a pass of s rays per pixel, seconds (simulated: no test here times anything): a line; one that grows
# faster (s^1.15); a step where the tracer's tiles shrink to one row (30 % dearer past 2000 spp); a 2.8x jump,
# the size of the miss a 16/64-spp line made on a glass scene.
COSTS = {
    "line": lambda s: 0.15 + 0.00113 * s,
    "power": lambda s: 0.1 + 0.0004 * s ** 1.15,
    "step": lambda s: 0.15 + 0.00113 * s * (1.3 if s > 2000 else 1.0),
    "jump": lambda s: 0.05 + 0.02 * s * (2.8 if s > 3000 else 1.0),
}


def _run(schedule: SppSchedule, cost) -> float:
    spent = 0.0
    while (n := schedule.next_spp(spent)) is not None:
        assert n >= 1
        spent += cost(n)
        schedule.record(n, cost(n))
    return spent


@pytest.mark.parametrize("budget_s", [6.0, 90.0])
@pytest.mark.parametrize("cost", sorted(COSTS))
def test_the_passes_fill_the_budget(cost, budget_s):
    sc = SppSchedule(budget_s=budget_s)
    spent = _run(sc, COSTS[cost])
    assert 0.9 * budget_s <= spent <= 1.03 * budget_s, (spent, sc.passes)
    assert len(sc.passes) <= MAX_PASSES and sc.spp == sum(s for s, _ in sc.passes)
    # the rays are what the budget buys: a single pass of the total would not have fitted in much less time
    assert COSTS[cost](sc.spp) >= 0.8 * budget_s


@pytest.mark.parametrize("budget_s", [97.0, 300.0])
def test_a_large_fixed_part_per_pass(budget_s):
    # The paper's display with five recording planes: storing a pass's rows took 20 s whatever its rays (15 s for
    # the first, which writes instead of adding), a ray per pixel 2.3 s. The renderer measures that part; the
    # schedule must not spend 20 s on a pass of one ray per pixel, nor run past the budget.
    sc, spent = SppSchedule(budget_s=budget_s), 0.0
    while (n := sc.next_spp(spent)) is not None:
        fixed = 20.0 if sc.passes else 15.0
        spent += fixed + 2.3 * n
        sc.record(n, fixed + 2.3 * n, fixed_s=fixed)
    assert 0.85 * budget_s <= spent <= budget_s, (spent, sc.passes)
    assert all(s >= 0.25 * sum(x for x, _ in sc.passes[:i]) for i, (s, _) in enumerate(sc.passes) if i), sc.passes
    assert sc.cost_model() == (20.0, pytest.approx(2.3))


def test_the_cap_and_a_budget_shorter_than_one_pass():
    sc = SppSchedule(budget_s=90.0, max_spp=300)
    _run(sc, COSTS["line"])
    assert sc.spp == 300
    sc = SppSchedule(budget_s=0.01)  # the first pass runs (a render needs rays), then nothing more fits
    _run(sc, COSTS["line"])
    assert [s for s, _ in sc.passes] == [16]


@pytest.mark.parametrize("kw", [{"budget_s": 0.0}, {"budget_s": float("nan")}, {"budget_s": 1.0, "max_spp": 0}])
def test_bad_schedules_are_refused(kw):
    with pytest.raises(ValueError):
        SppSchedule(**kw)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    return write_demo_scene(tmp_path_factory.mktemp("demo") / "scene").parent


def _forced(monkeypatch, spps):
    """Make every schedule run the passes ``spps`` (whatever the clock says)."""
    def next_spp(self, elapsed_s):
        return spps[len(self.passes)] if len(self.passes) < len(spps) else None

    monkeypatch.setattr(SppSchedule, "next_spp", next_spp)


@pytest.mark.slow
@pytest.mark.parametrize("streamed, planes", [(False, 1), (True, 1), (False, 3)])
def test_the_passes_make_the_spp_weighted_mean(demo, tmp_path, monkeypatch, streamed, planes):
    # A pass is an unbiased estimate of the same field from its own rays (seed ray_seed + 7919 k, the same
    # random-phase bank): the time-limited render must equal (4 U(4 spp, seed 5) + 12 U(12 spp, seed 5 + 7919)) / 16,
    # on both planes, in memory, and streamed to a file in one-frame chunks (the later chunks replay the first
    # chunk's passes), and with three recording planes chained to the WRP (each pass's deeper planes in their own
    # scratch files).
    from holocore.io import load_result
    from holocore.pipeline import RenderOptions, render, render_to_file

    # f = 20 mm: this small view holds the wall and two objects at other depths (several planes have work)
    optics = OpticsConfig(resolution_hw=(36, 48), frames=3, seed=5, **({"focal_length_mm": 20.0} if planes > 1 else {}))
    # With the signal-only equaliser (C3, a fixed linear filter): the default one's gain depends on the recording's
    # own noise (Eq. C4 of holocore.optics.cone_equaliser), so a render is not linear in its passes' rays with it.
    one = [render(demo, optics, RenderOptions(preset="fast", spp=n, ray_seed=seed, wrp_planes=planes,
                                              equalise_noise=False))
           for n, seed in ((4, 5), (12, 5 + 7919))]
    assert (len(one[0].meta["wrp_planes_m"]) > 1) == (planes > 1)  # 3 asked: as many as the depth holds
    _forced(monkeypatch, [4, 12])
    opts = RenderOptions(preset="fast", time_limit_s=60.0, wrp_planes=planes, equalise_noise=False)
    if streamed:
        out = tmp_path / "RESULT.npz"
        meta = render_to_file(demo, out, optics, opts, memory_budget_bytes=256 << 20)
        assert meta["memory"]["trace_passes"] == 3  # one frame per chunk
        slm, wrp, _ = load_result(out)
    else:
        r = render(demo, optics, opts)
        slm, wrp, meta = r.slm_field, r.wrp_field, r.meta
    for got, a, b in ((wrp, one[0].wrp_field, one[1].wrp_field), (slm, one[0].slm_field, one[1].slm_field)):
        want = (4 * a.astype(np.complex128) + 12 * b) / 16
        assert np.abs(got - want).max() <= 1e-5 * np.abs(want).max()
        # and it is neither pass alone: the two passes' rays differ
        assert np.abs(a - b).max() > 0.05 * np.abs(want).max()
    sm = meta["sampling"]
    assert sm["time_limit_s"] == 60.0 and sm["spp"] == 16 and [p["spp"] for p in sm["passes"]] == [4, 12]
    assert meta["plan"]["spp"] == 16 and any("time limit" in w for w in meta["plan"]["summary"])
    assert meta["stats"]["rays"] == sum(m.meta["stats"]["rays"] for m in one)


@pytest.mark.slow
def test_holo_render_with_a_time_limit(demo, tmp_path):
    out, progress = tmp_path / "RESULT.npz", tmp_path / "progress.jsonl"
    p = subprocess.run([sys.executable, "-m", "holo", "render", str(demo), "--out", str(out), "--preset", "fast",
                        "--frames", "2", "--resolution", "24x32", "--time-limit-s", "3", "--spp", "4000",
                        "--progress-jsonl", str(progress)], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    assert "time limit 3 s" in p.stderr
    with np.load(out, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        assert np.isfinite(z["slm_field"]).all()
    sm = meta["sampling"]
    assert 16 <= sm["spp"] <= 4000 and sm["passes"][0]["spp"] == 16 and sm["trace_budget_s"] < 3.0
    assert meta["stats"]["rays"] == 24 * 32 * sm["spp"]  # every pass's rays were traced and counted
    # the trace's progress counts seconds of its budget, never past it
    trace = [json.loads(line) for line in progress.read_text().splitlines() if '"trace"' in line]
    assert trace and all(0 <= t["done"] <= t["total"] == max(1, math.ceil(sm["trace_budget_s"])) for t in trace)
