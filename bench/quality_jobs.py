"""Measured viewer-faithful PSNR of many jobs of ours, for fitting and checking the quality model.

Each job is one render of ours (frames, frame-phase mode, rays per pixel, preset, recording planes) and one
phase-only encoding (SGD with the stop rule or a fixed count, or DPAC), scored as an eye sees it
(``holocore.evaluate.viewer.viewer_score``: pupils 2, 3, 4, 6 mm, a jittered eye grid, one brightness per
colour) against the wave ground truth at the yardstick's fair planes (``bench/paper_report.py``'s
``cell_grid``). Beside the score, each job keeps what the quality model reads before a job runs (the plan's
Monte Carlo noise-to-signal, the scene's image statistics) and its wall times, so that
``bench/quality_fit.py`` can fit and cross-check the model without rerunning anything.

    python bench/quality_jobs.py --scenes mirror,glass,depth,glossy,demo --resolution 135x240 \
        --out bench/results/quality/jobs

One JSON per scene (``jobs_<scene>.json``), written after every job, so a stopped run keeps what it measured.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from paper_report import Runner, cell_grid, phase_only_field  # noqa: E402

# (frames, frame phases, spp (None: the preset's own), encoder, SGD iterations (None: the stop rule), preset)
PUPILS_M = (2e-3, 4e-3, 6e-3)
DEFAULT_JOBS = [
    (24, "coded", None, "sgd", None, "balanced"),
    (8, "coded", None, "sgd", None, "balanced"),
    (3, "coded", None, "sgd", None, "balanced"),
    (1, "coded", None, "sgd", None, "balanced"),
    (24, "coded", 4, "sgd", None, "balanced"),
    (24, "coded", 64, "sgd", None, "balanced"),
    (24, "directional", None, "sgd", None, "balanced"),
    (4, "directional", None, "sgd", None, "balanced"),
    (24, "coded", None, "dpac", None, "balanced"),
    (2, "coded", 16, "dpac", None, "balanced"),
    (24, "coded", None, "sgd", 15, "balanced"),
    (8, "coded", None, "sgd", None, "fast"),
    (12, "coded", None, "sgd", None, "balanced"),
    (24, "coded", 16, "sgd", None, "balanced"),
    (8, "directional", None, "sgd", None, "balanced"),
    (1, "coded", None, "dpac", None, "balanced"),
    (24, "coded", None, "sgd", 40, "balanced"),
]


def parse_jobs(text: str) -> list[tuple]:
    """``F:mode:spp:encoder:iterations:preset;...`` (spp or iterations ``-``: the default)."""
    out = []
    for part in text.split(";"):
        F, mode, spp, encm, it, preset = part.strip().split(":")
        out.append((int(F), mode, None if spp == "-" else int(spp), encm, None if it == "-" else int(it), preset))
    return out


def image_stats(img: np.ndarray) -> dict:
    """What the score's normalisation makes of an image [C, H, W]: mean(I^2) / w^2 and mean(I) / w, w its 99th
    percentile (the score's white)."""
    a = np.asarray(img, dtype=np.float64)
    w = float(np.percentile(a, 99.0))
    if not w > 0:
        return {"q2": 0.0, "q1": 0.0}
    c = np.clip(a / w, 0.0, 1.0)
    return {"q2": float(np.mean(c ** 2)), "q1": float(np.mean(c))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="mirror,glass,depth,glossy,demo")
    ap.add_argument("--resolution", default="135x240")
    ap.add_argument("--jobs", default=None, help="F:mode:spp:encoder:iterations:preset;... (default: a fixed list)")
    ap.add_argument("--gt-spp", type=int, default=32)
    ap.add_argument("--eye-grid", type=int, default=3)
    ap.add_argument("--filter", choices=["4f", "none"], default="4f")
    ap.add_argument("--z-inf-mm", type=float, default=4.0, help="virtual infinity (the paper display's own: 80)")
    ap.add_argument("--complex", action="store_true", help="also score the complex field (no encoder)")
    ap.add_argument("--out", default="bench/results/quality/jobs")
    ap.add_argument("--work", default="/tmp/quality_jobs")
    a = ap.parse_args(argv)
    H, W = (int(v) for v in a.resolution.lower().split("x"))
    jobs = parse_jobs(a.jobs) if a.jobs else DEFAULT_JOBS
    args = SimpleNamespace(shape_hw=(H, W), work=a.work, filter=a.filter, z_inf_mm=a.z_inf_mm, frame_phases="coded",
                           alt_frame_phases=None, lf_hogel_px=3, wrp_planes="auto", enc_iterations="auto",
                           enc_max_iterations=500)
    out_dir = Path(a.out)
    out_dir.mkdir(parents=True, exist_ok=True)

    def log(msg: str) -> None:
        print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)

    from holocore.encode.encoder import encode
    from holocore.evaluate.truths import ground_truth
    from holocore.evaluate.viewer import viewer_score
    from holocore.pipeline import RenderOptions, render_loaded

    run = Runner(args, log)
    for scene in [s.strip() for s in a.scenes.split(",") if s.strip()]:
        loaded = run.load(scene)
        run.warm(loaded, methods=("wrp/balanced", "wrp/fast"))
        record = {"scene": scene, "shape_hw": [H, W], "filter": a.filter, "z_inf_mm": a.z_inf_mm, "gt_spp": a.gt_spp,
                  "eye_grid": a.eye_grid, "machine": f"{platform.machine()} {os.cpu_count()} cores",
                  "date": dt.date.today().isoformat(), "jobs": []}
        truth = planes = None
        path = out_dir / f"jobs_{scene}.json"
        done = json.loads(path.read_text())["jobs"] if path.is_file() else []
        keys = {(j["frames"], j["frame_phases"], j["spp_asked"], j["encoder"], j["iterations_asked"], j["preset"])
                for j in done}
        record["jobs"] = done
        if path.is_file():  # the scene's own measures of an earlier run are kept
            record.update({k: v for k, v in json.loads(path.read_text()).items() if k not in record or k == "date"})
        # what the quality model reads of the scene before a job: its picture's image statistic and the share of
        # its light seen through glass (holocore.plan.quality)
        from holocore.evaluate.groundtruth import camera_picture
        from holocore.evaluate.metrics import white_power
        from holocore.pipeline import plan_scene

        record["picture_q"] = white_power(camera_picture(loaded, max_width_px=64, spp=16))
        record["refracted_share"] = plan_scene(loaded, run.optics(24), RenderOptions()).analysis.refracted_share
        for F, mode, spp, encm, iters, preset in jobs:
            if (F, mode, spp, encm, iters, preset) in keys:
                continue  # measured by an earlier run
            optics = run.display.optics(resolution_hw=(H, W), frames=F, z_inf_mm=a.z_inf_mm, frame_phases=mode)
            load0 = os.getloadavg()[0]
            t0 = time.perf_counter()
            res = render_loaded(loaded, optics, RenderOptions(preset=preset, spp=spp), display=run.display)
            t_render = time.perf_counter() - t0
            m = res.meta
            if truth is None:
                truth = ground_truth("wave", loaded, m, shape_hw=(H, W), spp=a.gt_spp, seed=1)
                focus, _views = cell_grid(scene, m, view_deg=0.5, seed=0)
                planes = [z for _n, z in focus]
                centre = truth.channels(focus_z_m=planes[0], pupil_diameter_m=4e-3, view_offset_m=(0.0, 0.0))
                record["truth_stats"] = image_stats(centre)
            kw = {} if encm != "sgd" else ({"iterations": 500, "stop_db": 0.05} if iters is None
                                           else {"iterations": int(iters), "stop_db": 0.0})
            t1 = time.perf_counter()
            enc = encode(encm, res.wrp_field, z_wrp_m=m["z_wrp_m"], wavelengths_m=m["wavelengths_m"],
                         pitch_m=m["pitch_m"], fourier_filter=run.display.fourier_filter, **kw)
            t_enc = time.perf_counter() - t1
            fld = phase_only_field(enc)
            vs = viewer_score(fld, m, truth, pupils_m=PUPILS_M, eye_grid=a.eye_grid, seed=0, focus_z_m=planes)
            vs_c = viewer_score(res.slm_field, m, truth, pupils_m=PUPILS_M, eye_grid=a.eye_grid, seed=0,
                                focus_z_m=planes) if a.complex else None
            es = enc.summary()
            job = {"frames": F, "frame_phases": mode, "spp_asked": spp, "spp": int(m["sampling"]["spp"]),
                   "preset": preset, "encoder": encm, "iterations_asked": iters,
                   "iterations_mean": float(np.mean(es["iterations_per_target"])) if es.get("iterations_per_target")
                   else float(es["iterations"]),
                   "encoder_loss_mean": es["loss_mean"], "render_s": t_render, "encode_s": t_enc,
                   "load_1min": load0, "wrp_planes": len(m["wrp_planes_m"]),
                   "plan_noise_to_signal": m["plan"].get("noise_to_signal"),
                   "equaliser_noise_to_signal": [eq["noise_to_signal"] for eq in m["cone_equaliser"] or []],
                   "psnr_by_pupil": {str(p.pupil_mm): p.mean_psnr_db for p in vs.pupils},
                   "psnr_2_6_db": vs.mean_over([p * 1e3 for p in PUPILS_M]),
                   "complex_psnr_2_6_db": vs_c.mean_over([p * 1e3 for p in PUPILS_M]) if vs_c else None,
                   "brightness_steps": max(p.brightness_max_over_min for p in vs.pupils)}
            record["jobs"].append(job)
            log(f"[{scene}] F={F} {mode} spp={job['spp']} {preset} {encm}"
                f"{'' if iters is None else f' {iters} it'}: {job['psnr_2_6_db']:.2f} dB "
                f"render {t_render:.1f} s, encode {t_enc:.1f} s")
            path.write_text(json.dumps(record, indent=1, default=float))
            del res, enc, fld
        if record["jobs"]:
            path.write_text(json.dumps(record, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
