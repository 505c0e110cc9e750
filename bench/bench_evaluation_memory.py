"""Peak RSS and output bytes of a job's evaluate step (`holo evaluate`, as service/workers/evaluation.py runs it:
the cells at the sweep's depths with their PNG pairs, and for more than one frame the viewer score) on the demo
scene at a few SLM sizes, beside the model (holocore.plan.memory_estimate.evaluation_bytes and
service.evaluation_rules.evaluation_output_bytes). Writes bench/results/evaluation_memory.md. Usage:
``.venv/bin/python bench/bench_evaluation_memory.py [--sizes 352x480x1,540x960x1,720x1280x1]`` (H x W x frames,
3 colours). The stack is a short render (fast preset, 4 spp) and a DPAC encode: the evaluation's cost does not
depend on how good the hologram is; the ground truth takes the service's own GT_SPP."""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def peak_rss(cmd: list[str]) -> tuple[int, float]:
    """(peak RSS bytes, seconds) of a command, from GNU time."""
    out = subprocess.run(["/usr/bin/time", "-f", "%M %e", *cmd], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"{cmd[:3]} failed: {out.stderr[-2000:]}")
    kb, secs = out.stderr.strip().splitlines()[-1].split()
    return int(kb) * 1024, float(secs)


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="352x480x1,540x960x1,720x1280x1")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "evaluation_memory.md")
    ap.add_argument("--table-only", action="store_true", help="rewrite the table from the measurements kept beside "
                                                               "it (after a change of the model), measuring nothing")
    args = ap.parse_args()
    raw_path = args.out.with_suffix(".json")
    if args.table_only:
        raw = json.loads(raw_path.read_text())
    else:
        raw = {"machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.node()}",
               "date": datetime.date.today().isoformat(), "runs": measure(args.sizes)}
        raw["load_after"] = round(os.getloadavg()[0], 2)
        raw_path.write_text(json.dumps(raw, indent=1))
    write_table(raw, args.out)


def measure(sizes: str) -> list[dict]:
    from holocore.formats.hashing import file_sha256
    from holocore.formats.npz import read_npz_meta
    from holocore.scene.demo import write_demo_scene
    from service.workers.evaluation import cells_args, plan_evaluation, viewer_args

    holo = [sys.executable, "-m", "holo"]
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        write_demo_scene(t / "scene")
        for size in sizes.split(","):
            h, w, f = (int(v) for v in size.split("x"))
            job = t / f"job{size}"
            job.mkdir()
            r, s = t / f"r{size}.npz", job / "stack.npz"
            subprocess.run([*holo, "render", str(t / "scene"), "--out", str(r), "--resolution", f"{h}x{w}",
                            "--frames", str(f), "--preset", "fast", "--spp", "4"], check=True, capture_output=True)
            subprocess.run([*holo, "encode", str(r), "--out", str(s), "--method", "dpac"], check=True,
                           capture_output=True)
            r.unlink()
            plan = plan_evaluation(job, read_npz_meta(s), shape_hw=(h, w), frames=f, stack_sha256=file_sha256(s))
            out = job / "evaluation"
            out.mkdir()
            got = [("cells", *peak_rss([*holo, *cells_args(s, str(t / "scene"), out, plan, str(job / "p.jsonl"))]))]
            if plan.viewer:
                got.append(("viewer", *peak_rss([*holo, *viewer_args(s, str(t / "scene"), out, plan,
                                                                     str(job / "p.jsonl"))])))
            disk = folder_bytes(out)
            for part, peak, secs in got:
                runs.append({"h": h, "w": w, "frames": f, "run": part, "depths": len(plan.scored), "views": plan.views,
                             "peak_rss": peak, "seconds": secs, "output_bytes": disk, "load": os.getloadavg()[0]})
                print(runs[-1], flush=True)
    return runs


def write_table(raw: dict, out: Path) -> None:
    from holocore.plan.memory_estimate import evaluation_bytes
    from service.evaluation_rules import evaluation_output_bytes

    rows = []
    for r in raw["runs"]:
        h, w, f, peak = r["h"], r["w"], r["frames"], r["peak_rss"]
        pred = evaluation_bytes(height_px=h, width_px=w, colors=3, frames=f)
        pred_disk = evaluation_output_bytes(height_px=h, width_px=w)
        rows.append(f"| {h}x{w}x3x{f} | {r['run']} ({r['depths']} depths, {r['views']}x{r['views']} views) "
                    f"| {peak / 1e6:.0f} MB | {pred / 1e6:.0f} MB | {pred / peak:.2f} | {r['seconds']:.0f} s | "
                    f"{r['load']:.2f} | {r['output_bytes'] / 1e6:.1f} MB | {pred_disk / 1e6:.1f} MB |")
    text = (f"# Peak memory and output of the evaluate step vs the model\n\n{raw['machine']}, {raw['date']}; "
            "load: the 1-minute load average as each run ended (the runs themselves use both cores); "
            "demo scene, stack from a fast 4-spp render and a DPAC encode; "
            "`holo evaluate` with the service's arguments (service/workers/evaluation.py: GT_SPP samples, the "
            "sweep's depths, 3 x 3 views, PNG pairs). Peak RSS from GNU time; output: the evaluation folder's "
            "bytes. `.venv/bin/python bench/bench_evaluation_memory.py`.\n\n"
            "| size (H x W x C x F) | run | peak RSS | model | model / measured | time | load | output | output model |\n"
            "|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
            + "".join(f"\n{note}\n" for note in raw.get("notes", [])))
    out.write_text(text)


if __name__ == "__main__":
    main()
