"""Shared test fixtures: the scene bundles the tests run on (the project's own, see tests/project_scenes.py, and
../shared's third-party scenes for the tests whose id says ``shared``), and where the third-party scenes live.
A test's tier is the ``slow`` marker in its own file (``bash scripts/test.sh --quick``, pytest ``-m "not slow"``,
leaves those to the full run); tests/test_tiers.py checks the tiers."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import pytest

from tests.project_scenes import SHARED_SCENES, SceneBundles, shared_available

__all__ = ["SHARED_SCENES", "WEB_SLOW_UNTIL_MARKED"]

# Transitional: the tests/service/test_web_*.py tests that belong to the full tier only still get the ``slow``
# marker here by name until they carry ``@pytest.mark.slow`` / ``pytestmark`` themselves; every other test says
# its tier with the marker in its own file (tests/test_tiers.py checks both). Path -> why it is slow.
WEB_SLOW_UNTIL_MARKED: dict[str, str] = {
    # a job submitted from the page's form and watched to its end (25 s): test_re_run_with_changes submits from
    # the form, the done job's tests show a finished job's page and list, test_web_journey.py follows progress
    "tests/service/test_web_page.py::test_a_job_named_after_its_file_whose_progress_only_moves_forward":
        "a job submitted from the page's form and watched to its end",
    "tests/service/test_web_compare.py": "headless Chromium on two jobs; tests/service/test_web_page.py drives the page",
    "tests/service/test_web_journey.py": "headless Chromium through three jobs of the mirror room; "
                                         "tests/service/test_web_page.py drives each part",
    "tests/service/test_web_evaluation.py": "headless Chromium on an evaluated job; "
                                            "tests/service/test_evaluation_job.py holds the API it shows",
    "tests/service/test_web_list.py": "headless Chromium on four jobs; tests/service/test_scene_picture.py and "
                                      "test_queue_status.py hold the API it shows",
}


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


@pytest.hookimpl(tryfirst=True)  # before pytest's own -m selection reads the markers
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests of :data:`WEB_SLOW_UNTIL_MARKED` get the ``slow`` marker (transitional, see there)."""
    for item in items:
        if any(item.nodeid == p or item.nodeid.startswith(p if "::" in p else p + "::")
               for p in WEB_SLOW_UNTIL_MARKED):
            item.add_marker(pytest.mark.slow)
