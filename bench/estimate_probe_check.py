"""`holo render --estimate` (probe of the scene + calibrated model) against the measured wall time of the same
`holo render` command, start-up and compilation included, on the project's scenes and, where ../shared is
present, on third-party scenes the calibration never saw. Writes bench/results/estimate_probe.md.
Usage: ``.venv/bin/python bench/estimate_probe_check.py [--sizes 96x128,270x480] [--frames 8]``."""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
SHARED = REPO.parent / "shared" / "scenes"


def scenes(tmp: Path) -> list[tuple[str, Path, str]]:
    from holocore.scene.demo import write_demo_scene
    from holocore.scene.paper import write_paper_scene

    out = []
    write_demo_scene(tmp / "demo")
    out.append(("demo (calibration scene)", tmp / "demo", "project"))
    for name in ("mirror", "glass"):
        write_paper_scene(name, tmp / name)
        out.append((f"paper {name}", tmp / name, "project, not calibrated on"))
    if SHARED.is_dir():
        for name in ("cbox-mirror-glass", "veach-mis"):
            if (SHARED / name).is_dir():
                out.append((name, SHARED / name, "third-party, not calibrated on"))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="96x128,270x480")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--scenes", default="", help="Comma-separated labels to run (default: all).")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "estimate_probe.md")
    args = ap.parse_args()
    holo = [sys.executable, "-m", "holo"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        for label, path, kind in scenes(t):
            if args.scenes and label not in args.scenes.split(","):
                continue
            for size in args.sizes.split(","):
                common = [str(path), "--resolution", size, "--frames", str(args.frames), "--preset", args.preset]
                est = subprocess.run([*holo, "render", *common, "--out", str(t / "x.npz"), "--estimate"],
                                     capture_output=True, text=True, env={**os.environ, "COLUMNS": "400"})
                m = re.search(r"estimated time of `holo render`: ([0-9.]+) s", est.stdout + est.stderr)
                if not m:
                    rows.append(f"| {label} | {kind} | {size} | estimate failed: "
                                f"{(est.stderr.strip().splitlines() or [''])[-1][:80]} | | |")
                    continue
                t0 = time.perf_counter()
                run = subprocess.run([*holo, "render", *common, "--out", str(t / "r.npz")], capture_output=True,
                                     text=True)
                wall = time.perf_counter() - t0
                ok = run.returncode == 0
                pred = float(m.group(1))
                rows.append(f"| {label} | {kind} | {size} | {pred:.1f} s | {wall:.1f} s{'' if ok else ' (failed)'} | "
                            f"{pred / wall:.2f} |")
                print(rows[-1], flush=True)
    load = os.getloadavg()[0]
    text = (f"# Estimate (probe + calibration) vs the measured `holo render` command\n\n{platform.machine()}, "
            f"{os.cpu_count()} cores, {datetime.date.today().isoformat()}, load average at the end {load:.1f}; "
            f"{args.frames} frames, preset {args.preset}, the paper display otherwise (f = 50 mm, 3 colors). "
            "Wall time includes start-up and kernel compilation. Goal: within 1.5x (0.67..1.5).\n\n"
            "| scene | kind | size | estimate | measured | estimate / measured |\n|---|---|---|---|---|---|\n"
            + "\n".join(rows) + "\n\n`.venv/bin/python bench/estimate_probe_check.py`\n")
    args.out.write_text(text)


if __name__ == "__main__":
    main()
