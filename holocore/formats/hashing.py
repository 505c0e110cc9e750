"""Content hashes of files (the sha256 used for ETags, cache checks and artifact integrity)."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Union

__all__ = ["file_sha256"]


def file_sha256(path: Union[str, Path]) -> str:
    """Hex SHA-256 of a file's bytes (the content hash used for ETags and cache checks)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
