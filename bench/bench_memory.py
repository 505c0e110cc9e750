"""Peak RSS of `holo render`, `holo encode` and `holo view` on the demo scene at a few sizes, beside the memory
model (holocore.plan.memory_estimate). Writes bench/results/memory.md. Usage:
``.venv/bin/python bench/bench_memory.py [--sizes 135x240x8,270x480x8,1080x1920x24:render+view]`` (H x W x frames,
3 colors; ``:STAGE+STAGE`` runs only those stages at that size: without encode, view reads the render's RESULT)."""

from __future__ import annotations

import argparse
import datetime
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def peak_rss(cmd: list[str]) -> tuple[int, float]:
    """(peak RSS bytes, seconds) of a command, from GNU time."""
    out = subprocess.run(["/usr/bin/time", "-f", "%M %e", *cmd], capture_output=True, text=True, check=True)
    kb, secs = out.stderr.strip().splitlines()[-1].split()
    return int(kb) * 1024, float(secs)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="135x240x8,270x480x8,1080x1920x24:render+view")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "memory.md")
    args = ap.parse_args()
    from holocore.plan.memory_estimate import estimate_memory
    from holocore.scene.demo import write_demo_scene

    holo = [sys.executable, "-m", "holo"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        write_demo_scene(t / "scene")
        for spec in args.sizes.split(","):
            size, _, only = spec.partition(":")
            stages = only.split("+") if only else ["render", "encode", "view"]
            h, w, f = (int(v) for v in size.split("x"))
            r, s = t / f"r{size}.npz", t / f"s{size}.npz"
            got = {"render": peak_rss([*holo, "render", str(t / "scene"), "--out", str(r), "--resolution", f"{h}x{w}",
                                       "--frames", str(f), "--preset", "fast"])}
            if "encode" in stages:
                got["encode"] = peak_rss([*holo, "encode", str(r), "--out", str(s), "--iterations", "3"])
            if "view" in stages:
                got["view"] = peak_rss([*holo, "view", str(s if "encode" in stages else r), "--focus-mm", "81",
                                        "--pupil-mm", "4", "--out", str(t / "v.png")])
            for path in (r, s):
                path.unlink(missing_ok=True)
            model = estimate_memory(height_px=h, width_px=w, colors=3, frames=f)
            for stage, (peak, secs) in got.items():
                pred = getattr(model, f"{stage}_bytes")
                rows.append(f"| {h}x{w}x3x{f} | {stage} | {peak / 1e6:.0f} MB | {pred / 1e6:.0f} MB | "
                            f"{pred / peak:.2f} | {secs:.1f} s |")
                print(rows[-1], flush=True)
    text = (f"# Peak memory per stage vs the model\n\n{platform.machine()}, {platform.node()}, "
            f"{datetime.date.today().isoformat()}; demo scene, fast preset, SGD encode 3 iterations; default memory "
            "budget (8 GiB: render and view work in chunks of frames and colors and stream to and from the files); "
            "a size run without encode views its RESULT.npz; "
            "`.venv/bin/python bench/bench_memory.py`. Peak RSS from GNU time.\n\n"
            "| size (H x W x C x F) | stage | measured | model | model / measured | time |\n|---|---|---|---|---|---|\n"
            + "\n".join(rows) + "\n")
    args.out.write_text(text)


if __name__ == "__main__":
    main()
