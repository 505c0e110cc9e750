"""Fit the quality model (holocore/plan/quality.py) to measured jobs and check it on scenes it was not fitted on.

Reads the JSONs of ``bench/quality_jobs.py``; fits the model's coefficients by least squares on the PSNR in dB
(each coefficient kept positive); then, to say how well it predicts a scene it has never seen, refits once per
scene with that scene's jobs left out and predicts them (leave-one-scene-out). Writes the coefficients and the
left-out residual (the ± every prediction carries) to ``holocore/plan/data/quality_model.json`` and a table of
predicted against measured to ``bench/results/quality/predicted_vs_measured.md``.

    python bench/quality_fit.py bench/results/quality/jobs_135x240 [more folders]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from holocore.plan.quality import DEFAULT_IMAGE_Q, MODEL_PATH, predict_quality  # noqa: E402

NAMES = ["s_one", "s_coded", "a_coded", "s_directional", "a_directional", "c_mc", "b_mc", "e_sgd", "i_half",
         "e_dpac", "a_dpac", "floor"]
START = [0.5, 0.3, 1.0, 0.2, 1.0, 0.01, 0.5, 0.01, 20.0, 0.3, 0.3, 0.005]
FIXED = {"e_naive": 0.5}


def load_jobs(folders: list[str]) -> list[dict]:
    rows = []
    for folder in folders:
        for p in sorted(Path(folder).glob("jobs_*.json")):
            doc = json.loads(p.read_text())
            q = doc.get("truth_stats", {}).get("q2")
            for j in doc["jobs"]:
                if not math.isfinite(j.get("psnr_2_6_db", math.nan)):
                    continue
                rows.append({**j, "scene": doc["scene"], "shape_hw": doc["shape_hw"], "image_q": q,
                             "source": str(p.relative_to(ROOT) if p.is_absolute() else p)})
    return rows


def coefficients(theta: np.ndarray) -> dict:
    return {**dict(zip(NAMES, (float(v) for v in theta))), **FIXED}


def predict(row: dict, coef: dict, *, use_q: bool = True) -> float:
    return predict_quality(frames=int(row["frames"]), frame_phases=row["frame_phases"],
                           noise_to_signal=float(row["plan_noise_to_signal"]), encoder=row["encoder"],
                           iterations=row["iterations_asked"], image_q=row["image_q"] if use_q else None,
                           model={"coefficients": coef}).psnr_db


def fit(rows: list[dict], *, use_q: bool = True) -> dict:
    y = np.array([r["psnr_2_6_db"] for r in rows])

    def resid(log_theta):
        coef = coefficients(np.exp(log_theta))
        return np.array([predict(r, coef, use_q=use_q) for r in rows]) - y

    sol = least_squares(resid, np.log(START), method="trf", loss="soft_l1", f_scale=1.5, max_nfev=4000)
    return coefficients(np.exp(sol.x))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--no-image-q", action="store_true", help="fit without the scene's image statistic")
    ap.add_argument("--write", action="store_true", help="store the model in holocore/plan/data")
    ap.add_argument("--table", default="bench/results/quality/predicted_vs_measured.md")
    a = ap.parse_args(argv)
    use_q = not a.no_image_q
    rows = load_jobs(a.folders)
    scenes = sorted({r["scene"] for r in rows})
    coef = fit(rows, use_q=use_q)
    held = {}
    for s in scenes:
        c = fit([r for r in rows if r["scene"] != s], use_q=use_q)
        for i, r in enumerate(rows):
            if r["scene"] == s:
                held[i] = predict(r, c, use_q=use_q)
    err_in = np.array([predict(r, coef, use_q=use_q) - r["psnr_2_6_db"] for r in rows])
    err_out = np.array([held[i] - r["psnr_2_6_db"] for i, r in enumerate(rows)])
    within = float(np.mean(np.abs(err_out) <= 1.5))
    unc = float(np.percentile(np.abs(err_out), 90))
    print(f"{len(rows)} jobs on {len(scenes)} scenes; fitted: rms {np.sqrt(np.mean(err_in ** 2)):.2f} dB; "
          f"scene left out: rms {np.sqrt(np.mean(err_out ** 2)):.2f} dB, within 1.5 dB {within:.0%}, "
          f"90th percentile {unc:.2f} dB")
    print(json.dumps({k: round(v, 5) for k, v in coef.items()}))
    lines = ["# Predicted against measured viewer-faithful PSNR", "",
             f"Made on {dt.date.today().isoformat()} by `python bench/quality_fit.py {' '.join(a.folders)}`"
             f"{' --no-image-q' if not use_q else ''}. Measured: `bench/quality_jobs.py` (paper display, 4f filter, "
             "wave ground truth, pupils 2/3/4/6 mm, a jittered 3 x 3 eye grid, mean PSNR). Predicted: "
             "`holocore/plan/quality.py`, fitted with the job's own scene left out (each scene is predicted by a "
             "model that never saw it).", "",
             f"**{len(rows)} jobs on {len(scenes)} scenes: {within:.0%} within ±1.5 dB; rms error "
             f"{np.sqrt(np.mean(err_out ** 2)):.2f} dB (fitted on all: {np.sqrt(np.mean(err_in ** 2)):.2f} dB); "
             f"90 % of errors within {unc:.2f} dB.**", "",
             "| scene | size | frames | phases | spp | encoder | measured dB | predicted dB | error dB | time s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for i, r in enumerate(rows):
        encw = r["encoder"] + ("" if r["encoder"] != "sgd" else
                               f" {r['iterations_asked']} it" if r["iterations_asked"] else " stop rule")
        lines.append(f"| {r['scene']} | {r['shape_hw'][0]}x{r['shape_hw'][1]} | {r['frames']} | {r['frame_phases']} "
                     f"| {r['spp']} | {encw} | {r['psnr_2_6_db']:.2f} | {held[i]:.2f} | {err_out[i]:+.2f} | "
                     f"{r['render_s'] + r['encode_s']:.1f} |")
    Path(a.table).parent.mkdir(parents=True, exist_ok=True)
    Path(a.table).write_text("\n".join(lines) + "\n")
    if a.write:
        qs = sorted(r["image_q"] for r in rows if r["image_q"])
        doc = {"coefficients": {k: round(v, 6) for k, v in coef.items()}, "uncertainty_db": round(max(unc, 0.5), 2),
               "fitted_on": {"jobs": len(rows), "scenes": scenes, "date": dt.date.today().isoformat(),
                             "display": "paper (8 um, f = 50 mm), 4f filter", "image_q": bool(use_q),
                             "image_q_median": qs[len(qs) // 2] if qs else DEFAULT_IMAGE_Q,
                             "left_out_rms_db": round(float(np.sqrt(np.mean(err_out ** 2))), 3)}}
        MODEL_PATH.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {MODEL_PATH}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
