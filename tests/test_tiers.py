"""The test tiers name tests by path (tests/conftest.py): a moved or renamed file must not fall silently into the
quick tier."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import FULL_TIER_ONLY, FULL_TIER_ONLY_MODULES

REPO = Path(__file__).resolve().parents[1]


def test_every_path_the_tiers_name_exists():
    missing = [p for p in [*FULL_TIER_ONLY, *FULL_TIER_ONLY_MODULES] if not (REPO / p.split("::")[0]).is_file()]
    assert missing == []
