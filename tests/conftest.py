"""Shared test fixtures: the scene bundles the tests run on (../shared's third-party scenes when present, else
the project's own stand-ins, see tests/project_scenes.py), and where the third-party scenes live."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import pytest

from tests.project_scenes import SHARED_SCENES, SceneBundles, shared_available

__all__ = ["SHARED_SCENES"]


@pytest.fixture(scope="session")
def shared_scenes() -> Path:
    """../shared/scenes, or a skip that says clearly that it is missing. Only for tests that need third-party
    data as such; every other test takes :func:`scene_bundle` / :func:`scene_bundles`, which never skip."""
    if not shared_available():
        pytest.skip(f"shared scenes not found at {SHARED_SCENES} (clone the project beside ../shared), or "
                    "hidden by HOLO_NO_SHARED")
    return SHARED_SCENES


@pytest.fixture(scope="session")
def project_scene_bundles(tmp_path_factory: pytest.TempPathFactory) -> SceneBundles:
    """The project's own scene bundles, written once per session on first use."""
    return SceneBundles("project", tmp_path_factory.mktemp("project-scenes"))


@pytest.fixture(scope="session")
def scene_bundles(project_scene_bundles: SceneBundles) -> SceneBundles:
    """The shared bundles when ../shared is there (and HOLO_NO_SHARED unset), else the project's stand-ins."""
    return SceneBundles("shared", SHARED_SCENES) if shared_available() else project_scene_bundles


@pytest.fixture(scope="session")
def scene_bundle(scene_bundles: SceneBundles) -> Callable[[str], Path]:
    """``scene_bundle("cbox-mirror-glass")``: that bundle's folder, shared if present, else the project's."""
    return scene_bundles.folder


@pytest.fixture(scope="session")
def bundles_by_source(project_scene_bundles: SceneBundles) -> dict[str, SceneBundles]:
    """Every available source by name (tests.project_scenes.SCENE_SOURCES): ``project`` always, ``shared``
    when present. For cheap tests that run on both."""
    out = {"project": project_scene_bundles}
    if shared_available():
        out["shared"] = SceneBundles("shared", SHARED_SCENES)
    return out
