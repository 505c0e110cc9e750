"""A finished job's phase frames one at a time: the index (frames, colours with their wavelengths, the SLM's
size) and each (frame, colour) as the 8-bit grey PNG the SLM is driven with.

The PNGs are the members of the job's frames.zip as the worker wrote them (``f{frame:03d}_c{colour}.png``, grey
level ``round(phase / 2pi * 256) mod 256`` of the stack's ``frames_u8``), sent as they are: nothing is decoded or
encoded again, so the page shows exactly the levels the display agent loads, and a frame costs one read of a
stored member."""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

from fastapi import APIRouter, Request
from fastapi import Path as PathParam
from fastapi.responses import Response
from pydantic import BaseModel, Field

from service.api.deps import Ctx, ReadScope, owned_job
from service.api.problems import PROBLEM_RESPONSES, ApiError
from service.integrity import artifact_intact
from service.models import ID_PATTERN
from service.untrusted import JSON_MAX_BYTES, open_job_file

__all__ = ["router", "colour_name", "PhaseIndex", "PhaseColour"]

router = APIRouter(tags=["jobs"])
_MEMBER = re.compile(r"^f(\d+)_c(\d+)\.png$")
# A frame's bytes never change while its job exists (a job's result is fixed once it succeeded; a deleted job
# answers 404), so the browser may keep a frame it has shown for a while instead of asking again.
_FRAME_CACHE = "private, max-age=3600"


class PhaseColour(BaseModel):
    index: int = Field(description="The colour's index: the C axis of the stack, {colour} in the frame URL.")
    name: str = Field(description="A name for people, from the wavelength (red, green, blue, ...).")
    wavelength_nm: float = Field(description="The laser wavelength this colour's frames are for, nm.")


class PhaseIndex(BaseModel):
    job_id: str
    frames: int = Field(description="Frames F (the time-multiplexed phase patterns); {frame} is 0..F-1.")
    colours: list[PhaseColour]
    height_px: int = Field(description="SLM rows H.")
    width_px: int = Field(description="SLM columns W.")
    shape: list[int] = Field(description="[F, C, H, W], the stack's phase and frames_u8 shape.")
    levels_per_2pi: int = Field(default=256, description="Grey level L meaning a phase of 2 pi: a pixel's "
                                "level is round(phase / 2pi * L) mod L, so 0..255 spans 0..2pi.")
    frame_url: str = Field(description="URL template of one frame's PNG: {frame} and {colour} are indices.")


def colour_name(wavelength_nm: float) -> str:
    """The colour a person calls light of this wavelength (the usual band edges, nm)."""
    for edge, name in ((380.0, "ultraviolet"), (450.0, "violet"), (495.0, "blue"), (570.0, "green"),
                       (590.0, "yellow"), (620.0, "orange"), (750.0, "red")):
        if wavelength_nm < edge:
            return name
    return "infrared"


def _succeeded(ctx, job_id: str, principal) -> dict:
    row = owned_job(ctx, job_id, principal)
    if row["state"] != "succeeded":
        raise ApiError(409, f"job {job_id} is {row['state']}; its phase frames exist once it has succeeded")
    return row


def _intact(row: dict, name: str, sha: str | None) -> Path:
    path = Path(row["artifact_dir"] or "") / name
    if not row["artifact_dir"] or not path.is_file() or not sha:
        raise ApiError(404, f"job {row['id']} has no {name}")
    if not artifact_intact(path, sha):
        raise ApiError(409, f"job {row['id']}: the stored {name} fails its integrity check (its sha256 is no longer "
                            f"{sha[:12]}...); it is not served. Submit the job again to recompute it")
    return path


def _job_shape(row: dict) -> tuple[int, int, int, int]:
    """[F, C, H, W] the job's options ask for: what its stack and frames may hold, at most."""
    o = ((row.get("spec") or {}).get("optics") or {}) if isinstance(row.get("spec"), dict) else {}
    try:
        h, w = (int(v) for v in o["resolution_hw"])
        return int(o["frames"]), len(o["wavelengths_nm"]), h, w
    except (KeyError, TypeError, ValueError):
        raise ApiError(409, f"job {row['id']}: its stored options give no stack shape") from None


def _member(zf: zipfile.ZipFile, name: str, *, max_bytes: int, what: str) -> zipfile.ZipInfo:
    """The stored (uncompressed) member ``name`` of at most ``max_bytes``: the worker writes every member stored,
    so a compressed one is not its, and its inflated size is checked before any byte is read."""
    info = zf.getinfo(name)
    if info.compress_type != zipfile.ZIP_STORED or info.compress_size != info.file_size:
        raise ApiError(409, f"{what}: {name} is compressed; the worker writes it stored, so it is not served")
    if info.file_size > max_bytes:
        raise ApiError(409, f"{what}: {name} holds {info.file_size} bytes, more than the job's size allows "
                            f"({max_bytes})")
    return info


def _png_max_bytes(h: int, w: int) -> int:
    """The most an 8-bit grey H x W PNG can take: a filter byte a row, zlib's stored blocks (5 bytes per 64 KiB)
    and the chunks' headers."""
    raw = h * (w + 1)
    return raw + 5 * (raw // 65535 + 1) + 4096


@router.get("/v1/jobs/{job_id}/phase", response_model=PhaseIndex, responses=PROBLEM_RESPONSES)
def phase_index(ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """The job's phase frames: how many, the colours with their wavelengths (nm), the SLM's size in pixels, and
    the URL of each frame's 8-bit PNG."""
    from holocore.formats.meta import parse_stack_meta
    from holocore.formats.npz import NpyMember, read_npz_meta

    row = _succeeded(ctx, job_id, principal)
    stack = _intact(row, "stack.npz", row["stack_sha256"])
    f_max, c_max, h_max, w_max = _job_shape(row)
    what = f"job {job_id}'s stack.npz"
    try:
        with open_job_file(stack.parent, stack.name) as fh, zipfile.ZipFile(fh) as zf:
            _member(zf, "frames_u8.npy", max_bytes=f_max * c_max * h_max * w_max + 4096, what=what)
            _member(zf, "meta.npy", max_bytes=JSON_MAX_BYTES, what=what)
        shape = NpyMember(stack, "frames_u8").shape
        meta = parse_stack_meta(read_npz_meta(stack), what="stack.npz")
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise ApiError(409, f"job {job_id}: its stack.npz cannot be read ({type(exc).__name__})") from None
    if len(shape) != 4 or len(meta.wavelengths_m) != shape[1]:
        raise ApiError(409, f"job {job_id}: its stack.npz is not a [F, C, H, W] stack with one wavelength a colour")
    f, c, h, w = (int(s) for s in shape)
    colours = [PhaseColour(index=i, name=colour_name(lam * 1e9), wavelength_nm=round(lam * 1e9, 3))
               for i, lam in enumerate(meta.wavelengths_m)]
    return PhaseIndex(job_id=job_id, frames=f, colours=colours, height_px=h, width_px=w, shape=[f, c, h, w],
                      frame_url=f"/v1/jobs/{job_id}/phase/{{frame}}/{{colour}}.png")


@router.get("/v1/jobs/{job_id}/phase/{frame}/{colour}.png",
            responses={200: {"content": {"image/png": {}}}, 304: {"description": "Not modified"},
                       **PROBLEM_RESPONSES})
def phase_frame(request: Request, ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN),
                frame: int = PathParam(ge=0, le=1_000_000, description="Frame index, 0..F-1."),
                colour: int = PathParam(ge=0, le=255, description="Colour index, 0..C-1 (GET .../phase lists "
                                                                  "their wavelengths).")):
    """One phase frame of one colour as the 8-bit grey PNG the SLM shows (grey level 0..255 for phase 0..2pi,
    ``round(phase / 2pi * 256) mod 256``), at the SLM's own size, W x H."""
    row = _succeeded(ctx, job_id, principal)
    info = (row["artifacts"] or {}).get("frames.zip") or {}
    path = _intact(row, "frames.zip", info.get("sha256"))
    _, _, h, w = _job_shape(row)
    try:
        with open_job_file(path.parent, path.name) as fh, zipfile.ZipFile(fh) as zf:
            names = zf.namelist()
            want = f"f{frame:03d}_c{colour}.png"
            if want not in names:
                held = [m for m in (_MEMBER.match(n) for n in names) if m]
                n_f = 1 + max((int(m.group(1)) for m in held), default=-1)
                n_c = 1 + max((int(m.group(2)) for m in held), default=-1)
                if frame >= n_f:
                    raise ApiError(404, f"job {job_id} has {n_f} frame(s), 0..{n_f - 1}; no frame {frame}")
                if colour >= n_c:
                    raise ApiError(404, f"job {job_id} has {n_c} colour(s), 0..{n_c - 1}; no colour {colour}")
                raise ApiError(404, f"job {job_id}: its frames.zip lacks frame {frame} colour {colour}")
            member = _member(zf, want, max_bytes=_png_max_bytes(h, w), what=f"job {job_id}'s frames.zip")
            data = zf.read(member)
    except (OSError, zipfile.BadZipFile):
        raise ApiError(409, f"job {job_id}: its frames.zip cannot be read") from None
    etag = f'"{info["sha256"][:32]}-f{frame}-c{colour}"'
    headers = {"ETag": etag, "Cache-Control": _FRAME_CACHE}
    inm = request.headers.get("if-none-match")
    if inm and etag in [t.strip().removeprefix("W/") for t in inm.split(",")]:
        return Response(status_code=304, headers=headers)
    return Response(data, media_type="image/png", headers=headers)
