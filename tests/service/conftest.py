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
