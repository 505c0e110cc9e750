"""The encoder's and the load's terms of the time model (holocore.plan.estimate): the encoder's work is counted
on the grid the encoder really transforms, its iterations are the stop rule's measured ones, and a loaded
machine's slowdown follows from fair sharing of the cores."""

from __future__ import annotations

import json
import math

import pytest
import torch

from holocore.display.optics import OpticsConfig
from holocore.encode.operator import Operator
from holocore.plan.estimate import (
    STOP_RULE_DATA,
    encode_work,
    estimate_breakdown,
    load_slowdown,
    machine_load,
    stop_iterations,
)
from holocore.pipeline import RenderOptions


def test_encode_work_counts_the_grids_the_encoder_transforms():
    """One iteration transforms each colour's padded grid; the time model must count those very grids, which
    grow with the WRP's distance (the ASM's reach, lambda z / 2p) up to twice the SLM's sides."""
    o = OpticsConfig(resolution_hw=(135, 240), frames=3, pitch_um=8.0)
    for z in (1e-3, 4.5e-3, 80e-3):
        grids = [Operator(o.resolution_hw, z, lam, o.pitch_m, cone=True, device=torch.device("cpu"))
                 for lam in o.wavelengths_m]
        want = o.frames * sum(op.hp * op.wp * math.log2(op.hp * op.wp) for op in grids)
        assert encode_work(o, z) == pytest.approx(want)
    # 80 mm from an 8 um SLM the reach (~400 px at 640 nm) exceeds the sides: the 2x grid, 4x the pixels
    near, far = encode_work(o, 1e-3), encode_work(o, 80e-3)
    assert 3.5 < far / near < 5.0
    # the estimate's encode stage follows the grid: z_inf is its default distance
    opts = RenderOptions(preset="balanced", spp=16)
    b4 = estimate_breakdown(o.model_copy(update={"z_inf_mm": 4.0}), opts, encode_iterations=100)
    b80 = estimate_breakdown(o.model_copy(update={"z_inf_mm": 80.0}), opts, encode_iterations=100)
    assert b80["encode"] / b4["encode"] == pytest.approx(encode_work(o, 80e-3) / encode_work(o, 4e-3))
    with pytest.raises(ValueError, match="z_wrp_m"):
        encode_work(o, 0.0)


def test_stop_iterations_are_the_measured_ones_by_size():
    doc = json.loads(STOP_RULE_DATA.read_text())
    for row in doc["sizes"]:
        h, w = row["shape_hw"]
        assert h * w == row["pixels"]
        assert stop_iterations(h, w) == row["median"] and stop_iterations(h, w, quantile="p90") == row["p90"]
        assert row["p90"] >= row["median"]
    # between two measured sizes: between their values; beyond them: held at the nearest
    a, b = sorted(doc["sizes"], key=lambda r: r["pixels"])[:2]
    mid = stop_iterations(190, 340)
    assert min(a["median"], b["median"]) <= mid <= max(a["median"], b["median"])
    assert stop_iterations(8, 8) == a["median"] and stop_iterations(4320, 7680) == doc["sizes"][-1]["median"]
    with pytest.raises(ValueError, match="quantile"):
        stop_iterations(10, 10, quantile="mean")


def test_a_loaded_machine_slows_a_run_by_its_share_of_the_cores():
    assert load_slowdown(0.0, 2) == 1.0
    assert load_slowdown(8.0, 2) == pytest.approx(5.0)  # 2 of 10 runnable threads' worth of 2 cores
    assert load_slowdown(2.0, 16) == pytest.approx(1.125)
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="other_load"):
            load_slowdown(bad, 2)
    now = machine_load()
    assert set(now) == {"load_1min", "runnable", "cores", "others", "slowdown"}
    assert 0 <= now["others"] <= now["runnable"] and now["slowdown"] >= 1.0
    # the caller's own runs are left out: with all of the load its own, the machine counts as idle
    assert machine_load(own_threads=1e6)["slowdown"] == 1.0


def test_the_load_is_the_runnable_threads_sampled_now_not_the_lagging_average(monkeypatch):
    """The one-minute average still counts a run that ended a minute ago; the estimate uses a fifth-of-a-second
    sample of the runnable threads, kept a few seconds (a form estimates on every keystroke)."""
    import os
    import time

    from holocore.plan import estimate

    monkeypatch.setattr(os, "getloadavg", lambda: (9.0, 9.0, 9.0))
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(estimate, "_SAMPLED", {"at": time.monotonic(), "value": 6.0})
    got = machine_load(own_threads=2.0)
    assert got["load_1min"] == 9.0 and got["runnable"] == 6.0 and got["others"] == 4.0
    assert got["slowdown"] == pytest.approx(3.0)
    monkeypatch.setattr(estimate, "_SAMPLED", {})
    fresh = estimate._runnable_now(samples=3, interval_s=0.01)
    assert fresh is None or fresh >= 0.0


def test_the_plan_counts_the_default_optimisers_iterations_at_their_cost():
    """The time model's encode follows the optimiser (holocore.plan.encode_steps): the default L-BFGS runs its 28
    iterations at every size, each 1.17 of Adam's; Adam runs until its stop rule (its measured median). The
    quality model counts L-BFGS's iterations as the Adam iterations that reach the same error."""
    from holocore.plan.encode_steps import rule
    from holocore.plan.estimate import encode_iterations
    from holocore.plan.quality import predict_quality

    for hw in ((135, 240), (1080, 1920)):
        assert encode_iterations(*hw) == 28
        assert encode_iterations(*hw, optimiser="adam") == stop_iterations(*hw)
        assert encode_iterations(*hw, iterations=12) == 12
    assert encode_iterations(1080, 1920, optimiser="adam", iterations=40) == 40
    o = OpticsConfig(resolution_hw=(135, 240), frames=3, pitch_um=8.0)
    opts = RenderOptions(preset="balanced", spp=16)
    lb = estimate_breakdown(o, opts, encode_iterations=30)["encode"]
    ad = estimate_breakdown(o, opts, encode_iterations=30, encode_optimiser="adam")["encode"]
    assert lb / ad == pytest.approx(rule("lbfgs").cost)
    common = dict(frames=24, frame_phases="coded", noise_to_signal=0.01, encoder="sgd")
    default = predict_quality(**common).psnr_db
    assert default == pytest.approx(predict_quality(**common, optimiser="lbfgs", iterations=28).psnr_db)
    # 28 x 1.4 = 39.2 Adam iterations: between Adam's 39 and 40
    assert predict_quality(**common, optimiser="adam", iterations=39).psnr_db < default
    assert default < predict_quality(**common, optimiser="adam", iterations=40).psnr_db
    assert default < predict_quality(**common, optimiser="adam").psnr_db  # the stop rule's 160: a little better
    with pytest.raises(ValueError, match="optimiser must be one of lbfgs, adam"):
        encode_iterations(10, 10, optimiser="newton")
