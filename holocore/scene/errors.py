"""Messages that leak nothing: what went wrong in the user's terms, with bundle-relative paths, never the
server's paths or another file's contents; and the error a refused bundle raises. Pure Python."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Iterable

__all__ = ["scrub_message", "BundleError"]


class BundleError(ValueError):
    """The bundle is refused; the message says why, with bundle-relative names."""

_SOURCE_TAG = re.compile(r"\[[\w./-]+\.(?:cpp|h|hpp|py):\d+\]\s*")
_ABS_PATH = re.compile(r"(?<![\w.:/-])(?:/[^\s/'\"`:,;()\[\]]+)+/?")


def scrub_message(text: str, *, roots: Iterable[str | Path] = (), entry_name: str | None = None,
                  limit: int = 500) -> str:
    """``text`` with source-file tags (``[parser.cpp:451]``) removed, each of ``roots`` (folders the user
    knows as their bundle or job) shown as relative, every other absolute path replaced by ``<server path>``,
    Mitsuba's ``string`` source named ``entry_name``, on one line of at most ``limit`` characters."""
    out = _SOURCE_TAG.sub("", str(text))
    for root in sorted((str(Path(r)) for r in roots), key=len, reverse=True):
        if root and root != "/":
            out = out.replace(root.rstrip("/") + "/", "").replace(root, ".")
    out = _ABS_PATH.sub("<server path>", out)
    if entry_name:
        out = re.sub(r"\b(?:At|loading) string\b", lambda m: m.group(0).replace("string", entry_name), out)
    out = " ".join(out.split())
    return out if len(out) <= limit else out[: limit - 3] + "..."
