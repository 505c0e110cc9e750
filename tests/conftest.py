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


@pytest.hookimpl(tryfirst=True)  # before pytest's own -m selection reads the markers
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests of :data:`WEB_SLOW_UNTIL_MARKED` get the ``slow`` marker (transitional, see there)."""
    for item in items:
        if any(item.nodeid == p or item.nodeid.startswith(p if "::" in p else p + "::")
               for p in WEB_SLOW_UNTIL_MARKED):
            item.add_marker(pytest.mark.slow)
