"""Downloads against the real test stack server process: ETag caching, hash checks, resume, refusal."""

from __future__ import annotations

import json

import numpy as np
import pytest

from display_agent.cache import StackCache
from display_agent.service_client import (
    BadStack,
    CorruptDownload,
    ServiceClient,
    ServiceError,
    TransientError,
)
from holocore.io import file_sha256, load_stack, save_stack
from tests.agent.helpers import WAVELENGTHS_M, StackServer, free_port, job, make_phase

TOKEN = "t0k3n"


@pytest.fixture()
def server(tmp_path):
    srv = StackServer(tmp_path / "srv", TOKEN).start()
    save_stack(srv.state / "j1.npz", phase=make_phase((2, 3, 40, 48), seed=21), meta={"wavelengths_m": WAVELENGTHS_M})
    srv.set_jobs([job("j1", t=1)])
    yield srv
    srv.stop()


def _stack_gets(srv):
    return [r for r in srv.log() if r["path"].endswith("/stack")]


def test_download_verify_cache_and_304(server, tmp_path):
    cache = StackCache(tmp_path / "cache")
    cl = ServiceClient(server.url, token=TOKEN)
    jobs = cl.list_jobs("lab1")
    assert [j["id"] for j in jobs] == ["j1"] and jobs[0]["stack_sha256"] == file_sha256(server.state / "j1.npz")
    assert cl.list_jobs("other") == []
    r1 = cl.fetch_stack("j1", cache, expected_sha256=jobs[0]["stack_sha256"])
    assert r1.downloaded and r1.stack.path.parent == cache.stacks
    assert r1.stack.path.read_bytes() == (server.state / "j1.npz").read_bytes()
    np.testing.assert_array_equal(r1.stack.phase, load_stack(server.state / "j1.npz")[0])
    r2 = cl.fetch_stack("j1", cache)
    assert not r2.downloaded and r2.stack.sha256 == r1.stack.sha256
    assert [g["status"] for g in _stack_gets(server)] == [200, 304]  # If-None-Match with the cached ETag
    assert list(cache.partial.iterdir()) == []
    cl.heartbeat("lab1", showing={"job_id": "j1", "frame": 0}, state="playing", message="hi")
    hb = [r for r in server.log() if "heartbeat" in r]
    assert hb[-1]["heartbeat"] == {"agent_version": "0", "showing": {"job_id": "j1", "frame": 0},
                                   "state": "playing", "message": "hi"}
    cl.close()


def test_corrupt_bytes_are_dropped_and_never_cached(server, tmp_path):
    cache = StackCache(tmp_path / "cache")
    cl = ServiceClient(server.url, token=TOKEN)
    server.control(mode="corrupt", count=1)
    with pytest.raises(CorruptDownload, match="hash to .* but ETag says"):
        cl.fetch_stack("j1", cache)
    assert cache.lookup("j1") is None and list(cache.partial.iterdir()) == [] and list(cache.stacks.iterdir()) == []
    r = cl.fetch_stack("j1", cache)  # the next (clean) try succeeds
    assert r.downloaded and r.stack.sha256 == file_sha256(server.state / "j1.npz")
    # the job list's hash is checked too (a stale/mismatching announcement is refused)
    cache2 = StackCache(tmp_path / "cache2")
    with pytest.raises(CorruptDownload, match="job stack_sha256 says"):
        cl.fetch_stack("j1", cache2, expected_sha256="ab" * 32)
    cl.close()


def test_truncated_transfer_resumes_with_range(server, tmp_path):
    cache = StackCache(tmp_path / "cache")
    cl = ServiceClient(server.url, token=TOKEN)
    server.control(mode="truncate", count=1)
    with pytest.raises(TransientError, match="interrupted at"):
        cl.fetch_stack("j1", cache)
    part = cache.partial_path("j1")
    size = (server.state / "j1.npz").stat().st_size
    have = part.stat().st_size
    assert 0 < have < size and cache.lookup("j1") is None  # partial kept aside, not installed
    r = cl.fetch_stack("j1", cache)
    assert r.downloaded and r.resumed_from == have and not part.exists()
    gets = _stack_gets(server)
    assert gets[-1]["status"] == 206 and gets[-1]["start"] == r.resumed_from
    assert r.stack.path.read_bytes() == (server.state / "j1.npz").read_bytes()
    cl.close()


def test_hash_consistent_garbage_is_a_bad_stack(server, tmp_path):
    (server.state / "junk.npz").write_bytes(b"PK\x03\x04 not really a zip" * 100)
    ok = server.state / "j3.npz"
    # 2 colours, 3 wavelengths: save_stack refuses to write that, so the file is made by hand
    np.savez(ok, phase=np.zeros((1, 2, 4, 4), np.float32), frames_u8=np.zeros((1, 2, 4, 4), np.uint8),
             meta=np.array(json.dumps({"wavelengths_m": WAVELENGTHS_M})))
    server.set_jobs([job("junk", t=3), job("j3", t=2), job("j1", t=1)])
    cache = StackCache(tmp_path / "cache")
    cl = ServiceClient(server.url, token=TOKEN)
    with pytest.raises(BadStack, match="not a readable npz"):
        cl.fetch_stack("junk", cache)
    with pytest.raises(BadStack, match="must list 2 wavelengths"):
        cl.fetch_stack("j3", cache)
    assert list(cache.stacks.iterdir()) == [] and list(cache.partial.iterdir()) == []
    cl.close()


def test_auth_errors_and_outages_are_classified(server, tmp_path):
    bad = ServiceClient(server.url, token="wrong")
    with pytest.raises(ServiceError, match="HTTP 401"):
        bad.list_jobs("lab1")
    cl = ServiceClient(server.url, token=TOKEN)
    server.control(mode="error500")
    with pytest.raises(TransientError, match="HTTP 500"):
        cl.fetch_stack("j1", StackCache(tmp_path / "c"))
    down = ServiceClient(f"http://127.0.0.1:{free_port()}", token=TOKEN, timeout_s=1)
    with pytest.raises(TransientError, match="ConnectError"):
        down.list_jobs("lab1")
    with pytest.raises(ValueError, match="http"):
        ServiceClient("ftp://x", token=None)
    for c in (bad, cl, down):
        c.close()
