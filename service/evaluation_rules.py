"""What a job's evaluation against ground truth is (service/workers/evaluation.py runs it): its cells and views,
its ground truth's samples, whether an SLM is large enough to score anything, and what it costs in seconds and
bytes. The API's estimate and admission read these before a job runs; no step of the evaluation is run here.
"""

from __future__ import annotations

from typing import Any, Optional

__all__ = ["EVALUATION_VERSION", "GT_SPP", "VIEWS", "VIEW_DEG", "VIEWER_PUPILS_MM", "VIEWER_EYE_GRID",
           "SWEEP_DEPTHS", "FILE_PATTERN", "MIN_LIT_PX", "evaluation_cells", "evaluation_too_small",
           "evaluation_seconds", "evaluation_output_bytes"]

EVALUATION_VERSION = 1
GT_SPP = 32
VIEWS = 3
VIEW_DEG = 0.5
VIEWER_PUPILS_MM = (2.0, 4.0)
VIEWER_EYE_GRID = 3
SWEEP_DEPTHS = 9  # the pictures step's sweep (service.workers.pictures), and the depths when it made none
FILE_PATTERN = r"^(recon|truth)-f\d{2}-v\d{2}\.png$"  # holocore.evaluate.score_files.pair_names
MIN_LIT_PX = 16  # holocore.evaluate.scoring.evaluate refuses a view with less fully lit than this



# ---- cost ------------------------------------------------------------------------------------------------------
# Measured on a 2-core CPU (the demo scene, holo evaluate): a ground truth render of 540x960 took 2.2 s at 16 spp
# and 5.5 s at 64 (1.3e-7 s a sample, 2.1e-6 s a pixel for the film and the pupil's diffraction), a view 0.4 s a
# frame (2.6e-7 s a pixel, colour and frame), and each cell about 0.6 s of its own (the sensor, the kernels, the
# transfer functions of its depth; 35 cells of 96x128 x 2 frames took 35 s with another job beside them); each
# holo evaluate process 5 s to start (Mitsuba, torch, the scene).
_S_PER_SAMPLE, _S_PER_PIXEL, _S_PER_VIEW_PX, _S_PER_CELL, _S_PER_PROCESS = 1.3e-7, 2.1e-6, 2.6e-7, 0.6, 5.0


def evaluation_cells(frames: int) -> tuple[int, int]:
    """(cells, holo evaluate processes) of an evaluation: the sweep's depths plus the other views at the middle
    one, and the viewer score's pupils x eye grid for more than one frame."""
    cells = SWEEP_DEPTHS + VIEWS * VIEWS - 1
    if frames > 1:
        return cells + len(VIEWER_PUPILS_MM) * VIEWER_EYE_GRID ** 2, 2
    return cells, 1


def evaluation_too_small(optics: Any, *, camera_fov_x_deg: Optional[float] = None) -> Optional[str]:
    """Why an evaluation would score nothing on this SLM (None when it can score): a view is scored only where
    the SLM lights all of the pupil's bundle, a border of ceil(z NA / p) px at hologram depth z
    (holocore.evaluate.scoring.lit_margin_px), and no depth it scores is nearer the SLM than virtual infinity,
    so an SLM whose shorter side is under 2 ceil(z_inf NA / p) + 16 px has no depth to score. ``optics``: the
    job's OpticsConfig; ``camera_fov_x_deg``: the scene camera's view (it sets f with fit_camera_fov)."""
    from holocore.evaluate.scoring import default_pupil_m, lit_margin_px  # numpy: not in the API's start-up

    try:
        meta = {"wavelengths_m": tuple(optics.wavelengths_m), "focal_length_m": optics.focal_length_m(camera_fov_x_deg),
                "z_inf_m": optics.z_inf_m, "pitch_m": optics.pitch_m}
        pupil = default_pupil_m(meta, view_deg=VIEW_DEG)
        need = 2 * lit_margin_px(meta, focus_z_m=optics.z_inf_m, pupil_diameter_m=pupil) + MIN_LIT_PX
    except (ValueError, TypeError):
        return None  # the step itself says why, in its warning
    h, w = (int(v) for v in optics.resolution_hw)
    if min(h, w) >= need:
        return None
    return (f"no evaluation at {h}x{w} px: the ground truth is scored only where the SLM lights all of a "
            f"{pupil * 1e3:.3g} mm pupil's light, which on this display needs at least {need} px on each side")


def evaluation_seconds(*, height: int, width: int, colors: int, frames: int) -> float:
    """Predicted seconds of the evaluate step (the pictures' 9 sweep depths; the model above)."""
    cells, processes = evaluation_cells(frames)
    px = height * width
    per_cell = _S_PER_CELL + px * (_S_PER_PIXEL + _S_PER_SAMPLE * GT_SPP) + _S_PER_VIEW_PX * px * colors * frames
    return processes * _S_PER_PROCESS + cells * per_cell


# The evaluation's folder (service/workers/evaluation.py): per cell a PNG pair of the SLM's size, 8-bit RGB, which
# PNG stores in at most 3 bytes a pixel and a filter byte a row (a noisy reconstruction hardly compresses), for
# each of the most cells its scored views can have whatever the frames (the viewer score writes no pictures);
# and its JSON. Measured (bench/results/evaluation_memory.md): 720x1280 with 17 cells 37 MB against a bound of
# 95 MB (its pictures compress).
_EVAL_FIXED = 1 << 20


def evaluation_output_bytes(*, height_px: int, width_px: int) -> int:
    """The most bytes a job's ``evaluation/`` folder holds on an SLM of ``height_px`` x ``width_px`` pixels."""
    cells, _ = evaluation_cells(1)
    return cells * 2 * (3 * height_px * width_px + height_px) + _EVAL_FIXED
