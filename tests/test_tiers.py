"""The test tiers: a test is in the full tier only when it carries the ``slow`` marker in its own file
(``@pytest.mark.slow``, ``pytest.param(..., marks=pytest.mark.slow)`` or a module's ``pytestmark``), so a renamed
or moved test keeps its tier. The quick tier (``bash scripts/test.sh --quick``, pytest ``-m "not slow"``) must
still hold tests of every package. The suite is collected once, in a subprocess, as CI collects it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest


REPO = Path(__file__).resolve().parents[1]

_PROBE = '''
import json, os
import pytest

@pytest.hookimpl(trylast=True)  # after every marker, conftest's included, is on the items
def pytest_collection_modifyitems(config, items):
    with open(os.environ["TIER_PROBE_OUT"], "w") as f:
        json.dump([[i.nodeid, i.get_closest_marker("slow") is not None] for i in items], f)
'''


@pytest.fixture(scope="module")
def collected(tmp_path_factory) -> dict[str, bool]:
    """Every test id of the suite -> whether it is marked slow, from ``pytest --collect-only``."""
    d = tmp_path_factory.mktemp("tier-probe")
    (d / "tier_probe.py").write_text(_PROBE)
    out = d / "items.json"
    env = {**os.environ, "TIER_PROBE_OUT": str(out),
           "PYTHONPATH": os.pathsep.join([str(d), str(REPO), os.environ.get("PYTHONPATH", "")])}
    r = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                        "-p", "tier_probe", "tests"], cwd=REPO, env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return dict(json.loads(out.read_text()))


def _packages() -> list[str]:
    """tests/ and every folder under it that holds test modules, as 'tests', 'tests/optics', ..."""
    return sorted({str(p.parent.relative_to(REPO)) for p in (REPO / "tests").rglob("test_*.py")
                   if "__pycache__" not in p.parts})


def test_the_slow_marker_is_registered(pytestconfig):
    names = [line.split(":", 1)[0].strip() for line in pytestconfig.getini("markers")]
    assert "slow" in names


@pytest.mark.slow  # collects the whole suite in a subprocess (about 12 s); CI's full run keeps the tiers in check
def test_the_quick_tier_holds_tests_of_every_package(collected):
    quick = [n for n, slow in collected.items() if not slow]
    without = [pkg for pkg in _packages()
               if not any(n.split("::")[0].rpartition("/")[0] == pkg for n in quick)]
    assert without == [], f"no quick-tier test in {without}"
    assert any(slow for slow in collected.values()), "no test marked slow: the full tier is the quick tier"
