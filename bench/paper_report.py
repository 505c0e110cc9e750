"""The paper's figures (Figs. 5, 6, 7) and an equal-time table, regenerated on the project's paper scenes
(holocore/scene/paper.py) at the paper display's pitch (8 µm), f = 50 mm, laser lines and 24 frames, on a
reduced part of the SLM (default 135x240 px; see the README this writes for why and where z_inf lies).

Stages (each writes a JSON under --out, the report is rebuilt from all JSONs present):

* ``equal``: per scene, every method gets the same wall-time budget ``--budget-s`` for 24 phase-only frames:
  ours = two-stage render (preset balanced) + the SGD phase-only encoder (``--enc-iterations``, default 60),
  spp chosen from 16- and 64-spp timing runs to fill the budget; fast = the same with
  preset fast; layers = the RGB-D layer baseline + the same encoder; light field = the stereogram baseline
  (`holocore.baselines.light_field`, ``--lf-hogel-px``, ``--lf-spp``) + the same encoder; light field SGD = phase-only
  frames fitted to the same light field (``fit="sgd"``), Adam steps until the budget's wall time runs out;
  focal stack = `holocore.baselines.focal_stack` (its Mitsuba targets included), Adam steps until the budget's
  wall time runs out (``time_limit_s``). Scored with holocore.evaluate.scoring's machinery (eye_view + compare) against
  Mitsuba thin-lens ground truth on 4 focus planes (near / middle / far of the image volume and the depth of the
  mirror or glass image) x 3 views (left, centre, right), none of them the focal stack's own planes unless by
  chance (the table gives each plane's distance to the nearest stack plane). Keeps the images of Fig. 7.
* ``conv``: convergence map (Fig. 5): two-stage, fast and direct at several spp, rendered with 3, 8 and 24
  frames (coded frame phases depend on the frame count, so a prefix of a 24-frame render is not an F-frame
  render; checked by tests/bench/test_paper_report.py; F = 1 is the 24-frame render's first frame, one random-phase
  frame, whereas a 1-frame render skips the random phase, docs/design.md §8), centre view, 3 focus planes. Convergence =
  PSNR(vs ground truth) / PSNR(converged reference vs ground truth), the reference a two-stage render at
  ``--ref-spp`` with 24 frames; the 80 % contour is drawn. PSNR against the reference's first F frames (Monte
  Carlo error alone) is kept too.
* ``runtime``: wall time over 1, 3, 8, 24 frames (Fig. 6) for ours, fast, layers, light field, focal stack at the
  settings the equal-time stage chose (24 frames: taken from it).

    .venv/bin/python bench/paper_report.py                   # or: holo bench paper
    .venv/bin/python bench/paper_report.py --stages report   # rebuild README/figures from the JSONs
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import platform
import sys
import textwrap
import time
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

RESULTS = ROOT / "bench" / "results" / "paper"
FRAMES = (1, 3, 8, 24)
METHOD_LABEL = {"ours": "ours (two-stage, balanced)", "fast": "fast (two-stage + radiance cache)",
                "direct": "direct (scene -> SLM)", "layers": "layers (RGB-D, 8 planes)",
                "light-field": "light field (stereogram)", "light-field-sgd": "light field (SGD fit)",
                "focal-stack": "focal stack"}


# ---- bookkeeping (pure, tested) -------------------------------------------------------------------------------
def fit_count(budget_s: float, fixed_s: float, per_unit_s: float, *, lo: int = 1, hi: int = 1 << 16) -> int:
    """The largest count n in [lo, hi] with fixed_s + n per_unit_s <= budget_s (lo if even that does not fit):
    how many rays per pixel, or Adam iterations, a method gets for an equal time budget."""
    if not (per_unit_s > 0 and math.isfinite(per_unit_s)):
        raise ValueError(f"per_unit_s must be > 0, got {per_unit_s!r}")
    n = math.floor((float(budget_s) - float(fixed_s)) / float(per_unit_s))
    return int(min(hi, max(lo, n)))


def convergence_ratio(psnr_db: float, ref_psnr_db: float) -> float:
    """PSNR (vs ground truth) relative to the converged reference's PSNR (vs the same ground truth)."""
    if not (math.isfinite(ref_psnr_db) and ref_psnr_db > 0):
        return math.nan
    return float(psnr_db) / float(ref_psnr_db)


def image_focus_m(scene: str, meta: dict) -> Optional[float]:
    """Hologram depth (m) of the image that carries the scene's cue: the mirror image, the glass ball's image,
    the glossy highlight, the middle card (z = z_inf + f^2 / zc)."""
    from holocore.scene.paper import PAPER_SCENES, scene_facts

    if scene not in PAPER_SCENES:
        return None
    fx = scene_facts(scene)
    zc = {"mirror": fx.get("mirror_image_zc_m"), "glass": fx.get("paraxial_image_zc_m"),
          "glossy": fx.get("highlight_image_zc_m"), "depth": (fx.get("depths_m") or {}).get("mid")}[scene]
    f, zi = float(meta["focal_length_m"]), float(meta["z_inf_m"])
    return zi + f * f / float(zc)


def cell_grid(scene: str, meta: dict, *, view_deg: float, seed: int = 0,
              avoid_m: Sequence[float] = ()) -> tuple[list[tuple[str, float]], list[tuple[str, tuple]]]:
    """Focus planes [(name, z)] and views [(name, (ex, ey))] (left, centre, right at +-view_deg).

    The planes (docs/evaluation.md, "Focus planes"): the cue's image (the mirror image, the glass ball's image,
    the highlight, the middle card) unless it lies on a method's own plane (``avoid_m``), and one drawn from
    ``seed`` in each third of the image volume (near, middle, far), kept off the methods' planes and the image
    by the blue SLM band's layer step (2 p^2 / lambda: the depth over which its defocus changes by a quarter
    wave) where the third leaves room; a plane is never scored twice."""
    from holocore.evaluate.scoring import fair_focus_planes_m
    from holocore.evaluate.wave_truth import layer_spacing_m

    gap = layer_spacing_m(pitch_m=float(meta["pitch_m"]), wavelength_m=min(meta["wavelengths_m"]))
    zi = image_focus_m(scene, meta)
    image = zi is not None and all(abs(zi - z) >= gap for z in avoid_m)
    far, mid, near = fair_focus_planes_m(meta, 3, seed=seed, avoid_m=[*avoid_m, *([zi] if image else [])],
                                         min_gap_m=gap)
    focus = [("near", near), ("middle", mid), ("far", far)]
    if image:
        focus.append(("image", zi))
    e = float(meta["focal_length_m"]) * math.sin(math.radians(view_deg))
    return focus, [("left", (-e, 0.0)), ("centre", (0.0, 0.0)), ("right", (e, 0.0))]


def margin_px(meta: dict, shape_hw: tuple[int, int], *, focus_z_m: float, pupil_m: float, view: tuple) -> int:
    """holocore.evaluate.scoring.lit_margin_px, capped so that at least 16 px stay (tiny test sizes)."""
    from holocore.evaluate.scoring import lit_margin_px

    m = lit_margin_px(meta, focus_z_m=focus_z_m, pupil_diameter_m=pupil_m, view_offset_m=view)
    return int(min(m, max(0, (min(shape_hw) - 16) // 2)))


def score_cell(recon: np.ndarray, truth: np.ndarray, m: int) -> tuple[float, float, float]:
    """(PSNR dB, SSIM, scale) of holocore.evaluate.scoring.compare on the lit part (border m px left out)."""
    from holocore.evaluate.scoring import compare

    H, W = recon.shape[-2:]
    sc = compare(recon[:, m:H - m, m:W - m], truth[:, m:H - m, m:W - m])
    return sc.psnr_db, sc.ssim, sc.scale


def phase_only_field(enc: Any) -> np.ndarray:
    """What the display shows for an encoder result: sqrt(P) exp(i phi), P the encoder's laser powers [F, C]."""
    P = np.sqrt(np.asarray(enc.illumination, dtype=np.float64)).astype(np.float32)
    return (np.exp(1j * enc.phase.astype(np.float32)) * P[..., None, None]).astype(np.complex64)


# ---- running ------------------------------------------------------------------------------------------------
class Runner:
    def __init__(self, args, log) -> None:
        from holocore.display.profiles import PAPER

        self.args, self.log = args, log
        self.H, self.W = args.shape_hw
        self.work = Path(args.work)
        self.work.mkdir(parents=True, exist_ok=True)
        # the paper's display with its filter ("4f": a Fourier filter passes each colour's recording cone) or
        # without one ("none": the prototype's SLM, eyepiece and iris; what the encoder parks outside the cone
        # reaches the eye)
        self.display = PAPER if args.filter == "4f" else PAPER.model_copy(update={"fourier_filter": False})

    def optics(self, frames: int, frame_phases: Optional[str] = None):
        return self.display.optics(resolution_hw=(self.H, self.W), frames=frames, z_inf_mm=self.args.z_inf_mm,
                            frame_phases=frame_phases or self.args.frame_phases)

    def load(self, scene: str):
        from holocore.scene.demo import write_cbox_scene, write_demo_scene
        from holocore.scene.load import load_scene
        from holocore.scene.paper import write_paper_scene

        own = {"demo": write_demo_scene, "cbox": write_cbox_scene}  # the project's own test scenes
        if scene in own:
            return load_scene(own[scene](self.work / scene))
        return load_scene(write_paper_scene(scene, self.work / scene))

    def warm(self, loaded, methods=("wrp/balanced", "wrp/fast", "direct/balanced")) -> None:
        """Compile every kernel once (tiny size), so no timed run pays for JIT compilation."""
        from holocore.baselines.layers import render_layers
        from holocore.encode.encoder import encode_sgd
        from holocore.pipeline import RenderOptions, render_loaded

        small = self.display.optics(resolution_hw=(24, 32), frames=2, z_inf_mm=self.args.z_inf_mm,
                             frame_phases=self.args.frame_phases)
        for key in methods:
            method, preset = key.split("/")
            r = render_loaded(loaded, small, RenderOptions(preset=preset, method=method, spp=4))
        if self.args.alt_frame_phases and self.args.alt_frame_phases != self.args.frame_phases:
            render_loaded(loaded, small.model_copy(update={"frame_phases": self.args.alt_frame_phases}),
                          RenderOptions(preset="balanced", spp=4))
        encode_sgd(r.wrp_field, z_wrp_m=r.meta["z_wrp_m"], wavelengths_m=r.meta["wavelengths_m"],
                   pitch_m=r.meta["pitch_m"], iterations=2, stop_db=0.0)
        render_layers(loaded, small, planes=2, spp=4)
        from holocore.baselines.light_field import render_light_field

        render_light_field(loaded, small, hogel_px=min(3, self.args.lf_hogel_px), spp=1)

    def render(self, loaded, frames: int, preset: str, spp: int, method: str = "wrp",
               time_limit_s: Optional[float] = None, frame_phases: Optional[str] = None):
        from holocore.pipeline import RenderOptions, render_loaded

        t0 = time.perf_counter()
        planes = self.args.wrp_planes if method == "wrp" else 1
        r = render_loaded(loaded, self.optics(frames, frame_phases), RenderOptions(preset=preset, method=method, spp=spp,
                                                                     wrp_planes=planes, time_limit_s=time_limit_s),
                          display=self.display)
        return r, time.perf_counter() - t0

    def encode(self, res):
        from holocore.encode.encoder import encode_sgd

        m = res.meta
        t0 = time.perf_counter()
        fixed = self.args.enc_iterations != "auto"
        enc = encode_sgd(res.wrp_field, z_wrp_m=m["z_wrp_m"], wavelengths_m=m["wavelengths_m"], pitch_m=m["pitch_m"],
                         iterations=int(self.args.enc_iterations) if fixed else self.args.enc_max_iterations,
                         stop_db=0.0 if fixed else 0.05, fourier_filter=self.display.fourier_filter)
        return enc, time.perf_counter() - t0

    @staticmethod
    def enc_label(enc) -> str:
        """The encoder's iterations as the report states them: fixed, or the stop rule's mean and largest."""
        per = enc.iterations_per_target
        if enc.options.get("stop_db") and per is not None:
            return f"SGD stop rule ({float(np.mean(per)):.0f} it mean, {int(np.max(per))} max)"
        return f"SGD {enc.iterations} it"

    def layers(self, loaded, frames: int):
        from holocore.baselines.layers import render_layers

        t0 = time.perf_counter()
        r = render_layers(loaded, self.optics(frames), planes=self.args.layer_planes, spp=self.args.layer_spp,
                          display=self.display)
        return r, time.perf_counter() - t0

    def light_field(self, loaded, frames: int, **fit):
        from holocore.baselines.light_field import render_light_field

        t0 = time.perf_counter()
        r = render_light_field(loaded, self.optics(frames), hogel_px=self.args.lf_hogel_px, spp=self.args.lf_spp,
                               display=self.display, **fit)
        return r, time.perf_counter() - t0

    @staticmethod
    def fs_spacing(meta: dict) -> Optional[float]:
        """The paper's 1.25 mm plane spacing where its 5 planes fit between z_inf and the WRP, else None (5
        planes uniform over the image volume where they do not)."""
        from holocore.baselines.focal_stack import stack_plane_depths

        ana = meta["analysis"]
        try:
            stack_plane_depths(z_inf_m=meta["z_inf_m"], z_far_m=ana["z_far_holo_m"], z_near_m=ana["z_near_holo_m"],
                               planes=5, spacing_m=1.25e-3, z_limit_m=meta["z_wrp_m"])
            return 1.25e-3
        except ValueError:
            return None

    def focal_stack(self, loaded, frames: int, iterations: int, spacing_m: Optional[float] = 1.25e-3,
                    time_limit_s: Optional[float] = None):
        from holocore.baselines.focal_stack import render_focal_stack

        t0 = time.perf_counter()
        # pupil-aware: fitted through the viewer-faithful score's pupils and eye positions, the stronger
        # baseline (a centred fit was never asked for the views that score takes)
        r = render_focal_stack(loaded, self.optics(frames), iterations=iterations, gt_spp=self.args.fs_gt_spp,
                               planes=5, spacing_m=spacing_m, display=self.display, time_limit_s=time_limit_s,
                               fit="pupil-aware", truth=self.args.truth)
        return r, time.perf_counter() - t0

    def fs_planes(self, meta: dict) -> list[float]:
        """The focal stack's 5 target planes (m), as :meth:`focal_stack` will place them."""
        from holocore.baselines.focal_stack import stack_plane_depths

        ana = meta["analysis"]
        return [float(z) for z in stack_plane_depths(
            z_inf_m=meta["z_inf_m"], z_far_m=ana["z_far_holo_m"], z_near_m=ana["z_near_holo_m"], planes=5,
            spacing_m=self.fs_spacing(meta), z_limit_m=meta["z_wrp_m"])]

    def fs_probe(self, meta: dict, pupil: float) -> tuple[float, float]:
        """(seconds of one focal-stack Adam iteration, seconds of its final no-gradient pass) at the report's frame
        count, from two short runs (0 and 2 iterations) on a random target. Probed at the real frame count: a
        2-frame probe scaled linearly gave the mirror's stack 192 s of a 90 s budget (memory traffic grows faster
        than the frames)."""
        from holocore.baselines.focal_stack import (
            optimise_focal_stack,
            stack_plane_depths,
        )

        ana = meta["analysis"]
        zs = stack_plane_depths(z_inf_m=meta["z_inf_m"], z_far_m=ana["z_far_holo_m"], z_near_m=ana["z_near_holo_m"],
                                planes=5, spacing_m=self.fs_spacing(meta), z_limit_m=meta["z_wrp_m"])
        # one view of the pupil-aware fit's bank: each step draws one, and every view costs the same
        T = np.random.default_rng(0).random((1, len(zs), 3, self.H, self.W))
        kw = dict(wavelengths_m=meta["wavelengths_m"], pitch_m=meta["pitch_m"], focal_length_m=meta["focal_length_m"],
                  pupil_diameter_m=pupil, frames=self.args.frames, views=[(pupil, (0.0, 0.0))],
                  z_inf_m=meta["z_inf_m"], fourier_filter=self.display.fourier_filter)
        t0 = time.perf_counter()
        optimise_focal_stack(T, zs, iterations=0, **kw)
        t1 = time.perf_counter()
        optimise_focal_stack(T, zs, iterations=2, **kw)
        t2 = time.perf_counter()
        return max(1e-3, ((t2 - t1) - (t1 - t0)) / 2.0), t1 - t0

    # ---- the equal-time comparison and Fig. 7 ----------------------------------------------------------------
    def equal(self, scene: str) -> dict:
        from holocore.evaluate.scoring import default_pupil_m, eye_view
        from holocore.evaluate.truths import ground_truth

        a, F, B = self.args, self.args.frames, self.args.budget_s
        loaded = self.load(scene)
        self.warm(loaded, methods=("wrp/balanced", "wrp/fast"))
        out: dict[str, Any] = {"scene": scene, "budget_s": B, "frames": F, "shape_hw": [self.H, self.W],
                               "frame_phases": a.frame_phases,
                               "z_inf_mm": a.z_inf_mm, "enc_iterations": a.enc_iterations, "methods": {}}
        fields: dict[str, np.ndarray] = {}
        # layers + encoder (this also measures the encoder's time at this size, the same for every WRP field)
        lay, t_lay = self.layers(loaded, F)
        enc, t_enc = self.encode(lay)
        meta = lay.meta
        fields["layers"] = phase_only_field(enc)
        fields["layers (complex)"] = lay.slm_field
        layer_planes = [float(z) for z in lay.meta["layers"]["plane_z_m"]]
        out["methods"]["layers"] = {"render_s": t_lay, "encode_s": t_enc, "time_s": t_lay + t_enc,
                                    "config": f"{a.layer_planes} planes, RGB-D {a.layer_spp} spp, {self.enc_label(enc)}"}
        self.log(f"[{scene}] layers {t_lay:.1f} s + encoder {t_enc:.1f} s")
        del lay
        # light field + encoder: its rays, the stereogram and the same encoder
        lf, t_lf = self.light_field(loaded, F)
        enc, t_e = self.encode(lf)
        fields["light-field"] = phase_only_field(enc)
        fields["light-field (complex)"] = lf.slm_field
        lfm = lf.meta["light_field"]
        out["methods"]["light-field"] = {"render_s": t_lf, "encode_s": t_e, "time_s": t_lf + t_e,
                                         "z_rs_m": lfm["z_rs_m"], "hogel_px": lfm["hogel_px"], "spp": lfm["spp"],
                                         "config": f"{lfm['hogel_px']}-px hogels, RS plane "
                                                   f"{lfm['z_rs_m'] * 1e3:.3f} mm, {lfm['spp']} spp, "
                                                   f"{self.enc_label(enc)}"}
        self.log(f"[{scene}] light field {t_lf:.1f} s + encoder {t_e:.1f} s")
        del lf
        # ours and fast: a render with a time limit (the budget less the encoder's time measured on the layers'
        # field, the same size): passes of rays until it is spent (holocore.plan.time_budget), at most max_spp
        alt = [(f"ours ({a.alt_frame_phases})", "balanced", a.alt_frame_phases)] \
            if a.alt_frame_phases and a.alt_frame_phases != a.frame_phases else []
        for name, preset, phases in [("ours", "balanced", None), ("fast", "fast", None), *alt]:
            res, t_r = self.render(loaded, F, preset, a.max_spp, time_limit_s=max(1.0, B - t_enc), frame_phases=phases)
            sampling = res.meta["sampling"]
            spp = sampling["spp"]
            e, t_e = self.encode(res)
            fields[name] = phase_only_field(e)
            if name == "ours":
                fields["ours (complex)"] = res.slm_field
                meta = res.meta
            out["methods"][name] = {"render_s": t_r, "encode_s": t_e, "time_s": t_r + t_e, "spp": spp,
                                    "sampling": sampling,
                                    "config": f"{spp} spp, {self.enc_label(e)}",
                                    "plan": res.meta["plan"]["summary"]}
            self.log(f"[{scene}] {name}: {spp} spp {t_r:.1f} s + encoder {t_e:.1f} s")
            del res
        # light field, SGD fit: Adam steps on its light field until the budget's wall time runs out
        if a.lf_sgd:
            lfs, t_lfs = self.light_field(loaded, F, fit="sgd", iterations=100_000, lr=a.lf_lr,
                                          time_limit_s=max(1.0, B - 1.0))
            fields["light-field-sgd"] = lfs.slm_field
            lm = lfs.meta["light_field"]
            done = [int(v) for v in lm["iterations_done"]]
            out["methods"]["light-field-sgd"] = {
                "render_s": t_lfs, "encode_s": 0.0, "time_s": t_lfs, "iterations": int(round(sum(done) / len(done))),
                "iterations_per_colour": done, "loss_first": lm["loss_first"], "loss_final": lm["loss_final"],
                "config": f"{lm['hogel_px']}-px hogels, {lm['spp']} spp, {'/'.join(map(str, done))} Adam it"}
            self.log(f"[{scene}] light field SGD: {'/'.join(map(str, done))} iterations {t_lfs:.1f} s")
            del lfs
        # focal stack: Adam iterations to fill the budget
        pupil = default_pupil_m(meta, view_deg=a.view_deg)
        truth = ground_truth(a.truth, loaded, meta, shape_hw=(self.H, self.W), spp=a.gt_spp, seed=1)
        own_planes = layer_planes + self.fs_planes(meta)  # where a method was fitted: never a scored plane
        seeds = [int(v) for v in str(a.plane_seeds).split(",")]
        focus, views = cell_grid(scene, meta, view_deg=a.view_deg, seed=seeds[0], avoid_m=own_planes)
        t_gt0 = time.perf_counter()
        gts = {(fn, vn): truth.channels(focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=e)
               for fn, z in focus for vn, e in views}
        gt_per_render = (time.perf_counter() - t_gt0) / len(gts)
        # The stack's Adam steps stop at the budget's wall time (its Mitsuba targets count in it); the probe's
        # estimate is kept for the record: on this machine it missed by up to 40 % either way.
        per_it, final = self.fs_probe(meta, pupil)
        from holocore.baselines.focal_stack import DEFAULT_FIT_EYE_GRID
        from holocore.evaluate.viewer import DEFAULT_PUPILS_M

        bank_renders = 5 * len(DEFAULT_PUPILS_M) * DEFAULT_FIT_EYE_GRID ** 2  # planes x pupils x eye grid
        fixed_fs = bank_renders * gt_per_render * a.fs_gt_spp / a.gt_spp + final + 1.0
        it_probe = fit_count(B, fixed_fs, per_it, lo=1, hi=100_000)
        spacing = self.fs_spacing(meta)
        fs, t_fs = self.focal_stack(loaded, F, 100_000, spacing, time_limit_s=max(1.0, B - final - 1.0))
        fields["focal-stack"] = fs.slm_field
        fsm = fs.meta["focal_stack"]
        done = [int(v) for v in fsm["iterations_done"]]
        it = int(round(sum(done) / len(done)))
        out["methods"]["focal-stack"] = {"render_s": t_fs, "encode_s": 0.0, "time_s": t_fs, "iterations": it,
                                         "iterations_per_colour": done, "iterations_probe": it_probe,
                                         "probe": {"per_iteration_s": per_it, "fixed_s": fixed_fs},
                                         "plane_z_m": fsm["plane_z_m"], "loss_first": fsm["loss_first"],
                                         "loss_final": fsm["loss_final"], "timings": fs.meta["timings"],
                                         "spacing_m": spacing,
                                         "config": (f"5 planes x {spacing * 1e3:g} mm" if spacing else
                                                    "5 planes uniform over the volume") +
                                                   f", pupil-aware ({fsm['target_renders']} targets)"
                                                   f", {'/'.join(map(str, done))} Adam it, targets {a.fs_gt_spp} spp"}
        self.log(f"[{scene}] focal stack: {it} iterations {t_fs:.1f} s (targets {fs.meta['timings']['targets_s']:.1f} s)")
        del fs
        stack_planes = np.asarray(out["methods"]["focal-stack"]["plane_z_m"])
        out.update(pupil_m=pupil, view_deg=a.view_deg, gt_spp=a.gt_spp,
                   focus=[{"name": fn, "z_m": z, "to_nearest_stack_plane_mm": float(np.min(np.abs(stack_planes - z)) * 1e3)}
                          for fn, z in focus],
                   views=[{"name": vn, "e_m": list(e)} for vn, e in views],
                   meta={k: meta[k] for k in ("focal_length_m", "z_inf_m", "z_wrp_m", "pitch_m", "wavelengths_m")},
                   analysis={k: meta["analysis"][k] for k in ("z_near_holo_m", "z_far_holo_m", "zc_image_min_m",
                                                               "zc_image_max_m") if k in meta["analysis"]})
        # scores and the images of Fig. 7
        rows, images = [], {}
        for label, fld in fields.items():
            complex_ = label.endswith("(complex)")
            for fn, z in focus:
                for vn, e in views:
                    if complex_ and vn != "centre":
                        continue
                    rec = eye_view(fld, meta, focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=e)
                    m = margin_px(meta, (self.H, self.W), focus_z_m=z, pupil_m=pupil, view=e)
                    p, s, k = score_cell(rec, gts[(fn, vn)], m)
                    rows.append({"method": label, "focus": fn, "z_m": z, "view": vn, "psnr_db": p, "ssim": s,
                                 "margin_px": m})
                    if not complex_ and (vn == "centre" or fn == "image"):
                        images[f"{label}|{fn}|{vn}"] = (rec * k).astype(np.float32)
            self.log(f"[{scene}] scored {label}: mean PSNR "
                     f"{np.mean([r['psnr_db'] for r in rows if r['method'] == label]):.2f} dB")
        for (fn, vn), g in gts.items():
            if vn == "centre" or fn == "image":
                images[f"ground truth|{fn}|{vn}"] = g.astype(np.float32)
        out["cells"] = rows
        if a.viewer_grid > 0:  # the viewer-faithful score (docs/evaluation.md): pupils x a jittered eye grid
            from holocore.evaluate.viewer import viewer_score

            out["viewer"] = {"eye_grid": a.viewer_grid, "focus": [fn for fn, _z in focus], "methods": {}}
            wanted = [m.strip() for m in a.viewer_methods.split(",") if m.strip()]
            for label, fld in fields.items():
                if label.endswith("(complex)") or (wanted and label.split(" (")[0] not in wanted):
                    continue
                vs = viewer_score(fld, meta, truth, eye_grid=a.viewer_grid, seed=seeds[0],
                                  focus_z_m=[z for _fn, z in focus])
                d = vs.to_dict()
                d.pop("cells")
                d["mean_2_6_db"] = vs.mean_over([2.0, 3.0, 4.0, 6.0])
                # the same score over other draws of the planes and the eye grid: how much the ranking rests on them
                d["seeds"] = {seeds[0]: d["mean_2_6_db"]}
                for sd in seeds[1:]:
                    fz, _ = cell_grid(scene, meta, view_deg=a.view_deg, seed=sd, avoid_m=own_planes)
                    d["seeds"][sd] = viewer_score(fld, meta, truth, eye_grid=a.viewer_grid, seed=sd,
                                                  focus_z_m=[z for _fn, z in fz]).mean_over([2.0, 3.0, 4.0, 6.0])
                out["viewer"]["methods"][label] = d
                self.log(f"[{scene}] viewer score {label}: {d['mean_2_6_db']:.2f} dB over 2-6 mm pupils, "
                         f"brightness steps {max(p['brightness_max_over_min'] for p in d['pupils']):.2f}")
        out["gt_seconds"] = truth.seconds
        np.savez_compressed(self.work / f"images_{scene}.npz", **{k.replace("|", "__"): v for k, v in images.items()})
        return out

    # ---- Fig. 5 ------------------------------------------------------------------------------------------------
    def conv(self, scene: str) -> dict:
        from holocore.evaluate.scoring import default_pupil_m, eye_view, focus_planes_m
        from holocore.evaluate.truths import ground_truth

        a = self.args
        loaded = self.load(scene)
        self.warm(loaded)
        def fields(preset: str, spp: int, method: str = "wrp"):
            """({F: the F-frame SLM field}, seconds of the 24-frame render, its meta): F = 3, 8, 24 rendered on
            their own (coded frame phases depend on the frame count), F = 1 the 24-frame render's first frame (one
            random-phase frame, the same in every bank; a 1-frame render has no random phase)."""
            out, t24, meta24 = {}, 0.0, None
            for F in sorted(set(FRAMES) - {1}):
                res, t = self.render(loaded, F, preset, spp, method=method)
                out[F] = res.slm_field
                if F == 24:
                    t24, meta24 = t, res.meta
                del res
            out[1] = out[24][:1]
            return out, t24, meta24

        ref, t_ref, meta = fields("balanced", a.ref_spp)
        pupil = default_pupil_m(meta, view_deg=a.view_deg)
        zs = focus_planes_m(meta, 3)
        truth = ground_truth(a.truth, loaded, meta, shape_hw=(self.H, self.W), spp=a.gt_spp, seed=1)
        gts = [truth.channels(focus_z_m=z, pupil_diameter_m=pupil) for z in zs]
        ms = [margin_px(meta, (self.H, self.W), focus_z_m=z, pupil_m=pupil, view=(0.0, 0.0)) for z in zs]
        ref_views = {F: [eye_view(ref[F], meta, focus_z_m=z, pupil_diameter_m=pupil) for z in zs] for F in FRAMES}
        del ref

        def scores(fld):
            out = {}
            for F in FRAMES:
                recs = [eye_view(fld[F], meta, focus_z_m=z, pupil_diameter_m=pupil) for z in zs]
                out[F] = {"psnr_gt_db": float(np.mean([score_cell(r, g, m)[0] for r, g, m in zip(recs, gts, ms)])),
                          "psnr_ref_db": float(np.mean([score_cell(r, g, m)[0]
                                                        for r, g, m in zip(recs, ref_views[F], ms)]))}
            return out

        ref_scores = {F: {"psnr_gt_db": float(np.mean([score_cell(r, g, m)[0]
                                                       for r, g, m in zip(ref_views[F], gts, ms)]))} for F in FRAMES}
        norm = ref_scores[24]["psnr_gt_db"]
        rows = []
        for key in ("wrp/balanced", "wrp/fast", "direct/balanced"):
            method, preset = key.split("/")
            name = {"wrp/balanced": "ours", "wrp/fast": "fast", "direct/balanced": "direct"}[key]
            for spp in a.conv_spp:
                fld, t, _meta = fields(preset, spp, method)
                sc = scores(fld)
                del fld
                for F in FRAMES:
                    rows.append({"method": name, "spp": spp, "frames": F, "render_s_24": t, **sc[F],
                                 "ratio": convergence_ratio(sc[F]["psnr_gt_db"], norm)})
                self.log(f"[{scene}] conv {name} {spp} spp ({t:.1f} s): ratio at 24 frames "
                         f"{rows[-1]['ratio']:.3f}, PSNR vs GT {rows[-1]['psnr_gt_db']:.2f} dB")
        return {"scene": scene, "ref_spp": a.ref_spp, "ref_render_s": t_ref, "ref": ref_scores, "norm_psnr_db": norm,
                "focus_z_m": zs, "pupil_m": pupil, "gt_spp": a.gt_spp, "shape_hw": [self.H, self.W], "rows": rows}

    # ---- Fig. 6 ------------------------------------------------------------------------------------------------
    def runtime(self, scene: str, equal: dict) -> dict:
        loaded = self.load(scene)
        self.warm(loaded, methods=("wrp/balanced", "wrp/fast"))
        em = equal["methods"]
        rows = []
        for F in FRAMES:
            if F == equal["frames"]:
                for name, v in em.items():
                    rows.append({"method": name, "frames": F, "render_s": v["render_s"], "encode_s": v["encode_s"]})
                continue
            for name in ("ours", "fast"):
                res, t = self.render(loaded, F, "balanced" if name == "ours" else "fast", em[name]["spp"])
                _, te = self.encode(res)
                rows.append({"method": name, "frames": F, "render_s": t, "encode_s": te})
            lay, t = self.layers(loaded, F)
            _, te = self.encode(lay)
            rows.append({"method": "layers", "frames": F, "render_s": t, "encode_s": te})
            lf, t = self.light_field(loaded, F)
            _, te = self.encode(lf)
            rows.append({"method": "light-field", "frames": F, "render_s": t, "encode_s": te})
            if "light-field-sgd" in em:
                _, t = self.light_field(loaded, F, fit="sgd", iterations=em["light-field-sgd"]["iterations"],
                                        lr=self.args.lf_lr)
                rows.append({"method": "light-field-sgd", "frames": F, "render_s": t, "encode_s": 0.0})
            _, t = self.focal_stack(loaded, F, em["focal-stack"]["iterations"], em["focal-stack"].get("spacing_m", 1.25e-3))
            rows.append({"method": "focal-stack", "frames": F, "render_s": t, "encode_s": 0.0})
            self.log(f"[{scene}] runtime F={F}: " + ", ".join(f"{r['method']} {r['render_s'] + r['encode_s']:.1f} s"
                                                            for r in rows if r["frames"] == F))
        return {"scene": scene, "rows": rows,
                "settings": {k: v["config"] for k, v in em.items()}}


# ---- outputs ------------------------------------------------------------------------------------------------
def _load_json(out: Path, prefix: str) -> dict[str, dict]:
    res = {}
    for p in sorted(out.glob(f"{prefix}_*.json")):
        res[p.stem[len(prefix) + 1:]] = json.loads(p.read_text())
    return res


def plot_convergence(conv: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = ["ours", "fast", "direct"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for ax, name in zip(axes, methods):
        rows = [r for r in conv["rows"] if r["method"] == name]
        spps = sorted({r["spp"] for r in rows})
        Z = np.array([[next(r["ratio"] for r in rows if r["spp"] == s and r["frames"] == F) for s in spps]
                      for F in FRAMES])
        im = ax.imshow(Z, origin="lower", cmap="viridis", vmin=0.0, vmax=1.0, aspect="auto")
        for i in range(len(FRAMES)):
            for j in range(len(spps)):
                ax.text(j, i, f"{Z[i, j]:.2f}", ha="center", va="center", fontsize=8,
                        color="w" if Z[i, j] < 0.6 else "k")
        if Z.min() < 0.8 < Z.max():
            ax.contour(np.arange(len(spps)), np.arange(len(FRAMES)), Z, levels=[0.8], colors="w",
                       linestyles="--", linewidths=1.5)
        ax.set_xticks(range(len(spps)))
        ax.set_xticklabels([str(s) for s in spps])
        ax.set_yticks(range(len(FRAMES)))
        ax.set_yticklabels([str(f) for f in FRAMES])
        ax.set_xlabel("rays per pixel (spp)")
        ax.set_ylabel("frames")
        ax.set_title(METHOD_LABEL[name], fontsize=9)
    fig.colorbar(im, ax=axes, label=f"PSNR / PSNR of the {conv['ref_spp']}-spp x 24-frame reference")
    fig.suptitle(f"{conv['scene']}: convergence (dashed: 80 %)", fontsize=10)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def plot_runtime(rt: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in ("ours", "fast", "layers", "light-field", "light-field-sgd", "focal-stack")
             if any(r["method"] == n for r in rt["rows"])]
    fig, ax = plt.subplots(figsize=(1.8 * len(names), 3.8))
    width = 0.2
    cols = {1: "#c6dbef", 3: "#6baed6", 8: "#2171b5", 24: "#08306b"}
    for k, F in enumerate(FRAMES):
        for i, n in enumerate(names):
            r = next((r for r in rt["rows"] if r["method"] == n and r["frames"] == F), None)
            if r is None:
                continue
            x = i + (k - 1.5) * width
            ax.bar(x, r["render_s"], width, color=cols[F], label=f"{F} frames" if i == 0 else None)
            if r["encode_s"] > 0:
                ax.bar(x, r["encode_s"], width, bottom=r["render_s"], color=cols[F], hatch="//", edgecolor="w")
    ax.set_xticks(range(len(names)))
    ax.set_xticklabels([f"{n}\n" + textwrap.fill(rt["settings"].get(n, ""), 24) for n in names], fontsize=7)
    ax.set_ylabel("wall time (s); hatched: phase-only encoder")
    ax.set_title(f"{rt['scene']}: runtime over frames (measured, one process at a time)", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", alpha=0.3)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def image_grid(eq: dict, npz: Path, path: Path, *, zoom: int = 1) -> None:
    """Fig. 7: rows = methods, columns = near / middle / far / image focus (centre view) and the left / right
    views at the image's focus; under each view a 2x close-up of its central half (the mirror or glass image).
    Each tile: the reconstruction times its least-squares scale, white = the ground truth's 99th percentile."""
    from PIL import Image, ImageDraw

    from holocore.evaluate.preview import to_png8
    from holocore.evaluate.score_files import to_rgb

    with np.load(npz) as z:
        imgs = {k.replace("__", "|"): z[k] for k in z.files}
    wl = eq["meta"]["wavelengths_m"]
    methods = [m for m in ("ours", "fast", "layers", "light-field", "light-field-sgd", "focal-stack")
               if any(k.startswith(m + "|") for k in imgs)] + ["ground truth"]
    zname = {f["name"]: f["z_m"] for f in eq["focus"]}
    cols = [(fn, vn) for fn, vn in [("near", "centre"), ("middle", "centre"), ("far", "centre"), ("image", "centre"),
                                    ("image", "left"), ("image", "right")] if fn in zname]
    H, W = next(iter(imgs.values())).shape[-2:]
    tw, th = W * zoom, 2 * H * zoom + 2  # view above, close-up below
    left, top = 90, 30
    sheet = Image.new("RGB", (left + len(cols) * (tw + 4), top + len(methods) * (th + 6)), (0, 0, 0))
    draw = ImageDraw.Draw(sheet)
    for j, (fn, vn) in enumerate(cols):
        x = left + j * (tw + 4)
        draw.text((x + 2, 2), f"{fn} focus, {vn} view", fill=(255, 255, 0))
        draw.text((x + 2, 14), f"z = {zname[fn] * 1e3:.3f} mm", fill=(255, 255, 0))
    for i, mname in enumerate(methods):
        y = top + i * (th + 6)
        draw.text((2, y + 4), mname, fill=(255, 255, 255))
        for j, (fn, vn) in enumerate(cols):
            key = f"{mname}|{fn}|{vn}"
            if key not in imgs:
                continue
            g = imgs[f"ground truth|{fn}|{vn}"]
            white = float(np.percentile(g, 99.0)) or 1.0
            rgb = to_png8(to_rgb(imgs[key], wl), white=white)
            x = left + j * (tw + 4)
            sheet.paste(Image.fromarray(rgb).resize((tw, H * zoom), Image.NEAREST), (x, y))
            crop = rgb[H // 4:H // 4 + H // 2, W // 4:W // 4 + W // 2]
            sheet.paste(Image.fromarray(crop).resize((tw, H * zoom), Image.NEAREST), (x, y + H * zoom + 2))
            row = [c for c in eq["cells"] if c["method"] == mname and c["focus"] == fn and c["view"] == vn]
            if row:
                draw.text((x + 2, y + 2), f"{row[0]['psnr_db']:.1f} dB", fill=(255, 255, 0))
    sheet.save(path)


def summary(eq: dict) -> dict:
    """Per method: mean PSNR / SSIM over the focus x view grid and over the views at the image's focus."""
    out = {}
    for name in dict.fromkeys(c["method"] for c in eq["cells"]):
        cs = [c for c in eq["cells"] if c["method"] == name]
        img = [c for c in cs if c["focus"] == "image"]
        fin = [c["psnr_db"] for c in cs if math.isfinite(c["psnr_db"])]
        out[name] = {"psnr_db": float(np.mean(fin)), "ssim": float(np.mean([c["ssim"] for c in cs])),
                     "psnr_image_db": float(np.mean([c["psnr_db"] for c in img])) if img else math.nan,
                     "ssim_image": float(np.mean([c["ssim"] for c in img])) if img else math.nan, "cells": len(cs)}
    return out


def _how_ours_fills(eq: dict) -> str:
    """How the equal stage gave ours and fast their budget (the JSON says which way it was run)."""
    if "sampling" in eq["methods"]["ours"]:
        return ("a render with a time limit (`holo render --time-limit-s`, holocore.plan.time_budget) of the budget "
                "less the encoder's time measured on the layers' field: passes of rays (16 spp, then more) until it is "
                "spent, added into the recording planes as the estimate of all their rays (`sampling` in the JSON)")
    return ("16- and 64-spp runs of the same scene and frames give the fixed cost and the cost per spp, and the spp "
            "that fills the budget is used (a run more than 3 % off the budget is redone at the spp its own time gives, "
            "twice at most: `probe.runs_spp_s` in the JSON)")


def _phase_words(name: str) -> str:
    from holocore.trace.frame_phases import get_frame_phases

    return f"{name} frame phases: {get_frame_phases(name).summary}"


def write_readme(out: Path, args, argv: list[str], env: dict) -> None:
    eqs, convs, rts = _load_json(out, "equal"), _load_json(out, "conv"), _load_json(out, "runtime")
    L = ["# The paper's figures, regenerated (Figs. 5, 6, 7 and an equal-time table)", "",
         f"Generated by `{env['command']}` (stages as listed per section) on {env['date']}: {env['machine']}. "
         "Every number below comes from that code as committed; the JSON files beside this README hold all of them.",
         ""]
    first = next(iter(eqs.values()), None) or next(iter(convs.values()), None)
    if first:
        H, W = first["shape_hw"]
        it = first.get("enc_iterations", 15)
        enc_words = (f"{it} iterations" if it != "auto" else
                     "its stop rule: each frame and color stops once its field SNR gained less than 0.05 dB over 30 "
                     "iterations")
        L += ["## Setup", "",
              f"Paper display (holocore.display.profiles.PAPER): pitch 8 µm, f = 50 mm, 640.0 / 516.5 / 455.4 nm, 24 frames "
              f"({_phase_words(first.get('frame_phases', 'coded'))}; the layers use the same frames, the light "
              "field coded ones), "
              f"Fourier filter (the encoder supervises the recording cone). Reduced here to a **{H}x{W}** part of the "
              f"SLM (the paper's 1080x1920): the paper scenes' cues sit in the middle of the view, and at {H}x{W} the "
              f"view (±{math.degrees(math.atan(W * 8e-6 / 2 / 0.05)):.2f}° x ±{math.degrees(math.atan(H * 8e-6 / 2 / 0.05)):.2f}°) "
              "lies inside the mirror and inside the glass ball: what the eye sees is the mirror image (2.0 m) or the "
              "ball's image of its card (0.345 m) throughout, not their frame. "
              f"**Virtual infinity at z_inf = {args.z_inf_mm:g} mm** instead of the paper's 80 mm: an image point z from "
              "the SLM collects light from z (NA + |e|/f) / p pixels around it, so at 80 mm a 1.6 mm pupil's view of "
              f"a {W}-px-wide SLM would be vignetted everywhere; at {args.z_inf_mm:g} mm the border left out of the "
              "scores (holocore.evaluate.scoring.lit_margin_px) is about 30 px. The depth structure beyond z_inf is the paper's "
              "(z = z_inf + f^2 / zc: 0.5 m at +5 mm, 0.9 m at +2.78 mm, 2 m at +1.25 mm, 10 m at +0.25 mm).", "",
              "Scoring: holocore.evaluate.scoring (eye_view: pupil-filtered, propagated, frame-averaged; compare: one "
              "least-squares brightness scale, white at the ground truth's 99th percentile, PSNR / SSIM on the lit "
              "part) against Mitsuba thin-lens ground truth through the same pupil (holocore.evaluate.groundtruth). Pupil: "
              "holocore.evaluate.scoring.default_pupil_m at ±0.5° views (1.61 mm). Every "
              "hologram scored in the equal-time table is phase-only (what the SLM can show): ours, fast and layers "
              "go through the same SGD encoder (holocore.encode.encoder.encode_sgd, complex supervision in the cone, "
              f"{enc_words}), whose time counts in their budget; the focal stack is phase-only by construction.", ""]
    if eqs:
        L += ["## Equal time (24 frames, phase-only)", "",
              f"Stage `equal`. Budget per method: {first['budget_s']:g} s of wall time for all 24 frames, encoder "
              f"included. ours / fast: {_how_ours_fills(first)}; layers: RGB-D baseline (8 planes, 64 spp) plus the "
              "encoder (it has nothing to spend more time on: more RGB-D samples or planes do not move the mirror "
              "image off the mirror); light field: a stereogram (holocore.baselines.light_field) of "
              f"{first['methods'].get('light-field', {}).get('hogel_px', '-')}-px hogels on a ray-sampling plane "
              "in the middle of the image volume, its radiance traced by Mitsuba, plus the encoder (it too has nothing "
              "to spend more on: a hogel's samples converge in tens of rays); light field SGD (the paper's LF): "
              "phase-only frames fitted by Adam to the same light field until the budget's wall time runs out, "
              "its rays included; focal stack: pupil-aware, its Mitsuba targets over the viewer-faithful score's "
              "pupils x a jittered 3x3 eye grid (another jitter than the score's) at each of its planes, then Adam "
              "steps, one of those views each, until the budget's wall time runs out (each colour an equal share of "
              "what is left). Measured times in the table.",
              "", "Focus planes: near / middle / far of the image volume (the renderer's analysis) and `image` = the "
              "depth of the mirror image (mirror) or of the glass ball's image (glass); views: left / centre / right "
              f"eye offsets at ±{first['view_deg']:g}°. Mean over the 4 x 3 = 12 cells, and over the 3 views at the "
              "image's focus. `(complex)`: the field before phase-only encoding, centre view only (an upper bound, "
              "not displayable, not in the equal-time comparison).", ""]
        for scene, eq in eqs.items():
            sm = summary(eq)
            fp = ", ".join(f"{f['name']} {f['z_m'] * 1e3:.3f} mm ({f['to_nearest_stack_plane_mm']:.2f} mm from a stack plane)"
                           for f in eq["focus"])
            sp = ", ".join(f"{z * 1e3:.3f}" for z in eq["methods"]["focal-stack"]["plane_z_m"])
            L += [f"### {scene}", "",
                  f"Image volume {eq['analysis']['z_far_holo_m'] * 1e3:.3f} .. {eq['analysis']['z_near_holo_m'] * 1e3:.3f} mm, "
                  f"WRP {eq['meta']['z_wrp_m'] * 1e3:.3f} mm; focus planes: {fp}; focal-stack planes: {sp} mm.", "",
                  "| method | settings | wall time s (render + encode) | PSNR dB (12 cells) | SSIM | PSNR dB at the image's focus | SSIM there |",
                  "|---|---|---|---|---|---|---|"]
            for name, s in sm.items():
                m = eq["methods"].get(name.replace(" (complex)", ""), {})
                t = (f"{m['time_s']:.1f} ({m['render_s']:.1f} + {m['encode_s']:.1f})" if m and not name.endswith(")")
                     else (f"{m['render_s']:.1f} + 0" if m else "-"))
                L.append(f"| {name} | {m.get('config', '') if not name.endswith(')') else 'no encoder'} | {t} | "
                         f"{s['psnr_db']:.2f} | {s['ssim']:.3f} | {s['psnr_image_db']:.2f} | {s['ssim_image']:.3f} |")
            o = sm.get("ours")
            diffs = [f"ours - {label}: {o['psnr_db'] - b['psnr_db']:+.2f} dB mean, "
                     f"{o['psnr_image_db'] - b['psnr_image_db']:+.2f} dB at the image's focus"
                     for label, b in (("layers", sm.get("layers")), ("light field", sm.get("light-field")),
                                      ("light field SGD", sm.get("light-field-sgd")),
                                      ("focal stack", sm.get("focal-stack"))) if o and b]
            if diffs:
                L += ["", "; ".join(diffs) + "."]
            L += ["", "Per cell (PSNR dB / SSIM):", "",
                  "| method | " + " | ".join(f"{f['name']} {v['name']}" for f in eq["focus"] for v in eq["views"]) + " |",
                  "|---|" + "---|" * (len(eq["focus"]) * len(eq["views"]))]
            for name in sm:
                if name.endswith(")"):
                    continue
                vals = []
                for f in eq["focus"]:
                    for v in eq["views"]:
                        c = next((c for c in eq["cells"] if c["method"] == name and c["focus"] == f["name"]
                                  and c["view"] == v["name"]), None)
                        vals.append(f"{c['psnr_db']:.2f} / {c['ssim']:.2f}" if c else "-")
                L.append(f"| {name} | " + " | ".join(vals) + " |")
            vw = eq.get("viewer")
            if vw:
                pup = [p["pupil_mm"] for p in next(iter(vw["methods"].values()))["pupils"]]
                L += ["", f"**The viewer-faithful score** (holocore.evaluate.viewer, docs/evaluation.md): pupils "
                      f"{', '.join(f'{p:g}' for p in pup)} mm x a {vw['eye_grid']}x{vw['eye_grid']} jittered eye grid "
                      f"x the focus planes above, one brightness scale per method and colour for all of them; PSNR dB "
                      "per pupil, the mean over 2-6 mm, the brightness over the eye grid (largest / smallest, the worst "
                      "pupil), the colour cast (worst pupil), the colour tint of single views (worst pupil: mean over its "
                      "views / its worst view) and the spread of the per-cell scales a per-cell fit hides.", "",
                      "| method | " + " | ".join(f"{p:g} mm" for p in pup) + " | mean 2-6 mm | brightness steps | "
                      "colour cast | colour tint (mean / worst view) | per-cell scale spread |",
                      "|---|" + "---|" * (len(pup) + 5)]
                for name, v in vw["methods"].items():
                    L.append(f"| {name} | " + " | ".join(f"{p['mean_psnr_db']:.2f}" for p in v["pupils"]) +
                             f" | **{v['mean_2_6_db']:.2f}** | {max(p['brightness_max_over_min'] for p in v['pupils']):.2f}"
                             f" | {max(p['colour_cast'] for p in v['pupils']):.2f}"
                             f" | {max(p['colour_tint'] for p in v['pupils']):.2f} / "
                             f"{max(p['colour_tint_worst'] for p in v['pupils']):.2f} | {v['scale_spread']:.2f} |")
            fsm = eq["methods"]["focal-stack"]
            per_c = fsm.get("iterations_per_colour")
            L += ["", (f"Focal stack: {'/'.join(map(str, per_c))} Adam iterations (red/green/blue) until the budget's "
                       f"wall time ran out (the probe estimated {fsm['iterations_probe']}: " if per_c else
                       f"Focal stack: {fsm['iterations']} Adam iterations in the budget (probe: ") +
                      f"{fsm['probe']['per_iteration_s']:.1f} s per iteration at 24 frames; targets "
                      f"{fsm['timings']['targets_s']:.1f} s); loss {fsm['loss_first']:.4f} -> {fsm['loss_final']:.4f}.",
                  f"Ground truth: {eq['gt_seconds']:.0f} s of Mitsuba rendering, {eq['gt_spp']} spp.", "",
                  f"![{scene} image grid](fig7_{scene}.png)", ""]
    if convs:
        for scene, cv in convs.items():
            L += [f"## Convergence (Fig. 5): {scene}", "",
                  f"Stage `conv`. Reference: two-stage, {cv['ref_spp']} spp x 24 frames ({cv['ref_render_s']:.0f} s), "
                  f"{cv['norm_psnr_db']:.2f} dB against the ground truth (mean of 3 focus planes, centre view). Each "
                  "cell: PSNR against the ground truth divided by that; second number: PSNR against the reference's "
                  "first F frames (Monte Carlo error only, same random phases). Complex fields (no encoder).", "",
                  "| method | spp | render s (24 frames) | " + " | ".join(f"F={F}" for F in FRAMES) + " |",
                  "|---|---|---|" + "---|" * len(FRAMES)]
            for name in ("ours", "fast", "direct"):
                for spp in sorted({r["spp"] for r in cv["rows"] if r["method"] == name}):
                    rs = {r["frames"]: r for r in cv["rows"] if r["method"] == name and r["spp"] == spp}
                    L.append(f"| {name} | {spp} | {rs[24]['render_s_24']:.1f} | " + " | ".join(
                        f"{rs[F]['ratio']:.2f} ({rs[F]['psnr_gt_db']:.1f} dB; {rs[F]['psnr_ref_db']:.1f} vs ref)"
                        for F in FRAMES) + " |")
            L.append("| reference | %d | %.1f | " % (cv["ref_spp"], cv["ref_render_s"]) + " | ".join(
                f"{cv['ref'][str(F)]['psnr_gt_db'] / cv['norm_psnr_db']:.2f} ({cv['ref'][str(F)]['psnr_gt_db']:.1f} dB)"
                for F in FRAMES) + " |")
            L += ["", f"![convergence {scene}](fig5_{scene}.png)", ""]
    if rts:
        for scene, rt in rts.items():
            L += [f"## Runtime over frames (Fig. 6): {scene}", "", "Stage `runtime`, the equal-time stage's settings "
                  "(24 frames: that stage's runs). Wall time in s, render + encoder.", "",
                  "| method | settings | " + " | ".join(f"{F} frames" for F in FRAMES) + " |", "|---|---|" + "---|" * len(FRAMES)]
            for name in ("ours", "fast", "layers", "light-field", "light-field-sgd", "focal-stack"):
                vals = []
                for F in FRAMES:
                    r = next((r for r in rt["rows"] if r["method"] == name and r["frames"] == F), None)
                    vals.append(f"{r['render_s'] + r['encode_s']:.1f} ({r['render_s']:.1f} + {r['encode_s']:.1f})" if r else "-")
                L.append(f"| {name} | {rt['settings'].get(name, '')} | " + " | ".join(vals) + " |")
            L += ["", f"![runtime {scene}](fig6_{scene}.png)", ""]
    notes = out / "NOTES.md"
    if notes.is_file():
        L += [notes.read_text()]
    (out / "README.md").write_text("\n".join(L) + "\n")


def environment(argv: list[str]) -> dict:
    import drjit
    import mitsuba
    import torch

    la = os.getloadavg()
    return {"command": " ".join([".venv/bin/python bench/paper_report.py"] + argv),
            "date": dt.datetime.now().strftime("%Y-%m-%d %H:%M"),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores shared with other engineers' jobs (load average "
                       f"{la[0]:.1f} when this README was written), torch {torch.__version__}, mitsuba "
                       f"{mitsuba.__version__}, drjit {drjit.__version__}"}


def main(argv: Optional[Sequence[str]] = None) -> int:
    from holocore.trace.frame_phases import frame_phase_modes

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stages", default="equal,conv,runtime,report",
                    help="Comma-separated: equal, conv, runtime, report (default all).")
    ap.add_argument("--scenes", default="mirror,glass",
                    help="Scenes for the equal-time table and Fig. 7: the paper's (mirror, glass, depth, glossy) or "
                         "the project's own test scenes (demo, cbox: no cue image, so only the image volume's planes "
                         "are scored).")
    ap.add_argument("--conv-scene", default="mirror", help="Scene of the convergence map and the runtime figure.")
    ap.add_argument("--resolution", default="135x240", help="HxW part of the paper's SLM (default 135x240).")
    ap.add_argument("--z-inf-mm", type=float, default=4.0, help="Virtual infinity (default 4 mm; see README).")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--budget-s", type=float, default=90.0, help="Equal wall-time budget per method (s).")
    ap.add_argument("--enc-iterations", type=lambda v: v if v == "auto" else int(v), default=60,
                    help="SGD encoder iterations of ours, fast and layers (default 60: within 0.15 dB of 200 on the "
                         "mirror scene, 4x the score gain of 15), or auto: the encoder's own stop rule (0.05 dB over 30 "
                         "iterations), at most --enc-max-iterations; on a 2-core machine it took 23-32 s at 24 frames, "
                         "more than the budget's estimate, and overran ours' budget.")
    ap.add_argument("--enc-max-iterations", type=int, default=300)
    ap.add_argument("--gt-spp", type=int, default=128, help="Ground-truth samples per pixel.")
    ap.add_argument("--truth", choices=("wave", "thinlens"), default="wave",
                    help="The ground truth (holocore.evaluate.truths): wave-optical (default) or thin-lens.")
    ap.add_argument("--filter", choices=("4f", "none"), default="4f",
                    help="The display's filter: 4f (a Fourier filter passes each colour's recording cone) or none.")
    ap.add_argument("--plane-seeds", default="0",
                    help="Seeds of the scored focus planes and eye grid; more than one: the viewer score's spread.")
    ap.add_argument("--fs-gt-spp", type=int, default=64, help="Focal-stack target samples per pixel.")
    ap.add_argument("--layer-planes", type=int, default=8)
    ap.add_argument("--layer-spp", type=int, default=64)
    ap.add_argument("--lf-hogel-px", type=int, default=3, help="Light-field baseline: hogel side in pixels.")
    ap.add_argument("--lf-spp", type=int, default=64, help="Light-field baseline: rays per light-field sample.")
    ap.add_argument("--lf-sgd", type=int, default=1, help="1: also the light field's SGD fit (the paper's LF).")
    ap.add_argument("--lf-lr", type=float, default=0.1, help="Adam learning rate of the light field's SGD fit.")
    ap.add_argument("--max-spp", type=int, default=16384)
    ap.add_argument("--conv-spp", default="8,32,128", help="spp of the convergence map.")
    ap.add_argument("--ref-spp", type=int, default=512, help="spp of the converged reference (24 frames).")
    ap.add_argument("--view-deg", type=float, default=0.5)
    ap.add_argument("--viewer-grid", type=int, default=3,
                    help="Eye grid (n x n, jittered) of the viewer-faithful score over pupils 1.6-6 mm; 0: off.")
    ap.add_argument("--viewer-methods", default="ours,layers,focal-stack",
                    help="Methods the viewer-faithful score sees (comma list of labels without their '(...)' part: "
                         "'ours' includes 'ours (<alt mode>)'; '': every method). Each costs pupils x grid x focus "
                         "eye views (180 by default, minutes at 135x240).")
    ap.add_argument("--alt-frame-phases", choices=("", *frame_phase_modes()), default="directional",
                    help="Also render ours with these frame phases (labelled 'ours (<mode>)'); '': not.")
    ap.add_argument("--frame-phases", choices=frame_phase_modes(), default="coded",
                    help="Phases of the frames of ours, fast and the layers (OpticsConfig.frame_phases).")
    ap.add_argument("--wrp-planes", type=lambda v: v if v == "auto" else int(v), default="auto",
                    help="Recording planes of ours and fast: 1..8 or auto (default).")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--work", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "holo_paper_report")
    argv = list(sys.argv[1:] if argv is None else argv)
    args = ap.parse_args(argv)
    args.shape_hw = tuple(int(v) for v in args.resolution.lower().split("x"))
    args.conv_spp = [int(v) for v in args.conv_spp.split(",")]
    stages = [s.strip() for s in args.stages.split(",") if s.strip()]
    bad = [s for s in stages if s not in ("equal", "conv", "runtime", "report")]
    if bad:
        ap.error(f"unknown stage(s) {bad}")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()

    def log(msg: str) -> None:
        print(f"{time.perf_counter() - t0:7.1f}s {msg}", flush=True)

    run = Runner(args, log)
    if "equal" in stages:
        for scene in [s for s in args.scenes.split(",") if s]:
            eq = run.equal(scene)
            eq["load_average"] = os.getloadavg()
            (out / f"equal_{scene}.json").write_text(json.dumps(eq, indent=1))
            image_grid(eq, run.work / f"images_{scene}.npz", out / f"fig7_{scene}.png")
    if "conv" in stages:
        cv = run.conv(args.conv_scene)
        cv["load_average"] = os.getloadavg()
        (out / f"conv_{args.conv_scene}.json").write_text(json.dumps(cv, indent=1))
        plot_convergence(cv, out / f"fig5_{args.conv_scene}.png")
    if "runtime" in stages:
        eqp = out / f"equal_{args.conv_scene}.json"
        if not eqp.is_file():
            log(f"runtime needs {eqp} (stage equal for {args.conv_scene}) first")
            return 2
        rt = run.runtime(args.conv_scene, json.loads(eqp.read_text()))
        rt["load_average"] = os.getloadavg()
        (out / f"runtime_{args.conv_scene}.json").write_text(json.dumps(rt, indent=1))
        plot_runtime(rt, out / f"fig6_{args.conv_scene}.png")
    if "report" in stages:
        for scene, eq in _load_json(out, "equal").items():
            npz = run.work / f"images_{scene}.npz"
            if npz.is_file():
                image_grid(eq, npz, out / f"fig7_{scene}.png")
        for scene, cv in _load_json(out, "conv").items():
            plot_convergence(cv, out / f"fig5_{scene}.png")
        for scene, rt in _load_json(out, "runtime").items():
            plot_runtime(rt, out / f"fig6_{scene}.png")
        write_readme(out, args, argv, environment(argv))
        log(f"wrote {out / 'README.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
