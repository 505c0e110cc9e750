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
from holocore.plan.quality import DEFAULT_IMAGE_Q, MIN_FITTED_SPP, MODEL_PATH, predict_quality  # noqa: E402

NAMES = ["s_one", "s_coded", "a_coded", "s_directional", "a_directional", "c_mc", "d_split", "e_sgd", "i_half",
         "e_dpac", "k_q"]
START = [0.5, 0.3, 0.8, 0.2, 0.8, 0.01, 1.0, 0.01, 20.0, 0.3, 0.7]
# Held, not fitted: fitted freely on the 135x240 campaign these went to their bounds (no gain of the noise from
# re-phasing, no floor, DPAC's error the same in every frame and at every image statistic), and four
# coefficients fewer predict the scenes left out better (rms 1.07 against 1.11 dB).
FIXED = {"e_naive": 0.5, "b_mc": 0.0, "floor": 0.0, "a_dpac": 0.0, "k_dpac": 0.0}


def load_jobs(folders: list[str]) -> list[dict]:
    rows = []
    for folder in folders:
        for p in sorted(Path(folder).glob("jobs_*.json")):
            doc = json.loads(p.read_text())
            for j in doc["jobs"]:
                if not math.isfinite(j.get("psnr_2_6_db", math.nan)):
                    continue
                rows.append({**j, "scene": doc["scene"], "shape_hw": doc["shape_hw"], "image_q": doc["picture_q"],
                             "refracted_share": doc["refracted_share"], "z_inf_mm": doc.get("z_inf_mm", 4.0),
                             "source": str(p)})
    return rows


def coefficients(theta: np.ndarray) -> dict:
    return {**dict(zip(NAMES, (float(v) for v in theta))), **FIXED}


def predict(row: dict, coef: dict, *, use_q: bool = True) -> float:
    return predict_quality(frames=int(row["frames"]), frame_phases=row["frame_phases"],
                           noise_to_signal=float(row["plan_noise_to_signal"]), encoder=row["encoder"],
                           iterations=row["iterations_asked"], image_q=row["image_q"] if use_q else None,
                           refracted_share=row["refracted_share"], model={"coefficients": coef}).psnr_db


def fit(rows: list[dict], *, use_q: bool = True) -> dict:
    y = np.array([r["psnr_2_6_db"] for r in rows])

    def resid(log_theta):
        coef = coefficients(np.exp(log_theta))
        return np.array([predict(r, coef, use_q=use_q) for r in rows]) - y

    sol = least_squares(resid, np.log(START), method="trf", max_nfev=4000)
    return coefficients(np.exp(sol.x))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", help="the jobs to fit on")
    ap.add_argument("--validate", nargs="*", default=[], help="jobs at other optics, predicted by the model fitted "
                                                             "on the others (never fitted on)")
    ap.add_argument("--no-image-q", action="store_true", help="fit without the scene's image statistic")
    ap.add_argument("--write", action="store_true", help="store the model in holocore/plan/data")
    ap.add_argument("--table", default="bench/results/quality/predicted_vs_measured.md")
    a = ap.parse_args(argv)
    use_q = not a.no_image_q
    every = load_jobs(a.folders)
    rows = [r for r in every if r["spp"] >= MIN_FITTED_SPP]
    below = [r for r in every if r["spp"] < MIN_FITTED_SPP]
    checks = [r for r in load_jobs(a.validate) if r["spp"] >= MIN_FITTED_SPP] if a.validate else []
    scenes = sorted({r["scene"] for r in rows})
    coef = fit(rows, use_q=use_q)
    out = []  # (row, prediction, how it was predicted)
    for s in scenes:
        c = fit([r for r in rows if r["scene"] != s], use_q=use_q)
        out += [(r, predict(r, c, use_q=use_q), "scene left out") for r in rows if r["scene"] == s]
    out += [(r, predict(r, coef, use_q=use_q), "other optics") for r in checks]
    err_in = np.array([predict(r, coef, use_q=use_q) - r["psnr_2_6_db"] for r in rows])
    err = np.array([p - r["psnr_2_6_db"] for r, p, _ in out])
    within = float(np.mean(np.abs(err) <= 1.5))
    unc = float(np.percentile(np.abs(err), 90))
    left = np.array([p - r["psnr_2_6_db"] for r, p, how in out if how == "scene left out"])
    other = err[len(left):]
    rms = float(np.sqrt(np.mean(err ** 2)))
    print(f"{len(out)} jobs ({len(rows)} fitted on {len(scenes)} scenes, {len(checks)} at other optics): fitted rms "
          f"{np.sqrt(np.mean(err_in ** 2)):.2f} dB; predicted unseen: rms {rms:.2f} dB, within 1.5 dB {within:.0%}, "
          f"90th percentile {unc:.2f} dB")
    print(json.dumps({k: round(v, 5) for k, v in coef.items()}))
    cmd = f"python bench/quality_fit.py {' '.join(a.folders)}" + (f" --validate {' '.join(a.validate)}"
                                                                  if a.validate else "")
    lines = ["# Predicted against measured viewer-faithful PSNR", "",
             f"Made on {dt.date.today().isoformat()} by `{cmd}`{' --no-image-q' if not use_q else ''}. Measured: "
             "`bench/quality_jobs.py` (the paper's display with its filter, wave ground truth, pupils 2/4/6 mm, a "
             "jittered 3 x 3 eye grid, mean PSNR). Predicted: `holocore/plan/quality.py`, never by a model that saw "
             "the job: each scene of the fitted set by the model fitted on the other scenes, the jobs at other "
             "optics (virtual infinity, SLM size) by the model fitted on all of the fitted set.", "",
             f"**{len(left)} jobs on {len(scenes)} scenes, each predicted with its scene left out: "
             f"{np.mean(np.abs(left) <= 1.5):.0%} within ±1.5 dB ({int(np.sum(np.abs(left) <= 1.5))} of {len(left)}), "
             f"rms error {np.sqrt(np.mean(left ** 2)):.2f} dB.**"
             + (f" At other optics: {int(np.sum(np.abs(other) <= 1.5))} of {len(other)} within ±1.5 dB." if len(other)
                else "")
             + f" All {len(out)}: {within:.0%} within ±1.5 dB, rms {rms:.2f} dB, 90 % of errors within {unc:.2f} dB "
             f"(the ± each prediction carries; fitted on all, in-sample: rms {np.sqrt(np.mean(err_in ** 2)):.2f} dB).",
             "",
             "| scene | size | z_inf mm | frames | phases | spp | encoder | measured dB | predicted dB | error dB | "
             "predicted by |", "|---|---|---|---|---|---|---|---|---|---|---|"]

    def enc_words(r):
        return r["encoder"] + ("" if r["encoder"] != "sgd" else
                               f" {r['iterations_asked']} it" if r["iterations_asked"] else " stop rule")

    for r, p, how in out:
        lines.append(f"| {r['scene']} | {r['shape_hw'][0]}x{r['shape_hw'][1]} | {r['z_inf_mm']:g} | {r['frames']} | "
                     f"{r['frame_phases']} | {r['spp']} | {enc_words(r)} | {r['psnr_2_6_db']:.2f} | {p:.2f} | "
                     f"{p - r['psnr_2_6_db']:+.2f} | {how} |")
    if below:
        lines += ["", f"Below {MIN_FITTED_SPP} rays per pixel (the balanced preset's least, outside the fitted range: "
                  "the cone equaliser filters the signal with the noise, and the estimate warns that it will come out "
                  "below the prediction):", "", "| scene | frames | spp | measured dB | predicted dB (all fitted) |",
                  "|---|---|---|---|---|"]
        lines += [f"| {r['scene']} | {r['frames']} | {r['spp']} | {r['psnr_2_6_db']:.2f} | "
                  f"{predict(r, coef, use_q=use_q):.2f} |" for r in below]
    Path(a.table).parent.mkdir(parents=True, exist_ok=True)
    Path(a.table).write_text("\n".join(lines) + "\n")
    if a.write:
        qs = sorted(r["image_q"] for r in rows if r["image_q"])
        doc = {"coefficients": {k: round(v, 6) for k, v in coef.items()}, "uncertainty_db": round(max(unc, 0.5), 2),
               "fitted_on": {"jobs": len(rows), "scenes": scenes, "date": dt.date.today().isoformat(),
                             "display": "paper (8 um, f = 50 mm), 4f filter", "image_q": bool(use_q),
                             "image_q_median": qs[len(qs) // 2] if qs else DEFAULT_IMAGE_Q,
                             "unseen_rms_db": round(rms, 3)}}
        MODEL_PATH.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {MODEL_PATH}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
