"""Stored artifacts are checked against their recorded sha256 before they are served or reused. A file's hash
is computed once per version of the file, so repeated downloads cost one ``stat``; any change to the file
(truncation, a rewrite) hashes it again. A version is (size, mtime, ctime, inode, device): mtime alone can be
set back with utime(2) after an in-place overwrite, ctime cannot (every write and every utime sets it to now).
Reuse of a result for a new job re-hashes the files regardless (``fresh``): it happens once per submit, and a
stale cache entry there would hand one job's bytes to another."""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path
from typing import Optional

from service.untrusted import open_job_file

__all__ = ["artifact_intact", "current_sha256"]

_lock = threading.Lock()
_known: dict[str, tuple[tuple[int, ...], str]] = {}


def current_sha256(path: Path, *, fresh: bool = False, root: Optional[Path] = None) -> str:
    """Hex sha256 of the file as it is now (cached per size, mtime, ctime, inode and device; ``fresh``: hashed
    again whatever the cache holds). The file is a job's (``root``: its folder, else the file's own folder) and
    read as service/untrusted.py reads a job's files: no link followed, no FIFO, one name."""
    rel = path.relative_to(root) if root is not None else Path(path.name)
    with open_job_file(root if root is not None else path.parent, rel.as_posix()) as fh:
        st = os.fstat(fh.fileno())
        key = (st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino, st.st_dev)
        with _lock:
            hit = _known.get(str(path))
        if hit is not None and hit[0] == key and not fresh:
            return hit[1]
        h = hashlib.sha256()
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    digest = h.hexdigest()
    with _lock:
        _known[str(path)] = (key, digest)
    return digest


def artifact_intact(path: Path, sha256: str | None, *, fresh: bool = False, root: Optional[Path] = None) -> bool:
    """Whether ``path`` is a plain file of the job's (``root``: the job's folder, see :func:`current_sha256`)
    whose content hashes to ``sha256`` (``fresh``: hashed now)."""
    try:
        return bool(sha256) and current_sha256(path, fresh=fresh, root=root) == sha256
    except (OSError, ValueError):
        return False
