"""Encoder benchmarks: error against iterations, and the peak RSS of `holo encode` at the paper's 1080x1920 x 3
x 24. One iteration against the FFT floor: bench/bench_floor.py.

    python bench/bench_encode.py error  [--hw 1080x1920] [--frames 1] [--iterations 400] [--z-mm 85] [--optimiser lbfgs]
    python bench/bench_encode.py rss    [--frames 24] [--iterations 3] [--workdir /tmp/enc_rss]

error: E (and the field SNR 10 log10((1-E)/E)) every 10 iterations with no stop rule, where the 0.05 dB rule
stops, for both supervisions. rss: writes a synthetic RESULT (a random smooth complex field; no render) and
runs `holo encode` under /usr/bin/time -v. Run one at a time; each prints a markdown block.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from holocore.encode.block import encode_block  # noqa: E402
from holocore.trace.randomfield import random_field  # noqa: E402

P = 8e-6
LAMS = [640e-9, 516.5e-9, 455.4e-9]


def _target(frames: int, hw: tuple[int, int], lam: float, seed: int = 1) -> torch.Tensor:
    """A band-limited random-phase field (Eq. 4) times a smooth amplitude with a bright disc and a bar."""
    h, w = hw
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    amp = 0.3 + ((xx - 0.4) ** 2 + (yy - 0.25) ** 2 < 0.15 ** 2) + 0.6 * (xx > 0.7)
    return (random_field(frames, hw, lam, P, seed=seed) * torch.from_numpy(amp.astype(np.float32))).contiguous()


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__} ({torch.get_num_threads()} threads)"


def error(args) -> None:
    hw = tuple(int(v) for v in args.hw.split("x"))
    z = args.z_mm * 1e-3
    print(f"### Error vs iterations ({time.strftime('%Y-%m-%d')}, {_machine()})\n")
    print(f"{hw[0]}x{hw[1]}, {args.frames} frame(s), z_wrp {args.z_mm} mm, {args.optimiser} lr {args.lr}; "
          f"E = 1 - rho^2 under "
          f"each supervision, SNR = 10 log10((1-E)/E)\n")
    for lam in LAMS[: args.colors]:
        t = _target(args.frames, hw, lam)
        for sup in ("cone", "full"):
            t0 = time.perf_counter()
            full = encode_block("sgd", t, z_m=z, wavelength_m=lam, pitch_m=P, supervision=sup,
                                iterations=args.iterations, lr=args.lr, stop_db=0.0, optimiser=args.optimiser)
            secs = time.perf_counter() - t0
            stop = encode_block("sgd", t, z_m=z, wavelength_m=lam, pitch_m=P, supervision=sup,
                                iterations=args.iterations, lr=args.lr, stop_db=0.05, optimiser=args.optimiser)
            tr = np.array(full.trace[0])
            snr = 10 * np.log10((1 - tr) / tr)
            marks = [k for k in (10, 20, 50, 100, 200, 300, 400, 600, 800, 1000) if k <= len(tr) * 10]
            print(f"- {lam * 1e9:.1f} nm, {sup} supervision (naive start E = {full.loss_init[0]:.4f}, "
                  f"{10 * np.log10((1 - full.loss_init[0]) / full.loss_init[0]):.2f} dB; {secs:.0f} s for "
                  f"{args.iterations} iterations):")
            print("  " + ", ".join(f"{k}: E {tr[k // 10 - 1]:.4f} ({snr[k // 10 - 1]:.2f} dB)" for k in marks))
            e_stop = stop.loss_cone[0] if sup == "cone" else stop.loss_full[0]
            print(f"  0.05 dB rule stops at {int(stop.iterations[0])} iterations: E {e_stop:.4f} "
                  f"({10 * np.log10((1 - e_stop) / e_stop):.2f} dB); light in the cone "
                  f"{stop.efficiency[0]:.0%}, in the target {stop.efficiency_target[0]:.0%}")
    if args.warm:  # warm start of frame 1 from frame 0's solution vs the naive start
        lam = LAMS[1]
        t = _target(2, hw, lam)
        a = encode_block("sgd", t, z_m=z, wavelength_m=lam, pitch_m=P, iterations=100, stop_db=0.0)
        warm = encode_block("sgd", t[1:], z_m=z, wavelength_m=lam, pitch_m=P, iterations=100, stop_db=0.0,
                            init=torch.from_numpy(a.phase[:1]))
        print(f"- warm start, frame 1 from frame 0's phase: E at start {warm.loss_init[0]:.4f} vs naive "
              f"{a.loss_init[1]:.4f}; after 100 iterations {warm.loss_cone[0]:.4f} vs {a.loss_cone[1]:.4f}")


def rss(args) -> None:
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    result = work / "RESULT.npz"
    F, C, H, W = args.frames, 3, 1080, 1920
    if not result.exists():
        code = f"""
import numpy as np, torch
from holocore.io import save_result
F, C, H, W = {F}, {C}, {H}, {W}
rng = np.random.default_rng(0)
field = np.empty((F, C, H, W), np.complex64)
fy = np.fft.fftfreq(H)[:, None]; fx = np.fft.fftfreq(W)[None, :]
low = np.exp(-(fx ** 2 + fy ** 2) / (2 * 0.02 ** 2)).astype(np.float32)  # smooth: ~1/50 of the band
for f in range(F):
    for c in range(C):
        noise = (rng.standard_normal((H, W)) + 1j * rng.standard_normal((H, W))).astype(np.complex64)
        field[f, c] = np.fft.ifft(np.fft.ifft(np.fft.fft2(noise) * low, axis=0), axis=1) * 50
meta = {{"focal_length_m": 0.05, "z_inf_m": 0.08, "z_wrp_m": {args.z_mm * 1e-3}, "pitch_m": 8e-6,
        "wavelengths_m": [640e-9, 516.5e-9, 455.4e-9], "display_profile": "paper",
        "display": {{"name": "paper", "fourier_filter": True}}, "scene": "synthetic smooth random field"}}
save_result("{result}", slm_field=field, wrp_field=field, meta=meta)
"""
        subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
    out = work / "STACK.npz"
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "holo", "encode", str(result), "--out", str(out),
           "--iterations", str(args.iterations), "--stop-db", "0", "--optimiser", args.optimiser, "--device", "cpu",
           "--memory-limit-gb", str(args.memory_limit_gb)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    peak_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr).group(1))
    line = [ln for ln in proc.stderr.splitlines() if ln.startswith("encoded")]
    print(f"### Peak RSS of holo encode ({time.strftime('%Y-%m-%d')}, {_machine()})\n")
    print(f"RESULT {F}x{C}x{H}x{W} ({result.stat().st_size / 2**30:.2f} GiB), z_wrp {args.z_mm} mm, "
          f"{args.iterations} {args.optimiser} iteration(s), --memory-limit-gb {args.memory_limit_gb}: peak RSS "
          f"{peak_kb / 2**20:.2f} GiB, wall {wall:.0f} s, exit {proc.returncode}\n")
    print(line[0] if line else proc.stderr[-2000:])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("error", "rss"))
    ap.add_argument("--hw", default="1080x1920")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--colors", type=int, default=1)
    ap.add_argument("--z-mm", type=float, default=85.0)
    ap.add_argument("--iterations", type=int, default=None)
    ap.add_argument("--lr", type=float, default=0.2)
    ap.add_argument("--optimiser", default="adam", choices=("adam", "lbfgs"))
    ap.add_argument("--warm", action="store_true")
    ap.add_argument("--memory-limit-gb", type=float, default=8.0)
    ap.add_argument("--workdir", default="/tmp/enc_rss")
    args = ap.parse_args()
    if args.frames is None:
        args.frames = {"error": 1, "rss": 24}[args.what]
    if args.iterations is None:
        args.iterations = {"error": 400, "rss": 3}[args.what]
    {"error": error, "rss": rss}[args.what](args)


if __name__ == "__main__":
    main()
