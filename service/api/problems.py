"""Errors as RFC 9457 problem details (``application/problem+json``) with one clear message in ``detail``."""

from __future__ import annotations

import logging
from http import HTTPStatus
from typing import Optional

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

__all__ = ["ApiError", "problem", "install_handlers", "PROBLEM_RESPONSES"]

log = logging.getLogger("holo.service.api")
MEDIA = "application/problem+json"


class ApiError(Exception):
    """Raise in a route to answer ``status`` with a problem body saying ``detail``."""

    def __init__(self, status: int, detail: str, *, headers: Optional[dict[str, str]] = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.headers = headers


def problem(status: int, detail: str, *, instance: Optional[str] = None,
            headers: Optional[dict[str, str]] = None) -> JSONResponse:
    try:
        title = HTTPStatus(status).phrase
    except ValueError:
        title = "Error"
    body = {"type": "about:blank", "title": title, "status": status, "detail": detail}
    if instance:
        body["instance"] = instance
    return JSONResponse(body, status_code=status, media_type=MEDIA, headers=headers)


def _loc(loc: tuple) -> str:
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "header")]
    return ".".join(parts) or str(loc[0] if loc else "request")


def install_handlers(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError):
        return problem(exc.status, exc.detail, instance=request.url.path, headers=exc.headers)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException):
        detail = exc.detail if isinstance(exc.detail, str) else HTTPStatus(exc.status_code).phrase
        if exc.status_code == 404 and detail == "Not Found":
            detail = f"no such resource: {request.url.path}"
        elif exc.status_code == 405:
            detail = f"method {request.method} is not allowed on {request.url.path}"
        return problem(exc.status_code, detail, instance=request.url.path, headers=getattr(exc, "headers", None))

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError):
        # Messages only: the offending input may hold NaN or huge values that must not be echoed back.
        msgs = []
        for err in exc.errors()[:10]:
            msg = str(err.get("msg", "invalid"))
            msgs.append(f"{_loc(tuple(err.get('loc', ())))}: {msg}"[:300])
        return problem(422, "; ".join(msgs) or "invalid request", instance=request.url.path)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem(500, f"internal error ({type(exc).__name__}); the server log has the details",
                       instance=request.url.path)


PROBLEM_RESPONSES = {
    s: {"description": HTTPStatus(s).phrase, "content": {MEDIA: {"schema": {"$ref": "#/components/schemas/Problem"}}}}
    for s in (400, 401, 403, 404, 409, 413, 415, 422)
}
