"""The CUDA path, measured end to end: the demo scene rendered to a chosen convergence, encoded
and viewed, each stage a `holo` subprocess on the chosen device; prints per stage the seconds, the peak host
RSS, the peak GPU memory (nvidia-smi, when there is one) and the ratio to the CPU figures of
bench/results/cpu_fullscale.json (only where the size is the same). Run through bench/device_check.sh, which
sets up the environment; ``--dry-run`` is the same sequence at 96x128, 2 frames, on the CPU.

Convergence: the plan states the Monte Carlo noise-to-signal power r at the farthest image point for its rays
per pixel N (noise ~ 1/N, docs/design.md §4); a signal share s = 1 / (1 + r) of ``--convergence`` needs
N' = N r / (1/s - 1) rays per pixel (80%: r = 0.25).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


class GpuMemory:
    """Peak used GPU memory (MiB) over a stage, polled from nvidia-smi every 0.2 s (None without one)."""

    def __init__(self) -> None:
        self.exe = shutil.which("nvidia-smi")
        self.peak = None
        self._stop = threading.Event()
        self._t = None

    def _read(self):
        try:
            out = subprocess.run([self.exe, "--query-gpu=memory.used", "--format=csv,noheader,nounits"],
                                 capture_output=True, text=True, timeout=5).stdout
            return max(float(v) for v in out.split())
        except Exception:  # noqa: BLE001 - a missed reading is no failure of the check
            return None

    def __enter__(self):
        if self.exe:
            base = self._read()
            self.base = base

            def poll():
                while not self._stop.wait(0.2):
                    v = self._read()
                    if v is not None:
                        self.peak = v if self.peak is None else max(self.peak, v)

            self._t = threading.Thread(target=poll, daemon=True)
            self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self._t:
            self._t.join()


def stage(name: str, argv: list[str], env: dict) -> dict:
    """Run one `holo` stage; its seconds, peak RSS (from the kernel's rusage of the child) and GPU memory."""
    cmd = [sys.executable, "-m", "holo", *argv]
    print(f"[{name}] {' '.join(cmd[2:])}", flush=True)
    with GpuMemory() as gpu:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, cwd=REPO)
        _, status, ru = os.wait4(proc.pid, 0)
        secs = time.perf_counter() - t0
    rc = os.waitstatus_to_exitcode(status)
    if rc != 0:
        raise SystemExit(f"[{name}] failed with exit status {rc}")
    return {"stage": name, "seconds": secs, "peak_rss_mb": ru.ru_maxrss / 1024, "gpu_peak_mb": gpu.peak}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dry-run", action="store_true", help="96x128, 2 frames, CPU, a few iterations")
    ap.add_argument("--device", default=None, help="cpu | cuda | auto (default: cuda; cpu for --dry-run)")
    ap.add_argument("--resolution", default=None, help="HxW (default 1080x1920; 96x128 for --dry-run)")
    ap.add_argument("--frames", type=int, default=None, help="default 24; 2 for --dry-run")
    ap.add_argument("--convergence", type=float, default=0.8, help="signal share of the farthest image point")
    ap.add_argument("--max-spp", type=int, default=None, help="cap on rays per pixel (default none; 8 dry)")
    ap.add_argument("--iterations", type=int, default=None, help="SGD iterations (default: the default encode's; "
                                                                 "2 dry)")
    ap.add_argument("--work", type=Path, default=None, help="folder for the scene and files (default: a temp one)")
    ap.add_argument("--out-json", type=Path, default=None, help="where to write the figures (default: $OUT/"
                                                                "device_check.json if OUT is set, else the work folder)")
    args = ap.parse_args()
    dry = args.dry_run
    device = args.device or ("cpu" if dry else "cuda")
    res = args.resolution or ("96x128" if dry else "1080x1920")
    frames = args.frames or (2 if dry else 24)
    iters = args.iterations if args.iterations is not None else (2 if dry else None)
    max_spp = args.max_spp or (8 if dry else None)
    if not 0.0 < args.convergence < 1.0:
        raise SystemExit("--convergence must be in (0, 1)")
    import tempfile

    work = args.work or Path(tempfile.mkdtemp(prefix="holo-device-check-"))
    work.mkdir(parents=True, exist_ok=True)
    from holocore.scene.demo import write_demo_scene

    scene = write_demo_scene(work / "scene").parent
    env = {**os.environ, "HOLO_DEVICE": device, "PYTHONUNBUFFERED": "1",
           "PYTHONPATH": os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])}
    common = ["--resolution", res, "--frames", str(frames)]

    # rays per pixel for the asked-for convergence, from the plan's own noise figure
    plan = json.loads(subprocess.run([sys.executable, "-m", "holo", "plan", str(scene), "--json", "--preset", "fast",
                                      *common], env=env, cwd=REPO, capture_output=True, text=True,
                                     check=True).stdout)["plan"]
    ratio = float(plan["noise_to_signal"])
    target = 1.0 / args.convergence - 1.0
    spp = max(1, math.ceil(plan["spp"] * ratio / target))
    if max_spp:
        spp = min(spp, max_spp)
    reached = 1.0 / (1.0 + plan["spp"] * ratio / spp)
    print(f"plan: {plan['spp']} rays/px give noise {ratio:.3g}x signal; {spp} rays/px for "
          f"{100 * reached:.2g}% convergence (asked {args.convergence:.0%})", flush=True)

    result, stack, png = work / "RESULT.npz", work / "STACK.npz", work / "view.png"
    rows = [stage("render", ["render", str(scene), "--out", str(result), "--preset", "fast", "--spp", str(spp),
                             "--device", device, *common], env)]
    from holocore.io import read_npz_meta

    meta = read_npz_meta(result)
    rows[-1]["rays"] = meta["stats"]["rays"]
    rows[-1]["device"] = meta.get("device")
    rows[-1]["variant"] = meta["versions"]["variant"]
    rows.append(stage("encode", ["encode", str(result), "--out", str(stack), "--device", device,
                                 *([] if iters is None else ["--iterations", str(iters)])], env))
    smeta = read_npz_meta(stack)
    enc = smeta.get("encoder") or {}
    done = int(enc.get("iterations") or iters or 0)
    from holocore.plan.encode_steps import rule

    per_iteration = rule(enc.get("optimiser") or "adam").cost  # the CPU reference times Adam's iterations
    rows[-1]["iterations"] = done
    ana = meta.get("analysis") or {}
    z = 0.5 * (float(ana.get("z_near_holo_m") or meta["z_inf_m"]) + float(ana.get("z_far_holo_m") or meta["z_inf_m"]))
    rows.append(stage("view", ["view", str(stack), "--focus-mm", f"{z * 1e3:.4f}", "--pupil-mm", "4", "--out", str(png),
                               "--device", device], env))

    ref = json.loads((REPO / "bench" / "results" / "cpu_fullscale.json").read_text())
    H, W = (int(v) for v in res.split("x"))
    same = list(ref["size"]) == [H, W, len(meta["wavelengths_m"]), frames]
    cpu = {"render": ref["render_s"] * (rows[0]["rays"] / ref["render_rays"]),  # the CPU at these rays
           "encode": ref["encode_s_per_iteration"] * per_iteration * done, "view": ref["view_s"]}
    total = sum(r["seconds"] for r in rows)
    print(f"\ndevice check: {res} x {len(meta['wavelengths_m'])} colors x {frames} frames on {device} "
          f"({rows[0]['variant']}), {spp} rays/px ({100 * reached:.2g}% convergence), {done} SGD iteration(s)")
    print(f"{'stage':8} {'seconds':>9} {'host RSS MB':>12} {'GPU MB':>8} {'CPU s (same work)':>18} {'CPU / this':>11}")
    for r in rows:
        c = cpu[r["stage"]] if same else None
        r["cpu_seconds_same_work"] = c
        r["speedup_vs_cpu"] = (c / r["seconds"]) if c else None
        gpu = f"{r['gpu_peak_mb']:.0f}" if r["gpu_peak_mb"] is not None else "-"
        c_txt = f"{c:.0f}" if c else "-"
        x_txt = f"{c / r['seconds']:.1f}x" if c else "-"
        print(f"{r['stage']:8} {r['seconds']:9.1f} {r['peak_rss_mb']:12.0f} {gpu:>8} {c_txt:>18} {x_txt:>11}")
    print(f"{'total':8} {total:9.1f}" + ("" if same else "   (CPU ratios only at the reference size "
                                         f"{'x'.join(map(str, ref['size']))})"))
    doc = {"dry_run": dry, "device": device, "size": [H, W, len(meta["wavelengths_m"]), frames], "spp": spp,
           "convergence": reached, "iterations": done, "total_seconds": total, "stages": rows,
           "cpu_reference": ref}
    out = args.out_json or (Path(os.environ["OUT"]) / "device_check.json" if os.environ.get("OUT")
                            else work / "device_check.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=1))
    print(f"figures -> {out}")


if __name__ == "__main__":
    main()
