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
