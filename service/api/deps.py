"""Request dependencies: the service context and bearer-token authentication with scopes, with the aliases
routes declare them by (``ctx: Ctx``, ``principal: ReadScope``)."""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Annotated, Callable, Optional

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.api.context import ServiceContext
from service.api.problems import ApiError
from service.auth import Principal, allows, verify_token

__all__ = ["get_ctx", "context", "require", "Ctx", "ReadScope", "SubmitScope", "AgentScope", "AdminScope"]

_bearer = HTTPBearer(auto_error=False, description="A token from `holo token create`.")
_CHALLENGE = {"WWW-Authenticate": 'Bearer realm="holo"'}


def get_ctx(request: Request) -> ServiceContext:
    return request.app.state.ctx


async def context(request: Request) -> ServiceContext:
    """The service context as a dependency (async: answered on the event loop, no thread-pool trip)."""
    return request.app.state.ctx


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


_FAILURES = AuthFailures()


def _client(request: Request) -> str:
    return request.client.host if request.client else "?"


def require(scope: str) -> Callable[..., Principal]:
    """A dependency that admits tokens allowing ``scope`` (401 without a valid token, 403 without the scope)."""

    async def dependency(request: Request, creds: Optional[HTTPAuthorizationCredentials] = Depends(_bearer)
                         ) -> Principal:
        # async on purpose: one indexed SQLite read (WAL readers never wait for writers) costs less than a
        # trip through the thread pool, which matters for agents polling status.
        ctx = get_ctx(request)
        client = _client(request)
        wait = _FAILURES.blocked_for(client, ctx.settings.auth_failures_per_minute)
        if wait > 0:
            raise ApiError(429, f"too many failed authentications from this address; try again in {wait:.0f} s",
                           headers={"Retry-After": str(max(1, int(wait + 0.999)))})
        if creds is None:
            has_header = bool(request.headers.get("authorization"))
            if has_header:
                _FAILURES.record(client)
            raise ApiError(401, "malformed Authorization header: use 'Bearer <token>'" if has_header
                           else "authentication required: send 'Authorization: Bearer <token>'", headers=_CHALLENGE)
        principal = verify_token(ctx.db, creds.credentials)
        if principal is None:
            _FAILURES.record(client)
            raise ApiError(401, "invalid or revoked token (or expired)", headers=_CHALLENGE)
        if not allows(principal.scopes, scope):
            raise ApiError(403, f"this token lacks the '{scope}' scope (it has: {', '.join(sorted(principal.scopes))})")
        return principal

    dependency.__name__ = f"require_{scope}"
    return dependency


Ctx = Annotated[ServiceContext, Depends(context)]
ReadScope = Annotated[Principal, Depends(require("read"))]
SubmitScope = Annotated[Principal, Depends(require("submit"))]
AgentScope = Annotated[Principal, Depends(require("agent"))]
AdminScope = Annotated[Principal, Depends(require("admin"))]
