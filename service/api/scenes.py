"""``POST /v1/scenes`` (upload a bundle) and ``GET /v1/scenes/{id}`` (its report and effect plan).

An upload is unpacked into a staging folder (zip-bomb guard, no path leaves it), checked with
``holocore.scene.bundle.validate_bundle`` before Mitsuba ever sees it, and stored content-addressed under
``scenes/<id>/bundle``: the same files with the same entry give the same id. The effect plan is computed
later by a worker subprocess (``holo plan --json``); the scene shows ``plan_state`` pending until then.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Optional

from fastapi import APIRouter, File, Form, Request, UploadFile
from fastapi import Path as PathParam
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from holocore.scene.bundle import BundleError, BundleLimits, validate_bundle
from service.api.context import ServiceContext
from service.api.deps import Ctx, ReadScope, SubmitScope
from service.api.problems import PROBLEM_RESPONSES, ApiError
from service.auth import DEFAULT_OWNER
from service.api.files import file_response
from service.integrity import artifact_intact
from service.models import ID_PATTERN, SceneOut
from service.scene_view import scene_field_of_view_box
from service.api.submission import storage_error
from service.uploads import UploadError, bundle_root, unpack_zip, write_files
from service.workers.planner import killed_from_outside

__all__ = ["router", "scene_out", "iso", "scene_id_for"]

router = APIRouter(tags=["scenes"])


def iso(t: Optional[float]) -> Optional[str]:
    return None if t is None else datetime.fromtimestamp(t, tz=timezone.utc).isoformat().replace("+00:00", "Z")


def _picture(row: dict) -> Optional[dict]:
    """What the stored plan says of the scene's picture when there is one (its size and SHA-256)."""
    plan = row["plan"] if row["plan_state"] == "ready" and isinstance(row["plan"], dict) else {}
    pic = plan.get("picture")
    return pic if isinstance(pic, dict) and isinstance(pic.get("sha256"), str) else None


def scene_out(row: dict) -> dict:
    return {"id": row["id"], "sha256": row["sha256"], "entry": row["entry"], "created_at": iso(row["created_at"]),
            "report": row["report"], "plan_state": row["plan_state"], "plan": row["plan"],
            "plan_error": row["plan_error"],
            "picture_url": f"/v1/scenes/{row['id']}/picture.png" if _picture(row) else None,
            "field_of_view_box": scene_field_of_view_box(row)}


def scene_id_for(owner: str, sha256: str, entry: str) -> str:
    """A scene's id: its content and entry, within its owner. Each owner gets a scene of their own (their own
    created_at, plan and 201 on their first upload), so an upload never tells one owner that another uploaded
    the same files; the default owner keeps the ids of a single-tenant service."""
    key = f"{sha256}\0{entry}" if owner == DEFAULT_OWNER else f"{owner}\0{sha256}\0{entry}"
    return "s" + hashlib.sha256(key.encode()).hexdigest()[:24]


def _replan_if_killed(ctx: ServiceContext, scene_id: str) -> bool:
    """A scene whose plan failed only because its process was killed from outside (the machine short of
    memory, say) is planned again when its bundle is uploaded again: that failure says nothing of the
    content. True when it went back to pending."""
    row = ctx.db.get_scene(scene_id)
    if row is None or row["plan_state"] != "failed" or not killed_from_outside(row["plan_error"]):
        return False
    return ctx.db.update_scene(scene_id, where_plan_state="failed", plan_state="pending", plan=None,
                               plan_error=None, plan_updated_at=time.time())


def _ingest(ctx: ServiceContext, bundle: Optional[UploadFile], files: list[UploadFile], entry: Optional[str],
            owner: str) -> tuple[dict, bool]:
    lim = ctx.settings.upload_limits
    staging_parent = ctx.settings.scenes_dir / ".staging"
    staging_parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=staging_parent))
    try:
        if bundle is not None:
            bundle.file.seek(0)
            unpack_zip(bundle.file, staging, limits=lim)
        else:
            write_files(((f.filename or "", f.file) for f in files), staging, limits=lim)
        root = bundle_root(staging)
        limits = BundleLimits(max_total_bytes=lim.max_total_bytes, max_files=lim.max_files,
                              max_mesh_faces=lim.max_mesh_faces, max_image_pixels=lim.max_image_pixels)
        report = validate_bundle(root, entry=entry, limits=limits)
        entry_rel = report.entry.relative_to(root.resolve()).as_posix()
        scene_id = scene_id_for(owner, report.sha256, entry_rel)
        cap = ctx.settings.max_scenes_per_owner
        if not ctx.db.scene_owned_by(scene_id, owner):
            if ctx.db.count_scenes(owner) >= cap:
                raise UploadError(f"this owner stores {cap} scenes, the most it may (max_scenes_per_owner)", 403)
            full = storage_error(ctx, owner, report.total_bytes, "this scene")
            if full is not None:
                raise UploadError(full.detail, 403)
        final = ctx.settings.scenes_dir / scene_id
        created = False
        if not (final / "bundle").is_dir():
            final.mkdir(parents=True, exist_ok=True)
            try:
                os.rename(root, final / "bundle")
            except OSError:
                if not (final / "bundle").is_dir():  # not a concurrent twin upload: a real error
                    raise
        summary = {"files": report.files, "total_bytes": report.total_bytes, "plugins": report.plugins,
                   "warnings": report.warnings, "mesh_faces": report.mesh_faces, "image_pixels": report.image_pixels,
                   "ignored": report.ignored}
        first = ctx.db.insert_scene({"id": scene_id, "sha256": report.sha256, "entry": entry_rel, "report": summary,
                                     "plan_state": "pending", "created_at": time.time()})
        if not first:
            first = _replan_if_killed(ctx, scene_id)
        created = ctx.db.add_scene_owner(scene_id, owner)
        return ctx.db.get_scene(scene_id), created, first
    finally:
        shutil.rmtree(staging, ignore_errors=True)


@router.post("/v1/scenes", status_code=201, response_model=SceneOut,
             responses={200: {"model": SceneOut, "description": "The same bundle was uploaded before"},
                        **PROBLEM_RESPONSES})
async def upload_scene(
    ctx: Ctx,
    principal: SubmitScope,
    bundle: Optional[UploadFile] = File(default=None, description="The whole bundle as one zip."),
    files: Optional[list[UploadFile]] = File(default=None, description="Files; each filename is its path "
                                                                       "relative to the bundle root."),
    entry: Optional[str] = Form(default=None, max_length=1024, description="The scene XML, relative to the root "
                                                                          "(needed when there are several)."),
) -> JSONResponse:
    """Upload a scene bundle; answers its id, content hash, validation report and (later) effect plan."""
    if bundle is not None and files:
        raise ApiError(422, "send either 'bundle' (one zip) or 'files', not both")
    if bundle is None and not files:
        raise ApiError(422, "no scene: send a 'bundle' zip or one or more 'files' fields")
    if isinstance(bundle, str) or any(isinstance(f, str) for f in files or []):
        raise ApiError(422, "'bundle' and 'files' must be file parts (with a filename)")
    try:
        row, created, first = await run_in_threadpool(_ingest, ctx, bundle, files or [], entry, principal.owner)
    except (UploadError, BundleError) as exc:
        ctx.metrics.uploads.labels(outcome="refused").inc()
        raise ApiError(getattr(exc, "status", 422), f"scene refused: {exc}") from None
    ctx.metrics.uploads.labels(outcome="created" if created else "existing").inc()
    if first:
        ctx.wake_planner()
    return JSONResponse(scene_out(row), status_code=201 if created else 200,
                        headers={"Location": f"/v1/scenes/{row['id']}"})


@router.get("/v1/scenes/{scene_id}", response_model=SceneOut, responses=PROBLEM_RESPONSES)
def get_scene(ctx: Ctx, principal: ReadScope, scene_id: str = PathParam(pattern=ID_PATTERN)):
    """A scene's validation report and its effect plan (``plan_state``: pending, running, ready, failed)."""
    row = ctx.db.get_scene(scene_id)
    if row is None or not (principal.is_admin or ctx.db.scene_owned_by(scene_id, principal.owner)):
        raise ApiError(404, f"no scene {scene_id!r}")
    return scene_out(row)


@router.get("/v1/scenes/{scene_id}/picture.png", responses={200: {"content": {"image/png": {}}},
                                                             304: {"description": "Not modified"},
                                                             **PROBLEM_RESPONSES})
def get_scene_picture(request: Request, ctx: Ctx, principal: ReadScope, scene_id: str = PathParam(pattern=ID_PATTERN)):
    """The scene through its own camera (at most 320 px wide, the camera's aspect, sRGB), made with its plan;
    ``field_of_view_box`` in the scene's JSON says where the hologram's view lies on it."""
    row = ctx.db.get_scene(scene_id)
    if row is None or not (principal.is_admin or ctx.db.scene_owned_by(scene_id, principal.owner)):
        raise ApiError(404, f"no scene {scene_id!r}")
    if row["plan_state"] in ("pending", "running"):
        raise ApiError(404, f"scene {scene_id} has no picture yet: it is made with the scene's plan, which is "
                            f"{row['plan_state']}")
    if row["plan_state"] == "failed":
        raise ApiError(404, f"scene {scene_id} has no picture: its plan failed ({row['plan_error'] or 'no reason'})")
    info = _picture(row)
    path = ctx.settings.scenes_dir / scene_id / "picture.png"
    if info is None or not path.is_file():
        said = (row["plan"] or {}).get("picture") if isinstance(row["plan"], dict) else None
        why = said.get("error") if isinstance(said, dict) and isinstance(said.get("error"), str) else None
        raise ApiError(404, f"scene {scene_id} has no picture" + (f" ({why})" if why else
                                                                  " (planned before pictures were made)"))
    if not artifact_intact(path, info["sha256"]):
        raise ApiError(409, f"scene {scene_id}: its picture fails its integrity check; it is not served")
    resp = file_response(request, path, sha256=info["sha256"], media_type="image/png",
                         filename=f"{scene_id}-picture.png")
    resp.headers["Content-Disposition"] = f'inline; filename="{scene_id}-picture.png"'
    return resp
