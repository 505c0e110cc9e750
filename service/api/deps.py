"""Request dependencies: the service context and bearer-token authentication with scopes, with the aliases
routes declare them by (``ctx: Ctx``, ``principal: ReadScope``)."""

from __future__ import annotations

import ipaddress
from typing import Annotated, Callable, Optional

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.api.context import ServiceContext
from service.api.problems import ApiError
from service.auth import Principal, allows, verify_token

__all__ = ["get_ctx", "context", "require", "authenticate", "client_address", "scope_error", "PRINCIPAL_KEY", "Ctx",
           "ReadScope", "SubmitScope", "AgentScope", "AdminScope", "owned_job"]

_bearer = HTTPBearer(auto_error=False, description="A token from `holo token create`.")
_CHALLENGE = {"WWW-Authenticate": 'Bearer realm="holo"'}


def get_ctx(request: Request) -> ServiceContext:
    return request.app.state.ctx


async def context(request: Request) -> ServiceContext:
    """The service context as a dependency (async: answered on the event loop, no thread-pool trip)."""
    return request.app.state.ctx


PRINCIPAL_KEY = "holo.principal"  # the ASGI scope entry the body guard leaves an authenticated principal in


def client_address(scope, trusted: tuple = ()) -> str:
    """The client's address: the peer's, or, when the peer is a trusted proxy (``trusted``: ip networks), the
    nearest address in its X-Forwarded-For that is not a trusted proxy. A header from any other peer is the
    client's word and is ignored (anyone could send one to pass for someone else)."""
    peer = (scope.get("client") or ("?", 0))[0]
    if not trusted or not _in(peer, trusted):
        return peer
    forwarded = [v.decode("latin-1") for k, v in scope.get("headers") or [] if k == b"x-forwarded-for"]
    hops = [h.strip() for h in ",".join(forwarded).split(",") if h.strip()]
    for hop in reversed(hops):  # each proxy appends the address it got the request from
        try:
            ipaddress.ip_address(hop)
        except ValueError:
            return peer  # a garbled chain: the proxy's own address is the one thing known
        if not _in(hop, trusted):
            return hop
    return hops[0] if hops else peer


def failure_key(addr: str) -> str:
    """What failed authentications are counted by: an IPv4 address, or an IPv6 address's /64 (one host is
    commonly given a whole /64, so counting single IPv6 addresses would give it 2^64 fresh counts)."""
    try:
        ip = ipaddress.ip_address(addr)
    except ValueError:
        return addr
    if ip.version == 4:
        return str(ip)
    if ip.ipv4_mapped is not None:  # ::ffff:a.b.c.d is that IPv4 client
        return str(ip.ipv4_mapped)
    return str(ipaddress.ip_network(f"{ip}/64", strict=False))


def _in(addr: str, nets: tuple) -> bool:
    try:
        ip = ipaddress.ip_address(addr)
    except ValueError:
        return False
    return any(ip in n for n in nets)


def _bearer_token(authorization: Optional[str]) -> Optional[str]:
    scheme, _, cred = (authorization or "").partition(" ")
    return cred.strip() if scheme.lower() == "bearer" and cred.strip() else None


def authenticate(ctx: ServiceContext, scope) -> Principal:
    """The principal of the request's bearer token, or ApiError: 401 without a valid token, 429 when its
    address has failed too often this minute. Only failures count and only failures are turned away: a valid
    token always passes, so wrong tokens from one address (everyone behind one proxy or NAT) lock out nobody
    who holds a real one."""
    auth = next((v.decode("latin-1") for k, v in scope.get("headers") or [] if k == b"authorization"), None)
    token = _bearer_token(auth)
    principal = verify_token(ctx.db, token) if token else None
    if principal is not None:
        return principal
    client = failure_key(client_address(scope, ctx.settings.trusted_proxy_networks))
    wait = ctx.auth_failures.blocked_for(client, ctx.settings.auth_failures_per_minute)
    if wait > 0:
        raise ApiError(429, f"too many failed authentications from this address; try again in {wait:.0f} s",
                       headers={"Retry-After": str(max(1, int(wait + 0.999)))})
    ctx.auth_failures.record(client)
    if auth is None:
        raise ApiError(401, "authentication required: send 'Authorization: Bearer <token>'", headers=_CHALLENGE)
    if token is None:
        raise ApiError(401, "malformed Authorization header: use 'Bearer <token>'", headers=_CHALLENGE)
    raise ApiError(401, "invalid or revoked token (or expired)", headers=_CHALLENGE)


def scope_error(principal: Principal, scope: str) -> Optional[ApiError]:
    """The 403 for a token that lacks ``scope`` (None when it has it)."""
    if allows(principal.scopes, scope):
        return None
    return ApiError(403, f"this token lacks the '{scope}' scope (it has: {', '.join(sorted(principal.scopes))})")


def require(scope: str) -> Callable[..., Principal]:
    """A dependency that admits tokens allowing ``scope`` (401 without a valid token, 403 without the scope)."""

    async def dependency(request: Request, creds: Optional[HTTPAuthorizationCredentials] = Depends(_bearer)
                         ) -> Principal:  # noqa: ARG001 - creds: the OpenAPI security scheme
        # async on purpose: one indexed SQLite read (WAL readers never wait for writers) costs less than a
        # trip through the thread pool, which matters for agents polling status.
        principal = request.scope.get(PRINCIPAL_KEY) or authenticate(get_ctx(request), request.scope)
        refused = scope_error(principal, scope)
        if refused is not None:
            raise refused
        return principal

    dependency.__name__ = f"require_{scope}"
    dependency.holo_scope = scope  # type: ignore[attr-defined] - read by the body guard (service/api/app.py)
    return dependency


Ctx = Annotated[ServiceContext, Depends(context)]
ReadScope = Annotated[Principal, Depends(require("read"))]
SubmitScope = Annotated[Principal, Depends(require("submit"))]
AgentScope = Annotated[Principal, Depends(require("agent"))]
AdminScope = Annotated[Principal, Depends(require("admin"))]


def owned_job(ctx: ServiceContext, job_id: str, principal: Optional[Principal] = None) -> dict:
    """The job, or 404 when it does not exist or belongs to another owner (the same answer: no leak)."""
    row = ctx.db.get_job(job_id)
    if row is None or (principal is not None and not principal.sees(row.get("owner"))):
        raise ApiError(404, f"no job {job_id!r}")
    return row
