"""The focus controller's line protocol (docs/focus_protocol.md), shared by the client and the simulator.

Request ``<id> <VERB> [ARG...]``; reply ``<id> OK [PAYLOAD]`` or ``<id> ERR <CODE> <message>``; unsolicited
lines start with ``READY`` (boot banner) or ``#`` (comments). ASCII, ``\\n``-terminated (``\\r`` ignored).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Optional

__all__ = ["PROTOCOL_VERSION", "MAX_LINE", "ERROR_CODES", "Reply", "format_request", "parse_reply",
           "parse_kv", "ID_RE"]

PROTOCOL_VERSION = 1
MAX_LINE = 80
ID_RE = re.compile(r"^[0-9A-Za-z]{1,8}$")
ERROR_CODES = ("SYNTAX", "UNKNOWN", "ARG", "RANGE", "INTERNAL")


@dataclass(frozen=True)
class Reply:
    id: str
    ok: bool
    payload: str = ""  # after OK
    code: str = ""  # after ERR
    message: str = ""


def format_request(req_id: str, verb: str, *args: object) -> str:
    """``"<id> VERB args\\n"``; ValueError on an id or token the protocol cannot carry."""
    if not ID_RE.match(req_id):
        raise ValueError(f"request id must be 1-8 letters or digits, got {req_id!r}")
    tokens = [verb.upper(), *(str(a) for a in args)]
    for t in tokens:
        if not t or any(ch.isspace() for ch in t) or not t.isascii():
            raise ValueError(f"protocol tokens must be non-empty ASCII without spaces, got {t!r}")
    line = " ".join([req_id, *tokens])
    if len(line) > MAX_LINE:
        raise ValueError(f"request longer than {MAX_LINE} characters: {line!r}")
    return line + "\n"


def parse_reply(line: str) -> Optional[Reply]:
    """A reply line -> :class:`Reply`; None for banners, comments and anything that is not a reply."""
    parts = line.strip().split(" ", 2)
    if len(parts) < 2 or not ID_RE.match(parts[0]):
        return None
    rid, status = parts[0], parts[1]
    rest = parts[2] if len(parts) > 2 else ""
    if status == "OK":
        return Reply(id=rid, ok=True, payload=rest)
    if status == "ERR":
        code, _, msg = rest.partition(" ")
        return Reply(id=rid, ok=False, code=code or "INTERNAL", message=msg)
    return None


def parse_kv(payload: str) -> dict[str, str]:
    """``"SETTLED pos=12 target=12"`` -> {"state": "SETTLED", "pos": "12", "target": "12"}."""
    out: dict[str, str] = {}
    for i, tok in enumerate(payload.split()):
        k, eq, v = tok.partition("=")
        if eq:
            out[k] = v
        elif i == 0:
            out["state"] = tok
    return out
