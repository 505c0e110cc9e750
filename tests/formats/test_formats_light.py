"""holocore.formats and the display agent work where torch, Mitsuba and Dr.Jit are not installed (docs/design.md §1):
a subprocess whose sitecustomize makes importing any of them raise ImportError."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
_BLOCKER = '''
import importlib.abc, sys

class _NoHeavy(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("torch", "mitsuba", "drjit"):
            raise ImportError(f"{name} is blocked: this environment has no torch, Mitsuba or Dr.Jit")
        return None

sys.meta_path.insert(0, _NoHeavy())
'''


def _run_blocked(tmp_path: Path, code: str) -> subprocess.CompletedProcess:
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(_BLOCKER)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(REPO)])}
    return subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)


def test_blocker_blocks(tmp_path):
    r = _run_blocked(tmp_path, "import torch")
    assert r.returncode != 0 and "is blocked" in r.stderr


@pytest.mark.slow
def test_agent_and_formats_import_without_torch_mitsuba_drjit(tmp_path):
    r = _run_blocked(tmp_path, "import display_agent, holocore.formats")
    assert r.returncode == 0, r.stderr
    code = ("import sys, display_agent.daemon, display_agent.phasemap, display_agent.cache, "
            "display_agent.service_client, holocore.formats, holocore.io; "
            "print(sorted(m for m in ('torch', 'mitsuba', 'drjit') if m in sys.modules))")
    r = _run_blocked(tmp_path, code)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_formats_round_trip_without_torch(tmp_path):
    """A stack written and read back, with 8-bit levels and a lookup table, in the blocked environment."""
    code = (
        "import json, numpy as np; from holocore import formats as f; "
        "ph = np.linspace(0, 2 * np.pi, 2 * 3 * 4 * 5, endpoint=False).reshape(2, 3, 4, 5); "
        "f.save_stack('s.npz', phase=ph, meta={'wavelengths_m': [6.4e-7, 5.2e-7, 4.5e-7]}); "
        "st = f.open_stack('s.npz', expected_sha256=f.file_sha256('s.npz')); "
        "assert np.array_equal(st.frames_u8, f.phase_to_u8(st.phase)); "
        "assert np.array_equal(f.phase_levels(st.phase), st.frames_u8); "
        "json.dump({'luts': [{'wavelength_nm': 640.0, 'table': list(range(255, -1, -1))}]}, open('l.json', 'w')); "
        "(wl, t), = f.load_lut_file('l.json'); assert wl == 640.0 and t[0] == 255 and t.dtype == np.uint8; "
        "print('ok')")
    r = _run_blocked(tmp_path, code)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_old_holocore_names_are_the_formats_ones():
    from holocore import formats, io

    for name in ("save_result", "load_result", "save_stack", "load_stack", "phase_to_u8", "file_sha256",
                 "NpzWriter", "NpyMember", "npz_members", "read_npz_meta", "RESULT_META_KEYS"):
        assert getattr(io, name) is getattr(formats, name), name
    assert formats.phase_levels(np.array([np.pi]))[0] == formats.phase_to_u8(np.array([np.pi]))[0] == 128
