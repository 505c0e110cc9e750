"""Stored artifacts are checked against their recorded sha256 before they are served or reused (issue 10
item 4). A file's hash is computed once per version of the file (size, mtime and inode), so repeated downloads
cost one ``stat``; any change to the file (truncation, a rewrite) hashes it again."""

from __future__ import annotations

import hashlib
import threading
from pathlib import Path

__all__ = ["artifact_intact", "current_sha256"]

_lock = threading.Lock()
_known: dict[str, tuple[tuple[int, int, int], str]] = {}


def current_sha256(path: Path) -> str:
    """Hex sha256 of the file as it is now (cached per size, mtime and inode)."""
    st = path.stat()
    key = (st.st_size, st.st_mtime_ns, st.st_ino)
    with _lock:
        hit = _known.get(str(path))
    if hit is not None and hit[0] == key:
        return hit[1]
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    digest = h.hexdigest()
    with _lock:
        _known[str(path)] = (key, digest)
    return digest


def artifact_intact(path: Path, sha256: str | None) -> bool:
    """Whether ``path`` is a regular file whose content hashes to ``sha256``."""
    try:
        return bool(sha256) and path.is_file() and current_sha256(path) == sha256
    except OSError:
        return False
