"""Predicting a run's time before it starts, from rates measured on this machine.

The renderer's time is a sum of stages (``holocore.pipeline`` reports each in ``meta["timings"]`` and the
tracer's split in ``meta["stats"]``); each stage follows a simple cost model with one or two rates:

    analysis   a_analysis                                      (sparse pre-pass, fixed size)
    bank       a_bank  F C H W log2(H W)                       (random-phase bank; only with > 1 frame)
    cache      a_cache                                         (ambient cache, "fast" preset; fixed size)
    trace      a_tile n_tiles + a_ray[method/preset] R         (Mitsuba: R = H W N rays, N rays per pixel)
    accumulate R C (a_acc + a_acc_frame F)                     (phasors, bank gather, sums; F = 0 for one frame)
    propagate  a_fft F C P log2 P                              (ASM, P = padded pixels = 4 H W)
    overhead   a_overhead

and for the extras the report times: phase-only encoding (``a_enc`` per iteration per F sum_c G_c log2 G_c, G_c
the pixels of the encoder's padded grid for colour c, which grows with the WRP's distance from the SLM:
``holocore.optics.grids.encoder_grid``; a job without an iteration count runs to its stop rule's median at
that size, :func:`stop_iterations`) and the layer baseline (RGB-D ``a_rgbd`` H W spp, then (planes + 1) F C
ASMs). ``holo bench calibrate`` measures small runs on a scene (default: the project's demo scene, which has a
mirror and glass), fits every rate by non-negative least squares and stores them as JSON in the user's cache
directory; without one, the committed default (``holocore/plan/data/calibration_default.json``, measured on the
development machine) is used.

Times are for warm runs: the first Mitsuba render of a process also compiles its kernels (seconds).
When ``options.spp`` is None the preset's rays per pixel depend on the scene's depth (its farthest image
point's sub-hologram radius); the estimate then assumes a shallow scene (radius = WRP margin + 2 px) unless
``subhologram_radius_px`` is given.

The cost model itself needs no numpy (the service's API process estimates a job with it). Measuring the rates
(``holocore.calibration``) runs the renderer, so it lives above the pipeline.
"""

from __future__ import annotations

import json
import math
import numbers
import os
import statistics
import time
from pathlib import Path
from typing import Any, Optional

from holocore.display.optics import OpticsConfig
from holocore.optics.grids import encoder_grid
from holocore.plan.effects import choose_spp
from holocore.plan.encode_steps import default_iterations, rule
from holocore.plan.presets import PRESETS

__all__ = ["TYPICAL_STOP_ITERATIONS", "stop_iterations", "encode_iterations", "encode_work", "load_slowdown",
           "machine_load", "estimate_seconds", "estimate_breakdown", "estimate_layers_seconds", "load_calibration",
           "user_calibration_path", "DEFAULT_CALIBRATION", "CALIBRATION_VERSION", "save_calibration", "features"]

# Where the SGD encoder's default stop rule (holocore.encode.sgd) typically ends, whatever the size (the
# encoder's cap is 500): what a prediction assumes when it knows no size; :func:`stop_iterations` has the
# measured value by size.
TYPICAL_STOP_ITERATIONS = 160
STOP_RULE_DATA = Path(__file__).resolve().parent / "data" / "encode_stop_rule.json"

DEFAULT_CALIBRATION = Path(__file__).resolve().parent / "data" / "calibration_default.json"
# 2: the encoder's rate is per iteration and per its real padded grid (1: per 4 H W, whatever the distance)
CALIBRATION_VERSION = 2
REFERENCE_PRIMITIVES = 1000  # primitives of a calibration that does not record its scene's (BVH depth ~ log2)

RATE_KEYS = ("analysis", "bank", "cache", "tile", "acc", "acc_frame", "fft", "overhead", "enc", "rgbd",
             "layers_overhead")


def user_calibration_path() -> Path:
    """Where `holo bench calibrate` stores this machine's rates: $HOLO_CACHE_DIR, else $XDG_CACHE_HOME or
    ~/.cache, under holopathtracer/calibration.json."""
    root = os.environ.get("HOLO_CACHE_DIR")
    if root:
        return Path(root).expanduser() / "calibration.json"
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "holopathtracer" / "calibration.json"


def _check_calibration(cal: Any, source: str) -> dict:
    if not isinstance(cal, dict) or cal.get("version") != CALIBRATION_VERSION or not isinstance(cal.get("rates"), dict):
        raise ValueError(f"{source} is not a version-{CALIBRATION_VERSION} calibration (needs 'version', 'rates')")
    rates = cal["rates"]
    for k, v in rates.items():
        if k == "ray":
            if not isinstance(v, dict) or not v:
                raise ValueError(f"{source}: rates.ray must map 'method/preset' to seconds per ray")
            for kk, vv in v.items():
                if not (isinstance(vv, (int, float)) and math.isfinite(vv) and vv >= 0):
                    raise ValueError(f"{source}: rates.ray[{kk!r}] must be a finite number >= 0, got {vv!r}")
        elif not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{source}: rates[{k!r}] must be a finite number >= 0, got {v!r}")
    missing = [k for k in RATE_KEYS + ("ray",) if k not in rates]
    if missing:
        raise ValueError(f"{source}: rates lack {missing}")
    return cal


def load_calibration(path: Optional[str | Path] = None) -> dict:
    """The calibration at ``path``; default the user's (if present and valid) else the committed default."""
    if path is not None:
        p = Path(path)
        return _check_calibration(json.loads(p.read_text()), str(p))
    user = user_calibration_path()
    if user.is_file():
        try:
            return _check_calibration(json.loads(user.read_text()), str(user))
        except (ValueError, OSError, json.JSONDecodeError):
            pass  # a stale or broken user file: fall back to the default
    return _check_calibration(json.loads(DEFAULT_CALIBRATION.read_text()), str(DEFAULT_CALIBRATION))


def save_calibration(cal: dict, path: Optional[str | Path] = None) -> Path:
    """Write a calibration (validated) to ``path`` (default :func:`user_calibration_path`); returns it."""
    p = Path(path) if path is not None else user_calibration_path()
    _check_calibration(cal, "calibration")
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_suffix(".tmp")
    tmp.write_text(json.dumps(cal, indent=1, sort_keys=True))
    os.replace(tmp, p)
    return p


# ---- the cost model ---------------------------------------------------------------------------------------
_STOP_SIZES: list[tuple[float, float, float]] = []


def stop_iterations(height: int, width: int, *, quantile: str = "median") -> int:
    """Iterations the SGD encoder's stop rule runs per frame and colour at an H x W SLM (``quantile``:
    "median" or "p90"): measured medians by size (``data/encode_stop_rule.json``), interpolated in log pixels
    and held flat beyond the sizes measured."""
    if quantile not in ("median", "p90"):
        raise ValueError(f"quantile must be 'median' or 'p90', got {quantile!r}")
    if not _STOP_SIZES:
        doc = json.loads(STOP_RULE_DATA.read_text())
        _STOP_SIZES.extend(sorted((float(r["pixels"]), float(r["median"]), float(r["p90"])) for r in doc["sizes"]))
    col = 1 if quantile == "median" else 2
    x = math.log(max(1, int(height) * int(width)))
    pts = [(math.log(r[0]), r[col]) for r in _STOP_SIZES]
    if x <= pts[0][0]:
        return int(round(pts[0][1]))
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        if x <= x1:
            return int(round(y0 + (y1 - y0) * (x - x0) / (x1 - x0)))
    return int(round(pts[-1][1]))


def encode_iterations(height: int, width: int, *, optimiser: Optional[str] = None, iterations: Optional[int] = None,
                      quantile: str = "median") -> int:
    """Iterations the encoder is expected to run per frame and colour at an H x W SLM: those given, else the
    optimiser's default count (:mod:`holocore.plan.encode_steps`; None: the default optimiser), fewer where its stop
    rule usually ends it first (Adam's, measured by size: :func:`stop_iterations`)."""
    n = default_iterations(optimiser, iterations)
    return min(n, stop_iterations(height, width, quantile=quantile)) if rule(optimiser).stops_early else n


def load_slowdown(other_load: float, cores: int) -> float:
    """How many times longer a run takes beside ``other_load`` runnable threads of other work on ``cores``
    cores than on an idle machine: a run keeps every core busy (Dr.Jit and torch each use one thread a core),
    and the scheduler shares the cores fairly among all runnable threads, so it gets cores / (others + cores)
    of them."""
    if not (math.isfinite(other_load) and other_load >= 0) or int(cores) < 1:
        raise ValueError(f"other_load must be finite and >= 0 and cores >= 1, got {other_load!r}, {cores!r}")
    return 1.0 + float(other_load) / int(cores)


_SAMPLED: dict[str, float] = {}  # the last sample of the runnable threads: {"at": monotonic s, "value": threads}


def _runnable_now(*, samples: int = 10, interval_s: float = 0.02, max_age_s: float = 5.0) -> Optional[float]:
    """Runnable threads on the machine now, other than the one reading: the mean of ``samples`` readings of
    /proc/loadavg's fourth field over ``samples x interval_s`` seconds (None where there is no such file). Kept
    ``max_age_s`` seconds: a form that estimates on every keystroke samples once."""
    now = time.monotonic()
    if _SAMPLED and now - _SAMPLED["at"] < max_age_s:
        return _SAMPLED["value"]
    vals = []
    try:
        for i in range(samples):
            with open("/proc/loadavg") as fh:
                vals.append(max(0, int(fh.read().split()[3].split("/")[0]) - 1))
            if i + 1 < samples:
                time.sleep(interval_s)
    except (OSError, ValueError, IndexError):
        return None
    _SAMPLED.update(at=time.monotonic(), value=statistics.fmean(vals))
    return _SAMPLED["value"]


def machine_load(*, own_threads: float = 0.0) -> dict[str, float]:
    """This machine's load now: ``runnable`` (threads running or ready to run, sampled over a fifth of a second),
    ``load_1min`` (the kernel's one-minute average of the same, which lags: a run that ended a minute ago still
    counts in it, so it is shown, not used, where the sample exists), ``cores``, ``others`` (the runnable threads
    less ``own_threads``, the threads of runs the caller knows of and that the estimated run will not share the
    machine with) and the ``slowdown`` (:func:`load_slowdown`) an estimate is multiplied by."""
    try:
        load = float(os.getloadavg()[0])
    except OSError:  # no load average on this platform: assume an idle machine
        load = 0.0
    runnable = _runnable_now()
    cores = os.cpu_count() or 1
    others = max(0.0, (load if runnable is None else runnable) - max(0.0, float(own_threads)))
    return {"load_1min": round(load, 2), "runnable": round(load if runnable is None else runnable, 2),
            "cores": cores, "others": round(others, 2), "slowdown": round(load_slowdown(others, cores), 3)}


def encode_work(optics: OpticsConfig, z_wrp_m: Optional[float] = None) -> float:
    """One SGD iteration's FFT work over every frame and colour: F sum_c G_c log2 G_c, G_c the pixels of the
    encoder's padded grid for colour c at the WRP's distance ``z_wrp_m`` from the SLM (default z_inf: the WRP
    lies a few millimetres beyond it at most, docs/design.md §2)."""
    z = optics.z_inf_m if z_wrp_m is None else float(z_wrp_m)
    if not (math.isfinite(z) and z > 0):
        raise ValueError(f"z_wrp_m must be finite and > 0, got {z_wrp_m!r}")
    work = 0.0
    for lam in optics.wavelengths_m:
        hp, wp = encoder_grid(optics.resolution_hw, z, lam, optics.pitch_m)
        work += hp * wp * math.log2(max(2, hp * wp))
    return float(optics.frames * work)


def _plan_numbers(optics: OpticsConfig, options: Any, subhologram_radius_px: Optional[float]) -> dict:
    if options.preset not in PRESETS:
        raise ValueError(f"options.preset must be one of {sorted(PRESETS)}, got {options.preset!r}")
    theta = max(optics.theta_max(lam) for lam in optics.wavelengths_m)
    if options.spp is not None:
        n = int(options.spp)
    else:
        radius = optics.wrp_margin_px + 2.0 if subhologram_radius_px is None else float(subhologram_radius_px)
        if not (math.isfinite(radius) and radius >= 0):
            raise ValueError(f"subhologram_radius_px must be finite and >= 0, got {subhologram_radius_px!r}")
        n = choose_spp(options.preset, radius, theta, getattr(options, "max_spp", None))
    H, W = optics.resolution_hw
    rows_per_tile = max(1, int(getattr(options, "tile_rays", 1 << 19)) // max(1, n * W))
    return {"spp": n, "rays": H * W * n, "tiles": math.ceil(H / rows_per_tile),
            "cache": PRESETS[options.preset].use_cache and not getattr(options, "force_all_effects", False),
            "random_phase": optics.frames > 1 or getattr(options, "force_all_effects", False)}


def features(optics: OpticsConfig, options: Any, *, subhologram_radius_px: Optional[float] = None) -> dict:
    """The quantities the cost model multiplies by its rates (rays, tiles, F C P log2 P, ...)."""
    pn = _plan_numbers(optics, options, subhologram_radius_px)
    H, W = optics.resolution_hw
    F, C = optics.frames, len(optics.wavelengths_m)
    P = 4 * H * W
    return {
        "key": f"{options.method}/{options.preset}",
        "spp": pn["spp"],
        "rays": float(pn["rays"]),
        "tiles": float(pn["tiles"]),
        "bank": float(F * C * H * W * math.log2(max(2, H * W))) if pn["random_phase"] else 0.0,
        "cache": 1.0 if pn["cache"] else 0.0,
        "acc": float(pn["rays"] * C),
        "acc_frame": float(pn["rays"] * C * F) if pn["random_phase"] else 0.0,
        "fft": float(F * C * P * math.log2(P)),
    }


def _prim_factor(scene_primitives: Optional[int], calibration_primitives: int = REFERENCE_PRIMITIVES) -> float:
    """BVH traversal grows like log2 of the primitive count; relative to the calibration scene's."""
    if scene_primitives is None:
        return 1.0
    n = int(scene_primitives)
    if n < 0:
        raise ValueError(f"scene_primitives must be >= 0, got {scene_primitives!r}")
    return max(0.5, math.log2(n + 16) / math.log2(max(0, int(calibration_primitives)) + 16))


def _ray_rate(rates: dict, key: str) -> float:
    table = rates["ray"]
    if key in table:
        return float(table[key])
    method, preset = key.split("/")
    for k, v in table.items():  # same preset, other method; else the mean
        if k.endswith("/" + preset):
            return float(v)
    return float(statistics.fmean(table.values()))


def estimate_breakdown(optics: OpticsConfig, options: Any, *, scene_primitives: Optional[int] = None,
                       subhologram_radius_px: Optional[float] = None, encode_iterations: int = 0,
                       encode_optimiser: Optional[str] = None, z_wrp_m: Optional[float] = None,
                       calibration: Optional[dict] = None) -> dict[str, float]:
    """Predicted seconds per stage (see the module docstring) and ``total``; ``z_wrp_m``: the WRP's distance
    from the SLM, which sizes the encoder's grid (:func:`encode_work`); ``encode_optimiser``: whose iterations
    ``encode_iterations`` counts (None: the default's; the calibration times Adam's)."""
    if not isinstance(optics, OpticsConfig):
        raise ValueError(f"optics must be an OpticsConfig, got {type(optics).__name__}")
    if isinstance(encode_iterations, bool) or not isinstance(encode_iterations, numbers.Integral) \
            or not 0 <= encode_iterations <= 10**6:
        raise ValueError(f"encode_iterations must be an integer in 0..1000000, got {encode_iterations!r}")
    cal = calibration if calibration is not None else load_calibration()
    r = cal["rates"]
    x = features(optics, options, subhologram_radius_px=subhologram_radius_px)
    out = {
        "analysis": r["analysis"],
        "bank": r["bank"] * x["bank"],
        "cache": r["cache"] * x["cache"],
        "trace": (r["tile"] * x["tiles"] + _ray_rate(r, x["key"]) * x["rays"])
        * _prim_factor(scene_primitives, cal.get("primitives", REFERENCE_PRIMITIVES)),
        "accumulate": r["acc"] * x["acc"] + r["acc_frame"] * x["acc_frame"],
        "propagate": r["fft"] * x["fft"],
        "overhead": r["overhead"],
    }
    if encode_iterations:
        out["encode"] = r["enc"] * encode_iterations * rule(encode_optimiser).cost * encode_work(optics, z_wrp_m)
    out["total"] = float(sum(out.values()))
    return {k: float(v) for k, v in out.items()}


def estimate_seconds(optics: OpticsConfig, options: Any, *, scene_primitives: Optional[int] = None,
                     subhologram_radius_px: Optional[float] = None, encode_iterations: int = 0,
                     encode_optimiser: Optional[str] = None, z_wrp_m: Optional[float] = None,
                     calibration: Optional[dict] = None) -> float:
    """Predicted wall time (s) of ``holocore.pipeline.render`` with these optics and options on this machine
    (warm), plus ``encode_iterations`` iterations of ``encode_optimiser``'s phase-only encoding if asked."""
    return estimate_breakdown(optics, options, scene_primitives=scene_primitives,
                              subhologram_radius_px=subhologram_radius_px, encode_iterations=encode_iterations,
                              encode_optimiser=encode_optimiser, z_wrp_m=z_wrp_m, calibration=calibration)["total"]


def estimate_layers_seconds(optics: OpticsConfig, *, planes: int = 8, spp: int = 64,
                            calibration: Optional[dict] = None) -> float:
    """Predicted wall time (s) of :func:`holocore.baselines.layers.render_layers`."""
    if not 1 <= int(planes) <= 256 or not 1 <= int(spp) <= 65536:
        raise ValueError(f"planes must be in 1..256 and spp in 1..65536, got {planes!r}, {spp!r}")
    cal = calibration if calibration is not None else load_calibration()
    r = cal["rates"]
    H, W = optics.resolution_hw
    F, C = optics.frames, len(optics.wavelengths_m)
    P = 4 * H * W
    bank = F * C * H * W * math.log2(max(2, H * W))
    # Per plane a masked copy of the frames and an ASM: its own rate where the calibration measured one
    # (calibrations before it had only the tracer's ASM rate, which leaves the masks out).
    fft = r.get("layer_fft", r["fft"])
    return float(r["analysis"] + r["layers_overhead"] + r["rgbd"] * H * W * spp + r["bank"] * bank
                 + fft * (int(planes) + 1) * F * C * P * math.log2(P))
