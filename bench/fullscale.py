"""The paper's full hologram on this machine, end to end, as a user runs it: the demo scene at 1080x1920 x 3
colours x 24 frames rendered at the rays its preset chooses (`holo render`), encoded by the default encoder
(`holo encode`: its default, 28 L-BFGS iterations), and one eye view (`holo view`, 4 mm pupil), each a process of its own
timed with its peak memory by GNU time. Then the same RESULT encoded to convergence (Adam until its stop rule,
which ends once 30 iterations gain less than 0.05 dB of field SNR), and both stacks scored as an eye sees them
(holocore.evaluate.viewer: one 4 mm pupil, an n x n jittered eye grid, focus planes across the image volume, one
brightness per colour) against the wave ground truth, computed once for both. Writes ``fullscale.md`` and
``fullscale.json`` under ``--out``.

    .venv/bin/python bench/fullscale.py --preset fast --work /tmp/fs   # the paper's size, about an hour on 2 cores
    .venv/bin/python bench/fullscale.py --work /tmp/fs --stages encode   # the encode again on the same RESULT
    .venv/bin/python bench/fullscale.py --resolution 135x240 --frames 4 --out /tmp/fs   # a minute

Run it alone: every stage uses every core.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

HOLO = [sys.executable, "-m", "holo"]


def timed(cmd: list[str]) -> dict:
    """Wall seconds and peak RSS (bytes) of one command, from GNU time; its output's last lines kept."""
    out = subprocess.run(["/usr/bin/time", "-f", "%M %e", *cmd], capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({out.returncode}):\n{out.stdout[-2000:]}\n{out.stderr[-2000:]}")
    kb, secs = out.stderr.strip().splitlines()[-1].split()
    return {"s": float(secs), "peak_bytes": int(kb) * 1024, "tail": (out.stdout + out.stderr).strip()[-1500:]}


def machine() -> str:
    model = "?"
    try:
        model = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                     if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    import torch

    return (f"{platform.machine()} {model}, {os.cpu_count()} cores, torch {torch.__version__}, "
            f"{platform.platform()}")


def score(stacks: dict[str, Path], scene: Path, *, pupil_mm: float, eye_grid: int, focus_planes: int,
          gt_spp: int) -> dict:
    """Viewer-faithful mean PSNR / SSIM of each stack at one pupil, against one wave ground truth."""
    from holocore.evaluate.truths import ground_truth
    from holocore.evaluate.viewer import viewer_score
    from holocore.optics.fieldsource import open_slm_field
    from holocore.scene.load import load_scene

    loaded = load_scene(scene)
    fields = {k: open_slm_field(p) for k, p in stacks.items()}
    first = next(iter(fields.values()))
    truth = ground_truth("wave", loaded, first.meta, shape_hw=tuple(first.shape[-2:]), spp=gt_spp)  # lazy
    out = {}
    for name, field in fields.items():
        t0 = time.perf_counter()
        vs = viewer_score(field, field.meta, truth, pupils_m=[pupil_mm * 1e-3], eye_grid=eye_grid,
                          focus_planes=focus_planes)
        out[name] = {"psnr_db": vs.mean_psnr_db, "ssim": vs.pupils[0].mean_ssim, "cells": len(vs.cells),
                     "score_s": time.perf_counter() - t0}
        print(f"  {name}: {vs.mean_psnr_db:.2f} dB, SSIM {vs.pupils[0].mean_ssim:.3f} over {len(vs.cells)} views "
              f"({out[name]['score_s']:.0f} s)", flush=True)
    return out


def report(r: dict) -> str:
    s, gib = r["stages"], 2 ** 30
    e2e = s["render"]["s"] + s["encode"]["s"] + s["view"]["s"]
    def peak(v: dict) -> str:
        return "-" if v.get("peak_bytes") is None else f"{v['peak_bytes'] / gib:.2f}"

    rows = [f"| {name} | {s[k]['s']:.0f} | {s[k]['s'] / e2e:.0%} | {peak(s[k])} |"
            for k, name in (("render", f"render (`holo render`, {r['preset']} preset)"),
                            ("encode", "encode (`holo encode`, default: 28 L-BFGS iterations)"),
                            ("view", "one eye view (`holo view`, 4 mm pupil)"))]
    lines = [f"# The paper's full hologram end to end ({r['size']})", "",
             f"{r['date']}; {r['machine']}; load average before the run {r['load_before']}. "
             f"`{r['command']}`.", "",
             *([f"Stages kept from earlier runs: {r['first_run']}.", ""] if r.get("first_run") else []),
             "| stage | s | share | peak GiB |", "|---|---|---|---|", *rows,
             f"| **render + encode + view** | **{e2e:.0f}** ({e2e / 60:.1f} min) | | "
             f"{max((v['peak_bytes'] or 0) for v in s.values()) / gib:.2f} |", ""]
    if "converged" in s and "score" in r:
        sc = r["score"]
        d, c = sc["default"], sc["converged"]
        lines += [f"Converged reference: `holo encode --optimiser adam` (Adam until its stop rule) on the same RESULT, "
                  f"{s['converged']['s']:.0f} s, peak {peak(s['converged'])} GiB.", "",
                  f"What an eye sees (holocore.evaluate.viewer: a {r['pupil_mm']:g} mm pupil, a {r['eye_grid']} x "
                  f"{r['eye_grid']} jittered eye grid, {r['focus_planes']} focus planes across the image volume, one "
                  f"brightness per colour; wave ground truth at {r['gt_spp']} samples per pixel):", "",
                  "| encode | s | viewer-faithful PSNR dB | SSIM |", "|---|---|---|---|",
                  f"| default (28 L-BFGS iterations) | {s['encode']['s']:.0f} | {d['psnr_db']:.2f} | {d['ssim']:.3f} |",
                  f"| converged (Adam, stop rule) | {s['converged']['s']:.0f} | {c['psnr_db']:.2f} | {c['ssim']:.3f} |",
                  *[f"| {k} | - | {v['psnr_db']:.2f} | {v['ssim']:.3f} |" for k, v in sc.items()
                    if k not in ("default", "converged")],
                  *(["", r["score_note"]] if r.get("score_note") else []),
                  "", f"The default is {c['psnr_db'] - d['psnr_db']:.2f} dB below the converged encode in "
                  f"{s['encode']['s'] / s['converged']['s']:.0%} of its time.", ""]
    return "\n".join(lines)


STAGES = ("render", "encode", "view", "converged", "score")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", default="1080x1920")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--preset", default=None, help="default: the options' default preset")
    ap.add_argument("--focus-mm", default="81", help="the eye view's focus (mm from the SLM)")
    ap.add_argument("--pupil-mm", type=float, default=4.0)
    ap.add_argument("--eye-grid", type=int, default=3)
    ap.add_argument("--focus-planes", type=int, default=3)
    ap.add_argument("--gt-spp", type=int, default=64)
    ap.add_argument("--stages", default=",".join(STAGES), help="those to run; the others' figures are kept from "
                                                               "the last fullscale.json under --out")
    ap.add_argument("--work", type=Path, default=None, help="keep the scene, RESULT and stacks here (default: a "
                                                            "temporary folder); a later run's stages reuse them")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args()
    from holocore.options import HologramOptions
    from holocore.scene.demo import write_demo_scene

    todo = [x for x in args.stages.split(",") if x]
    if not set(todo) <= set(STAGES):
        raise SystemExit(f"--stages takes {', '.join(STAGES)}")
    preset = args.preset or HologramOptions().preset
    last = args.out / "fullscale.json"
    r = json.loads(last.read_text()) if set(todo) != set(STAGES) and last.is_file() else {"stages": {}}
    r.update({"date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M"), "machine": machine(),
              "load_before": " ".join(Path("/proc/loadavg").read_text().split()[:3]),
              "size": f"{args.resolution} x 3 colours x {args.frames} frames", "preset": preset,
              "command": "python bench/fullscale.py " + " ".join(sys.argv[1:]), "pupil_mm": args.pupil_mm,
              "eye_grid": args.eye_grid, "focus_planes": args.focus_planes, "gt_spp": args.gt_spp})
    with tempfile.TemporaryDirectory() as tmp:
        t = args.work or Path(tmp)
        t.mkdir(parents=True, exist_ok=True)
        if not (t / "scene").is_dir():
            write_demo_scene(t / "scene")
        res, stack, conv = t / "RESULT.npz", t / "STACK.npz", t / "CONVERGED.npz"
        commands = {
            "render": [*HOLO, "render", str(t / "scene"), "--out", str(res), "--resolution", args.resolution,
                       "--frames", str(args.frames), "--preset", preset],
            "encode": [*HOLO, "encode", str(res), "--out", str(stack)],
            "view": [*HOLO, "view", str(stack), "--focus-mm", args.focus_mm, "--pupil-mm", f"{args.pupil_mm:g}",
                     "--out", str(t / "view.png")],
            "converged": [*HOLO, "encode", str(res), "--out", str(conv), "--optimiser", "adam"]}
        for name in (x for x in STAGES if x in todo and x in commands):
            r["stages"][name] = timed(commands[name])
            print(f"{name} {r['stages'][name]['s']:.0f} s", flush=True)
        if "score" in todo:
            r["score"] = score({"default": stack, "converged": conv}, t / "scene", pupil_mm=args.pupil_mm,
                               eye_grid=args.eye_grid, focus_planes=args.focus_planes, gt_spp=args.gt_spp)
    args.out.mkdir(parents=True, exist_ok=True)
    last.write_text(json.dumps(r, indent=1))
    text = report(r)
    (args.out / "fullscale.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
