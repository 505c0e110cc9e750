"""A finished job's evaluation against ground truth (the job field ``evaluate``; made by its worker's last step,
service/workers/evaluation.py): ``GET /v1/jobs/{id}/evaluation``, the index (per focus depth of the focal sweep:
the ground truth's and the scored hologram view's PNG, the sweep picture at that depth, PSNR and SSIM; per view
of the grid likewise; the viewer-faithful score where the job has one) and ``GET
/v1/jobs/{id}/evaluation/{file}.png``, each PNG checked against the SHA-256 its index records. Files only: the
request does no work."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Optional

from fastapi import APIRouter, Request
from fastapi import Path as PathParam
from pydantic import BaseModel, Field

from service.api.deps import Ctx, ReadScope, owned_job
from service.api.files import file_response
from service.api.problems import PROBLEM_RESPONSES, ApiError
from service.integrity import artifact_intact
from service.models import ID_PATTERN
from service.untrusted import open_job_file, read_job_json
from service.workers.evaluation import FILE_PATTERN

__all__ = ["router", "EvaluationOut", "EvaluationFocus", "EvaluationView", "ViewerScoreOut", "ViewerPupil"]

router = APIRouter(tags=["jobs"])
_FILE = re.compile(FILE_PATTERN)
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class _Cell(BaseModel):
    truth_url: Optional[str] = Field(default=None, description="The Mitsuba thin-lens ground truth (PNG).")
    hologram_url: Optional[str] = Field(default=None, description="The hologram's simulated view as scored: the "
                                        "same pupil, its least-squares brightness scale applied, at the ground "
                                        "truth's white level (PNG).")
    psnr_db: Optional[float] = Field(default=None, description="PSNR (dB) of the view against the ground truth, "
                                     "after one brightness scale; none when infinite.")
    ssim: Optional[float] = None
    margin_px: Optional[int] = Field(default=None, description="Border left out of the score: the SLM's aperture "
                                     "vignettes it (docs/evaluation.md).")


class EvaluationFocus(_Cell):
    index: int = Field(description="The focal sweep's index at this depth (GET /v1/jobs/{id}/pictures, far to "
                                   "near): the page's focus slider position.")
    z_mm: float = Field(description="Focus depth, mm from the SLM.")
    words: str = Field(description="Where that lies in the scene.")
    sweep_url: Optional[str] = Field(default=None, description="The focal sweep's picture at this depth (4 mm "
                                     "pupil, the sweep's white level).")
    skipped: Optional[str] = Field(default=None, description="Why this depth has no score (no URL, no numbers).")


class EvaluationView(_Cell):
    col: int
    row: int = Field(description="Row of the view grid, 0 at the top (the eye moved up).")
    offset_mm: list[float] = Field(description="Eye offset (x right, y up), mm.")
    focus_mm: float = Field(description="The focus depth of the view grid (the sweep's middle), mm from the SLM.")


class ViewerPupil(BaseModel):
    pupil_mm: float
    mean_psnr_db: Optional[float] = None
    mean_ssim: Optional[float] = None
    brightness_max_over_min: Optional[float] = Field(default=None, description="Over the eye grid.")
    colour_cast: Optional[float] = None
    colour_tint: Optional[float] = None
    edge_error: Optional[float] = None
    parallax_error_px: Optional[float] = None


class ViewerScoreOut(BaseModel):
    mean_psnr_db: Optional[float] = Field(default=None, description="Mean PSNR (dB) over every pupil, eye position "
                                          "and focus, at one brightness scale per colour (docs/evaluation.md).")
    scale_spread: Optional[float] = Field(default=None, description="Largest / smallest of the cells' own best "
                                          "scales: what a per-cell fit would hide.")
    eye_grid: int
    eye_span_mm: Optional[float] = None
    focus_mm: list[float]
    cells: int
    pupils: list[ViewerPupil]


class EvaluationOut(BaseModel):
    job_id: str
    stack_sha256: str
    pupil_mm: float = Field(description="The pupil of every cell: the largest inside every colour's recording cone "
                                        "at the views (holo evaluate's default).")
    gt_spp: int = Field(description="Samples per pixel of the ground truth renders.")
    views: int = Field(description="The view grid is views x views (1: the centre view only).")
    view_deg: float
    white: Optional[float] = Field(default=None, description="The white level (linear) of every PNG of the index.")
    gamma: Optional[float] = Field(default=None, description="The PNGs' encoding: value = (linear / white)^(1/gamma).")
    mean_psnr_db: Optional[float] = None
    mean_ssim: Optional[float] = None
    focus: list[EvaluationFocus] = Field(description="Every depth of the focal sweep, in the sweep's order.")
    view_grid: list[EvaluationView] = Field(description="The views at the middle depth (empty with one view).")
    viewer: Optional[ViewerScoreOut] = Field(default=None, description="The viewer-faithful score, for stacks of "
                                             "more than one frame.")
    viewer_error: Optional[str] = None
    notes: list[str] = Field(default_factory=list)
    seconds: Optional[float] = None


def _evaluated(ctx, job_id: str, principal) -> tuple[dict, Path, dict]:
    """The job's row, evaluation folder and index; 404 with the reason when there is none to give."""
    row = owned_job(ctx, job_id, principal)
    spec = row["spec"] if isinstance(row["spec"], dict) else {}
    if not spec.get("evaluate"):
        raise ApiError(404, f"job {job_id} did not ask for an evaluation against ground truth (submit it with "
                            "\"evaluate\": true)")
    if row["state"] != "succeeded":
        raise ApiError(404, f"job {job_id} is {row['state']}: its evaluation is made when it has succeeded"
                       if row["state"] in ("queued", "running") else
                       f"job {job_id} is {row['state']}: it has no evaluation")
    folder = Path(row["artifact_dir"] or "") / "evaluation"
    try:
        doc = read_job_json(row["artifact_dir"], "evaluation/index.json") if row["artifact_dir"] else None
    except (OSError, ValueError):
        doc = None
    if not isinstance(doc, dict) or doc.get("stack_sha256") != row["stack_sha256"]:
        plan = row["plan"] if isinstance(row.get("plan"), dict) else {}
        why = next((w for w in plan.get("warnings") or [] if isinstance(w, str) and w.startswith("no evaluation")),
                   None)
        raise ApiError(404, f"job {job_id} has no evaluation: " + (why or "its evaluate step made none"))
    return row, folder, doc


def _files(doc: dict) -> dict[str, str]:
    """{file name: sha256} of every PNG the index names."""
    out = {}
    for c in [*(doc.get("focus") or []), *(doc.get("view_grid") or [])]:
        for key in ("truth", "hologram"):
            name, sha = c.get(f"{key}_file"), c.get(f"{key}_sha256")
            if isinstance(name, str) and _FILE.match(name) and isinstance(sha, str):
                out[name] = sha
    return out


def _urls(job_id: str, c: dict) -> dict:
    base = f"/v1/jobs/{job_id}/evaluation/"
    return {k: v for k, v in c.items() if not k.endswith(("_file", "_sha256"))} | {
        f"{key}_url": base + c[f"{key}_file"] for key in ("truth", "hologram")
        if isinstance(c.get(f"{key}_file"), str) and _FILE.match(c[f"{key}_file"])}


@router.get("/v1/jobs/{job_id}/evaluation", response_model=EvaluationOut, responses=PROBLEM_RESPONSES)
def job_evaluation(ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN)):
    """The job's evaluation against Mitsuba thin-lens ground truth: per depth of its focal sweep (the page's
    focus slider) the ground truth's and the scored view's PNG, the sweep picture at that depth, PSNR and SSIM;
    per view of the grid likewise; the viewer-faithful score where the job has one. 404 when the job did not ask
    for an evaluation (``evaluate``), has not succeeded, or its evaluation failed (its warnings say why)."""
    _, _, doc = _evaluated(ctx, job_id, principal)
    focus = []
    for c in doc.get("focus") or []:
        sweep = c.get("sweep_file")
        focus.append({**_urls(job_id, c), "sweep_url": f"/v1/jobs/{job_id}/pictures/{sweep}"
                      if isinstance(sweep, str) and re.fullmatch(r"sweep-\d{2}\.png", sweep) else None})
    return EvaluationOut(**{**doc, "job_id": job_id, "focus": focus,
                            "view_grid": [_urls(job_id, c) for c in doc.get("view_grid") or []]})


@router.get("/v1/jobs/{job_id}/evaluation/{name}", tags=["jobs"],
            responses={200: {"content": {"image/png": {}}}, 304: {"description": "Not modified"},
                       **PROBLEM_RESPONSES})
def job_evaluation_file(request: Request, ctx: Ctx, principal: ReadScope, job_id: str = PathParam(pattern=ID_PATTERN),
                        name: str = PathParam(pattern=FILE_PATTERN)):
    """One PNG of the evaluation (``truth-fFF-vVV.png``, ``recon-fFF-vVV.png``: focus FF, view VV), checked
    against the SHA-256 its index records."""
    row, folder, doc = _evaluated(ctx, job_id, principal)
    sha = _files(doc).get(name)
    path = folder / "pairs" / name
    root = Path(row["artifact_dir"])
    if sha is None or not path.is_file() or path.is_symlink():
        raise ApiError(404, f"job {job_id}'s evaluation has no picture {name!r}")
    if not artifact_intact(path, sha, root=root):
        raise ApiError(409, f"job {job_id}: evaluation picture {name} fails its integrity check; it is not served")
    with open_job_file(root, f"evaluation/pairs/{name}") as fh:
        if fh.read(8) != _PNG_MAGIC:
            raise ApiError(409, f"job {job_id}: evaluation picture {name} is not a PNG; it is not served")
    resp = file_response(request, path, sha256=sha, media_type="image/png", filename=f"{job_id}-{name}")
    resp.headers["Content-Disposition"] = f'inline; filename="{job_id}-{name}"'
    return resp
