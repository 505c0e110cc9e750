"""File downloads with a content-hash ETag: ``If-None-Match`` (304), single ``Range`` requests (206/416) and
``If-Range`` (resume only while the file is unchanged)."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Iterator, Optional

from fastapi import Request
from fastapi.responses import Response, StreamingResponse

from service.untrusted import open_job_file

__all__ = ["file_response", "parse_range"]

_CHUNK = 1 << 20


class Unsatisfiable(Exception):
    pass


def _num(digits: str) -> str:
    """Digits as they are, or 10^19 for longer numbers (past the end of any file; int() refuses 4300+ digits)."""
    return digits if len(digits) <= 19 else str(10**19)


def parse_range(header: str, size: int) -> Optional[tuple[int, int]]:
    """(first, last) byte of a single ``bytes=`` range; None to ignore the header (malformed or several
    ranges: the whole file is sent); raises Unsatisfiable when the range starts past the end."""
    m = re.fullmatch(r"\s*bytes\s*=\s*(\d*)\s*-\s*(\d*)\s*", header)
    if not m or (not m.group(1) and not m.group(2)):
        return None
    a, b = _num(m.group(1)), _num(m.group(2))
    if a:
        first = int(a)
        last = min(int(b), size - 1) if b else size - 1
        if b and int(b) < first:
            return None
        if first >= size:
            raise Unsatisfiable
        return first, last
    n = int(b)
    if n == 0 or size == 0:
        raise Unsatisfiable
    return max(0, size - n), size - 1


def _iter(path: Path, first: int, last: int) -> Iterator[bytes]:
    with open_job_file(path.parent, path.name) as fh:
        fh.seek(first)
        left = last - first + 1
        while left > 0:
            chunk = fh.read(min(_CHUNK, left))
            if not chunk:
                break
            left -= len(chunk)
            yield chunk


def _etags(header: str) -> list[str]:
    return [t.strip().removeprefix("W/") for t in header.split(",")]


def file_response(request: Request, path: Path, *, sha256: str, media_type: str, filename: str) -> Response:
    etag = f'"{sha256}"'
    base = {"ETag": etag, "X-Content-SHA256": sha256, "Accept-Ranges": "bytes", "Cache-Control": "no-cache",
            "Content-Disposition": f'attachment; filename="{filename}"'}
    inm = request.headers.get("if-none-match")
    if inm and (inm.strip() == "*" or etag in _etags(inm)):
        return Response(status_code=304, headers={k: v for k, v in base.items() if k != "Content-Disposition"})
    with open_job_file(path.parent, path.name) as fh:  # files a job made: no link, no FIFO (service/untrusted.py)
        size = os.fstat(fh.fileno()).st_size
    rng = request.headers.get("range")
    if_range = request.headers.get("if-range")
    if rng and (if_range is None or if_range.strip().removeprefix("W/") == etag):
        try:
            span = parse_range(rng, size)
        except Unsatisfiable:
            return Response(status_code=416, headers={**base, "Content-Range": f"bytes */{size}"})
        if span is not None:
            first, last = span
            return StreamingResponse(_iter(path, first, last), status_code=206, media_type=media_type,
                                     headers={**base, "Content-Range": f"bytes {first}-{last}/{size}",
                                              "Content-Length": str(last - first + 1)})
    return StreamingResponse(_iter(path, 0, size - 1), media_type=media_type,
                             headers={**base, "Content-Length": str(size)})
