"""One encoder iteration and one ASM step against the FFT floor: the fastest bare transforms this machine offers.

    python bench/bench_floor.py [--hw 1080x1920] [--frames 12] [--z-mm 85] [--repeats 5]

On ``frames`` frames of one color (640 nm: the widest cone, the largest encoder grid) it times, interleaved,
best of ``repeats``:
- one iteration of each optimiser (Adam, L-BFGS): (11 iterations - 1) / 10, so the set-up is excluded and one
  stop-rule check included;
- two ASM steps of the render (``propagation.asm`` on the same grid under the heap reuse its propagations run
  under): the work of one iteration's forward and adjoint;
- the floor, the four whole-grid transforms an iteration needs (two forward and two inverse 2-D DFTs of the
  padded grid), by every library here: torch (MKL) with fresh outputs and on reused heap pages, scipy's
  pocketfft in place, and, where pyFFTW is installed (it is not a dependency of the project), FFTW in place
  (FFTW_MEASURE plans) batched over the frames, frame by frame, and one single-threaded plan per thread with
  the frames spread over the threads.
Each row is given over the fastest floor (best of the rounds), and paired: the median over the rounds of its time
over the fastest floor of the same round, which cancels the drift of a shared machine's speed between rounds.
Prints a markdown block and one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import scipy.fft
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

try:  # optional: FFTW's floors are timed where pyFFTW is installed
    import pyfftw
except ImportError:
    pyfftw = None

from bench.bench_encode import LAMS, P, _machine, _target  # noqa: E402
from holocore.encode.lbfgs import optimise_lbfgs  # noqa: E402
from holocore.encode.sgd import Operator, optimise  # noqa: E402
from holocore.optics.propagation import asm  # noqa: E402
from holocore.runtime.heap import heap_reuse  # noqa: E402

FLOORS = ("torch", "torch_heap", "pocketfft", "fftw_batched", "fftw_frames", "fftw_items")
NAMES = {
    "adam": "one Adam iteration",
    "lbfgs": "one L-BFGS iteration (the default optimiser)",
    "asm": "two ASM steps of the render (heap reuse)",
    "torch": "floor: torch fft2 + ifft2, x2, fresh outputs",
    "torch_heap": "floor: the same on reused heap pages",
    "pocketfft": "floor: scipy's pocketfft in place",
    "fftw_batched": "floor: FFTW in place, all frames in one plan",
    "fftw_frames": "floor: FFTW in place, frame by frame",
    "fftw_items": "floor: FFTW in place, one thread a frame, frames on all threads",
}


def _iteration(fn, phi0, tb, op, lit):
    def run(n):
        fn(phi0, tb, op, lit=lit, iterations=n, lr=0.2, stop_db=0.0, tol=None, efficiency_weight=0.0)

    def timed():
        t0 = time.perf_counter()
        run(1)
        t1 = time.perf_counter()
        run(11)
        return ((time.perf_counter() - t1) - (t1 - t0)) / 10
    return timed


def _floors(frames: int, hp: int, wp: int) -> dict:
    """The floor's four whole-grid transforms by each library (module docstring), as timed closures."""
    x = torch.randn(frames, hp, wp, dtype=torch.complex64)
    xn = x.numpy().copy()
    nt = torch.get_num_threads()

    def pairs():
        for _ in range(2):
            torch.fft.ifft2(torch.fft.fft2(x))

    def pairs_heap():
        with heap_reuse():
            pairs()
            t0 = time.perf_counter()
            pairs()
            return time.perf_counter() - t0

    def pocket():
        for _ in range(2):
            scipy.fft.ifft2(scipy.fft.fft2(xn, overwrite_x=True, workers=nt), overwrite_x=True, workers=nt)

    jobs = {"torch": _clock(pairs), "torch_heap": pairs_heap, "pocketfft": _clock(pocket)}
    return {**jobs, **_fftw(xn, nt)} if pyfftw is not None else jobs


def _fftw(xn: np.ndarray, nt: int) -> dict:
    """FFTW's floors: one plan over all frames, one plan run frame by frame (both on ``nt`` threads), and one
    single-threaded plan per thread with the frames spread over the threads."""
    frames, hp, wp = xn.shape
    big = pyfftw.empty_aligned((frames, hp, wp), dtype="complex64")
    one = pyfftw.empty_aligned((hp, wp), dtype="complex64")
    big[:], one[:] = xn, xn[0]
    plans = {"batched": _plan_pair(big, nt), "frames": _plan_pair(one, nt)}

    def fftw(kind, times):
        fwd, inv = plans[kind]
        for _ in range(2 * times):
            fwd.execute()
            inv.execute()
    return {"fftw_batched": _clock(lambda: fftw("batched", 1)), "fftw_frames": _clock(lambda: fftw("frames", frames)),
            "fftw_items": _items(frames, hp, wp, nt)}


def _plan_pair(buf: np.ndarray, threads: int) -> tuple:
    """In-place forward and inverse 2-D FFTW plans (FFTW_MEASURE) of ``buf`` on ``threads`` threads."""
    flags = dict(threads=threads, flags=("FFTW_MEASURE", "FFTW_DESTROY_INPUT"))
    return tuple(pyfftw.FFTW(buf, buf, axes=(-2, -1), direction=d, **flags) for d in ("FFTW_FORWARD", "FFTW_BACKWARD"))


def _items(frames: int, hp: int, wp: int, workers: int):
    """The floor item by item: one single-threaded plan per thread, frames spread over the
    threads (no thread pool inside a transform)."""
    plans = [_plan_pair(pyfftw.empty_aligned((hp, wp), dtype="complex64"), 1) for _ in range(workers)]
    pool = ThreadPoolExecutor(workers)

    def share(j):
        fwd, inv = plans[j]
        for _ in range(j, frames, workers):
            for _ in range(2):
                fwd.execute()
                inv.execute()
    return _clock(lambda: list(pool.map(share, range(workers))))


def _clock(fn):
    def timed():
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0
    return timed


def _asm_steps(frames: int, hw: tuple[int, int], z: float, lam: float, grid: tuple[int, int]):
    x_win = torch.randn(frames, *hw, dtype=torch.complex64)

    def timed():  # the second pair timed: the first faults the heap in
        with torch.no_grad(), heap_reuse():
            for _ in range(2):
                t0 = time.perf_counter()
                for _ in range(2):
                    asm(x_win, z, lam, P, grid=grid)
            return time.perf_counter() - t0
    return timed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--hw", default="1080x1920")
    ap.add_argument("--lam-nm", type=float, default=LAMS[0] * 1e9, help="the color (nm): its cone sets the grid")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--z-mm", type=float, default=85.0)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    hw = tuple(int(v) for v in args.hw.split("x"))
    z, lam = args.z_mm * 1e-3, args.lam_nm * 1e-9
    op = Operator(hw, z, lam, P, cone=True, device=torch.device("cpu"))
    t = _target(args.frames, hw, lam)
    with torch.no_grad():
        u0 = op(t, adjoint=True)
        tb = op(u0)
        tb = tb / tb.abs().square().sum(dim=(-2, -1), keepdim=True).sqrt()
        phi0 = torch.angle(u0)
    lit = np.ones(args.frames, bool)
    jobs = {"adam": _iteration(optimise, phi0, tb, op, lit), "lbfgs": _iteration(optimise_lbfgs, phi0, tb, op, lit),
            "asm": _asm_steps(args.frames, hw, z, lam, (op.hp, op.wp)), **_floors(args.frames, op.hp, op.wp)}
    for fn in jobs.values():  # warm-up: plans, heap pages
        fn()
    rounds = [{k: fn() for k, fn in jobs.items()} for _ in range(args.repeats)]
    best = {k: min(r[k] for r in rounds) for k in jobs}
    floors = [k for k in FLOORS if k in best]
    fastest = min(floors, key=lambda k: best[k])
    # the paired ratio: each round's time over the fastest floor of the same round (drift cancels), median
    paired = {k: statistics.median(r[k] / min(r[f] for f in floors) for r in rounds) for k in jobs}
    print(f"### Iteration and ASM step vs the FFT floor ({time.strftime('%Y-%m-%d %H:%M')}, {_machine()}, load "
          f"average {' '.join(f'{v:.2f}' for v in os.getloadavg())}, {torch.get_num_threads()} threads)\n")
    print(f"{hw[0]}x{hw[1]}, {args.frames} frames of one color ({lam * 1e9:.1f} nm), z_wrp {args.z_mm} mm, encoder "
          f"grid {op.hp}x{op.wp}; {args.repeats} interleaved rounds. The fastest floor (best of the rounds): "
          f"{NAMES[fastest]}. Paired: the median over rounds of the row's time over that round's fastest floor.\n")
    print("| | best s | / the fastest floor (best) | paired, median |\n|---|---|---|---|")
    for k, v in best.items():
        mark = "**" if k in ("adam", "lbfgs", "asm") else ""
        print(f"| {NAMES[k]} | {v:.3f} | {mark}{v / best[fastest]:.2f}{mark} | {mark}{paired[k]:.2f}{mark} |")
    print(json.dumps({"hw": hw, "frames": args.frames, "grid": [op.hp, op.wp], "fastest": fastest,
                      "best_s": best, "paired_median": paired, "rounds_s": rounds}))

if __name__ == "__main__":
    main()
