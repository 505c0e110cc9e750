"""Measuring this machine: the rates of the time model (:func:`calibrate`, ``holo bench calibrate``) and a
probe of one scene before a render (:func:`probe_scene`, ``holo render --estimate``). Both run the renderer,
the encoder and the layer baseline, so they sit above the pipeline; the models they feed
(``holocore.plan.estimate``, ``holocore.plan.estimate_probe``) need none of it and stay in plan/."""

from __future__ import annotations

import math
import os
import platform
import time
from pathlib import Path
from typing import Any, Callable, Optional

from holocore.display.optics import OpticsConfig
from holocore.plan.estimate import CALIBRATION_VERSION, encode_work, features, machine_load
from holocore.plan.estimate_probe import PROBE_HW, Probe
from holocore.scene.load import load_scene

__all__ = ["calibrate", "probe_scene"]

_RUNS = (  # (H, W, preset, method, spp, frames)
    (48, 64, "balanced", "wrp", 16, 1), (48, 64, "balanced", "wrp", 64, 8), (96, 128, "balanced", "wrp", 16, 4),
    (96, 128, "balanced", "wrp", 48, 16), (48, 64, "fast", "wrp", 32, 4), (96, 128, "fast", "wrp", 16, 8),
    (96, 128, "fast", "wrp", 48, 1), (48, 64, "reference", "wrp", 16, 4), (96, 128, "reference", "wrp", 16, 8),
    (48, 64, "balanced", "direct", 64, 4), (96, 128, "balanced", "direct", 32, 16),
    (96, 128, "fast", "direct", 32, 8), (48, 64, "balanced", "wrp", 32, 24),
)


def _fit(rows: list[list[float]], y: list[float]):
    import numpy as np
    from scipy.optimize import nnls

    A = np.asarray(rows, dtype=np.float64)
    b = np.asarray(y, dtype=np.float64)
    scale = np.where(A.max(axis=0) > 0, A.max(axis=0), 1.0)
    coef, _ = nnls(A / scale, b)
    return coef / scale


def _best_of(repeats: int, fn: Callable[[], Any], seconds: Callable[[Any], float]) -> Any:
    """The run with the smallest time of ``repeats`` (timing noise on a shared machine only adds)."""
    best = None
    for _ in range(max(1, repeats)):
        out = fn()
        if best is None or seconds(out) < seconds(best):
            best = out
    return best


def calibrate(*, scene: Optional[str | Path] = None, quick: bool = False, repeats: int = 2,
              optics: Optional[dict] = None, progress: Optional[Callable[[str, int, int], None]] = None) -> dict:
    """Time small renders, encodings and layer baselines on ``scene`` (default: the demo scene) and fit the
    rates of the cost model; each run is repeated ``repeats`` times and the fastest kept. Returns a
    calibration dict (save it with :func:`save_calibration`).

    ``optics``: OpticsConfig fields every calibration run uses (z_inf_mm, focal_length_mm, pitch_um, ...; the
    runs set resolution, frames and seed). The cost of a ray depends on where it goes (a direct ray from an SLM
    80 mm away mostly leaves the field of view; from 4 mm it hits the scene), so calibrate with the optics the
    estimates are for."""
    if isinstance(repeats, bool) or not isinstance(repeats, int) or not 1 <= repeats <= 10:
        raise ValueError(f"repeats must be an integer in 1..10, got {repeats!r}")
    base = dict(optics or {})
    for k in ("resolution_hw", "frames", "seed"):
        base.pop(k, None)
    OpticsConfig(**base)  # refuse bad optics before anything runs
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        if scene is None:
            from holocore.scene.demo import write_demo_scene

            scene = write_demo_scene(Path(tmp) / "demo", fov_deg=10.0)
            label = "demo scene (holocore.scene.demo, 10 deg)"
        else:
            label = str(scene)
        loaded = load_scene(scene)
        primitives = sum(int(sh.primitive_count()) for sh in loaded.scene.shapes())
        runs = _RUNS[::2] if quick else _RUNS
        tick = (lambda n: progress("calibrate", n, len(runs) + 5)) if progress else (lambda n: None)
        samples = _render_samples(loaded, base, runs, repeats, tick)
        enc_samples = _encode_samples(repeats, lambda j: tick(len(runs) + j + 1))
        lay_samples = _layer_samples(loaded, base, repeats, lambda j: tick(len(runs) + 4 + j))
    import torch

    return {"version": CALIBRATION_VERSION, "created_unix": time.time(), "scene": label, "optics": base,
            "primitives": primitives,
            "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                        "cpus": os.cpu_count(), "torch_threads": torch.get_num_threads()},
            "repeats": repeats, "rates": _fit_rates(samples, enc_samples, lay_samples), "samples": samples}


def _render_samples(loaded, base: dict, runs, repeats: int, tick) -> list[dict]:
    """The timed renders of ``runs`` (each the fastest of ``repeats``), after one warm-up per preset and method
    that compiles every kernel (the first render of a process pays for it)."""
    from holocore.baselines.layers import render_layers
    from holocore.pipeline import RenderOptions, render_loaded

    for preset, method in {(r[2], r[3]) for r in runs}:
        render_loaded(loaded, OpticsConfig(**base, resolution_hw=(24, 32), frames=2, seed=1),
                      RenderOptions(preset=preset, method=method, spp=4))
    render_layers(loaded, OpticsConfig(**base, resolution_hw=(24, 32), frames=2), planes=2, spp=4)
    samples = []
    for i, (H, W, preset, method, spp, F) in enumerate(runs):
        optics = OpticsConfig(**base, resolution_hw=(H, W), frames=F, seed=i)
        options = RenderOptions(preset=preset, method=method, spp=spp)
        res = _best_of(repeats, lambda o=optics, op=options: render_loaded(loaded, o, op),
                       lambda r: r.meta["timings"]["total_s"])
        x = features(optics, options)
        samples.append({"H": H, "W": W, "preset": preset, "method": method, "spp": spp, "frames": F,
                        "features": {k: v for k, v in x.items() if k != "key"}, "key": x["key"],
                        "timings": res.meta["timings"], "trace_s": res.meta["stats"]["seconds_trace"],
                        "accumulate_s": res.meta["stats"]["seconds_accumulate"]})
        tick(i + 1)
    return samples


def _encode_samples(repeats: int, tick) -> list[dict]:
    """SGD encodings of random targets: two sizes near the SLM (a grid barely wider than the SLM) and one far
    from it (the 2x grid), with their work (iterations x the encoder's transforms, holocore.plan.estimate)."""
    import torch

    from holocore.encode.encoder import encode_sgd

    out = []
    lams = [640e-9, 516.5e-9, 455.4e-9]
    for j, (H, W, F, it, z) in enumerate(((48, 64, 4, 20, 1e-3), (96, 128, 8, 20, 1e-3), (96, 128, 4, 20, 40e-3))):
        g = torch.Generator().manual_seed(j)
        tgt = torch.polar(torch.rand((F, 3, H, W), generator=g), 6.3 * torch.rand((F, 3, H, W), generator=g))

        def enc(tgt=tgt, it=it, z=z) -> float:
            t0 = time.perf_counter()
            encode_sgd(tgt, z_wrp_m=z, wavelengths_m=lams, pitch_m=8e-6, iterations=it, tol=0.0, optimiser="adam")
            return time.perf_counter() - t0

        grid = OpticsConfig(resolution_hw=(H, W), frames=F, pitch_um=8.0, wavelengths_nm=[x * 1e9 for x in lams])
        out.append({"seconds": _best_of(repeats, enc, float), "x": it * encode_work(grid, z)})
        tick(j)
    return out


def _layer_samples(loaded, base: dict, repeats: int, tick) -> list[dict]:
    """The layer baseline's timed renders: RGB-D renders of 0.05 to 0.2 s, well above the timing noise."""
    from holocore.baselines.layers import render_layers

    out = []
    for j, (H, W, planes, spp, F) in enumerate(((48, 64, 4, 128, 4), (96, 128, 8, 128, 8))):
        optics = OpticsConfig(**base, resolution_hw=(H, W), frames=F)
        res = _best_of(repeats, lambda o=optics, n=planes, s=spp: render_layers(loaded, o, planes=n, spp=s),
                       lambda r: r.meta["timings"]["total_s"])
        P = 4 * H * W
        out.append({"t": res.meta["timings"], "pix_spp": H * W * spp,
                    "fft": (planes + 1) * F * 3 * P * math.log2(P)})
        tick(j)
    return out


def _fit_rates(samples: list[dict], enc_samples: list[dict], lay_samples: list[dict]) -> dict[str, Any]:
    """The cost model's rates fitted to the timed runs (holocore.plan.estimate reads them)."""
    import numpy as np

    rates: dict[str, Any] = {}
    rates["analysis"] = float(np.median([s["timings"]["analysis_s"] for s in samples]))
    banked = [s for s in samples if s["features"]["bank"] > 0]
    rates["bank"] = float(_fit([[s["features"]["bank"]] for s in banked], [s["timings"]["bank_s"] for s in banked])[0])
    cached = [s["timings"]["cache_s"] for s in samples if "cache_s" in s["timings"]]
    rates["cache"] = float(np.median(cached)) if cached else 0.0
    keys = sorted({s["key"] for s in samples})
    rows = [[s["features"]["tiles"]] + [s["features"]["rays"] if s["key"] == k else 0.0 for k in keys]
            for s in samples]
    coef = _fit(rows, [s["trace_s"] for s in samples])
    rates["tile"] = float(coef[0])
    rates["ray"] = {k: float(c) for k, c in zip(keys, coef[1:])}
    coef = _fit([[s["features"]["acc"], s["features"]["acc_frame"]] for s in samples],
                [s["accumulate_s"] for s in samples])
    rates["acc"], rates["acc_frame"] = float(coef[0]), float(coef[1])
    rates["fft"] = float(_fit([[s["features"]["fft"]] for s in samples],
                              [s["timings"]["propagate_s"] for s in samples])[0])
    staged = ("analysis_s", "bank_s", "cache_s", "propagate_s")
    rates["overhead"] = float(max(0.0, np.median([
        s["timings"]["total_s"] - sum(s["timings"].get(k, 0.0) for k in staged) - s["trace_s"] - s["accumulate_s"]
        for s in samples])))
    rates["enc"] = float(_fit([[e["x"]] for e in enc_samples], [e["seconds"] for e in enc_samples])[0])
    rates["rgbd"] = float(_fit([[s["pix_spp"]] for s in lay_samples], [s["t"]["rgbd_s"] for s in lay_samples])[0])
    rates["layer_fft"] = float(_fit([[s["fft"]] for s in lay_samples], [s["t"]["propagate_s"] for s in lay_samples])[0])
    rates["layers_overhead"] = float(max(0.0, np.median([
        s["t"]["total_s"] - s["t"]["analysis_s"] - s["t"]["rgbd_s"] - s["t"]["propagate_s"] for s in lay_samples])))
    return rates


def _work(result: Any) -> tuple[float, float]:
    """(rays, seconds of tracing and accumulation) of a render's meta."""
    stats, timings = result.meta.get("stats") or {}, result.meta.get("timings") or {}
    rays = float(stats.get("rays") or 0)
    work = float(stats.get("seconds_trace", 0.0)) + float(stats.get("seconds_accumulate", 0.0))
    if rays <= 0 or work <= 0:  # a black scene traces nothing: the whole trace stage then
        return max(rays, 1.0), float(timings.get("trace_s", 0.0))
    return rays, work


def probe_scene(loaded: Any, optics: OpticsConfig, options: Any, *, startup_s: float) -> Probe:
    """Render ``loaded`` at ``PROBE_HW`` (cold, then warm) and at twice its sides (warm), one frame, with
    ``options``; the warm pair's difference is the cost of the extra rays alone (no fixed costs). Its seconds
    are an idle machine's: each is divided by the slowdown of the load other work made as the probe began
    (``holocore.plan.estimate.load_slowdown``), so that a scene planned on a busy machine is not priced at its
    load twice, once in its probe and again by the estimate's load."""
    from holocore.pipeline import render_loaded

    slow = machine_load()["slowdown"]
    small = optics.model_copy(update={"resolution_hw": PROBE_HW, "frames": 1})
    big = small.model_copy(update={"resolution_hw": (2 * PROBE_HW[0], 2 * PROBE_HW[1])})
    t0 = time.perf_counter()
    render_loaded(loaded, small, options)
    t1 = time.perf_counter()
    warm_small = render_loaded(loaded, small.model_copy(update={"seed": small.seed + 1}), options)
    t2 = time.perf_counter()
    warm_big = render_loaded(loaded, big, options)
    t3 = time.perf_counter()
    (r1, w1), (r2, w2) = _work(warm_small), _work(warm_big)
    n_colors = len(optics.wavelengths_m)
    per_ray = (w2 - w1) / (r2 - r1) if r2 > r1 and w2 > w1 else w2 / r2
    return Probe(startup_s=float(startup_s) / slow, compile_s=max(0.0, (t1 - t0) - (t2 - t1)) / slow,
                 ray_color_s=per_ray / n_colors / slow, probe_s=t3 - t0, load_slowdown=slow)
