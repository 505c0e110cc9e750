"""Static checks of deploy/: the compose file, Dockerfiles and systemd unit agree with the service's CLI."""

from __future__ import annotations

import configparser
import re
from pathlib import Path

import pytest

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def test_compose_services_share_the_data_volume_and_bind_locally():
    yaml = pytest.importorskip("yaml")
    doc = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    services = doc["services"]
    assert {"service", "ray-head", "ray-worker", "ray-worker-gpu"} <= set(services)
    for name, svc in services.items():
        assert "holo-data:/data" in svc["volumes"], name
    assert services["service"]["environment"]["HOLO_RAY_ADDRESS"].startswith("ray://ray-head:")
    assert all(p.startswith("127.0.0.1:") for p in services["service"]["ports"])
    gpu = services["ray-worker-gpu"]["deploy"]["resources"]["reservations"]["devices"][0]
    assert gpu["capabilities"] == ["gpu"] and services["ray-worker-gpu"]["profiles"] == ["gpu"]
    for svc in services.values():
        df = DEPLOY.parent / svc["build"]["dockerfile"]
        assert df.is_file()


@pytest.mark.parametrize("name", ["Dockerfile.cpu", "Dockerfile.cuda"])
def test_dockerfiles_pin_torch_and_run_holo_serve(name):
    text = (DEPLOY / "docker" / name).read_text()
    assert re.search(r'pip install "torch==2\.13\.0"', text)
    for pkg in ("holocore", "holo", "service"):
        assert f"COPY {pkg} ./{pkg}" in text
    assert '"holo", "serve", "--data-dir", "/data"' in text and "USER holo" in text


def test_systemd_unit_runs_the_service_on_localhost():
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.read_string((DEPLOY / "systemd" / "holo-serve.service").read_text())
    start = cp["Service"]["ExecStart"]
    assert "holo serve --data-dir /var/lib/holo" in start and "--host 127.0.0.1" in start
    assert cp["Service"]["User"] == "holo" and cp["Service"]["KillMode"] == "mixed"
    assert cp["Service"]["ReadWritePaths"] == "/var/lib/holo"
