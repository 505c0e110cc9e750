"""A highlight seen in near-smooth metal and through near-smooth glass, over the roughness alpha: where the eye
focuses it sharpest and how far it moves when the eye moves, in our hologram and in Mitsuba's thin-lens ground
truth through the same pupil (holocore.trace.near_smooth; docs/physics.md "Near-smooth surfaces").

The scene: a small glowing ball 1.5 m away, seen in a plate 0.5 m away turned 12 degrees (metal:
roughconductor) or through a 5 mm plate facing the eye (glass: roughdielectric, n 1.5). A smooth plate shows the
ball at its own depth, a rough one only a glow on the plate; between them the image blurs and its best focus
moves from the ball to the plate. For each alpha both are viewed at focus depths from beyond the ball's image to
the plate, and the best focus is where the brightest blob holds half its light in the smallest radius; its shift
is the blob's centroid moved between eyes 0.8 mm left and right of the centre, focused on the plate.

    .venv/bin/python bench/near_smooth_sweep.py            # ~10 min on 2 cores; writes near_smooth_sweep.md
    .venv/bin/python bench/near_smooth_sweep.py --renders 4   # also the mean field of 4 renders (~4x the time)

A single render carries Monte Carlo glow: each pixel's rays sample the ball's random-phase cells sparsely, an
error field on the recording plane that the eye sees with that plane's parallax. With ``--renders K`` "ours" is
also measured on the eye's intensity of the mean field over K renders of independent ray seeds,
(I(sum U_k) - sum I(U_k)) / (K (K - 1)) (tests/trace/test_far_image_parallax.py), which separates what the
coherent chain does from that noise.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

H, W, P_M, F_M, ZI_M = 96, 128, 8e-6, 0.05, 4e-3
Z_PLATE_M, Z_BALL_M = 0.5, 1.5  # scene distances of the plate and of the ball (or of its mirror image)


def highlight_scene(kind: str, alpha: float):
    """The ball seen in (``metal``) or through (``glass``) a plate of roughness ``alpha``."""
    from holocore.runtime.mitsuba_env import mitsuba

    mi = mitsuba()
    T = mi.ScalarTransform4f
    fov = 2 * math.degrees(math.atan(W * P_M / 2 / F_M))
    smooth = alpha == 0  # alpha 0: the smooth (delta) surface, the paper's own coherent chain
    if kind == "glass":
        bsdf = {"type": "dielectric", "int_ior": 1.5} if smooth else \
            {"type": "roughdielectric", "alpha": alpha, "int_ior": 1.5}
        plate = {"type": "cube", "bsdf": bsdf,
                 "to_world": T().translate([0, 0, -Z_PLATE_M]).scale([0.05, 0.05, 0.0025])}
        ball = [0.0, 0.0, -Z_BALL_M]
    else:
        plate = {"type": "rectangle", "bsdf": {"type": "conductor"} if smooth else
                 {"type": "roughconductor", "alpha": alpha},
                 "to_world": T().translate([0, 0, -Z_PLATE_M]).rotate([0, 1, 0], 12.0).scale(0.05)}
        ang = math.radians(24.0)  # the ball 1 m from the plate along the reflected axis: its image 1.5 m away
        ball = [math.sin(ang), 0.0, -Z_PLATE_M + math.cos(ang)]
    return mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": fov, "fov_axis": "x",
                   "to_world": T().look_at(origin=[0, 0, 0], target=[0, 0, -1], up=[0, 1, 0])},
        "plate": plate,
        "light": {"type": "sphere", "center": ball, "radius": 0.0015,
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 50.0}}}})


def blob(img: np.ndarray) -> tuple[float, float]:
    """(radius px holding half the light of the brightest blob, its centroid x px), in a +-24 px window."""
    from holocore.evaluate.metrics import brightest_blob

    r50, _, cx = brightest_blob(img)
    return r50, cx


def measure(view, depths: np.ndarray, z_plate: float, z_ball: float, eye_mm: float) -> dict:
    """Best focus (hologram depth m) and sharpest radius of ``view(z, offset)``, and the shift (px) for eyes
    +-eye_mm at the plate's focus and at the ball's image (in focus the shift is the geometric one whatever part
    of the pupil the display's band passes; defocused it depends on that part)."""
    radii = [blob(view(z, (0.0, 0.0)))[0] for z in depths]
    k = int(np.argmin(radii))

    def shift(z: float) -> float:
        left, right = (blob(view(z, (s * eye_mm * 1e-3, 0.0)))[1] for s in (-1, 1))
        return right - left
    return {"best_focus_m": float(depths[k]), "r50_px": float(radii[k]), "shift_px": shift(z_plate),
            "shift_ball_px": shift(z_ball)}


def one(kind: str, alpha: float, *, spp: int, gt_spp: int, pupil_mm: float, eye_mm: float, renders: int = 1) -> dict:
    from holocore.display.optics import OpticsConfig
    from holocore.evaluate.groundtruth import GroundTruth
    from holocore.evaluate.scoring import eye_view
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.load import from_mitsuba_scene

    loaded = from_mitsuba_scene(highlight_scene(kind, alpha))
    opt = OpticsConfig(resolution_hw=(H, W), pitch_um=P_M * 1e6, frames=8, focal_length_mm=F_M * 1e3,
                       z_inf_mm=ZI_M * 1e3, seed=1)
    t0 = time.perf_counter()
    if renders > 1:  # no cone equaliser: the renders must differ by their rays alone
        runs = [render_loaded(loaded, opt, RenderOptions(preset="fast", spp=spp, ray_seed=s, cone_equaliser=False))
                for s in range(1, renders + 1)]
    else:
        runs = [render_loaded(loaded, opt, RenderOptions(preset="fast", spp=spp))]
    res = runs[0]
    render_s = (time.perf_counter() - t0) / len(runs)
    gt = GroundTruth(loaded, res.meta, shape_hw=(H, W), spp=gt_spp)
    z_plate, z_ball = ZI_M + F_M ** 2 / Z_PLATE_M, ZI_M + F_M ** 2 / Z_BALL_M
    depths = np.linspace(z_ball - 1.0e-3, z_plate + 0.5e-3, 13)
    pupil = pupil_mm * 1e-3
    ours = measure(lambda z, o: eye_view(res.slm_field, res.meta, focus_z_m=z, pupil_diameter_m=pupil,
                                         view_offset_m=o), depths, z_plate, z_ball, eye_mm)
    truth = measure(lambda z, o: gt.channels(focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=o), depths,
                    z_plate, z_ball, eye_mm)
    plan = [s for s in res.meta["plan"]["summary"] if "near-smooth" in s or "glossy" in s]
    row = {"kind": kind, "alpha": alpha, "ours": ours, "truth": truth, "render_s": render_s,
           "z_plate_m": z_plate, "z_ball_m": z_ball, "plan": plan[:1]}
    if renders > 1:
        total, k = sum(r.slm_field for r in runs), len(runs)

        def views(z, o):
            """(the glow-free mean field's view, the renders' average view)."""
            kw = dict(focus_z_m=z, pupil_diameter_m=pupil, view_offset_m=o)
            each = sum(eye_view(r.slm_field, res.meta, **kw) for r in runs)
            return np.clip((eye_view(total, res.meta, **kw) - each) / (k * (k - 1)), 0.0, None), each / k
        row["ours_mean"] = measure(lambda z, o: views(z, o)[0], depths, z_plate, z_ball, eye_mm)
        # the glow's light against the image's in the eye, focused on the ball's image, against the plan's estimate
        mean, avg = (float(v.sum()) for v in views(z_ball, (0.0, 0.0)))
        row["glow_to_signal"] = (avg - mean) / mean if mean > 0 else float("inf")
        row["plan_noise_to_signal"] = float(res.meta["plan"]["noise_to_signal"])
    return row


def table(rows: list[dict]) -> str:
    out = ["| surface | alpha | best focus: ours / truth (mm from the plate's image towards the ball's, at "
           f"{(rows[0]['z_plate_m'] - rows[0]['z_ball_m']) * 1e3:.2f}) | sharpest r50 px: ours / truth | "
           "shift px for eyes +-0.8 mm focused on the plate: ours / truth | the same focused on the ball's image | "
           "the plan |", "|---|---|---|---|---|---|---|"]
    mean = "ours_mean" in rows[0]
    if mean:  # ours as single render / mean field of the renders
        out = [out[0].replace("ours / truth", "ours, single / mean field / truth")
               + " glow / image light in the eye (the plan's noise estimate) |", out[1] + "---|"]
    for r in rows:
        o, t = r["ours"], r["truth"]
        m = r.get("ours_mean")
        zp = r["z_plate_m"]
        focus = f"{(zp - o['best_focus_m']) * 1e3:.2f}" + (f" / {(zp - m['best_focus_m']) * 1e3:.2f}" if m else "")
        r50 = f"{o['r50_px']:.1f}" + (f" / {m['r50_px']:.1f}" if m else "")
        shift = f"{o['shift_px']:+.1f}" + (f" / {m['shift_px']:+.1f}" if m else "")
        shift_b = f"{o['shift_ball_px']:+.1f}" + (f" / {m['shift_ball_px']:+.1f}" if m else "")
        out.append(f"| {r['kind']} | {r['alpha']:g} | {focus} / {(zp - t['best_focus_m']) * 1e3:.2f} | "
                   f"{r50} / {t['r50_px']:.1f} | {shift} / {t['shift_px']:+.1f} | "
                   f"{shift_b} / {t['shift_ball_px']:+.1f} | "
                   f"{'; '.join(r['plan']) or '-'} |"
                   + (f" {r['glow_to_signal']:.2f} ({r['plan_noise_to_signal']:.2f}) |" if m else ""))
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--alphas", default="0,0.001,0.003,0.01,0.03,0.1,0.3", help="0: the smooth surface")
    ap.add_argument("--kinds", default="metal,glass")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--gt-spp", type=int, default=256)
    ap.add_argument("--pupil-mm", type=float, default=1.6)
    ap.add_argument("--eye-mm", type=float, default=0.8)
    ap.add_argument("--renders", type=int, default=1, help="K > 1: also the mean field of K renders (ray seeds 1..K)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args()
    load = " ".join(Path("/proc/loadavg").read_text().split()[:3])
    k = args.renders
    mean_note = f"; ours also as the mean field of {k} renders (ray seeds 1..{k})" if k > 1 else ""
    rows = []
    for kind in args.kinds.split(","):
        for a in (float(v) for v in args.alphas.split(",")):
            rows.append(one(kind, a, spp=args.spp, gt_spp=args.gt_spp, pupil_mm=args.pupil_mm, eye_mm=args.eye_mm,
                            renders=args.renders))
            r = rows[-1]
            print(f"{kind} alpha {a:g}: focus {r['ours']['best_focus_m'] * 1e3:.2f} / "
                  f"{r['truth']['best_focus_m'] * 1e3:.2f} mm, r50 {r['ours']['r50_px']:.1f} / "
                  f"{r['truth']['r50_px']:.1f} px, shift {r['ours']['shift_px']:+.1f} / "
                  f"{r['truth']['shift_px']:+.1f} px ({r['render_s']:.0f} s)", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "near_smooth_sweep.json").write_text(json.dumps(rows, indent=1))
    text = (f"# A highlight in near-smooth metal and glass against Mitsuba, over alpha\n\n"
            f"{datetime.datetime.now():%Y-%m-%d %H:%M}, {platform.machine()} {platform.node()}, load {load}; "
            f"`python bench/near_smooth_sweep.py {' '.join(sys.argv[1:])}`. {H}x{W} SLM of the paper's display "
            f"(8 um, f 50 mm, z_inf 4 mm), 8 frames, {args.spp} rays per pixel; Mitsuba's thin-lens truth at "
            f"{args.gt_spp} samples per pixel; a {args.pupil_mm:g} mm pupil"
            f"{mean_note}. The plate's image lies "
            f"{rows[0]['z_plate_m'] * 1e3:.2f} mm from the SLM, the ball's {rows[0]['z_ball_m'] * 1e3:.2f} mm; the "
            f"best focus was sought at 13 depths from 0.5 mm beyond the plate's to 1 mm beyond the ball's."
            f"\n\n{table(rows)}\n")
    (args.out / "near_smooth_sweep.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
