"""Reading a job's folder, whose every entry the job may have made.

While a sandboxed run goes on, its folder belongs to its uid and the service reading it may be root; after the
run, what the job left there is still the job's doing. Any entry may be a symlink (to the database,
/etc/shadow), a FIFO (an open that never returns, freezing the scheduler's thread), a hard link to another
file, a folder swapped for a link, or a file of any size. So the service trusts nothing of a job's folder and
reads it only through this module: each component is opened relative to the descriptor of the one above it
(``openat``), links are never followed, opens never block, what is opened must be a plain file with one name,
and every read has a size cap. ``docs/service.md`` lists what the root side reads this way.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path, PurePosixPath
from typing import Any, BinaryIO, Optional

__all__ = ["UntrustedFile", "JSON_MAX_BYTES", "open_job_file", "read_job_bytes", "read_job_json", "read_job_tail"]

# The JSON files a run writes (job.json, status.json, step.json, the pictures' and evaluation's index.json) are
# a few KiB; a plan's is the largest, at most tens of KiB. Past this a file is the job's attack, not its record.
JSON_MAX_BYTES = 1 << 20

_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
_FILE_FLAGS = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC


class UntrustedFile(OSError):
    """A job's file that is not a plain file of its own with one name, or larger than its cap."""


def _parts(rel: str | PurePosixPath) -> tuple[str, ...]:
    parts = PurePosixPath(rel).parts
    if not parts or PurePosixPath(rel).is_absolute() or any(p in ("", ".", "..") for p in parts):
        raise UntrustedFile(f"{rel}: not a name inside the job's folder")
    return parts


def open_job_file(folder: str | Path, rel: str | PurePosixPath, *, max_bytes: Optional[int] = None) -> BinaryIO:
    """``folder/rel`` opened for reading as described above (``max_bytes``: its size at most this). The caller
    closes it. Raises :class:`UntrustedFile` (an OSError) for a link, FIFO, device, folder, hard-linked or
    oversized file, and OSError when it is missing."""
    parts = _parts(rel)
    dfd = os.open(folder, _DIR_FLAGS)
    try:
        for part in parts[:-1]:
            nxt = os.open(part, _DIR_FLAGS, dir_fd=dfd)
            os.close(dfd)
            dfd = nxt
        fd = os.open(parts[-1], _FILE_FLAGS, dir_fd=dfd)
    finally:
        os.close(dfd)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
            raise UntrustedFile(f"{rel} is not a plain file of the job's own")
        if max_bytes is not None and st.st_size > max_bytes:
            raise UntrustedFile(f"{rel} is {st.st_size} bytes, more than the {max_bytes} such a file may have")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_job_bytes(folder: str | Path, rel: str | PurePosixPath, *, max_bytes: int) -> bytes:
    """The whole of ``folder/rel``, at most ``max_bytes`` (a file still growing past it is refused too)."""
    with open_job_file(folder, rel, max_bytes=max_bytes) as fh:
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise UntrustedFile(f"{rel} grew past the {max_bytes} bytes such a file may have")
    return data


def read_job_json(folder: str | Path, rel: str | PurePosixPath, *, max_bytes: int = JSON_MAX_BYTES) -> Any:
    """``folder/rel`` parsed as JSON (ValueError when it is not JSON)."""
    return json.loads(read_job_bytes(folder, rel, max_bytes=max_bytes))


def read_job_tail(folder: str | Path, rel: str | PurePosixPath, *, tail_bytes: int) -> tuple[bytes, int]:
    """The last ``tail_bytes`` of ``folder/rel`` (a log, a progress file of any size) and the file's size."""
    with open_job_file(folder, rel) as fh:
        size = os.fstat(fh.fileno()).st_size
        fh.seek(max(0, size - tail_bytes))
        return fh.read(tail_bytes), size
