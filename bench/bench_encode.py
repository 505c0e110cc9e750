"""Encoder benchmarks: one SGD iteration against its FFT floor, error
against iterations, and the peak RSS of `holo encode` at the paper's 1080x1920 x 3 x 24.

    python bench/bench_encode.py floor  [--hw 1080x1920] [--frames 2] [--z-mm 85] [--repeats 3]
    python bench/bench_encode.py error  [--hw 1080x1920] [--frames 1] [--iterations 400] [--z-mm 85] [--optimiser lbfgs]
    python bench/bench_encode.py rss    [--frames 24] [--iterations 3] [--workdir /tmp/enc_rss]

floor: the same run times (a) one iteration of the optimiser (Adam, and L-BFGS) on a block of ``frames`` frames of one
color, (b) the FFT work it needs, two bare batched fft2 + ifft2 pairs (forward and adjoint) on the encoder's
padded grid, (c) the same on the 2x grid of docs/design.md §5, and (d) the FFT work of (b) done as pruned 1-D FFTs
(row FFTs of the H nonzero input rows only, row FFTs of the H kept output rows only); (a) again without
``holocore.runtime.heap.heap_reuse`` and (b) again under it; interleaved, best of ``repeats``.
error: E (and the field SNR 10 log10((1-E)/E)) every 10 iterations with no stop rule, where the 0.05 dB rule
stops, for both supervisions. rss: writes a synthetic RESULT (a random smooth complex field; no render) and
runs `holo encode` under /usr/bin/time -v. Run one at a time; each prints a markdown block.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from holocore.encode.block import encode_block  # noqa: E402
from holocore.encode.lbfgs import optimise_lbfgs  # noqa: E402
from holocore.encode.sgd import Operator, optimise, spread_px  # noqa: E402
from holocore.optics.propagation import asm, padded_shape  # noqa: E402
from holocore.runtime.heap import heap_reuse  # noqa: E402
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


def floor(args) -> None:
    hw = tuple(int(v) for v in args.hw.split("x"))
    z, lam = args.z_mm * 1e-3, LAMS[0]  # the widest cone: the largest spread and grid
    t = _target(args.frames, hw, lam)
    op = Operator(hw, z, lam, P, cone=True, device=torch.device("cpu"))
    g2 = padded_shape(hw, 2)
    x_own = torch.randn(args.frames, op.hp, op.wp, dtype=torch.complex64)
    x_2x = torch.randn(args.frames, *g2, dtype=torch.complex64)
    with torch.no_grad():
        u0 = op(t, adjoint=True)
        tb = op(u0)
        tb = tb / tb.abs().square().sum(dim=(-2, -1), keepdim=True).sqrt()
        phi0 = torch.angle(u0)
    lit = np.ones(args.frames, bool)

    def one_iteration(fn=optimise):  # (11 iterations - 1) / 10: set-up excluded, one stop-rule check included
        def run(n):
            fn(phi0, tb, op, lit=lit, iterations=n, lr=0.2, stop_db=0.0, tol=None, efficiency_weight=0.0)

        t0 = time.perf_counter()
        run(1)
        t1 = time.perf_counter()
        run(11)
        return ((time.perf_counter() - t1) - (t1 - t0)) / 10

    def pairs(x):
        for _ in range(2):  # forward and adjoint
            torch.fft.ifft2(torch.fft.fft2(x))

    x_win = torch.randn(args.frames, *hw, dtype=torch.complex64)

    def pruned():  # the same transforms from 1-D FFTs that skip the zero rows and the cropped-away rows
        for _ in range(2):
            s = torch.fft.fft(torch.fft.fft(x_win, n=op.wp, dim=-1), n=op.hp, dim=-2)  # H nonzero rows only
            torch.fft.fft(torch.fft.fft(s, dim=-2)[..., :hw[0], :], dim=-1)  # only the H rows kept

    x_pocket = x_own.numpy().copy()

    def pocket():  # the same transforms by scipy's pocketfft, in place: no output to allocate or fault in
        import scipy.fft

        for _ in range(2):
            scipy.fft.ifft2(scipy.fft.fft2(x_pocket, overwrite_x=True, workers=torch.get_num_threads()),
                            overwrite_x=True, workers=torch.get_num_threads())

    def pairs_heap():  # the same with the allocator setting the optimiser runs under (runtime.heap.heap_reuse)
        with heap_reuse():
            pairs(x_own)
            t0 = time.perf_counter()
            pairs(x_own)
            return time.perf_counter() - t0

    def asm_steps():  # two of the render's ASM steps (propagation.asm, the reach grid: pad, 2 fft2, multiply,
        # crop) under the allocator setting the render's propagations run under; the second pair timed
        with torch.no_grad(), heap_reuse():
            for k in range(2):
                t0 = time.perf_counter()
                for _ in range(2):
                    asm(x_win, z, lam, P, grid=(op.hp, op.wp))
            return time.perf_counter() - t0

    def iteration_mmap():  # the optimiser without heap_reuse: every FFT output on fresh pages
        with mock.patch("holocore.encode.sgd.heap_reuse", lambda enabled=True: contextlib.nullcontext()):
            return one_iteration()

    best = {k: math.inf for k in ("iter", "iter_lbfgs", "iter_mmap", "asm", "own", "own_heap", "pocket", "2x",
                                  "pruned")}
    one_iteration(), one_iteration(optimise_lbfgs), pairs(x_own), pairs(x_2x), pruned(), pocket(), asm_steps()
    for _ in range(args.repeats):
        best["iter"] = min(best["iter"], one_iteration())
        best["iter_lbfgs"] = min(best["iter_lbfgs"], one_iteration(optimise_lbfgs))
        best["iter_mmap"] = min(best["iter_mmap"], iteration_mmap())
        best["own_heap"] = min(best["own_heap"], pairs_heap())
        best["asm"] = min(best["asm"], asm_steps())
        for key, fn in (("own", lambda: pairs(x_own)), ("2x", lambda: pairs(x_2x)), ("pruned", pruned),
                        ("pocket", pocket)):
            t0 = time.perf_counter()
            fn()
            best[key] = min(best[key], time.perf_counter() - t0)
    r = spread_px(z, lam, P)
    print(f"### Iteration vs FFT floor ({time.strftime('%Y-%m-%d %H:%M')}, {_machine()}, load average "
          f"{' '.join(f'{v:.2f}' for v in os.getloadavg())})\n")
    print(f"{hw[0]}x{hw[1]}, {args.frames} frame(s) of one color ({lam * 1e9:.1f} nm), z_wrp {args.z_mm} mm: "
          f"spread r = {r} px, encoder grid {op.hp}x{op.wp} (2x grid {g2[0]}x{g2[1]})\n")
    print("| | seconds | per frame | / floor on own grid | / same, heap reuse | / pocketfft in place "
          "| / floor on 2x grid |\n|---|---|---|---|---|---|---|")
    for key, name in (("iter", "one SGD iteration"), ("iter_lbfgs", "one L-BFGS iteration (--optimiser lbfgs)"),
                      ("iter_mmap", "one SGD iteration without heap reuse"),
                      ("asm", "two ASM steps of the render (propagation.asm on the same grid, heap reuse)"),
                      ("own", "floor: 2 x (fft2 + ifft2), own grid"),
                      ("own_heap", "floor: the same under heap reuse"),
                      ("pocket", "floor: the same by scipy's pocketfft, in place"),
                      ("pruned", "pruned: the same from 1-D FFTs (zero rows skipped)"),
                      ("2x", "floor: 2 x (fft2 + ifft2), 2x grid")):
        v = best[key]
        print(f"| {name} | {v:.3f} | {v / args.frames:.3f} | {v / best['own']:.2f} | {v / best['own_heap']:.2f} "
              f"| {v / best['pocket']:.2f} | {v / best['2x']:.2f} |")
    print(json.dumps({"hw": hw, "frames": args.frames, "grid": [op.hp, op.wp], "best_s": best}))


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
    ap.add_argument("what", choices=("floor", "error", "rss"))
    ap.add_argument("--hw", default="1080x1920")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--colors", type=int, default=1)
    ap.add_argument("--z-mm", type=float, default=85.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--iterations", type=int, default=None)
    ap.add_argument("--lr", type=float, default=0.2)
    ap.add_argument("--optimiser", default="adam", choices=("adam", "lbfgs"))
    ap.add_argument("--warm", action="store_true")
    ap.add_argument("--memory-limit-gb", type=float, default=8.0)
    ap.add_argument("--workdir", default="/tmp/enc_rss")
    args = ap.parse_args()
    if args.frames is None:
        args.frames = {"floor": 2, "error": 1, "rss": 24}[args.what]
    if args.iterations is None:
        args.iterations = {"floor": 1, "error": 400, "rss": 3}[args.what]
    {"floor": floor, "error": error, "rss": rss}[args.what](args)


if __name__ == "__main__":
    main()
