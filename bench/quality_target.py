"""A quality target against the default options, end to end through the CLI a user runs.

1. The default: ``holo render`` (the display's 24 frames, the preset's rays) and ``holo encode`` (SGD, its stop
   rule), timed as wall clock of the two commands, scored by ``holo evaluate --viewer`` (pupils 2, 4, 6 mm, a
   3 x 3 eye grid, 3 focus planes, the wave ground truth).
2. For each target (dB below the default's measured score): ``holo render --quality-db X``, then
   ``holo encode`` with the iterations it names, timed and scored the same way.

A target is met when its measured score reaches it; it pays when it also took less time than the default,
which reached that quality too. Writes ``bench/results/quality/target.md``.

    python bench/quality_target.py --scene demo --resolution 270x480 --below 1,3
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HOLO = [sys.executable, "-m", "holo"]


def run(args: list[str]) -> tuple[float, str]:
    t0 = time.perf_counter()
    env = {**os.environ, "COLUMNS": "400"}  # one line per message: the choice is read back from it
    out = subprocess.run(HOLO + args, cwd=ROOT, capture_output=True, text=True, env=env)
    if out.returncode != 0:
        raise SystemExit(f"holo {' '.join(args[:2])} failed: {out.stderr[-1500:]}")
    return time.perf_counter() - t0, out.stderr + out.stdout


def score(stack: Path, scene: Path, work: Path) -> float:
    run(["evaluate", str(stack), "--scene", str(scene), "--out", str(work), "--viewer", "--pupils-mm", "2,4,6",
         "--eye-grid", "3", "--focus-planes", "3", "--gt-spp", "32"])
    return float(json.loads((work / "viewer.json").read_text())["mean_psnr_db"])


def job(scene: Path, work: Path, optics: list[str], *, target: float | None) -> dict:
    work.mkdir(parents=True, exist_ok=True)
    res, stack = work / "RESULT.npz", work / "STACK.npz"
    extra = [] if target is None else ["--quality-db", f"{target:g}"]
    t_r, said = run(["render", str(scene), "--out", str(res), *optics, *extra])
    it = re.search(r"then `holo encode(?: --iterations (\d+))?`", said)
    chosen = re.search(r"--quality-db [\d.]+: (.*?) \(", said)
    enc = [] if not (it and it.group(1)) else ["--iterations", it.group(1)]
    t_e, _ = run(["encode", str(res), "--out", str(stack), *enc])
    return {"target_db": target, "chosen": chosen.group(1) if chosen else "the defaults", "render_s": t_r,
            "encode_s": t_e, "time_s": t_r + t_e, "measured_db": score(stack, scene, work / "eval")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="demo", help="demo, or a paper scene (mirror, glass, depth, glossy)")
    ap.add_argument("--resolution", default="270x480")
    ap.add_argument("--z-inf-mm", type=float, default=None, help="default: the display's own")
    ap.add_argument("--below", default="1,3", help="targets: dB below the default's measured score")
    ap.add_argument("--work", default="/tmp/quality_target")
    ap.add_argument("--out", default="bench/results/quality/target.md")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from holocore.scene.demo import write_demo_scene
    from holocore.scene.paper import write_paper_scene

    work = Path(a.work)
    scene = Path(write_demo_scene(work / "scene") if a.scene == "demo" else write_paper_scene(a.scene, work / "scene"))
    scene = scene.parent if scene.suffix == ".xml" else scene
    optics = ["--resolution", a.resolution] + ([] if a.z_inf_mm is None else ["--z-inf-mm", f"{a.z_inf_mm:g}"])
    load0 = os.getloadavg()[0]
    t0 = time.time()
    base = job(scene, work / "default", optics, target=None)
    print(f"default: {base['measured_db']:.2f} dB in {base['time_s']:.1f} s", flush=True)
    rows = [base]
    for d in (float(v) for v in a.below.split(",")):
        target = round(base["measured_db"] - d, 1)
        r = job(scene, work / f"target_{target:g}", optics, target=target)
        rows.append(r)
        print(f"target {target:g}: {r['measured_db']:.2f} dB in {r['time_s']:.1f} s ({r['chosen']})", flush=True)
    lines = ["# A quality target against the default options", "",
             f"Made on {dt.date.today().isoformat()} by `python bench/quality_target.py --scene {a.scene} "
             f"--resolution {a.resolution}{'' if a.z_inf_mm is None else f' --z-inf-mm {a.z_inf_mm:g}'} "
             f"--below {a.below}` on {platform.machine()}, {os.cpu_count()} cores, load {load0:.1f} at the start and "
             f"{os.getloadavg()[0]:.1f} at the end ({(time.time() - t0) / 60:.0f} min, the scoring included). "
             "Times: wall clock of `holo render` plus `holo encode` (start-up and compilation included); score: "
             "`holo evaluate --viewer --pupils-mm 2,4,6 --eye-grid 3 --focus-planes 3 --gt-spp 32`.", "",
             "| run | options | measured dB | time s | reached | quicker than the default |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        t = r["target_db"]
        run_name = "default" if t is None else f"--quality-db {t:g}"
        reached = "–" if t is None else ("yes" if r["measured_db"] >= t else "no")
        share = "–" if t is None else f"{r['time_s'] / base['time_s']:.0%} of its time"
        lines.append(f"| {run_name} | {r['chosen']} | {r['measured_db']:.2f} | {r['time_s']:.1f} | {reached} | "
                     f"{share} |")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
