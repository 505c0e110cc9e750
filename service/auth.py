"""Bearer tokens with scopes, stored hashed (sha256 of a 256-bit random secret; the secret is shown once).

Scopes: ``read`` (list and download), ``submit`` (upload scenes, submit and cancel jobs; implies read),
``agent`` (read + display heartbeats) and ``admin`` (everything).
"""

from __future__ import annotations

import hashlib
import secrets
import time
from dataclasses import dataclass
from typing import Iterable, Optional

from service.db import Database

__all__ = ["SCOPES", "Principal", "create_token", "verify_token", "revoke_token", "list_tokens", "allows"]

SCOPES = ("submit", "read", "admin", "agent")
_IMPLIES = {"admin": set(SCOPES), "submit": {"submit", "read"}, "agent": {"agent", "read"}, "read": {"read"}}
_PREFIX = "hpt_"


@dataclass(frozen=True)
class Principal:
    token_id: str
    name: str
    scopes: frozenset[str]


def _hash(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8", "surrogateescape")).hexdigest()


def allows(scopes: Iterable[str], needed: str) -> bool:
    """Whether a token with ``scopes`` may do what ``needed`` guards (admin and submit imply others)."""
    return any(needed in _IMPLIES.get(s, set()) for s in scopes)


def create_token(db: Database, *, scopes: Iterable[str], name: str = "") -> tuple[str, str]:
    """Create a token; returns (token id, secret token string). Only its sha256 is stored."""
    scopes = sorted(set(scopes))
    if not scopes:
        raise ValueError(f"scopes: give at least one of {', '.join(SCOPES)}")
    bad = [s for s in scopes if s not in SCOPES]
    if bad:
        raise ValueError(f"scopes: unknown {bad}; allowed: {', '.join(SCOPES)}")
    if len(name) > 100:
        raise ValueError("name must be at most 100 characters")
    token_id = secrets.token_hex(6)
    token = f"{_PREFIX}{token_id}_{secrets.token_urlsafe(32)}"
    import json

    db.execute("INSERT INTO tokens (id, hash, name, scopes, created_at) VALUES (?, ?, ?, ?, ?)",
               (token_id, _hash(token), name, json.dumps(scopes), time.time()))
    return token_id, token


def verify_token(db: Database, token: Optional[str]) -> Optional[Principal]:
    """The token's principal, or None for an unknown, malformed or revoked token."""
    if not token or len(token) > 200 or not token.startswith(_PREFIX):
        return None
    row = db.one("SELECT id, name, scopes, revoked FROM tokens WHERE hash = ?", (_hash(token),))
    if row is None or row["revoked"]:
        return None
    return Principal(token_id=row["id"], name=row["name"], scopes=frozenset(row["scopes"]))


def revoke_token(db: Database, token_id: str) -> bool:
    return db.execute("UPDATE tokens SET revoked = 1 WHERE id = ?", (token_id,)) > 0


def list_tokens(db: Database) -> list[dict]:
    return db.query("SELECT id, name, scopes, created_at, revoked FROM tokens ORDER BY created_at")
