"""The results web page and the API routes it needs beyond the rest.

- ``GET /`` and ``GET /web/{file}``: the page (static HTML, CSS and JavaScript modules shipped in
  ``service/web/``; no build step, no inline script). The page itself needs no token: it asks for one and sends
  it as ``Authorization: Bearer`` on every API call; it keeps it in the browser session (sessionStorage).
- ``GET /v1/whoami``: the token's owner and scopes (the page shows the submit form only to tokens that may).
- ``GET /v1/display-profiles``: the built-in display profiles and their optics (the form's "display profile").
- ``POST /v1/jobs/estimate``: what ``POST /v1/jobs`` would predict (seconds, memory), after the same checks, and
  whether an earlier identical result would be reused; nothing is created. ``plan`` is the effect plan expected
  at the request's options (from the scene's plan, made at its default optics; None while that is pending),
  ``field_of_view_box`` where the hologram's view lies in the scene's picture at the request's optics.
- ``GET /v1/jobs/{id}/pictures`` and ``.../pictures/{file}``: the focal sweep and view grid the job's worker
  made when it finished (``service/workers/pictures.py``), as a JSON index and PNGs.

``SecurityHeaders`` (pure ASGI) puts on every response ``X-Content-Type-Options: nosniff``,
``Referrer-Policy: no-referrer``, ``X-Frame-Options: DENY`` and a Content-Security-Policy: the page's
(``default-src 'self'``, scripts only from files of this origin, images also from ``blob:``, no framing) on
``/`` and ``/web/``, and ``default-src 'none'`` on API answers and on the API index at ``/docs`` (a page of
plain HTML written from the schema: FastAPI's try-it pages, which load their script from a CDN, are off).
"""

from __future__ import annotations

import hashlib
import re
from functools import lru_cache
from pathlib import Path
from typing import Optional

from fastapi import APIRouter, Request
from fastapi import Path as PathParam
from fastapi.responses import JSONResponse, Response

from holocore.display.profiles import BUILTIN_DISPLAYS, DEFAULT_DISPLAY, OPTICS_FIELDS
from holocore.plan import stored_plan
from service.api.context import ServiceContext
from service.api.deps import Ctx, ReadScope, SubmitScope
from service.api.files import file_response
from service.api.problems import PROBLEM_RESPONSES, ApiError
from service.api.submission import admit_job, busy_threads, resolve_target, reusable_job, scene_plane_border
from service.auth import allows
from service.auth import Principal
from service.cost import evaluation_skipped
from service.cost import estimate_cost
from service.integrity import artifact_intact
from service.job_rules import binding_max_spp, option_limits
from service.models import ID_PATTERN, JobRequest, cache_key, effective_optics
from service.scene_view import scene_field_of_view_box
from service.untrusted import open_job_file, read_job_json

__all__ = ["router", "SecurityHeaders", "WEB_DIR", "PAGE_CSP", "API_CSP"]

router = APIRouter()
WEB_DIR = Path(__file__).resolve().parent.parent / "web"
PAGE_CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
            "connect-src 'self'; font-src 'self'; object-src 'none'; base-uri 'none'; form-action 'none'; "
            "frame-ancestors 'none'")
API_CSP = "default-src 'none'; frame-ancestors 'none'; sandbox"
DOCS_CSP = "default-src 'none'; frame-ancestors 'none'"  # the API index: no script, no style, no fetch
_DOCS = ("/docs",)
_MEDIA = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
          ".css": "text/css; charset=utf-8", ".svg": "image/svg+xml", ".png": "image/png"}
_STATIC = re.compile(r"^[a-z0-9][a-z0-9_-]{0,63}\.(js|css|svg|png)$")
_PICTURE = re.compile(r"^(sweep|view)-\d{2}\.png$")
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class SecurityHeaders:
    """Pure ASGI middleware adding the security headers above to every response (streams untouched)."""

    def __init__(self, app) -> None:
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        path = scope.get("path", "")
        if path == "/" or path.startswith("/web/"):
            csp = PAGE_CSP
        elif any(path == d or path.startswith(d + "/") for d in _DOCS):
            csp = DOCS_CSP
        else:
            csp = API_CSP
        extra = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer"),
                 (b"x-frame-options", b"DENY"), (b"content-security-policy", csp.encode()),
                 (b"cross-origin-opener-policy", b"same-origin")]

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                have = {k.lower() for k, _ in message.get("headers", [])}
                message = {**message, "headers": [*message.get("headers", []),
                                                  *((k, v) for k, v in extra if k not in have)]}
            await send(message)

        await self.app(scope, receive, send_with_headers)


# ---- the page -----------------------------------------------------------------------------------------------
@lru_cache(maxsize=64)
def _static(name: str, mtime_ns: int) -> tuple[bytes, str]:  # noqa: ARG001 - mtime_ns keys the cache
    data = (WEB_DIR / name).read_bytes()
    return data, hashlib.sha256(data).hexdigest()[:32]


def _serve_static(request: Request, name: str) -> Response:
    path = WEB_DIR / name
    try:
        st = path.stat()
    except OSError:
        raise ApiError(404, f"no file {name!r} in the web page") from None
    data, tag = _static(name, st.st_mtime_ns)
    etag = f'"{tag}"'
    headers = {"ETag": etag, "Cache-Control": "no-cache"}
    if request.headers.get("if-none-match") == etag:
        return Response(status_code=304, headers=headers)
    return Response(data, media_type=_MEDIA[path.suffix], headers=headers)


@router.get("/", include_in_schema=False)
def index(request: Request) -> Response:
    """The results page (it asks for a token; the page itself holds no data)."""
    return _serve_static(request, "index.html")


@router.get("/web/{name}", include_in_schema=False)
def web_file(request: Request, name: str) -> Response:
    if not _STATIC.match(name):
        raise ApiError(404, f"no file {name!r} in the web page")
    return _serve_static(request, name)


# ---- small API routes the page needs -------------------------------------------------------------------------
@router.get("/v1/whoami", tags=["tokens"], responses=PROBLEM_RESPONSES)
async def whoami(principal: ReadScope) -> dict:
    """The calling token's owner, name and scopes (what the page may offer)."""
    return {"owner": principal.owner, "name": principal.name, "scopes": sorted(principal.scopes),
            "admin": principal.is_admin, "may_submit": allows(principal.scopes, "submit")}


@router.get("/v1/display-profiles", tags=["displays"], responses=PROBLEM_RESPONSES)
def display_profiles(principal: ReadScope) -> dict:  # noqa: ARG001
    """The built-in display profiles (holocore.display.profiles) and the optics each gives a job."""
    out = []
    for p in BUILTIN_DISPLAYS.values():
        optics = {k: list(v) if isinstance(v, tuple) else v for k, v in
                  ((k, getattr(p, k)) for k in OPTICS_FIELDS)}
        out.append({"name": p.name, "description": p.description, "fourier_filter": p.fourier_filter,
                    "field_of_view_x_deg": round(p.field_of_view_x_deg(), 3), "optics": optics})
    return {"default": DEFAULT_DISPLAY, "profiles": out}


@router.get("/v1/job-options", tags=["jobs"], responses=PROBLEM_RESPONSES)
def job_options(ctx: Ctx, principal: ReadScope) -> dict:  # noqa: ARG001
    """Each job option's allowed values on this service (the hologram's options model tightened by the service's
    job limits: docs/options.md): ``min``, ``max`` and ``choices`` per option, and the SLM's side in pixels."""
    return {"options": option_limits(ctx.settings.job_limits)}


@router.post("/v1/jobs/estimate", tags=["jobs"], responses=PROBLEM_RESPONSES)
def estimate_job(req: JobRequest, ctx: Ctx, principal: SubmitScope) -> dict:
    """What ``POST /v1/jobs`` with this body would predict, after the same checks (limits, the scene and display
    being this owner's, sane optics, memory); nothing is created. ``reuses`` names the earlier job whose result
    an identical submit would reuse at once."""
    req, target_db = resolve_target(ctx, req, principal)
    scene = admit_job(ctx, req, principal)
    optics = effective_optics(req)
    max_spp = binding_max_spp(req, ctx.settings.job_limits)
    key = cache_key(req, scene_sha256=scene["sha256"], entry=scene["entry"], code_version=ctx.code_version,
                    max_spp=max_spp)
    prev = reusable_job(ctx, key, principal.owner)
    est = estimate_cost(req, scene_plan=scene["plan"], max_spp=max_spp,
                        plane_border=scene_plane_border(ctx, req, scene), target_db=target_db,
                        busy_threads=busy_threads(ctx))
    return {"estimate": est, "options": req.fields() if target_db is not None else None,
            "plan_state": scene["plan_state"], "optics": optics.model_dump(mode="json"),
            "reuses": prev["id"] if prev is not None else None,
            "worker_memory_bytes": ctx.settings.worker_memory_bytes,
            "plan": plan_at_options(req, scene, max_spp=max_spp),
            "field_of_view_box": scene_field_of_view_box(scene, optics),
            "warnings": _estimate_warnings(req, scene) + est["quality"]["warnings"]}


def _estimate_warnings(req: JobRequest, scene: dict) -> list[str]:
    """What the job would not give that it asks for (an evaluation on an SLM too small to score)."""
    why = evaluation_skipped(req, scene.get("plan")) if req.evaluate else None
    return [why] if why else []


def plan_at_options(req: JobRequest, scene: dict, *, max_spp: Optional[int] = None) -> Optional[dict]:
    """The effect plan in words that the job's options would give (holocore.plan.stored_plan), from the scene's
    stored plan when it is ready."""
    plan = scene.get("plan") if scene.get("plan_state") == "ready" else None
    return stored_plan.plan_at_options(plan, effective_optics(req), req.hologram_options(), max_spp=max_spp)


# ---- pictures -------------------------------------------------------------------------------------------------
def _job(ctx: ServiceContext, job_id: str, principal: Principal) -> dict:
    row = ctx.db.get_job(job_id)
    if row is None or not principal.sees(row.get("owner")):
        raise ApiError(404, f"no job {job_id!r}")
    if row["state"] != "succeeded":
        raise ApiError(409, f"job {job_id} is {row['state']}; its pictures are made when it has succeeded")
    return row


def _index(row: dict) -> tuple[Path, dict]:
    folder = Path(row["artifact_dir"] or "") / "pictures"
    try:
        doc = read_job_json(row["artifact_dir"] or "", "pictures/index.json")
    except (OSError, ValueError):
        doc = None
    if not isinstance(doc, dict) or doc.get("stack_sha256") != row["stack_sha256"]:
        raise ApiError(404, f"job {row['id']} has no pictures (its worker makes them as its last step; jobs "
                            "from before the web page, or whose picture step failed, have none: see plan.warnings)")
    return folder, doc


def _pictures(doc: dict) -> list[dict]:
    try:
        rows = [*doc["sweep"]["pictures"], *doc["grid"]["pictures"]]
    except (KeyError, TypeError):
        return []
    return [r for r in rows if isinstance(r, dict) and _PICTURE.match(str(r.get("file", "")))]


@router.get("/v1/jobs/{job_id}/pictures", tags=["jobs"], responses=PROBLEM_RESPONSES)
def job_pictures(ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """The job's focal sweep (far to near, with each focus depth in mm and in words) and view grid (eye
    offsets in mm), each picture with its URL and SHA-256."""
    row = _job(ctx, job_id, principal)
    _, doc = _index(row)
    for r in _pictures(doc):
        r["url"] = f"/v1/jobs/{job_id}/pictures/{r['file']}"
    return JSONResponse(doc)


@router.get("/v1/jobs/{job_id}/pictures/{name}", tags=["jobs"],
            responses={200: {"content": {"image/png": {}}}, 304: {"description": "Not modified"},
                       **PROBLEM_RESPONSES})
def job_picture(request: Request, ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN),
                name: str = PathParam(pattern=r"^(sweep|view)-\d{2}\.png$")):
    """One picture of the sweep or grid, checked against the SHA-256 its index records."""
    row = _job(ctx, job_id, principal)
    folder, doc = _index(row)
    info: Optional[dict] = next((r for r in _pictures(doc) if r["file"] == name), None)
    path = folder / name
    if info is None or not isinstance(info.get("sha256"), str) or not path.is_file():
        raise ApiError(404, f"job {job_id} has no picture {name!r}")
    if not artifact_intact(path, info["sha256"], root=Path(row["artifact_dir"])):
        raise ApiError(409, f"job {job_id}: picture {name} fails its integrity check; it is not served")
    with open_job_file(row["artifact_dir"], f"pictures/{name}") as fh:
        if fh.read(8) != _PNG_MAGIC:
            raise ApiError(409, f"job {job_id}: picture {name} is not a PNG; it is not served")
    resp = file_response(request, path, sha256=info["sha256"], media_type="image/png", filename=f"{job_id}-{name}")
    resp.headers["Content-Disposition"] = f'inline; filename="{job_id}-{name}"'
    return resp
