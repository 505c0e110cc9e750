"""`holo submit` takes `holo render`'s optics options (one list, holo/common.py), so the two cannot drift apart,
and refuses bad ones in one line before it reaches the network."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _holo(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "holo", *args], capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, PYTHONPATH=str(REPO)), cwd=REPO)


def test_submit_has_every_option_render_has_for_the_optics():
    from holo.common import OPTICS_OPTIONS

    sub, ren = _holo("submit", "--help"), _holo("render", "--help")
    for _name, _tp, opt in OPTICS_OPTIONS:
        flag = opt.param_decls[0]
        assert flag in ren.stdout and flag in sub.stdout, flag
    assert "--wrp-planes" in sub.stdout and "--to-display" in sub.stdout


@pytest.mark.parametrize("args, message", [
    (["--wrp-planes", "9"], "--wrp-planes must be in 1..8"),
    (["--frame-phases", "bogus"], "frame_phases"),
    (["--display", "no-such-profile"], "no-such-profile"),
])
def test_bad_options_are_refused_in_one_line_before_any_request(tmp_path, args, message):
    scene = tmp_path / "scene.xml"
    scene.write_text("<scene version='3.0.0'/>")
    # port 9 (discard) is never asked: the options fail first
    r = _holo("submit", str(scene), "--server", "http://127.0.0.1:9", "--token", "hpt_x_y", *args)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in r.stderr, r.stderr
