"""SLM backends and time-multiplexed, colour-sequential playback."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from PIL import Image

from display_agent.playback import Player
from display_agent.slm import NullSLM, SLMError, open_slm
from display_agent.slm.sim import SimSLM, frame_png_name
from tests.agent.helpers import slm_shows


def _levels(shape=(3, 3, 16, 24), seed=0):
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def test_sim_slm_writes_exact_pngs_and_logs_every_presentation(tmp_path):
    lv = _levels()
    slm = open_slm(f"sim:{tmp_path}")
    assert isinstance(slm, SimSLM)
    slm.load(stack_id="job1", levels=lv)
    p = Player(slm, rate_hz=0)
    st = p.play(passes=2)
    slm.close()
    assert st.frames_shown == 2 * 3 * 3 and slm.shown == 18
    for f in range(3):
        for c in range(3):
            img = Image.open(tmp_path / frame_png_name("job1", c, f))
            assert img.mode == "L"
            np.testing.assert_array_equal(np.asarray(img), lv[f, c])
    shows = slm_shows(tmp_path)
    assert len(shows) == 18
    # colour-sequential order inside each frame: (f0,c0),(f0,c1),(f0,c2),(f1,c0),...
    assert [(s["f"], s["c"]) for s in shows[:9]] == [(f, c) for f in range(3) for c in range(3)]
    import hashlib
    assert all(s["sha256"] == hashlib.sha256(lv[s["f"], s["c"]].tobytes()).hexdigest() for s in shows)


def test_slm_refuses_bad_input(tmp_path):
    slm = NullSLM()
    with pytest.raises(SLMError, match="no stack loaded"):
        slm.show(0)
    with pytest.raises(ValueError, match="uint8"):
        slm.load(stack_id="a", levels=np.zeros((1, 1, 2, 2), np.float32))
    with pytest.raises(ValueError, match="plain name"):
        slm.load(stack_id="../evil", levels=np.zeros((1, 1, 2, 2), np.uint8))
    slm.load(stack_id="a", levels=np.zeros((2, 1, 2, 2), np.uint8))
    with pytest.raises(ValueError, match=r"frame must be in \[0, 1\]"):
        slm.show(2)
    with pytest.raises(ValueError, match="slm driver must be one of .*null.*sim.*window"):
        open_slm("projector:1")
    with pytest.raises(ValueError, match="sim:DIR"):
        open_slm("sim:")


class FakeClock:
    """A clock that only moves when the player sleeps: the schedule is exact, whatever the machine's load."""

    def __init__(self, t0_s: float = 100.0) -> None:
        self.now_s = t0_s

    def clock(self) -> float:
        return self.now_s

    def sleep(self, dt_s: float) -> None:
        assert dt_s > 0
        self.now_s += dt_s


class TimedSLM(NullSLM):
    """A NullSLM that records the clock time and the (frame, colour) of each presentation; a presentation
    listed in ``stall_s`` takes that long (a slow panel)."""

    def __init__(self, clock: FakeClock, stall_s: dict[tuple[int, int], float] | None = None) -> None:
        super().__init__()
        self._clock = clock
        self._stall_s = dict(stall_s or {})
        self.shown_at_s: list[float] = []
        self.slots: list[tuple[int, int]] = []

    def _present(self, frame: int, color: int) -> None:
        self.shown_at_s.append(self._clock.clock())
        self.slots.append((frame, color))
        self._clock.now_s += self._stall_s.get((frame, color), 0.0)


def test_playback_paces_at_the_rate_and_switches_lasers_per_colour():
    fake = FakeClock()
    slm = TimedSLM(fake)
    slm.load(stack_id="a", levels=_levels((4, 3, 2, 2)))
    colors: list[int] = []
    p = Player(slm, rate_hz=240.0, laser_hook=colors.append, clock=fake.clock, sleep=fake.sleep)
    st = p.play(passes=2)
    n = 2 * 4 * 3
    assert st.frames_shown == n and st.passes == 2 and st.late == 0
    # slot k is presented at k / rate: n slots take (n - 1) / rate
    np.testing.assert_allclose(np.asarray(slm.shown_at_s) - 100.0, np.arange(n) / 240.0, atol=1e-9)
    assert st.seconds == pytest.approx((n - 1) / 240.0)
    assert colors == [0, 1, 2] * 8  # one switch before each colour's frame
    single = NullSLM()
    single.load(stack_id="m", levels=_levels((5, 1, 2, 2)))
    calls: list[int] = []
    Player(single, rate_hz=0, laser_hook=calls.append).play(passes=3)
    assert calls == [0]  # one colour: the laser is set once


def test_playback_paces_on_the_real_clock_by_default():
    slm = NullSLM()
    slm.load(stack_id="a", levels=_levels((2, 3, 2, 2)))
    t0 = time.monotonic()
    Player(slm, rate_hz=200.0).play(passes=1)
    assert time.monotonic() - t0 >= 5 / 200.0 - 1e-3  # it waits (a lower bound: load only adds to it)


def test_a_late_slot_is_counted_not_skipped():
    fake = FakeClock()
    slm = TimedSLM(fake, stall_s={(0, 1): 0.035})  # this presentation takes 3.5 periods at 100 Hz
    slm.load(stack_id="a", levels=_levels((2, 3, 2, 2)))
    st = Player(slm, rate_hz=100.0, clock=fake.clock, sleep=fake.sleep).play(passes=1)
    # every slot shown once, in order; the slots due during the stall (0.02, 0.03, 0.04 s) come at once after
    # it (0.045 s), the first two more than a period late; the slot due at 0.05 s is on time again
    assert slm.slots == [(f, c) for f in range(2) for c in range(3)] and st.frames_shown == 6
    np.testing.assert_allclose(np.asarray(slm.shown_at_s) - 100.0, [0.0, 0.01, 0.045, 0.045, 0.045, 0.05],
                               atol=1e-9)
    assert st.late == 2


def test_playback_stops_on_request():
    slm = NullSLM()
    slm.load(stack_id="a", levels=_levels((24, 3, 2, 2)))
    stop = threading.Event()
    p = Player(slm, rate_hz=100.0)
    threading.Timer(0.1, stop.set).start()
    st = p.play(passes=10, stop_event=stop)
    assert st.stopped and st.frames_shown < 24 * 3 * 10  # from another thread: stops long before 7.2 s
    # where the stop comes is exact on a fake clock: set during the wait for slot 5, slot 5 is the last shown
    fake = FakeClock()
    waits = []

    def sleep(dt_s: float) -> None:
        fake.sleep(dt_s)
        waits.append(dt_s)
        if len(waits) == 5:
            stop.set()

    stop.clear()
    st = Player(slm, rate_hz=100.0, clock=fake.clock, sleep=sleep).play(passes=10, stop_event=stop)
    assert st.stopped and st.frames_shown == 6 and st.passes == 0
    with pytest.raises(ValueError, match="rate_hz"):
        Player(slm, rate_hz=-1)
    with pytest.raises(ValueError, match="passes"):
        p.play(passes=0)


def test_window_slm_shows_the_levels_on_the_screen(monkeypatch):
    pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    lv = _levels((2, 3, 20, 30), seed=4)
    slm = open_slm("window:0:64x48")
    try:
        slm.load(stack_id="w", levels=lv)
        w, h = slm.size
        x0, y0 = (w - 30) // 2, (h - 20) // 2
        for f in range(2):
            for c in range(3):
                slm.show(f, c)
                screen = slm.screen_levels()
                np.testing.assert_array_equal(screen[y0:y0 + 20, x0:x0 + 30], lv[f, c])
                assert int(screen.sum()) == int(lv[f, c].astype(np.int64).sum())  # black around it
        with pytest.raises(ValueError, match="larger than the SLM window"):
            slm.load(stack_id="big", levels=np.zeros((1, 1, h + 1, 2), np.uint8))
    finally:
        slm.close()


def test_rate_holds_across_consecutive_passes():
    # looping one pass at a time (as the daemon does) must not squeeze the pass boundary
    fake = FakeClock()
    slm = TimedSLM(fake)
    slm.load(stack_id="a", levels=_levels((1, 3, 2, 2)))
    p = Player(slm, rate_hz=200.0, clock=fake.clock, sleep=fake.sleep)
    for _ in range(20):
        p.play(passes=1)
    assert p.total.frames_shown == 60
    # 60 slots at 200 Hz, one period apart across the pass boundaries too (not 40 periods)
    np.testing.assert_allclose(np.asarray(slm.shown_at_s) - 100.0, np.arange(60) / 200.0, atol=1e-9)
    fake.now_s += 0.1  # after a pause the schedule restarts instead of bursting to catch up
    resumed_s = fake.now_s
    p.play(passes=1)
    np.testing.assert_allclose(np.asarray(slm.shown_at_s[60:]) - resumed_s, np.arange(3) / 200.0, atol=1e-9)
