"""Does a render pass cost in proportion to its rays? The paper display's mirror scene rendered twice at one size,
with few and with many rays per recording-plane pixel, in one run; the rays' part of the trace (ray generation,
tracing, accumulation: the render's ``timings["trace_s"]`` less the recording planes' chain and equaliser), the
chain, and the whole render are compared with the ratio of rays. A ratio well under the rays' ratio is fixed cost
per pass (set-up, transfers) that a time-limited render pays again with every pass.

    .venv/bin/python bench/bench_pass_scaling.py [--resolution 540x960] [--frames 24] [--spp 16,128]
        [--repeats 2] [--device cpu] [--out bench/results/pass_scaling.md]

Each render is run ``repeats`` times, interleaved (few, many, few, many), and its best time kept, so that a
slow spell of a shared machine costs both alike; the first render of the process (Dr.Jit's kernel compilation)
is a warm-up and not counted.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _machine() -> str:
    cpu = platform.machine()
    try:
        cpu = next(ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                   if ln.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{cpu}, {os.cpu_count()} cores"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", default="540x960")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--spp", default="16,128", help="two ray counts per recording-plane pixel: few,many")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", type=Path, default=REPO / "bench/results/pass_scaling.md")
    args = ap.parse_args()
    os.environ["HOLO_DEVICE"] = args.device
    H, W = (int(v) for v in args.resolution.split("x"))
    few, many = (int(v) for v in args.spp.split(","))

    from holocore.display.profiles import PAPER
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.load import load_scene
    from holocore.scene.paper import write_paper_scene

    loaded = load_scene(write_paper_scene("mirror", Path("/tmp/pass_scaling") / "mirror"))
    optics = PAPER.optics(resolution_hw=(H, W), frames=args.frames, z_inf_mm=4.0)

    def render(spp: int) -> dict:
        t0 = time.perf_counter()
        res = render_loaded(loaded, optics, RenderOptions(preset="fast", spp=spp), display=PAPER)
        t = {"total_s": time.perf_counter() - t0, **res.meta["timings"]}
        # trace_s holds the recording planes' chain and equaliser, which run once per render whatever its passes
        t["rays_s"] = t["trace_s"] - t.get("planes_propagate_s", 0.0) - t.get("equalise_s", 0.0)
        return t

    render(few)  # warm-up: kernel compilation, caches
    best: dict[int, dict] = {}
    for _ in range(args.repeats):
        for spp in (few, many):
            t = render(spp)
            if spp not in best or t["total_s"] < best[spp]["total_s"]:
                best[spp] = t
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    rays = many / few
    lines = [f"# Render pass cost against its rays ({time.strftime('%Y-%m-%d %H:%M')})", "",
             f"Machine: {_machine()}, {args.device}; load average after the runs {load}. Mirror scene, paper display, "
             f"{H}x{W} x 3 colours x {args.frames} frames, preset fast, {few} and {many} rays per recording-plane "
             f"pixel, best of {args.repeats} interleaved runs each (`python bench/bench_pass_scaling.py "
             f"--resolution {args.resolution} --frames {args.frames} --spp {args.spp}`).", "",
             f"| stage | {few} rays (s) | {many} rays (s) | ratio (rays: {rays:g}x) |", "|---|---|---|---|"]
    for key in ("rays_s", "planes_propagate_s", "equalise_s", "trace_s", "propagate_s", "total_s"):
        a, b = best[few].get(key), best[many].get(key)
        if a is None or b is None:
            continue
        lines.append(f"| {key} | {a:.1f} | {b:.1f} | {b / a:.2f} |")
    ratio = best[many]["rays_s"] / best[few]["rays_s"]
    whole = best[many]["trace_s"] / best[few]["trace_s"]
    fixed = (rays * best[few]["rays_s"] - best[many]["rays_s"]) / (rays - 1)
    lines += ["", f"The rays' part of the trace (rays_s: trace_s without the recording planes' chain and equaliser, "
              f"which run once per render however many passes a time-limited render takes) costs {ratio:.2f}x for "
              f"{rays:g}x the rays, {ratio / rays:.0%} of proportional (the goal: 85-115%); a fixed "
              f"{fixed:.1f} s of it does not grow with the rays. The whole trace_s: {whole:.2f}x."]
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
