"""The FastAPI application: ``create_app(settings)``. Requests only read and write the database and files;
rendering happens in worker processes (docs/design.md §1: no Mitsuba, Dr.Jit or torch on this path)."""

from __future__ import annotations

import asyncio
import logging
import os
import time
from contextlib import asynccontextmanager
from typing import Optional

from fastapi import Depends, FastAPI
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from service.api import display_sends, displays, evaluation, jobs, phase_frames, queue, scenes, sweeps, web
from service.api.context import ServiceContext
from service.api.deps import PRINCIPAL_KEY, authenticate, require, scope_error
from service.api.problems import ApiError, install_handlers, problem
from service.auth import Principal
from service.db import Database
from service.metrics import Metrics, owner_registry
from service.models import Problem
from service.settings import ServiceSettings
from service.version import SERVICE_VERSION, code_version
from service.workers.engine import LocalEngine
from service.workers.planner import Planner
from service.workers.private_tmp import can_make_private
from service.workers.ray_engine import RayEngine
from service.workers.scheduler import Scheduler

__all__ = ["create_app"]

log = logging.getLogger("holo.service")

# The largest body of any request but a scene upload: a job, an estimate, a heartbeat or a display
# registration is a few kB of JSON, and FastAPI parses a JSON body whole before the route's checks run (a
# 40 MB array of zeros held 200 MB of Python objects: a body of the upload limit, a few GB per request).
JSON_BODY_BYTES = 1 << 20
_UPLOAD = ("POST", "/v1/scenes")


def _has_body(headers: dict) -> bool:
    try:
        declared = int(headers.get(b"content-length", b"0") or 0)
    except ValueError:
        declared = 1  # unreadable: treat it as a body (h11 refuses it anyway)
    return declared > 0 or b"transfer-encoding" in headers


class _Guard:
    """Pure ASGI middleware in front of every route:

    - a request to the API (``/v1/``) that carries a body is authenticated from its headers *before* a byte of
      the body is read: without a valid token the client gets 401 (or 429) at once and the connection is
      closed, so an anonymous client cannot make the server spool an upload (FastAPI reads a form before it
      runs the route's dependencies). The token must also hold the scope the route needs (403 before the body,
      so a read or agent token cannot make the server receive an upload either). The principal is left in
      the scope for the route's own check.
    - bodies over the upload limit (scene uploads) or over ``JSON_BODY_BYTES`` (every other request) are refused
      (413, from Content-Length or while streaming), and a body
      must arrive whole within ``body_timeout_s`` (408 and the connection closed: a client trickling a byte a
      second cannot hold a request open).
    - request counts and latency (time to the response start) per route template are recorded."""

    def __init__(self, app, *, ctx: ServiceContext, routers: tuple = ()) -> None:
        self.app = app
        self.ctx = ctx
        # the routers, in the order the app includes them (without prefixes): which scope a request's route
        # needs, known before its body is read
        self.routers = routers
        self._scopes: dict[int, Optional[str]] = {}

    def _needed_scope(self, scope) -> Optional[str]:
        """The scope the route of this request requires (None: no route matches, or it needs no token)."""
        from starlette.routing import Match

        for route in (r for router in self.routers for r in router.routes):
            if hasattr(route, "dependant") and route.matches(scope)[0] is Match.FULL:
                key = id(route)
                if key not in self._scopes:
                    self._scopes[key] = _dependency_scope(getattr(route, "dependant", None))
                return self._scopes[key]
        return None

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        upload = (scope.get("method"), scope.get("path")) == _UPLOAD
        limit = self.ctx.settings.upload_limits.max_body_bytes if upload else JSON_BODY_BYTES
        headers = dict(scope.get("headers") or [])
        t0 = time.perf_counter()
        status = {"code": 500}
        try:
            declared = int(headers.get(b"content-length", b"0") or 0)
        except ValueError:
            declared = 0
        if declared > limit:
            resp = problem(413, f"request body of {declared} bytes is larger than the limit of {limit} bytes",
                           headers={"Connection": "close"})
            await resp(scope, receive, send)
            self._record(scope, 413, t0)
            return
        upload_of = None
        if _has_body(headers) and scope.get("path", "").startswith("/v1/"):
            try:
                principal = scope[PRINCIPAL_KEY] = authenticate(self.ctx, scope)
                needed = self._needed_scope(scope)  # a read token's upload is refused before it is received
                refused = scope_error(principal, needed) if needed else None
                if refused is not None:
                    raise refused
                if upload:
                    upload_of = self._start_upload(principal.owner)
            except ApiError as exc:
                resp = problem(exc.status, exc.detail, instance=scope.get("path"),
                               headers={**(exc.headers or {}), "Connection": "close"})
                await resp(scope, receive, send)
                self._record(scope, exc.status, t0)
                return
        try:
            await self._guarded(scope, receive, send, limit=limit, t0=t0, status=status)
        finally:
            if upload_of is not None:
                self._end_upload(upload_of)

    def _start_upload(self, owner: str) -> str:
        """Count an owner's upload in; 429 when it has ``max_uploads_per_owner`` in progress already (one owner's
        parallel uploads would otherwise hold every worker thread and the disk)."""
        busy = self.ctx.uploads_in_flight
        cap = self.ctx.settings.max_uploads_per_owner
        if busy.get(owner, 0) >= cap:
            raise ApiError(429, f"this owner has {cap} uploads in progress, the most it may at once; send this "
                                "one when they are done", headers={"Retry-After": "5"})
        busy[owner] = busy.get(owner, 0) + 1
        return owner

    def _end_upload(self, owner: str) -> None:
        busy = self.ctx.uploads_in_flight
        busy[owner] -= 1
        if busy[owner] <= 0:
            del busy[owner]

    async def _guarded(self, scope, receive, send, *, limit: int, t0: float, status: dict) -> None:
        seen = 0
        over = {"limit": False, "timeout": False, "started": False, "body_done": False}
        deadline = asyncio.get_running_loop().time() + self.ctx.settings.body_timeout_s

        async def limited_receive():
            nonlocal seen
            if over["limit"] or over["timeout"]:
                return {"type": "http.disconnect"}
            if over["body_done"]:  # after the body: the app waits for a disconnect (streams), no deadline
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), max(0.0, deadline - asyncio.get_running_loop().time()))
            except asyncio.TimeoutError:
                over["timeout"] = True
                return {"type": "http.disconnect"}
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:  # a streamed (chunked) body: the app sees a disconnect, the client a 413
                    over["limit"] = True
                    return {"type": "http.disconnect"}
                if not message.get("more_body", False):
                    over["body_done"] = True
            return message

        async def recording_send(message):
            if (over["limit"] or over["timeout"]) and not over["started"]:
                return  # whatever the app answers to the cut body, the client gets the 413 or 408 below
            if message["type"] == "http.response.start":
                over["started"] = True
                status["code"] = message["status"]
                self._record(scope, message["status"], t0)
            await send(message)

        try:
            await self.app(scope, limited_receive, recording_send)
        except Exception:  # noqa: BLE001 - the app's reaction to the cut body
            if not (over["limit"] or over["timeout"]):
                raise
        if (over["limit"] or over["timeout"]) and not over["started"]:
            code = 413 if over["limit"] else 408
            detail = (f"request body is larger than the limit of {limit} bytes" if over["limit"] else
                      f"request body did not arrive within {self.ctx.settings.body_timeout_s:g} s")
            resp = problem(code, detail, headers={"Connection": "close"})
            await resp(scope, receive, send)
            self._record(scope, code, t0)

    def _record(self, scope, code: int, t0: float) -> None:
        route = scope.get("route")
        path = getattr(route, "path", None) or "unmatched"
        m = self.ctx.metrics
        m.requests.labels(method=scope.get("method", "?"), route=path, status=str(code)).inc()
        m.latency.labels(route=path).observe(time.perf_counter() - t0)

def _dependency_scope(dependant) -> Optional[str]:
    """The scope of the first ``require(...)`` dependency in a route's dependency tree (service/api/deps.py)."""
    todo = [dependant] if dependant is not None else []
    while todo:
        d = todo.pop(0)
        needed = getattr(d.call, "holo_scope", None)
        if needed:
            return needed
        todo.extend(d.dependencies)
    return None


# The API's routers, listed once: included in this order (the page's routes before the jobs', for POST
# /v1/jobs/estimate and the page at /) and guarded by the size and rate guard.
ROUTERS = (web.router, scenes.router, jobs.router, phase_frames.router, evaluation.router, display_sends.router,
           displays.router, queue.router, sweeps.router)


def create_app(settings: ServiceSettings, *, start_workers: bool = True, engine=None) -> FastAPI:
    """The service app. With ``start_workers`` its lifespan locks the data dir and runs the scheduler and the
    planner in this process (what `holo serve` does)."""
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    for d in (settings.scenes_dir, settings.jobs_dir):
        d.mkdir(parents=True, exist_ok=True)
    db = Database(settings.db_path)
    ctx = ServiceContext(settings=settings, db=db, metrics=Metrics(db.count_jobs), code_version=code_version())

    # No CDN pages: FastAPI's /docs and /redoc load their scripts from a CDN (no SRI), which would run a third
    # party's code next to the tokens the pages ask for. /docs is an API index written here, from the schema.
    app = FastAPI(title="HoloPathTracer service", version=SERVICE_VERSION,
                  lifespan=_lifespan(ctx, start_workers=start_workers, engine=engine), docs_url=None,
                  redoc_url=None,
                  description="Upload Mitsuba scene bundles, render them into phase-only hologram stacks, and "
                              "serve the stacks to display agents. Errors are application/problem+json.")
    app.state.ctx = ctx
    install_handlers(app)
    app.add_middleware(_Guard, ctx=ctx, routers=(*ROUTERS, app.router))
    app.add_middleware(web.SecurityHeaders)  # outermost: every answer, the Guard's 413 included
    for router in ROUTERS:
        app.include_router(router)
    _add_health(app, ctx, start_workers=start_workers)

    @app.get("/docs", include_in_schema=False)
    def docs() -> Response:
        """The API's routes and what they do, from the OpenAPI schema (/openapi.json): one self-contained page,
        no script, nothing from another origin."""
        return Response(api_index_html(app.openapi()), media_type="text/html; charset=utf-8")

    _add_problem_schema(app)
    return app


def _lifespan(ctx: ServiceContext, *, start_workers: bool, engine):
    """With ``start_workers``: lock the data dir, run the scheduler and the planner, stop them at the end."""
    settings, db = ctx.settings, ctx.db

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if start_workers:
            ctx.lock_data_dir()
            eng = engine if engine is not None else _make_engine(settings)
            ctx.scheduler = Scheduler(settings, db, eng, metrics=ctx.metrics)
            ctx.planner = Planner(settings, db)
            ctx.scheduler.start()
            ctx.planner.start()
            log.info("holo service %s (code %s) on data dir %s, %d worker(s), engine %s", SERVICE_VERSION,
                     ctx.code_version, settings.data_dir, settings.workers, eng.name)
        try:
            yield
        finally:
            if ctx.planner is not None:
                ctx.planner.stop()
            if ctx.scheduler is not None:
                ctx.scheduler.stop(requeue=True)
            ctx.unlock_data_dir()

    return lifespan


def _add_health(app: FastAPI, ctx: ServiceContext, *, start_workers: bool) -> None:
    """/livez, /readyz and /metrics (public or per owner, as the settings say)."""
    settings, db = ctx.settings, ctx.db

    @app.get("/livez", tags=["health"])
    def livez() -> dict:
        """The process answers."""
        return {"status": "ok"}

    @app.get("/readyz", tags=["health"], responses={503: {"description": "Not ready"}})
    def readyz():
        """Database reachable, data dir writable, scheduler alive; and whether jobs run sandboxed (``sandbox``:
        on or off, whether the server runs as root, whether jobs run as sandbox users and get temporary folders
        of their own)."""
        checks = {"database": db.ping(), "data_dir_writable": os.access(settings.data_dir, os.W_OK),
                  "scheduler": (ctx.scheduler.alive() if ctx.scheduler is not None else not start_workers)}
        ok = all(checks.values())
        # the sandbox as resolved at start (auto: not resolved, no workers in this process); jobs: whether jobs
        # themselves run as sandbox users (not on an engine that runs them elsewhere, e.g. Ray)
        jobs_sandboxed = None if ctx.scheduler is None else ctx.scheduler.sandbox_base is not None
        sandbox = {"state": str(settings.sandbox), "root": os.geteuid() == 0, "jobs": jobs_sandboxed,
                   "private_tmp": bool(jobs_sandboxed) and can_make_private()}
        return JSONResponse({"status": "ready" if ok else "not ready", "checks": checks, "sandbox": sandbox},
                            status_code=200 if ok else 503)

    if settings.metrics_public:
        @app.get("/metrics", tags=["health"], response_class=Response)
        def metrics() -> Response:
            """Prometheus metrics of the whole service (served without a token: metrics public)."""
            return Response(generate_latest(ctx.metrics.registry), media_type=CONTENT_TYPE_LATEST)
    else:
        @app.get("/metrics", tags=["health"], response_class=Response)
        def metrics(principal: Principal = Depends(require("read"))) -> Response:
            """Prometheus metrics: the whole service's for an admin token; for any other token with scope read,
            its owner's alone (jobs by state, scenes), since the service's counters tell one tenant what the
            others do."""
            registry = ctx.metrics.registry if principal.is_admin else owner_registry(db, principal.owner)
            return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)


def api_index_html(schema: dict) -> str:
    """The routes of an OpenAPI schema as a plain HTML page (every string escaped)."""
    from html import escape

    rows = []
    for path, ops in sorted((schema.get("paths") or {}).items()):
        for method, op in ops.items():
            if not isinstance(op, dict):
                continue
            summary = op.get("summary") or ""
            desc = (op.get("description") or "").strip()
            rows.append(f"<tr><td><code>{escape(method.upper())}</code></td><td><code>{escape(path)}</code></td>"
                        f"<td><b>{escape(summary)}</b><br>{escape(desc)}</td></tr>")
    info = schema.get("info") or {}
    return ("<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>"
            f"{escape(str(info.get('title', 'API')))}</title></head><body><h1>{escape(str(info.get('title', '')))} "
            f"{escape(str(info.get('version', '')))}</h1><p>The machine-readable schema: <a href=\"/openapi.json\">"
            "/openapi.json</a>. Every route but the health checks needs <code>Authorization: Bearer TOKEN</code>."
            "</p><table><thead><tr><th>Method</th><th>Path</th><th>What it does</th></tr></thead><tbody>"
            + "".join(rows) + "</tbody></table></body></html>")

def _make_engine(settings: ServiceSettings):
    if settings.engine == "ray":
        return RayEngine(settings)

    return LocalEngine()

def _add_problem_schema(app: FastAPI) -> None:
    original = app.openapi

    def openapi() -> dict:
        if app.openapi_schema:
            return app.openapi_schema
        schema = original()
        schema.setdefault("components", {}).setdefault("schemas", {})["Problem"] = Problem.model_json_schema()
        app.openapi_schema = schema
        return schema

    app.openapi = openapi

