"""The Arduino sketch, compiled on the host against a minimal Arduino stand-in, answers like the simulator."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from display_agent.focus.sim import FocusSimulator

ROOT = Path(__file__).resolve().parents[2]
SKETCH = ROOT / "deploy" / "firmware" / "focus_controller" / "focus_controller.ino"
STUB = Path(__file__).with_name("firmware_stub")


@pytest.fixture(scope="module")
def firmware(tmp_path_factory):
    cxx = shutil.which("g++") or shutil.which("clang++")
    if cxx is None:
        pytest.skip("no C++ compiler to build the sketch on the host")
    out = tmp_path_factory.mktemp("fw") / "focus_fw"
    res = subprocess.run([cxx, "-std=c++17", "-Wall", "-Werror", "-Wno-unused-const-variable", "-I", str(STUB),
                          "-I", str(SKETCH.parent), "-o", str(out), str(STUB / "harness.cpp")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    return out


def _run(fw: Path, script: str) -> list[str]:
    res = subprocess.run([str(fw)], input=script, capture_output=True, text=True, timeout=30)
    assert res.returncode == 0, res.stderr
    return [l.rstrip("\r") for l in res.stdout.split("\n") if l.strip()]


REQUESTS = ["1 PING", "3 PLANES", "7 MOVE PLANE 9", "8 FLY", "bad", "9 MOVE POS 99999", "10 MOVE POS x",
            "11 move plane 1", "12 MOVE", "13 MOVE FOO 3", "14 MOVE PLANE 1 2",
            "16 VERSION"]


def test_sketch_speaks_the_simulators_protocol(firmware):
    out = _run(firmware, "\n".join(REQUESTS) + "\n")
    assert out[0] == "READY focus_controller 1.0 proto=1 planes=5"
    sim = FocusSimulator(planes=[0, 400, 800, 1200, 1600], travel=(0, 2000), move_time_s=0.0, settle_s=0.0)
    expected = [r for line in REQUESTS for r in sim.handle(line)]
    got = out[1:]
    assert len(got) == len(expected)
    for g, e in zip(got, expected):
        if "focus_sim" in e:  # the firmware names itself
            assert g == e.replace("focus_sim", "focus_controller")
        elif e.startswith("?"):  # the sim quotes the offending line; both say SYNTAX
            assert g.startswith("? ERR SYNTAX")
        else:
            assert g == e


def test_sketch_moves_then_settles(firmware):
    out = _run(firmware, "1 VERSION\n2 MOVE PLANE 2\n3 STATUS\n@wait 300\n4 STATUS\n@wait 1000\n5 STATUS\n"
                         "6 MOVE POS 790\n@wait 20\n7 STATUS\n@wait 200\n8 STATUS\n"
                         "9 MOVE PLANE 0\n@wait 100\n10 STOP\n11 STATUS\n")
    r = {l.split()[0]: l for l in out[1:]}
    assert r["1"] == "1 OK focus_controller 1.0 proto=1"
    assert r["2"] == "2 OK MOVING plane=2 target=800"
    assert r["3"].startswith("3 OK MOVING pos=") and r["3"].endswith("target=800")  # ack before arrival
    pos4 = int(r["4"].split("pos=")[1].split()[0])
    assert r["4"].startswith("4 OK MOVING") and 300 <= pos4 <= 400  # 0.8 ms per step
    assert r["5"] == "5 OK SETTLED pos=800 target=800"
    assert r["7"] == "7 OK SETTLING pos=790 target=790"  # 10 steps back, then the settle time
    assert r["8"] == "8 OK SETTLED pos=790 target=790"
    stopped = int(r["10"].split("pos=")[1].split()[0])
    assert 0 < stopped < 790 and r["10"] == f"10 OK SETTLED pos={stopped} target={stopped}"  # stops where it is
    assert r["11"] == f"11 OK SETTLED pos={stopped} target={stopped}"
