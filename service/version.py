"""The code version that goes into every job's content address: a result is reused only when the scene, the
options and the code that would compute it are all the same."""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path

from holocore import __version__

__all__ = ["code_version", "SERVICE_VERSION"]

SERVICE_VERSION = "0.1.0"
_ROOT = Path(__file__).resolve().parent.parent
# Everything a job's bytes depend on: the physics, the CLIs the worker runs, and the worker itself.
_SOURCES = ("holocore", "holo/cmd_render.py", "holo/cmd_encode.py", "holo/cmd_view.py", "holo/common.py",
            "service/workers/driver.py", "service/workers/pictures.py")


@lru_cache(maxsize=1)
def code_version() -> str:
    """``<holocore version>+<first 12 hex of sha256 over the sources above>`` (computed once per process)."""
    h = hashlib.sha256()
    for item in _SOURCES:
        p = _ROOT / item
        files = sorted(p.rglob("*.py")) if p.is_dir() else [p]
        for f in files:
            if f.is_file():
                h.update(f.relative_to(_ROOT).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return f"{__version__}+{h.hexdigest()[:12]}"
