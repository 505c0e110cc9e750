"""Quality-time fronts: viewer-faithful PSNR against wall time for every method over its own knobs, per scene.

Ours over frames x rays x encoder (SGD stop rule or a fixed count, DPAC), the layers over their plane count,
the light field (stereogram, and its SGD fit over Adam steps) and the pupil-aware focal stack over its Adam
steps, each timed alone on this machine (render plus encode, warm: the first run of each kernel is a warm-up)
and scored as ``bench/quality_jobs.py`` scores (pupils 2, 4, 6 mm, a jittered 3 x 3 eye grid, the wave ground
truth at the yardstick's fair planes). Ours' points carry the quality model's prediction beside the measure.
One JSON per scene (``fronts_<scene>.json``), written after every point; ``bench/quality_report.py`` plots them
and writes ``bench/results/accuracy.md``.

    python bench/quality_fronts.py --scenes mirror,glass,depth,glossy,demo --resolution 135x240 \
        --out bench/results/quality/fronts_135x240
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
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from paper_report import Runner, cell_grid, phase_only_field  # noqa: E402

PUPILS_M = (2e-3, 4e-3, 6e-3)
# (label, kind, knobs)
POINTS = [
    ("ours", "ours", dict(frames=4, spp=16, iters=None)),
    ("ours", "ours", dict(frames=8, spp=None, iters=None)),
    ("ours", "ours", dict(frames=24, spp=16, iters=40)),
    ("ours", "ours", dict(frames=24, spp=None, iters=None)),
    ("ours", "ours", dict(frames=24, spp=256, iters=None)),
    ("ours", "ours", dict(frames=24, spp=1024, iters=None)),
    ("dpac", "ours", dict(frames=24, spp=None, iters=None, encoder="dpac")),
    ("layers", "layers", dict(planes=4)),
    ("layers", "layers", dict(planes=8)),
    ("light-field", "light-field", dict(hogel_px=3, spp=16)),
    ("light-field-sgd", "light-field-sgd", dict(hogel_px=3, spp=16, iterations=20)),
    ("focal-stack", "focal-stack", dict(iterations=5)),
    ("focal-stack", "focal-stack", dict(iterations=20)),
]


def predict_point(loaded, optics, knobs: dict, image_q: float) -> float:
    """The quality model's prediction for one of ours' points, made from what the estimate reads before a job
    (holo/render_quality.py): the plan's recording radius and refracted share, the picture's statistic."""
    from holocore.pipeline import RenderOptions, plan_scene
    from holocore.plan.quality import predict_for, recording_radius_px

    pl = plan_scene(loaded, optics, RenderOptions(spp=knobs["spp"]))
    theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    radius = recording_radius_px(noise_to_signal=pl.plan.noise_to_signal, spp=pl.plan.spp, theta_max=theta)
    return predict_for(optics, RenderOptions(spp=knobs["spp"]), encoder=knobs.get("encoder", "sgd"),
                       iterations=knobs["iters"], subhologram_radius_px=radius, image_q=image_q,
                       refracted_share=pl.analysis.refracted_share).psnr_db


def repredict(out_dir: Path, run) -> None:
    """Recompute ours' predictions in every JSON of ``out_dir`` with the model as it is now."""
    from holocore.evaluate.groundtruth import camera_picture
    from holocore.evaluate.metrics import white_power

    for path in sorted(out_dir.glob("fronts_*.json")):
        doc = json.loads(path.read_text())
        loaded = run.load(doc["scene"])
        q = white_power(camera_picture(loaded, max_width_px=64, spp=16))
        for p in doc["points"]:
            if p["predicted_db"] is not None:
                p["predicted_db"] = predict_point(loaded, run.optics(p["knobs"]["frames"]), p["knobs"], q)
        path.write_text(json.dumps(doc, indent=1, default=float))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="mirror,glass,depth,glossy,demo")
    ap.add_argument("--resolution", default="135x240")
    ap.add_argument("--frames", type=int, default=24, help="frames of the baselines")
    ap.add_argument("--out", default="bench/results/quality/fronts_135x240")
    ap.add_argument("--work", default="/tmp/quality_fronts")
    ap.add_argument("--repredict", action="store_true", help="only recompute ours' predictions in --out's JSON")
    a = ap.parse_args(argv)
    H, W = (int(v) for v in a.resolution.lower().split("x"))
    args = SimpleNamespace(shape_hw=(H, W), work=a.work, filter="4f", z_inf_mm=4.0, frame_phases="coded",
                           alt_frame_phases=None, lf_hogel_px=3, lf_spp=16, layer_planes=8, layer_spp=32,
                           wrp_planes="auto", enc_iterations="auto", enc_max_iterations=500, fs_gt_spp=32,
                           truth="wave")
    out_dir = Path(a.out)
    out_dir.mkdir(parents=True, exist_ok=True)

    def log(msg: str) -> None:
        print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)

    from holocore.baselines.focal_stack import render_focal_stack
    from holocore.baselines.layers import render_layers
    from holocore.baselines.light_field import render_light_field
    from holocore.encode.encoder import encode
    from holocore.evaluate.groundtruth import camera_picture
    from holocore.evaluate.metrics import white_power
    from holocore.evaluate.truths import ground_truth
    from holocore.evaluate.viewer import viewer_score
    from holocore.pipeline import RenderOptions, render_loaded

    run = Runner(args, log)
    if a.repredict:
        repredict(out_dir, run)
        return 0
    F = a.frames
    for scene in [s.strip() for s in a.scenes.split(",") if s.strip()]:
        loaded = run.load(scene)
        run.warm(loaded, methods=("wrp/balanced",))
        path = out_dir / f"fronts_{scene}.json"
        record = {"scene": scene, "shape_hw": [H, W], "baseline_frames": F, "machine":
                  f"{platform.machine()} {os.cpu_count()} cores", "date": dt.date.today().isoformat(), "points": []}
        q = white_power(camera_picture(loaded, max_width_px=64, spp=16))
        truth = planes = None
        for label, kind, knobs in POINTS:
            load0 = os.getloadavg()[0]
            t0 = time.perf_counter()
            predicted = None
            if kind == "ours":
                optics = run.optics(knobs["frames"])
                res = render_loaded(loaded, optics, RenderOptions(spp=knobs["spp"]), display=run.display)
                t_r = time.perf_counter() - t0
                encm = knobs.get("encoder", "sgd")
                kw = {} if encm != "sgd" else ({"iterations": 500, "stop_db": 0.05} if knobs["iters"] is None
                                               else {"iterations": knobs["iters"], "stop_db": 0.0})
                t1 = time.perf_counter()
                m = res.meta
                enc = encode(encm, res.wrp_field, z_wrp_m=m["z_wrp_m"], wavelengths_m=m["wavelengths_m"],
                             pitch_m=m["pitch_m"], fourier_filter=True, **kw)
                t_e = time.perf_counter() - t1
                fld = phase_only_field(enc)
                predicted = predict_point(loaded, optics, knobs, q)
                config = f"{knobs['frames']} frames, {m['sampling']['spp']} spp, {encm}" + (
                    "" if encm != "sgd" else f" {knobs['iters']} it" if knobs["iters"] else " stop rule")
            elif kind in ("layers", "light-field"):  # a complex field, then the same encoder as ours
                if kind == "layers":
                    res = render_layers(loaded, run.optics(F), planes=knobs["planes"], spp=32, display=run.display)
                    config = f"{knobs['planes']} planes, {F} frames, SGD stop rule"
                else:
                    res = render_light_field(loaded, run.optics(F), hogel_px=knobs["hogel_px"], spp=knobs["spp"],
                                             display=run.display)
                    config = f"stereogram, {knobs['hogel_px']}-px hogels, {knobs['spp']} spp, {F} frames, SGD stop rule"
                t_r = time.perf_counter() - t0
                enc, t_e = run.encode(res)
                fld, m = phase_only_field(enc), res.meta
            elif kind == "light-field-sgd":
                res = render_light_field(loaded, run.optics(F), hogel_px=knobs["hogel_px"], spp=knobs["spp"],
                                         display=run.display, fit="sgd", iterations=knobs["iterations"], lr=0.1)
                t_r, t_e = time.perf_counter() - t0, 0.0
                fld, m = res.slm_field, res.meta
                config = f"SGD fit, {knobs['iterations']} Adam it, {F} frames"
            else:
                res = render_focal_stack(loaded, run.optics(F), iterations=knobs["iterations"], gt_spp=32, planes=5,
                                         spacing_m=run.fs_spacing(truth_meta) if truth is not None else None,
                                         display=run.display, fit="pupil-aware", truth="wave")
                t_r, t_e = time.perf_counter() - t0, 0.0
                fld, m = res.slm_field, res.meta
                config = f"pupil-aware, 5 planes, {knobs['iterations']} Adam it, {F} frames"
            if truth is None:
                truth = ground_truth("wave", loaded, m, shape_hw=(H, W), spp=32, seed=1)
                truth_meta = m
                planes = [z for _n, z in cell_grid(scene, m, view_deg=0.5, seed=0)[0]]
            vs = viewer_score(fld, m, truth, pupils_m=PUPILS_M, eye_grid=3, seed=0, focus_z_m=planes)
            pt = {"method": label, "config": config, "knobs": knobs, "render_s": t_r, "encode_s": t_e,
                  "time_s": t_r + t_e, "psnr_db": vs.mean_over([p * 1e3 for p in PUPILS_M]),
                  "predicted_db": predicted, "load_1min": load0,
                  "brightness_steps": max(p.brightness_max_over_min for p in vs.pupils)}
            record["points"].append(pt)
            log(f"[{scene}] {label} ({config}): {pt['psnr_db']:.2f} dB"
                f"{'' if predicted is None else f' (predicted {predicted:.2f})'} in {pt['time_s']:.1f} s")
            path.write_text(json.dumps(record, indent=1, default=float))
            del res, fld
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
