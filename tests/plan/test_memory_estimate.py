"""The memory model (holocore.plan.memory_estimate): it reproduces the peaks it was measured at, grows with the
number of field samples H W C F, and refuses nonsense."""

from __future__ import annotations

import pytest

from holocore.plan.memory_estimate import MEASURED_PEAKS, STAGES, estimate_memory


def test_measured_points_are_reproduced():
    for stage in STAGES:
        for n, peak in MEASURED_PEAKS[stage]:
            # every measured size is H*W*3*F with H, W below; rebuild it from the sample count
            for h, w, f in ((135, 240, 8), (270, 480, 8), (1080, 1920, 24)):
                if h * w * 3 * f == n:
                    got = getattr(estimate_memory(height_px=h, width_px=w, colors=3, frames=f), f"{stage}_bytes")
                    assert abs(got - peak) <= 1, (stage, h, w, f, got, peak)


def test_memory_grows_with_samples_and_only_with_them():
    base = estimate_memory(height_px=540, width_px=960, colors=3, frames=8)
    assert base.peak_bytes == estimate_memory(height_px=960, width_px=540, colors=3, frames=8).peak_bytes
    assert base.peak_bytes == estimate_memory(height_px=540, width_px=960, colors=1, frames=24).peak_bytes
    bigger = estimate_memory(height_px=1080, width_px=1920, colors=3, frames=64)
    for stage in STAGES:
        assert getattr(bigger, f"{stage}_bytes") > getattr(base, f"{stage}_bytes") > 0
    # beyond the largest measurement the last segment's slope continues (linear in H W C F)
    a = estimate_memory(height_px=2160, width_px=3840, colors=3, frames=24).render_bytes
    b = estimate_memory(height_px=1080, width_px=1920, colors=3, frames=24).render_bytes
    c = estimate_memory(height_px=1080, width_px=1920, colors=3, frames=96).render_bytes
    assert a == pytest.approx(c, rel=1e-9) and a > 3 * b


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, None])
def test_bad_sizes_are_refused(bad):
    with pytest.raises(ValueError, match="positive integer"):
        estimate_memory(height_px=bad, width_px=10, colors=3, frames=1)


def test_an_evaluation_adds_its_own_peak_growing_with_the_pixels():
    """``evaluate`` adds the evaluate step's peak (holo evaluate: about 2 KB an SLM pixel, far above the other
    stages'): off, the estimate is as before; on, its size is linear in the pixels, above every peak measured
    (bench/results/evaluation_memory.json) and within twice it, and at 4096x2304 past 20 GB."""
    import json
    from pathlib import Path

    from holocore.plan.memory_estimate import evaluation_bytes

    kw = dict(colors=3, frames=1)
    off = estimate_memory(height_px=540, width_px=960, **kw)
    on = estimate_memory(height_px=540, width_px=960, evaluate=True, **kw)
    assert off.evaluate_bytes == 0 and "evaluate_bytes" not in off.as_dict()
    assert (on.render_bytes, on.encode_bytes, on.view_bytes) == (off.render_bytes, off.encode_bytes, off.view_bytes)
    assert on.peak_stage == "evaluate" and on.peak_bytes == on.evaluate_bytes > 2 * off.peak_bytes
    sizes = [(352, 480), (704, 960), (1056, 1440)]  # 1, 4 and 9 times the pixels
    b = [evaluation_bytes(height_px=h, width_px=w, **kw) for h, w in sizes]
    assert b[0] < b[1] < b[2] and abs((b[2] - b[1]) - (b[1] - b[0]) * 5 / 3) < 10  # linear in H W
    per_px = (b[2] - b[1]) / (1056 * 1440 - 704 * 960)
    assert 1500 < per_px < 4000, per_px
    assert evaluation_bytes(height_px=2304, width_px=4096, **kw) > 20e9
    raw = json.loads((Path(__file__).resolve().parents[2] / "bench/results/evaluation_memory.json").read_text())
    for run in raw["runs"]:
        model = evaluation_bytes(height_px=run["h"], width_px=run["w"], colors=3, frames=run["frames"])
        assert run["peak_rss"] <= model <= 2 * run["peak_rss"], run
