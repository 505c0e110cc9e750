"""Several wave recording planes vs one: rays for equal SLM-field accuracy on the demo scene.

For each plane count K (1, 2, 3 and auto) and rays per pixel N, two renders that differ only in the rays' seed
(the same random-phase bank) give two independent Monte Carlo estimates U_a, U_b of the same SLM field. Their
cross product estimates the signal energy S = Re<U_a, U_b> without bias, half their squared difference the
noise energy E|U - <U>|^2, so the field's signal-to-noise ratio S / noise needs no converged reference. Noise
falls as 1/N, so the rays a configuration needs for a target accuracy are K N x target / SNR, and the ratio
of those rays between one plane and K planes is the figure of merit (goal >= 8x). The correlation of the
one-plane and K-plane means, Re<U_1, U_K> / sqrt(S_1 S_K), says whether they estimate the same field.

    python bench/bench_wrp_planes.py [--resolution 270x480] [--spp 16,64] [--spp-one 256,1024] [--out bench/results/wrp_planes.md]
"""

from __future__ import annotations

import argparse
import datetime
import math
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _snr(ua: np.ndarray, ub: np.ndarray) -> float:
    """Signal / noise energy of a field from two independent estimates (see the module docstring)."""
    noise = float(np.sum(np.abs(ua - ub) ** 2) / 2)
    return float(np.real(np.vdot(ua, ub))) / noise if noise > 0 else math.inf


def _signal(ua: np.ndarray, ub: np.ndarray) -> float:
    return float(np.real(np.vdot(ua, ub)))


def _db(x: float) -> float:
    return 10 * math.log10(x) if x > 0 else -math.inf


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="270x480")
    ap.add_argument("--spp", default="16,64")
    ap.add_argument("--spp-one", default=None, help="rays per pixel for the one-plane rows (default: --spp)")
    ap.add_argument("--planes", default="1,2,3,auto")
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)

    from holocore.display.profiles import display_optics, load_display
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.demo import write_demo_scene
    from holocore.scene.load import load_scene

    H, W = (int(v) for v in a.resolution.lower().split("x"))
    optics = display_optics(load_display("paper"), overrides={"resolution_hw": (H, W), "frames": a.frames})
    tmp = Path(tempfile.mkdtemp(prefix="holo-bench-planes-"))
    loaded = load_scene(write_demo_scene(tmp / "scene"))
    plane_opts = [p if p == "auto" else int(p) for p in a.planes.split(",")]
    spps = [int(s) for s in a.spp.split(",")]
    spps_one = [int(s) for s in a.spp_one.split(",")] if a.spp_one else spps
    rows, means = [], {}
    for K in plane_opts:
        for n in (spps_one if K == 1 else spps):
            slm, wrp, secs = [], [], []
            for seed in (1, 2):
                t0 = time.perf_counter()
                # signal-only equaliser (C3): a fixed linear filter, so the two seeds' noise is the estimator's
                r = render_loaded(loaded, optics, RenderOptions(preset=a.preset, spp=n, wrp_planes=K, ray_seed=seed,
                                                                equalise_noise=False))
                secs.append(time.perf_counter() - t0)
                slm.append(r.slm_field.astype(np.complex128))
                wrp.append(r.wrp_field.astype(np.complex128))
            snr, snr_wrp = _snr(*slm), _snr(*wrp)
            planes = r.meta["wrp_planes_m"]
            rows.append(dict(K=K, planes=len(planes), n=n, snr=snr, snr_wrp=snr_wrp, S=_signal(*slm), rays=r.meta["stats"]["rays"],
                             seconds=min(secs), at=[(z - optics.z_inf_m) * 1e3 for z in planes]))
            means.setdefault(K, []).append((slm[0] + slm[1]) / 2)
            print(f"K={K!s:>4} ({len(planes)} planes) N={n:4d}: SLM SNR {_db(snr):6.2f} dB, WRP SNR "
                  f"{_db(snr_wrp):6.2f} dB, rays {rows[-1]['rays']:.3g}, {min(secs):.1f} s", flush=True)
    ref = means[plane_opts[0]][-1]  # the one-plane mean at the most rays
    lines = ["# Several wave recording planes: rays for equal SLM-field accuracy",
             "", f"Machine: {platform.machine()}, {platform.processor() or 'cpu'}, Python {platform.python_version()}; "
             f"{datetime.date.today()}. Demo scene (`holo demo`), paper display (f = 50 mm, 8 µm, 640/516.5/455.4 nm, "
             f"z_inf 80 mm) at {H}x{W}, {a.frames} frames, preset {a.preset}.",
             "", "SNR: signal energy / noise energy of the SLM field from two ray seeds (see the script's docstring); "
             "rays per 1 of SNR: total traced rays / SNR (lower is better; noise falls as 1/rays).", "",
             "| planes asked | planes (z - z_inf, mm) | N per pixel | rays | SLM SNR (dB) | WRP SNR (dB) | "
             "rays per unit SLM SNR | gain vs 1 plane | correlation with 1 plane | seconds |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    # The one-plane figure with the most rays is the trustworthy one (when noise swamps the signal, the cross
    # product's own noise biases S); every row is compared with it.
    one = max((r for r in rows if r["K"] == plane_opts[0]), key=lambda r: r["rays"])
    base_cost = one["rays"] / one["snr"]
    for r, m in zip(rows, [m for K in plane_opts for m in means[K]]):
        cost = r["rays"] / r["snr"]
        # noise-corrected: <mean_1, mean_K> / sqrt(S_1 S_K), S the unbiased signal energies (1: the same field)
        corr = float(np.real(np.vdot(ref, m)) / math.sqrt(max(1e-300, one["S"] * r["S"])))
        lines.append(f"| {r['K']} | {r['planes']} ({', '.join(f'{z:.2f}' for z in r['at'])}) | {r['n']} | "
                     f"{r['rays']:.3g} | {_db(r['snr']):.2f} | {_db(r['snr_wrp']):.2f} | {cost:.3g} | "
                     f"{base_cost / cost:.1f}x | {corr:.3f} | {r['seconds']:.1f} |")
    lines += ["", "Correlation: Re<mean_1, mean_K> / sqrt(S_1 S_K) with the one-plane mean at its most rays; the "
              "noise of the means cancels in expectation, so 1 means the same field (its own scatter is about "
              "1 / sqrt(SNR x pixels))."]
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        Path(a.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
