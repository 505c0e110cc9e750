"""Fixtures: real `holo serve` processes for the service tests."""

from __future__ import annotations

from typing import Iterator

import pytest

from tests.service.helpers import Server


@pytest.fixture
def server_factory(tmp_path) -> Iterator:
    servers: list[Server] = []

    def make(name: str = "data", **kw) -> Server:
        s = Server(tmp_path / name, **kw)
        servers.append(s)
        return s

    yield make
    for s in servers:
        s.stop()


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[Server]:
    """A server shared by a module's tests."""
    s = Server(tmp_path_factory.mktemp("svc") / "data").start()
    yield s
    s.stop()


# ---- one evaluated job for the session ----------------------------------------------------------------------------
# Evaluating a job is the most expensive thing a service test waits for (about 35 s on 2 cores: render, encode,
# ground truth, 17 scored cells and the viewer's score). The modules that look at an evaluated job share this one:
# their module-scoped ``server`` fixture returns :func:`evaluation_server`, and they take :func:`evaluated_job`.
# Tests on that server must leave the job as they found it (tests/service/test_evaluation_job.py restores the
# picture it alters).
@pytest.fixture(scope="session")
def evaluation_server(tmp_path_factory) -> Iterator[Server]:
    """The server that holds :func:`evaluated_job`, shared by the modules that look at it."""
    s = Server(tmp_path_factory.mktemp("svc-eval") / "data").start()
    yield s
    s.stop()


@pytest.fixture(scope="session")
def evaluation_demo(tmp_path_factory) -> dict:
    """The demo scene the project writes itself: its folder, a zip of it, and a scratch folder."""
    from holocore.scene.demo import write_demo_scene
    from tests.service.helpers import zip_dir

    tmp = tmp_path_factory.mktemp("eval")
    write_demo_scene(tmp / "demo")
    return {"dir": tmp / "demo", "zip": zip_dir(tmp / "demo"), "tmp": tmp}


@pytest.fixture(scope="session")
def evaluation_scene(evaluation_server, evaluation_demo) -> dict:
    """The demo scene uploaded to :func:`evaluation_server` and planned."""
    from tests.service.helpers import planned_scene

    return planned_scene(evaluation_server, evaluation_demo["zip"])


@pytest.fixture(scope="session")
def evaluated_job(evaluation_server, evaluation_scene) -> dict:
    """The finished job of tests/service/test_evaluation_job.py's EVAL_JOB with ``evaluate: true`` on
    :func:`evaluation_server`, and what its evaluation route answered right after the submit."""
    from tests.service.helpers import wait_state
    from tests.service.test_evaluation_job import EVAL_JOB

    with evaluation_server.client("submit") as c:
        r = c.post("/v1/jobs", json={"scene_id": evaluation_scene["id"], **EVAL_JOB, "evaluate": True})
        assert r.status_code == 202, r.text
        early = c.get(f"/v1/jobs/{r.json()['id']}/evaluation")
        job = wait_state(c, r.json()["id"], ("succeeded", "failed", "cancelled"), timeout=420)
    assert job["state"] == "succeeded", job["error"]
    return {"job": job, "early": early}
