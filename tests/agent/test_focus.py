"""Focus controller client against the real `holo focus-sim` process, over a pty and over TCP."""

from __future__ import annotations

import threading
import time

import pytest

from display_agent.focus import (
    FocusController,
    FocusDisconnected,
    FocusError,
    FocusTimeout,
)
from display_agent.focus.protocol import format_request, parse_kv, parse_reply
from tests.agent.helpers import (
    free_port,
    read_sim_log,
    start_focus_sim,
    stop_proc,
    wait_for,
)


def test_protocol_lines():
    assert format_request("12", "move", "PLANE", 3) == "12 MOVE PLANE 3\n"
    r = parse_reply("12 ERR RANGE plane must be in [0, 4]")
    assert r is not None and not r.ok and r.code == "RANGE" and r.message == "plane must be in [0, 4]"
    assert parse_reply("READY focus_sim 1.0 proto=1 planes=5") is None
    assert parse_kv("SETTLED pos=12 target=12") == {"state": "SETTLED", "pos": "12", "target": "12"}
    with pytest.raises(ValueError, match="request id"):
        format_request("a b", "PING")
    with pytest.raises(ValueError, match="without spaces"):
        format_request("1", "MOVE", "PLANE 3")


@pytest.fixture()
def tcp_sim(tmp_path):
    port = free_port()
    log = tmp_path / "sim.log"
    p, line = start_focus_sim(["--listen", f"127.0.0.1:{port}", "--move-time-s", "0.3", "--settle-s", "0.1",
                               "--reset-delay-s", "0.4"], log)
    assert line == f"listening 127.0.0.1:{port}"
    yield port, log, p
    stop_proc(p)


@pytest.mark.slow
def test_tcp_reset_on_open_move_ack_then_settled(tcp_sim):
    port, log, _ = tcp_sim
    c = FocusController(f"socket://127.0.0.1:{port}", ping_interval_s=0.1, ready_timeout_s=5)
    t0 = time.monotonic()
    assert c.connect().startswith("focus_sim 1.0 proto=1")
    assert time.monotonic() - t0 >= 0.35  # it had to wait for the simulated boot
    assert c.planes() == [0, 400, 800, 1200, 1600]
    t_move = time.monotonic()
    assert c.move_plane(3) == 1200
    st = c.status()
    assert st.state == "MOVING" and st.target == 1200 and st.pos < 1200  # ack comes before the lens arrives
    st = c.wait_settled(timeout_s=5)
    assert st.settled and st.pos == 1200 and time.monotonic() - t_move >= 0.4  # move 0.3 s + settle 0.1 s
    with pytest.raises(FocusError, match="RANGE") as ei:
        c.move_plane(7)
    assert ei.value.code == "RANGE"
    with pytest.raises(FocusError, match="UNKNOWN"):
        c.request("FLY")
    with pytest.raises(FocusError, match="RANGE"):
        c.move_pos(10**6)
    c.close()
    lines = read_sim_log(log)
    # pings sent while the controller "booted" were lost: the first RX after the banner is answered
    banner_t = next(t for t, d, l in lines if d == "TX" and l.startswith("READY"))
    assert all(t >= banner_t for t, d, _ in lines if d == "RX")
    assert sum(1 for _, d, l in lines if d == "RX" and "MOVE PLANE 3" in l) == 1


def test_pty_serial_port(tmp_path):
    link = tmp_path / "ttyFOCUS"
    p, line = start_focus_sim(["--pty", "--link", str(link), "--move-time-s", "0.15", "--settle-s", "0"],
                              tmp_path / "sim.log")
    try:
        assert line.startswith("pty /dev/")
        wait_for(link.exists, 5, "pty link")
        with FocusController(str(link), ready_timeout_s=5) as c:
            c.connect()
            c.ping()
            st = c.goto(plane=4, settle_timeout_s=5)
            assert st.pos == 1600 and st.settled
        # a second client session on the same pty
        with FocusController(line.split()[1], ready_timeout_s=5) as c2:
            c2.connect()
            assert c2.status().pos == 1600
    finally:
        stop_proc(p)
    wait_for(lambda: not link.exists(), 5, "link removed at exit")


@pytest.mark.slow
def test_timeouts_and_unreachable():
    # loop:// echoes our own request: no reply with our id ever comes
    c = FocusController("loop://", reply_timeout_s=0.2, ready_timeout_s=0.5, ping_interval_s=0.1)
    t0 = time.monotonic()
    with pytest.raises(FocusTimeout, match="did not answer within 0.5 s"):
        c.connect()
    assert time.monotonic() - t0 >= 0.45  # it waited its timeout (a lower bound: load only adds to it)
    port = free_port()  # nobody listens
    c = FocusController(f"socket://127.0.0.1:{port}", reconnect_timeout_s=0.5)
    with pytest.raises(FocusDisconnected, match="unreachable for 0.5 s"):
        c.goto(plane=0)
    with pytest.raises(ValueError, match="exactly one"):
        c.goto(plane=1, pos=3)


@pytest.mark.slow
@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_line_vanishes_and_comes_back(tmp_path, transport, caplog):
    log = tmp_path / "sim.log"
    link = tmp_path / "ttyFOCUS"
    port = free_port()
    args = (["--listen", f"127.0.0.1:{port}", "--reset-delay-s", "0.2"] if transport == "tcp"
            else ["--pty", "--link", str(link)]) + ["--move-time-s", "0.1", "--settle-s", "0"]
    url = f"socket://127.0.0.1:{port}" if transport == "tcp" else str(link)
    p, _ = start_focus_sim(args, log)
    c = FocusController(url, ready_timeout_s=3, reconnect_timeout_s=10, reply_timeout_s=1)
    holder: dict = {}
    try:
        assert c.goto(plane=1).pos == 400
        stop_proc(p)  # the line vanishes
        with pytest.raises(FocusDisconnected):
            for _ in range(20):
                c.status()
                time.sleep(0.05)
        assert not c.connected
        def restart():
            time.sleep(0.6)
            holder["p"], _ = start_focus_sim(args, log)

        th = threading.Thread(target=restart)
        th.start()
        with caplog.at_level("WARNING", logger="holo.agent.focus"):
            st = c.goto(plane=2)  # retries with backoff until the controller is back, then moves
        th.join()
        assert st.pos == 800 and c.reconnects >= 1
        assert any("retrying" in r.message or "reconnecting" in r.message for r in caplog.records)
    finally:
        c.close()
        stop_proc(p)
        stop_proc(holder.get("p"))
