"""Request dependencies: the service context and bearer-token authentication with scopes."""

from __future__ import annotations

from typing import Callable, Optional

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.api.context import ServiceContext
from service.api.problems import ApiError
from service.auth import Principal, allows, verify_token

__all__ = ["get_ctx", "require"]

_bearer = HTTPBearer(auto_error=False, description="A token from `holo token create`.")
_CHALLENGE = {"WWW-Authenticate": 'Bearer realm="holo"'}


def get_ctx(request: Request) -> ServiceContext:
    return request.app.state.ctx


def require(scope: str) -> Callable[..., Principal]:
    """A dependency that admits tokens allowing ``scope`` (401 without a valid token, 403 without the scope)."""

    async def dependency(request: Request, creds: Optional[HTTPAuthorizationCredentials] = Depends(_bearer)
                         ) -> Principal:
        # async on purpose: one indexed SQLite read (WAL readers never wait for writers) costs less than a
        # trip through the thread pool, which matters for agents polling status.
        if creds is None:
            has_header = bool(request.headers.get("authorization"))
            raise ApiError(401, "malformed Authorization header: use 'Bearer <token>'" if has_header
                           else "authentication required: send 'Authorization: Bearer <token>'", headers=_CHALLENGE)
        principal = verify_token(get_ctx(request).db, creds.credentials)
        if principal is None:
            raise ApiError(401, "invalid or revoked token", headers=_CHALLENGE)
        if not allows(principal.scopes, scope):
            raise ApiError(403, f"this token lacks the '{scope}' scope (it has: {', '.join(sorted(principal.scopes))})")
        return principal

    dependency.__name__ = f"require_{scope}"
    return dependency
