"""What the root side reads of a job's folder, with the job's files swapped for what a compromised job can make:
a FIFO (a plain open() blocks until a writer comes, freezing the scheduler's thread), a symlink and a hard link
to a file only root may read (its text must not reach the job's progress, status or the API), a folder swapped
for a link, and a file far larger than its kind. Each reader the scheduler and the API use is called as they
call it, in a thread that must return within seconds."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import pytest

from service.api.jobs import _log_text
from service.integrity import artifact_intact
from service.jobfiles import read_job_file, read_run_status
from service.untrusted import JSON_MAX_BYTES, UntrustedFile, read_job_json
from service.workers.runfiles import hash_artifacts, read_progress, step_weights

SECRET = "ROOT-ONLY-SECRET"
KINDS = ("fifo", "symlink", "hardlink", "oversized")


def _returns(fn, timeout: float = 5.0):
    """fn()'s value or exception, failing the test when it has not returned within ``timeout`` s (the thread is a
    daemon: a reader stuck on a FIFO does not keep the test run alive)."""
    out: dict = {}

    def run():
        try:
            out["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 - the caller judges it
            out["error"] = exc

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(timeout)
    assert not t.is_alive(), f"{fn} blocked for {timeout} s"
    if "error" in out:
        raise out["error"]
    return out["value"]


@pytest.fixture
def job(tmp_path) -> Path:
    d = tmp_path / "jobs" / "j1"
    d.mkdir(parents=True)
    (d / "job.json").write_text(json.dumps({"evaluate": True}))
    (d / "step.json").write_text(json.dumps({"step": "render", "index": 0}))
    (d / "progress-render.jsonl").write_text(json.dumps({"stage": "trace", "done": 1, "total": 2}) + "\n")
    return d


@pytest.fixture
def secret(tmp_path) -> Path:
    """A root-only file holding lines every reader would accept: JSON progress, a status, a job file."""
    p = tmp_path / "secret.jsonl"
    p.write_text(json.dumps({"step": "render", "stage": SECRET, "done": 1, "total": 2, "ok": True,
                             "evaluate": True, "error": SECRET}) + "\n")
    os.chmod(p, 0o600)
    return p


def _swap(path: Path, kind: str, secret: Path) -> None:
    """Replace ``path`` with a FIFO, a link to ``secret``, a hard link to it, or a file past any cap."""
    path.unlink(missing_ok=True)
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "symlink":
        path.symlink_to(secret)
    elif kind == "hardlink":
        os.link(secret, path)
    else:
        path.write_text(json.dumps({"step": "render", "pad": "x" * (JSON_MAX_BYTES + 10), "stage": SECRET}) + "\n")


@pytest.mark.parametrize("kind", KINDS)
def test_step_json_swapped_reads_as_no_progress(job, secret, kind):
    _swap(job / "step.json", kind, secret)
    assert _returns(lambda: read_progress(job)) is None


@pytest.mark.parametrize("kind", KINDS)
def test_a_progress_file_swapped_gives_none_of_its_text(job, secret, kind):
    _swap(job / "progress-render.jsonl", kind, secret)
    prog = _returns(lambda: read_progress(job))
    assert prog is not None and SECRET not in json.dumps(prog)
    if kind != "oversized":  # a progress file may grow long: its last line still counts
        assert (prog["step"], prog["done"], prog["total"]) == ("render", 0, 0)


@pytest.mark.parametrize("kind", KINDS)
def test_job_json_swapped_is_refused(job, secret, kind):
    _swap(job / "job.json", kind, secret)
    assert _returns(lambda: step_weights(job)).get("evaluate") is None  # not read: no evaluation share
    with pytest.raises(OSError):
        _returns(lambda: read_job_file(job))


@pytest.mark.parametrize("kind", KINDS)
def test_status_json_swapped_is_no_status(job, secret, kind):
    _swap(job / "status.json", kind, secret)
    assert _returns(lambda: read_run_status(job)) is None


@pytest.mark.parametrize("kind", KINDS)
def test_a_log_swapped_is_not_served(job, secret, kind):
    _swap(job / "render.log", kind, secret)
    if kind == "oversized":  # a log is read from its tail, whatever its size
        assert "bytes are left out" in _returns(lambda: _log_text(job / "render.log", [str(job)]))
        return
    with pytest.raises(OSError):
        _returns(lambda: _log_text(job / "render.log", [str(job)]))


@pytest.mark.parametrize("kind", ("fifo", "symlink", "hardlink"))
def test_an_artifact_swapped_is_neither_hashed_nor_intact(job, secret, kind):
    import hashlib

    _swap(job / "preview.png", kind, secret)
    assert "preview.png" not in _returns(lambda: hash_artifacts(job))
    sha = hashlib.sha256(secret.read_bytes()).hexdigest()
    assert _returns(lambda: artifact_intact(job / "preview.png", sha)) is False


@pytest.mark.parametrize("index", ("pictures/index.json", "evaluation/index.json"))
@pytest.mark.parametrize("kind", KINDS)
def test_an_index_swapped_is_refused(job, secret, kind, index):
    (job / index).parent.mkdir()
    _swap(job / index, kind, secret)
    with pytest.raises(OSError):
        _returns(lambda: read_job_json(job, index))


def test_a_folder_swapped_for_a_link_is_refused(job, tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "index.json").write_text(json.dumps({"stolen": True}))
    (job / "pictures").symlink_to(elsewhere)
    with pytest.raises(OSError):
        read_job_json(job, "pictures/index.json")
    with pytest.raises(UntrustedFile):
        read_job_json(job, "../j1/job.json")
    assert read_job_json(job, "job.json") == {"evaluate": True}  # and a plain file of the job's reads


@pytest.mark.parametrize("kind", ("fifo", "symlink", "hardlink"))
def test_the_engine_never_hands_a_swapped_driver_log_to_the_driver(job, secret, kind):
    """The engine (root) opens driver.log for the driver's output and, sandboxed, chowns it to the slot's uid:
    through a link that would give the job another file; a FIFO would block the scheduler."""
    from service.workers.engine import LocalEngine

    _swap(job / "driver.log", kind, secret)
    before = os.stat(secret)
    with pytest.raises(OSError, match="not a plain file|Too many levels|symbolic link|No such device"):
        _returns(lambda: LocalEngine().launch("j1", 1, job))
    after = os.stat(secret)
    assert (after.st_uid, after.st_size) == (before.st_uid, before.st_size)
