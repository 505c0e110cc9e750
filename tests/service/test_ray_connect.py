"""Connecting the Ray engine: a failed first connection (the Ray Client server for this connection failed to
start, as seen in CI on a loaded 2-core machine) is retried; a cluster that stays unreachable is one line."""

from __future__ import annotations

import pytest

from service.workers import ray_engine

pytestmark = pytest.mark.slow  # Ray Client start-up


class FakeRay:
    """ray.init fails ``failures`` times with Ray's own error text, then connects."""

    def __init__(self, failures: int) -> None:
        self.failures, self.calls, self.shutdowns = failures, 0, 0

    def init(self, **kwargs) -> None:
        self.calls += 1
        if self.calls <= self.failures:
            raise ConnectionAbortedError("Initialization failure from server:\nTraceback (most recent call last):\n"
                                         "RuntimeError: Starting Ray client server failed. See "
                                         "ray_client_server_23000.err for detailed logs.")

    def shutdown(self) -> None:
        self.shutdowns += 1


@pytest.fixture(autouse=True)
def no_backoff(monkeypatch):
    monkeypatch.setattr(ray_engine, "CONNECT_BACKOFF_S", 0.0)


def test_a_failed_first_connection_is_retried():
    ray = FakeRay(failures=ray_engine.CONNECT_ATTEMPTS - 1)
    ray_engine.connect(ray, "ray://127.0.0.1:10001")
    assert ray.calls == ray_engine.CONNECT_ATTEMPTS and ray.shutdowns == ray_engine.CONNECT_ATTEMPTS - 1


def test_an_unreachable_cluster_is_one_line_naming_the_address_and_the_cause():
    ray = FakeRay(failures=99)
    with pytest.raises(ray_engine.RayUnavailable) as err:
        ray_engine.connect(ray, "ray://127.0.0.1:10001")
    msg = str(err.value)
    assert "\n" not in msg and "ray://127.0.0.1:10001" in msg and "Ray client server failed" in msg
    assert ray.calls == ray_engine.CONNECT_ATTEMPTS
