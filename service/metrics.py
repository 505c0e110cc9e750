"""Prometheus metrics of one app (its own registry, so several apps can live in one process, e.g. tests)."""

from __future__ import annotations

from typing import Callable, Optional

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.core import GaugeMetricFamily

__all__ = ["Metrics", "owner_registry"]


class _JobStates:
    def __init__(self, counts: Callable[[], dict[str, int]], scenes: Optional[Callable[[], int]] = None) -> None:
        self._counts = counts
        self._scenes = scenes

    def collect(self):
        g = GaugeMetricFamily("holo_jobs", "Jobs by state (from the database at scrape time).", labels=["state"])
        for state, n in self._counts().items():
            g.add_metric([state], n)
        yield g
        if self._scenes is not None:
            yield GaugeMetricFamily("holo_scenes", "Scenes of this owner.", value=self._scenes())


def owner_registry(db, owner: str) -> CollectorRegistry:
    """The metrics one owner may see: its own jobs by state and its scenes, from the database at scrape time."""
    registry = CollectorRegistry()
    registry.register(_JobStates(lambda: db.count_jobs(owner), lambda: db.count_scenes(owner)))
    return registry


class Metrics:
    def __init__(self, job_counts: Callable[[], dict[str, int]]) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter("holo_http_requests", "HTTP requests by route and status.",
                                ["method", "route", "status"], registry=self.registry)
        self.latency = Histogram("holo_http_request_duration_seconds", "HTTP request latency by route.",
                                 ["route"], registry=self.registry,
                                 buckets=(0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 10))
        self.jobs_finished = Counter("holo_jobs_finished", "Jobs that reached a final state.", ["state"],
                                     registry=self.registry)
        self.jobs_submitted = Counter("holo_jobs_submitted", "Jobs submitted (reused: served from an identical "
                                      "earlier result).", ["reused"], registry=self.registry)
        self.uploads = Counter("holo_scene_uploads", "Scene uploads by outcome.", ["outcome"], registry=self.registry)
        self.workers_busy = Gauge("holo_workers_busy", "Jobs running now.", registry=self.registry)
        self.registry.register(_JobStates(job_counts))
