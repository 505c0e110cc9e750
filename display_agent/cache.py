"""The agent's local stack cache: verified files only, moved in atomically.

Layout under ``root``: ``stacks/<sha256>.npz`` (content-addressed), ``index.json`` (job id -> sha256, ETag,
shape, time), ``partial/<job>.part`` (+ ``.etag``) for resumable downloads. The index is rewritten atomically;
a file that no longer matches its hash is dropped on lookup, never shown."""

from __future__ import annotations

import json
import os
import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

from holocore.formats import Stack, StackError, open_stack

__all__ = ["CacheEntry", "StackCache", "safe_job_id"]

_JOB_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")
_SHA_RE = re.compile(r"^[0-9a-f]{64}$")


def safe_job_id(job_id: str) -> str:
    """``job_id`` if it is safe as a file name component, else ValueError."""
    if not isinstance(job_id, str) or not _JOB_RE.match(job_id) or ".." in job_id:
        raise ValueError(f"job id must be 1-128 of [A-Za-z0-9_.-] (no '..'), got {job_id!r}")
    return job_id


@dataclass(frozen=True)
class CacheEntry:
    job_id: str
    sha256: str
    etag: str
    path: Path
    stored_at: float


class StackCache:
    def __init__(self, root: Union[str, Path], *, max_stacks: int = 8) -> None:
        if max_stacks < 1:
            raise ValueError(f"max_stacks must be >= 1, got {max_stacks}")
        self.root = Path(root)
        self.stacks = self.root / "stacks"
        self.partial = self.root / "partial"
        self.stacks.mkdir(parents=True, exist_ok=True)
        self.partial.mkdir(parents=True, exist_ok=True)
        self.max_stacks = max_stacks
        self._index_path = self.root / "index.json"
        self._index: dict[str, dict] = self._read_index()

    def _read_index(self) -> dict[str, dict]:
        try:
            data = json.loads(self._index_path.read_text())
            return {k: v for k, v in data.items() if isinstance(v, dict) and _SHA_RE.match(str(v.get("sha256")))}
        except (OSError, json.JSONDecodeError, AttributeError):
            return {}

    def _write_index(self) -> None:
        fd, tmp = tempfile.mkstemp(dir=self.root, prefix=".index.", suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            json.dump(self._index, fh, indent=1, sort_keys=True)
        os.replace(tmp, self._index_path)

    def partial_path(self, job_id: str) -> Path:
        return self.partial / f"{safe_job_id(job_id)}.part"

    def lookup(self, job_id: str) -> Optional[CacheEntry]:
        """The cached entry for a job if its file is there (contents are checked by :meth:`open`)."""
        rec = self._index.get(safe_job_id(job_id))
        if rec is None:
            return None
        path = self.stacks / f"{rec['sha256']}.npz"
        if not path.is_file():
            self.forget(job_id)
            return None
        return CacheEntry(job_id=job_id, sha256=rec["sha256"], etag=str(rec.get("etag", "")), path=path,
                          stored_at=float(rec.get("stored_at", 0.0)))

    def open(self, job_id: str) -> Optional[Stack]:
        """Load a cached stack, re-verifying its hash and contents; a damaged file is removed (None)."""
        entry = self.lookup(job_id)
        if entry is None:
            return None
        try:
            return open_stack(entry.path, expected_sha256=entry.sha256)
        except StackError:
            entry.path.unlink(missing_ok=True)
            self.forget(job_id)
            raise

    def install(self, job_id: str, verified_file: Path, *, sha256: str, etag: str) -> CacheEntry:
        """Move a verified download into the cache (atomic rename on the same filesystem)."""
        safe_job_id(job_id)
        if not _SHA_RE.match(sha256):
            raise ValueError(f"sha256 must be 64 lowercase hex digits, got {sha256!r}")
        dest = self.stacks / f"{sha256}.npz"
        os.replace(verified_file, dest)
        self._index[job_id] = {"sha256": sha256, "etag": etag, "stored_at": time.time()}
        self._evict(keep=job_id)
        self._write_index()
        return CacheEntry(job_id=job_id, sha256=sha256, etag=etag, path=dest, stored_at=time.time())

    def forget(self, job_id: str) -> None:
        if self._index.pop(job_id, None) is not None:
            self._write_index()

    def _evict(self, *, keep: str) -> None:
        by_age = sorted(self._index.items(), key=lambda kv: kv[1].get("stored_at", 0.0))
        while len(by_age) > self.max_stacks:
            job, rec = by_age.pop(0)
            if job == keep:
                continue
            del self._index[job]
            if not any(r["sha256"] == rec["sha256"] for r in self._index.values()):
                (self.stacks / f"{rec['sha256']}.npz").unlink(missing_ok=True)
