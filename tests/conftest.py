"""Shared test fixtures: the scene bundles the tests run on (the project's own, see tests/project_scenes.py, and
../shared's third-party scenes for the tests whose id says ``shared``), and where the third-party scenes live.
A test's tier is the ``slow`` marker in its own file (``bash scripts/test.sh --quick``, pytest ``-m "not slow"``,
leaves those to the full run); tests/test_tiers.py checks the tiers."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import pytest

from tests.project_scenes import SHARED_SCENES, SceneBundles, shared_available

__all__ = ["SHARED_SCENES"]

@pytest.fixture(scope="session")
def shared_scenes() -> Path:
    """../shared/scenes, or a skip that says clearly that it is missing. Only for tests that need third-party
    data as such; a test that runs on the project's scenes too takes :func:`bundles_of`."""
    if not shared_available():
        pytest.skip(f"shared scenes not found at {SHARED_SCENES} (clone the project beside ../shared), or "
                    "hidden by HOLO_NO_SHARED")
    return SHARED_SCENES


@pytest.fixture(scope="session")
def project_scene_bundles(tmp_path_factory: pytest.TempPathFactory) -> SceneBundles:
    """The project's own scene bundles, written once per session on first use."""
    return SceneBundles("project", tmp_path_factory.mktemp("project-scenes"))


@pytest.fixture(scope="session")
def scene_bundle(project_scene_bundles: SceneBundles) -> Callable[[str], Path]:
    """``scene_bundle("cbox-mirror-glass")``: the folder of the project's own bundle of that name, the same data
    on a fresh clone and in CI. A test that should also run on ../shared's bundle takes :func:`bundles_of` with a
    parametrisation whose id says ``shared``."""
    return project_scene_bundles.folder


@pytest.fixture(scope="session")
def bundles_of(project_scene_bundles: SceneBundles) -> Callable[[str], SceneBundles]:
    """``bundles_of(source)`` for a source of tests.project_scenes.SCENE_SOURCES: ``"project"`` always,
    ``"shared"`` (../shared/scenes) or a skip that says it is missing."""
    def of(source: str) -> SceneBundles:
        if source == "project":
            return project_scene_bundles
        if source != "shared":
            raise ValueError(f"source must be 'project' or 'shared', got {source!r}")
        if not shared_available():
            pytest.skip(f"shared scenes not found at {SHARED_SCENES} (clone the project beside ../shared), or "
                        "hidden by HOLO_NO_SHARED")
        return SceneBundles("shared", SHARED_SCENES)
    return of
