"""Bearer tokens with scopes, stored hashed (sha256 of a 256-bit random secret; the secret is shown once).

Scopes: ``read`` (list and download), ``submit`` (upload scenes, submit and cancel jobs; implies read),
``agent`` (read + display heartbeats) and ``admin`` (everything, for every owner).

Every token has an *owner* (a lab or a person; ``default`` unless given): scenes, jobs and displays belong to
the owner of the token that made them, and only tokens of that owner (or admin tokens) see or change them.
Tokens may expire (``expires_at``).
"""

from __future__ import annotations

import hashlib
import math
import re
import secrets
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Iterable, Optional

from service.db import Database

__all__ = ["AuthFailures", "SCOPES", "DEFAULT_OWNER", "Principal", "create_token", "verify_token", "revoke_token",
           "list_tokens", "allows"]

SCOPES = ("submit", "read", "admin", "agent")
_IMPLIES = {"admin": set(SCOPES), "submit": {"submit", "read"}, "agent": {"agent", "read"}, "read": {"read"}}
_PREFIX = "hpt_"


_OWNER = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
DEFAULT_OWNER = "default"


@dataclass(frozen=True)
class Principal:
    token_id: str
    name: str
    scopes: frozenset[str]
    owner: str = DEFAULT_OWNER

    @property
    def is_admin(self) -> bool:
        return "admin" in self.scopes

    def sees(self, owner: Optional[str]) -> bool:
        """Whether this token may see and act on something that belongs to ``owner`` (None: the default)."""
        return self.is_admin or (owner or DEFAULT_OWNER) == self.owner


def _hash(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8", "surrogateescape")).hexdigest()


def allows(scopes: Iterable[str], needed: str) -> bool:
    """Whether a token with ``scopes`` may do what ``needed`` guards (admin and submit imply others)."""
    return any(needed in _IMPLIES.get(s, set()) for s in scopes)


def create_token(db: Database, *, scopes: Iterable[str], name: str = "", owner: str = DEFAULT_OWNER,
                 expires_in_s: Optional[float] = None) -> tuple[str, str]:
    """Create a token of ``owner``, valid for ``expires_in_s`` seconds (None: until revoked); returns (token
    id, secret token string). Only its sha256 is stored."""
    scopes = sorted(set(scopes))
    if not scopes:
        raise ValueError(f"scopes: give at least one of {', '.join(SCOPES)}")
    bad = [s for s in scopes if s not in SCOPES]
    if bad:
        raise ValueError(f"scopes: unknown {bad}; allowed: {', '.join(SCOPES)}")
    if len(name) > 100:
        raise ValueError("name must be at most 100 characters")
    if not isinstance(owner, str) or not _OWNER.match(owner):
        raise ValueError("owner: 1-64 letters, digits, '.', '_' or '-', starting with a letter or digit")
    if expires_in_s is not None and not (math.isfinite(expires_in_s) and 0 < expires_in_s <= 10 * 365 * 86400):
        raise ValueError("expiry must be more than 0 s and at most 10 years")
    token_id = secrets.token_hex(6)
    token = f"{_PREFIX}{token_id}_{secrets.token_urlsafe(32)}"
    now = time.time()
    db.insert_token(token_id=token_id, token_hash=_hash(token), name=name, scopes=scopes, created_at=now, owner=owner,
                    expires_at=None if expires_in_s is None else now + expires_in_s)
    return token_id, token


def verify_token(db: Database, token: Optional[str]) -> Optional[Principal]:
    """The token's principal, or None for an unknown, malformed, expired or revoked token."""
    if not token or len(token) > 200 or not token.startswith(_PREFIX):
        return None
    row = db.token_by_hash(_hash(token))
    if row is None or row["revoked"] or (row["expires_at"] is not None and row["expires_at"] <= time.time()):
        return None
    return Principal(token_id=row["id"], name=row["name"], scopes=frozenset(row["scopes"]),
                     owner=row["owner"] or DEFAULT_OWNER)


def revoke_token(db: Database, token_id: str) -> bool:
    return db.revoke_token(token_id)


def list_tokens(db: Database) -> list[dict]:
    return db.list_tokens()


class AuthFailures:
    """Failed authentications per client address over the last minute (in memory; one server process)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen: dict[str, deque] = {}

    def blocked_for(self, client: str, limit: int) -> float:
        """Seconds until ``client`` may try again (0: not blocked)."""
        now = time.monotonic()
        with self._lock:
            q = self._seen.get(client)
            while q and now - q[0] > 60.0:
                q.popleft()
            if not q:
                self._seen.pop(client, None)
                return 0.0
            return 60.0 - (now - q[0]) if len(q) >= limit else 0.0

    def record(self, client: str) -> None:
        with self._lock:
            if len(self._seen) > 100_000:  # a flood of addresses: forget the oldest half
                for key in list(self._seen)[:50_000]:
                    del self._seen[key]
            self._seen.setdefault(client, deque(maxlen=10_000)).append(time.monotonic())
