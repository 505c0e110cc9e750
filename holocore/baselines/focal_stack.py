"""The focal-stack baseline the paper compares with (Sec. 5.2, "FS"; Choi et al. 2022, time-multiplexed neural
holography): phase-only SGD of F frames on the amplitude of a focal stack.

1. Targets: K focus planes z_k across the image volume, by default chosen from the renderer's image volume
   (:func:`default_stack_planes`: up to the paper's 5, uniform from its far to its near end, no two closer than
   the pupil's depth of focus, 2 lambda f^2 / D^2, which is the paper's 1.25 mm for red through a 1.6 mm pupil
   at f = 50 mm; a fixed spacing when asked, centred on the volume and never beyond optical infinity), one
   ground-truth view per plane of what the eye sees focused there through its pupil D, from the ground truth
   `holo evaluate` scores against (``truth``, :mod:`holocore.evaluate.truths`: by default the wave-optical one,
   whose views of one depth-layer render cost an FFT pass each; ``thinlens``, a Mitsuba render each). Per laser
   line the channel that holds it; all targets share one white level (their ``white_percentile``; emitters above
   it clip).
2. Model: frame m's SLM field exp(i phi_m), propagated from the SLM (z = 0) to z_k with the band-limited ASM
   (:func:`holocore.optics.propagation.transfer_function`, 2x zero padding, docs/design.md §5) through the same
   pupil disc (:func:`holocore.optics.viewing.pupil_mask`; the centre view), |.|^2 averaged over the F frames:
   exactly the centre view `holo view` and `holo evaluate` simulate.
3. Loss (per colour c, all planes): sum_k || s_c sqrt(mean_m I_{m,k}) - sqrt(T_k) ||^2 / (K H W), Adam on the
   phases of all frames together (time multiplexing: only the frame average is supervised), s_c the
   least-squares scale of the previous iteration (variable projection; no gradient through it). Each plane is
   back-propagated on its own, so memory holds one plane's graph.
Pupil-aware fit (``fit="pupil-aware"``, the default; ``"centred"`` is the fit above). The viewer-faithful
score (:mod:`holocore.evaluate.viewer`) looks through pupils of 1.6-6 mm from a jittered grid of eye positions;
a stack fitted through one centred pupil was never asked for those views, which makes it a weak yardstick. So:

1'. Targets: a bank of ground-truth renders over the score's own distribution of views, every pupil of
    :data:`holocore.evaluate.viewer.DEFAULT_PUPILS_M` from every eye offset of a jittered 3 x 3
    :func:`holocore.evaluate.viewer.eye_grid_m` (its default span; the jitter from the optics' seed +
    :data:`FIT_EYE_SEED`, so never the score's own positions), at every stack plane: pupils x 9 x K Mitsuba
    renders (225 for 5 planes), held as float32 (pupils x 9 x K x C x H x W x 4 bytes); one white level for all.
2'. Model: each Adam step draws one view of the bank and takes, at every plane, exactly the view
    :func:`holocore.evaluate.scoring.eye_view` takes (:func:`holocore.optics.viewing.simulate_view`: the pupil
    disc at the eye offset, the content shift :func:`holocore.evaluate.scoring.view_shift_px`, the display's
    Fourier filter where its profile has one), divided by the pupil's share of the eyebox
    (:func:`holocore.evaluate.viewer.aperture_share`), as the score divides it.
3'. Loss: as in 3. for the drawn view, with one scale per colour for the whole bank (least squares over about
    one bank's worth of recent steps, exponentially weighted), as the score fits one scale for all its views.
    A step costs about what a centred step costs plus the view's shift, and the loss history is that of the
    drawn views (noisier than the centred fit's).

4. Output: a phase-only stack. The colours are balanced by the laser power: colour c is lit with power
   P_c = (s_c / max s)^2, so that each colour's frame average matches its target's brightness. The RESULT's
   ``slm_field`` is sqrt(P_c) exp(i phi) (what `holo view` and `holo evaluate` read), its ``wrp_field`` that
   field propagated to the WRP; :func:`stack_of` gives the same as a STACK (phase and
   ``meta["encoder"]["illumination"]``).

``meta["method"] == "focal-stack"``; the renderer's analysis is in the meta, so evaluation picks the same
focus planes as for a render.
"""

from __future__ import annotations

import math
import time
from typing import Any, Literal, Optional, Sequence

import numpy as np

from pydantic import Field

from holocore import validate
from holocore.baselines.adam_budget import MAX_ITERATIONS, AdamFitOptions, torch_device
from holocore.baselines.focal_stack_fit import FocalStackFit, optimise_focal_stack
from holocore.baselines.registry import Baseline, register_baseline
from holocore.display.optics import OpticsConfig
from holocore.evaluate.scoring import default_pupil_m
from holocore.render_meta import RenderResult, result_meta

__all__ = ["DEFAULT_PLANES", "DEFAULT_SPACING_M", "MAX_PLANES", "MAX_ITERATIONS", "FITS", "DEFAULT_FIT_EYE_GRID",
           "FIT_EYE_SEED", "stack_plane_depths", "depth_of_focus_m", "default_stack_planes", "optimise_focal_stack",
           "FocalStackFit", "render_focal_stack", "stack_of", "FocalStackOptions", "FocalStackBaseline"]

DEFAULT_PLANES = 5
DEFAULT_SPACING_M = 1.25e-3  # the paper's 5 planes at 1.25 mm spacing within 80-85 mm
MAX_PLANES = 64
FITS = ("pupil-aware", "centred")
DEFAULT_FIT_EYE_GRID = 3  # 3 x 3 eye positions per pupil: the viewer-faithful score's grid in the paper report
FIT_EYE_SEED = 7919  # added to the optics' seed for the bank's eye jitter: never the score's own (0 by default)


def stack_plane_depths(*, z_inf_m: float, z_far_m: Optional[float], z_near_m: Optional[float],
                       planes: int = DEFAULT_PLANES, spacing_m: Optional[float] = DEFAULT_SPACING_M,
                       z_limit_m: Optional[float] = None) -> np.ndarray:
    """Hologram depths (m, far to near) of the focal stack's planes.

    ``spacing_m`` given: ``planes`` planes that far apart, centred on the image volume [z_far, z_near], moved
    as a whole to stay nearer than the WRP ``z_limit_m`` (exclusive) and never beyond optical infinity
    (z >= z_inf; ValueError when both cannot hold). ``spacing_m`` None: ``planes`` planes uniform from z_far to
    z_near (one plane: the middle). No volume known (a black scene): centred at z_inf + (planes - 1) spacing / 2.
    """
    planes = validate.integer("planes", planes, 1, MAX_PLANES)
    zi = validate.positive("z_inf_m", z_inf_m, unit="")
    far = zi if z_far_m is None else float(z_far_m)
    near = far if z_near_m is None else float(z_near_m)
    far, near = min(far, near), max(far, near)
    if spacing_m is None:
        zs = np.array([0.5 * (far + near)]) if planes == 1 else np.linspace(far, near, planes)
    else:
        s = validate.positive("spacing_m", spacing_m, unit="")
        mid = 0.5 * (far + near) if z_far_m is not None else zi + 0.5 * (planes - 1) * s
        zs = mid + (np.arange(planes) - 0.5 * (planes - 1)) * s
        if z_limit_m is not None and zs[-1] >= float(z_limit_m):
            zs = zs - (zs[-1] - float(z_limit_m)) - 1e-3 * s
        if zs[0] < zi:
            zs = zs + (zi - zs[0])
        if z_limit_m is not None and zs[-1] >= float(z_limit_m):
            raise ValueError(f"{planes} planes {s * 1e3:g} mm apart do not fit between optical infinity "
               f"({zi * 1e3:.4f} mm) and the WRP ({float(z_limit_m) * 1e3:.4f} mm): use fewer planes "
                             "or a smaller spacing")
    return zs.astype(np.float64)


def depth_of_focus_m(*, wavelength_m: float, focal_length_m: float, pupil_diameter_m: float) -> float:
    """Hologram-depth step (m) over which the eye's defocus grows by a quarter wave at its pupil's rim:
    2 lambda f^2 / D^2 (Rayleigh; the pupil accepts direction sines within NA = D / 2f, and a step dz defocuses
    the rim by dz NA^2 / 2). Focal-stack planes closer than this give the eye the same image."""
    lam = validate.positive("wavelength_m", wavelength_m, unit="")
    f = validate.positive("focal_length_m", focal_length_m, unit="")
    D = validate.positive("pupil_diameter_m", pupil_diameter_m, unit="")
    return 2.0 * lam * f * f / (D * D)


def default_stack_planes(*, z_far_m: Optional[float], z_near_m: Optional[float], min_spacing_m: float,
                         most: int = DEFAULT_PLANES) -> int:
    """How many focal-stack planes the image volume [z_far, z_near] (hologram depths, m) holds when spread
    uniformly from its far to its near end no closer than ``min_spacing_m`` (the pupil's
    :func:`depth_of_focus_m`): 1 + floor(depth / min_spacing), at most ``most`` (the paper's 5); one plane for
    a volume shallower than one step or unknown (a black scene)."""
    most = validate.integer("most", most, 1, MAX_PLANES)
    step = validate.positive("min_spacing_m", min_spacing_m, unit="")
    if z_far_m is None or z_near_m is None:
        return 1
    depth = abs(float(z_near_m) - float(z_far_m))
    return int(min(most, 1 + math.floor(depth / step * (1 + 1e-9))))


def _check_fit_args(gt_spp: int, fit: str, fit_eye_grid: int, white_percentile: float) -> tuple[int, int, float]:
    """(gt_spp, fit_eye_grid, white percentile) checked; ValueError for a ``fit`` not in :data:`FITS` or a
    percentile outside 50..100."""
    gt_spp = validate.integer("gt_spp", gt_spp, 1, 1 << 16)
    if fit not in FITS:
        raise ValueError(f"fit must be one of {', '.join(FITS)}, got {fit!r}")
    fit_eye_grid = validate.integer("fit_eye_grid", fit_eye_grid, 1, 9)
    wp = float(white_percentile)
    if not (math.isfinite(wp) and 50.0 <= wp <= 100.0):
        raise ValueError(f"white_percentile must be in 50..100, got {white_percentile!r}")
    return gt_spp, fit_eye_grid, wp


def _plane_depths(optics: OpticsConfig, ana: Any, f: float, D: float, *, planes: Optional[int],
                  spacing_m: Optional[float], plane_z_m: Optional[Sequence[float]]) -> np.ndarray:
    """The stack's hologram depths (m): ``plane_z_m`` checked, else :func:`stack_plane_depths` of the image volume
    (``planes`` None: the paper's 5 for a fixed spacing, else :func:`default_stack_planes`); ValueError where a
    plane lies at or beyond the WRP."""
    if plane_z_m is not None:
        zs = np.asarray([float(z) for z in plane_z_m], dtype=np.float64)
        if zs.size < 1 or zs.size > MAX_PLANES or not np.all(np.isfinite(zs)) or np.any(zs < optics.z_inf_m):
            raise ValueError(f"plane_z_m must hold 1..{MAX_PLANES} finite depths at or beyond z_inf "
               f"({optics.z_inf_m * 1e3:g} mm), got {list(plane_z_m)!r}")
    else:
        if planes is None and spacing_m is not None:
            planes = DEFAULT_PLANES  # a fixed spacing asked for: the paper's stack of 5
        elif planes is None:
            # the longest wavelength has the deepest focus: planes that red cannot tell apart are not worth a target
            step = depth_of_focus_m(wavelength_m=max(optics.wavelengths_m), focal_length_m=f, pupil_diameter_m=D)
            planes = default_stack_planes(z_far_m=ana.z_far_holo_m, z_near_m=ana.z_near_holo_m, min_spacing_m=step)
        zs = stack_plane_depths(z_inf_m=optics.z_inf_m, z_far_m=ana.z_far_holo_m, z_near_m=ana.z_near_holo_m,
                                planes=planes, spacing_m=spacing_m, z_limit_m=ana.z_wrp_m)
    if zs.max() >= ana.z_wrp_m:
        raise ValueError(f"a focal-stack plane at {zs.max() * 1e3:.4f} mm lies at or beyond the WRP "
                         f"({ana.z_wrp_m * 1e3:.4f} mm)")
    return zs


def _fit_bank(base_meta: dict, fit_pupils_m: Optional[Sequence[float]], fit_eye_grid: int, seed: int
              ) -> tuple[list[float], list, list[tuple[float, tuple[float, float]]]]:
    """(pupils (m), the jittered eye grid [(index, offset)], the bank's views [(pupil, eye offset)]) of the
    pupil-aware fit: every pupil from every eye position, the jitter seeded ``seed`` + :data:`FIT_EYE_SEED`."""
    from holocore.evaluate.viewer import DEFAULT_PUPILS_M, eye_grid_m

    pupils = [validate.positive("fit_pupils_m", v, unit="") for v in (fit_pupils_m or DEFAULT_PUPILS_M)]
    eyes = eye_grid_m(base_meta, n=fit_eye_grid, seed=int(seed) + FIT_EYE_SEED)
    return pupils, eyes, [(Dv, e) for Dv in pupils for _idx, e in eyes]


def _stack_targets(truth: Any, zs: np.ndarray, D: float, bank: Optional[list], shape_chw: tuple[int, int, int],
                   progress: Optional[Any], wp: float) -> tuple[np.ndarray, float]:
    """(targets / white clipped to [0, 1], white): the ground truth's views at every plane, [views, K, C, H, W]
    float32 over the bank, or [K, C, H, W] through the centred pupil ``D`` when ``bank`` is None; white is their
    ``wp`` percentile, their max where that is not positive, 1 for black targets."""
    if bank is not None:
        targets = np.empty((len(bank), zs.size) + tuple(shape_chw), dtype=np.float32)
        for v, (Dv, e) in enumerate(bank):
            for k, z in enumerate(zs):
                targets[v, k] = truth.channels(focus_z_m=float(z), pupil_diameter_m=Dv, view_offset_m=e)
                if progress:
                    progress("targets", v * zs.size + k + 1, len(bank) * zs.size)
    else:
        targets = np.stack([truth.channels(focus_z_m=float(z), pupil_diameter_m=D) for z in zs])  # [K, C, H, W]
    white = float(np.percentile(targets, wp))
    if not white > 0:
        white = float(targets.max()) if targets.max() > 0 else 1.0
    return np.clip(targets / white, 0.0, 1.0), white


def _stack_fields(res: FocalStackFit, optics: OpticsConfig, z_wrp_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(SLM field sqrt(P_c) exp(i phi), that field propagated to the WRP), both complex64 [F, C, H, W]."""
    import torch

    from holocore.optics.propagation import asm

    power = res.illumination
    slm = (np.exp(1j * res.phase.astype(np.float32)) * np.sqrt(power).astype(np.float32)[None, :, None, None]
           ).astype(np.complex64)
    wrp = np.empty_like(slm)
    for c, lam in enumerate(optics.wavelengths_m):
        wrp[:, c] = asm(torch.from_numpy(np.ascontiguousarray(slm[:, c])), z_wrp_m, float(lam),
                        optics.pitch_m).numpy()
    return slm, wrp


def _stack_summary(zs: np.ndarray, D: float, pupils: Optional[list[float]], fit_eye_grid: int, renders: int,
                   gt_spp: int, frames: int, res: FocalStackFit) -> list[str]:
    """The result's one-line summary: planes, targets, frames and Adam steps."""
    through = (f"a {D * 1e3:.3g} mm centred pupil" if pupils is None else
               f"{len(pupils)} pupils ({', '.join(f'{v * 1e3:g}' for v in pupils)} mm) x a "
               f"{fit_eye_grid}x{fit_eye_grid} jittered eye grid ({renders} renders), one view drawn per Adam step")
    return [f"focal-stack baseline: {zs.size} planes from {zs[0] * 1e3:.3f} to {zs[-1] * 1e3:.3f} mm, "
            f"Mitsuba thin-lens targets through {through} at {gt_spp} spp, "
            f"{frames} phase-only frame(s) per colour optimised together "
            f"({'/'.join(str(n) for n in res.iterations)} Adam steps) on "
            f"the frame-averaged amplitude, colours balanced by laser power"]


def _fit_meta(fit: str, truth: str, renders: int, render_bytes: int, ff: bool, fit_eye_grid: int, seed: int,
              pupils: Optional[list[float]], eyes: Optional[list]) -> dict[str, Any]:
    """The meta's record of the fit: its kind, target renders and truth, and for a pupil-aware fit its bank."""
    fit_meta: dict[str, Any] = {"fit": fit, "target_renders": renders, "truth": truth}
    if pupils is not None:
        fit_meta["bank"] = {"pupils_m": pupils, "eye_grid": fit_eye_grid, "eye_seed": int(seed) + FIT_EYE_SEED,
                            "eye_offsets_m": [list(e) for _i, e in eyes], "views": len(pupils) * len(eyes),
                            "fourier_filter": ff, "bytes": renders * render_bytes}
    return fit_meta


def _stack_extra(*, zs: np.ndarray, plane_z_m: Optional[Sequence[float]], spacing_m: Optional[float], D: float,
                 iterations: int, res: FocalStackFit, time_limit_s: Optional[float], lr: float, gt_spp: int,
                 fit_meta: dict, wp: float, white: float) -> dict:
    """The meta's ``focal_stack`` record: planes, pupil, fit settings, white level, scales, powers and loss."""
    hist = res.loss
    step = max(1, len(hist) // 200)
    return {"planes": int(zs.size), "plane_z_m": [float(z) for z in zs],
            "spacing_m": None if plane_z_m is not None else spacing_m,
            "pupil_diameter_m": D, "iterations": iterations, "iterations_done": res.iterations,
            "time_limit_s": time_limit_s, "lr": lr, "gt_spp": gt_spp, **fit_meta,
            "white_percentile": wp, "target_white": white, "scale": [float(v) for v in res.scale],
            "illumination": [float(v) for v in res.illumination], "loss_first": hist[0], "loss_final": hist[-1],
            "loss_every": step, "loss": hist[::step], "phase_only": True}


def render_focal_stack(loaded: Any, optics: OpticsConfig, *, planes: Optional[int] = None,
                       spacing_m: Optional[float] = None, plane_z_m: Optional[Sequence[float]] = None,
                       pupil_diameter_m: Optional[float] = None, iterations: int = 200, lr: float = 0.05,
                       gt_spp: int = 64, white_percentile: float = 99.5, device: str = "cpu",
                       progress: Optional[Any] = None, display: Optional[Any] = None,
                       time_limit_s: Optional[float] = None, fit: str = "pupil-aware",
                       fit_pupils_m: Optional[Sequence[float]] = None, fit_eye_grid: int = DEFAULT_FIT_EYE_GRID,
                       truth: str = "wave") -> Any:
    """The focal-stack baseline for a loaded scene -> :class:`holocore.pipeline.RenderResult` (RESULT format).

    Planes: ``plane_z_m`` (hologram depths, m) or :func:`stack_plane_depths` of the renderer's image volume
    with ``planes`` and ``spacing_m``. Defaults from that volume: ``planes`` None is
    :func:`default_stack_planes` (up to 5, no two closer than the pupil's depth of focus for the longest
    wavelength), ``spacing_m`` None spreads them uniformly from the volume's far to its near end, so every plane
    lies inside it; a ``spacing_m`` given keeps that spacing, centred on the volume, with 5 planes unless
    ``planes`` says otherwise (ValueError where the stack does not fit between optical infinity and the WRP).
    ``pupil_diameter_m``: the eye's pupil of the targets and of the model (default: the one `holo evaluate` uses
    by default, :func:`holocore.evaluate.scoring.default_pupil_m` at +-0.5 deg).
    ``gt_spp``: Mitsuba samples per pixel of each target; ``white_percentile`` (50..100) of all targets is
    their common white level (brighter pixels clip). Frames, colours, pitch, seed and the WRP come from
    ``optics`` and the renderer's own scene analysis; ``display`` is recorded in the meta as the renderer does.
    ``time_limit_s``: the whole baseline's wall time (s), targets included: the Adam steps stop early to keep
    it (:func:`optimise_focal_stack`; the SLM fields' last propagation, about a second, is not counted).
    ``fit``: "pupil-aware" (the default) fits a bank of views, every pupil of ``fit_pupils_m`` (default the
    viewer-faithful score's, :data:`holocore.evaluate.viewer.DEFAULT_PUPILS_M`) from every eye position of a
    jittered ``fit_eye_grid`` x ``fit_eye_grid`` grid (:func:`holocore.evaluate.viewer.eye_grid_m`, its default
    span, jittered from ``optics.seed`` + :data:`FIT_EYE_SEED`, not the score's seed): pupils x grid x planes
    Mitsuba renders, held in memory as float32. "centred": one centred pupil of ``pupil_diameter_m``, one
    render per plane.
    """
    from holocore.evaluate.truths import ground_truth
    from holocore.render_setup import RenderOptions, plan_scene

    gt_spp, fit_eye_grid, wp = _check_fit_args(gt_spp, fit, fit_eye_grid, white_percentile)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pl = plan_scene(loaded, optics, RenderOptions(preset="fast"))
    ana = pl.analysis
    f = pl.focal_length_m
    timings["analysis_s"] = time.perf_counter() - t0
    base_meta = {"focal_length_m": f, "z_inf_m": optics.z_inf_m, "pitch_m": optics.pitch_m,
                 "wavelengths_m": list(optics.wavelengths_m), "scene_scale": optics.scene_scale}
    D = float(pupil_diameter_m) if pupil_diameter_m is not None else default_pupil_m(base_meta, view_deg=0.5)
    D = validate.positive("pupil_diameter_m", D, unit="")
    zs = _plane_depths(optics, ana, f, D, planes=planes, spacing_m=spacing_m, plane_z_m=plane_z_m)
    H, W = optics.resolution_hw
    C = len(optics.wavelengths_m)
    t1 = time.perf_counter()
    # the targets are the ground truth the score takes (holocore.evaluate.truths), not another one and its errors
    gt = ground_truth(truth, loaded, base_meta, shape_hw=(H, W), spp=gt_spp, seed=optics.seed)
    pupils, eyes, bank = (_fit_bank(base_meta, fit_pupils_m, fit_eye_grid, optics.seed) if fit == "pupil-aware"
                          else (None, None, None))
    targets, white = _stack_targets(gt, zs, D, bank, (C, H, W), progress, wp)
    timings["targets_s"] = time.perf_counter() - t1
    renders = zs.size * (1 if bank is None else len(bank))
    if progress and bank is None:
        progress("targets", 1, 1)
    left = None if time_limit_s is None else max(1e-3, float(time_limit_s) - (time.perf_counter() - t0))
    ff = bool(getattr(display, "fourier_filter", False))  # what the result's meta will tell eye_view
    res = optimise_focal_stack(targets, zs, wavelengths_m=optics.wavelengths_m, pitch_m=optics.pitch_m,
                               focal_length_m=f, pupil_diameter_m=D, frames=optics.frames, iterations=iterations,
                               lr=lr, seed=optics.seed, device=device, progress=progress, time_limit_s=left,
                               views=bank, z_inf_m=optics.z_inf_m, fourier_filter=ff)
    del targets
    fit_meta = _fit_meta(fit, truth, renders, C * H * W * 4, ff, fit_eye_grid, optics.seed, pupils, eyes)
    timings["optimise_s"] = res.seconds
    t2 = time.perf_counter()
    slm, wrp = _stack_fields(res, optics, ana.z_wrp_m)
    timings["propagate_s"] = time.perf_counter() - t2
    timings["total_s"] = time.perf_counter() - t0
    F = slm.shape[0]
    summary = _stack_summary(zs, D, pupils, fit_eye_grid, renders, gt_spp, F, res)
    extra = _stack_extra(zs=zs, plane_z_m=plane_z_m, spacing_m=spacing_m, D=D, iterations=iterations, res=res,
                         time_limit_s=time_limit_s, lr=lr, gt_spp=gt_spp, fit_meta=fit_meta, wp=wp, white=white)
    meta = result_meta(method="focal-stack", preset=None, loaded=loaded, optics=optics, scene_plan=pl,
                       shape_fchw=(F, C, H, W), timings=timings, display=display, summary=summary,
                       extra={"focal_stack": extra})
    return RenderResult(slm_field=slm, wrp_field=wrp, meta=meta)


def stack_of(result: Any) -> tuple[np.ndarray, dict]:
    """(phase [F, C, H, W] in [0, 2pi), STACK meta) of a focal-stack result: the phase of its SLM field and
    its meta with ``encoder`` = {"method": "focal-stack", "illumination": P [F, C]} (the laser powers `holo view`
    and `holo evaluate` light a stack with)."""
    slm = np.asarray(result.slm_field)
    meta = dict(result.meta)
    fs = meta.get("focal_stack")
    if meta.get("method") != "focal-stack" or not fs:
        raise ValueError("not a focal-stack result (meta['method'] must be 'focal-stack')")
    phase = np.mod(np.angle(slm), 2 * np.pi).astype(np.float32)
    F = slm.shape[0]
    meta["encoder"] = {"method": "focal-stack", "illumination": [list(map(float, fs["illumination"]))] * F,
                       "iterations": fs["iterations"]}
    return phase, meta


class FocalStackOptions(AdamFitOptions):
    planes: Optional[int] = Field(None, ge=1, le=64, description="focal-stack planes (default from the image volume)")
    spacing_mm: Optional[float] = Field(None, ge=0, lt=1000, description="plane spacing in hologram depth (mm); "
                                        "0 or None: spread over the image volume")
    pupil_mm: Optional[float] = Field(None, gt=0, le=1000, description="eye pupil of the targets and the model (mm)")
    gt_spp: int = Field(64, ge=1, le=65536, description="Mitsuba samples per pixel of each target")
    fit: Literal["pupil-aware", "centred"] = Field("pupil-aware", description="pupil-aware: targets and model "
                                                   "over the viewer-faithful score's pupils x a jittered eye grid, "
                                                   "one view per Adam step; centred: one centred pupil (pupil_mm)")
    eye_grid: int = Field(DEFAULT_FIT_EYE_GRID, ge=1, le=9, description="pupil-aware: n x n eye positions per "
                          "pupil (targets: pupils x n^2 x planes renders)")
    truth: Literal["wave", "thinlens"] = Field("wave", description="the ground truth of the targets "
                                               "(holocore.evaluate.truths): the one the score takes")


@register_baseline
class FocalStackBaseline(Baseline):
    name = "focal-stack"
    summary = ("focal stack: phase-only Adam fit of the frames to Mitsuba thin-lens targets at planes across the "
               "image volume, through the viewer-faithful score's pupils and eye positions (or one centred pupil)")
    Options = FocalStackOptions

    def describe(self, meta):
        fs = meta["focal_stack"]
        zs = fs["plane_z_m"]
        bank = fs.get("bank")
        if bank:  # pupil-aware: what the targets cost, since they dominate its time on small budgets
            fit = (f"pupil-aware fit over pupils {', '.join(f'{v * 1e3:g}' for v in bank['pupils_m'])} mm x a "
                   f"{bank['eye_grid']}x{bank['eye_grid']} jittered eye grid ({fs['target_renders']} target renders, "
                   f"{bank['bytes'] / 2**20:.1f} MiB)")
        else:
            fit = f"centred pupil {fs['pupil_diameter_m'] * 1e3:.3g} mm"
        return (f"{super().describe(meta)}, {len(zs)} planes from {zs[0] * 1e3:.4f} to {zs[-1] * 1e3:.4f} mm, {fit}, "
                f"loss {fs['loss_first']:.4g} -> {fs['loss_final']:.4g} in "
                f"{'/'.join(str(n) for n in fs['iterations_done'])} steps (per colour)")

    def render(self, loaded, optics, options, *, display=None, progress=None):
        return render_focal_stack(
            loaded, optics, planes=options.planes, spacing_m=options.spacing_mm * 1e-3 if options.spacing_mm else None,
            pupil_diameter_m=None if options.pupil_mm is None else options.pupil_mm * 1e-3,
            iterations=options.iterations, lr=options.lr, gt_spp=options.gt_spp,
            device=torch_device(options.device), progress=progress, display=display,
            time_limit_s=options.time_limit_s, fit=options.fit, fit_eye_grid=options.eye_grid, truth=options.truth)
