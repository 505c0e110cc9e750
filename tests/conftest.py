"""Shared test fixtures: where the third-party scenes live, and the Mitsuba variant."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"


@pytest.fixture(scope="session")
def shared_scenes() -> Path:
    """../shared/scenes, or a skip that says clearly that it is missing."""
    if not SHARED_SCENES.is_dir():
        pytest.skip(f"shared scenes not found at {SHARED_SCENES} (clone the project beside ../shared)")
    return SHARED_SCENES
