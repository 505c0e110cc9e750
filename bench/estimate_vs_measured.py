"""Predicted versus measured render time: the timing goal that used to be a test.

``tests/evaluate/test_evaluation.py::test_estimate_is_near_the_measured_time`` asserted that a warm render of the demo
scene took between 0.5x and 2x the committed default calibration's prediction; on a loaded machine it failed
(a timed assertion). The suite now checks only what is deterministic (the estimate counts the render's own
rays and stages, and grows with them as its model says); the time itself is measured here.

Each point renders warm (one compile run first, then the best of ``--repeats``) and is predicted by
:func:`holocore.plan.estimate.estimate_seconds` with the committed default calibration
(``holocore/data/calibration_default.json``, measured on the demo scene). Scenes: the demo scene (the
calibration's own) and the project's mirror-and-glass box (:func:`holocore.scene.demo.write_cbox_scene`), which
the calibration never saw. Goal (the old test's bound): estimate / measured in [0.5, 2.0] on the demo scene.

    .venv/bin/python bench/estimate_vs_measured.py                  # writes bench/results/estimate_vs_measured.md
    .venv/bin/python bench/estimate_vs_measured.py --quick --out /tmp/est.md
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import os
import platform
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from holocore.display.optics import OpticsConfig  # noqa: E402

GOAL_RATIO = (0.5, 2.0)  # estimate / measured, demo scene, default calibration


@dataclass(frozen=True)
class Point:
    scene: str
    resolution_hw: tuple[int, int]
    frames: int
    preset: str
    spp: int


def _points(quick: bool) -> list[Point]:
    base = [Point("demo", (96, 128), 8, "balanced", 64)]  # the old test's point
    if quick:
        return base + [Point("cbox", (96, 128), 8, "balanced", 64)]
    return base + [
        Point("demo", (96, 128), 8, "balanced", 16),
        Point("demo", (96, 128), 8, "balanced", 256),
        Point("demo", (96, 128), 1, "balanced", 64),
        Point("demo", (96, 128), 24, "balanced", 64),
        Point("demo", (48, 64), 8, "balanced", 64),
        Point("demo", (192, 256), 8, "balanced", 64),
        Point("demo", (96, 128), 8, "fast", 64),
        Point("cbox", (96, 128), 8, "balanced", 64),
        Point("cbox", (192, 256), 8, "balanced", 64),
        Point("cbox", (96, 128), 8, "fast", 64),
    ]


def _scenes(tmp: Path) -> dict[str, Any]:
    from holocore.scene.demo import write_cbox_scene, write_demo_scene
    from holocore.scene.load import load_scene

    return {"demo": load_scene(write_demo_scene(tmp / "demo", fov_deg=10.0)),
            "cbox": load_scene(write_cbox_scene(tmp / "cbox-mirror-glass"))}


def _optics(p: Point, scene: str) -> OpticsConfig:
    """The calibration's conditions: its runs used the default optics of their day, whose eyepiece fitted the
    camera's view (``fit_camera_fov`` where the display profiles made that an option)."""
    kw: dict[str, Any] = {"resolution_hw": p.resolution_hw, "frames": p.frames}
    if "fit_camera_fov" in OpticsConfig.model_fields:
        kw["fit_camera_fov"] = True
    if scene == "cbox":  # as the tests' cbox renders
        kw.update(z_inf_mm=2.0)
    return OpticsConfig(**kw)


def measure(points: list[Point], repeats: int) -> list[dict]:
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.plan.estimate import (
        DEFAULT_CALIBRATION,
        estimate_seconds,
        load_calibration,
    )

    cal = load_calibration(DEFAULT_CALIBRATION)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        scenes = _scenes(Path(tmp))
        for p in points:
            loaded = scenes[p.scene]
            optics = _optics(p, p.scene)
            options = RenderOptions(preset=p.preset, spp=p.spp)
            render_loaded(loaded, optics, options)  # compile
            best = math.inf
            for _ in range(repeats):
                t0 = time.perf_counter()
                render_loaded(loaded, optics, options)
                best = min(best, time.perf_counter() - t0)
            prims = sum(int(sh.primitive_count()) for sh in loaded.scene.shapes())
            est = estimate_seconds(optics, options, scene_primitives=prims, calibration=cal)
            row = {"point": p, "measured_s": best, "estimate_s": est, "ratio": est / best}
            rows.append(row)
            print(f"{p.scene:5s} {p.resolution_hw[0]}x{p.resolution_hw[1]:<4d} F={p.frames:<3d} {p.preset:9s} "
                  f"spp={p.spp:<4d} measured {best:7.3f} s  estimate {est:7.3f} s  ratio {est / best:5.2f}",
                  flush=True)
    return rows


def _machine() -> str:
    import drjit
    import mitsuba
    import torch

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{platform.machine()}, {os.cpu_count()} cores, load average {load:.2f} at the start, "
            f"Python {platform.python_version()}, torch {torch.__version__}, mitsuba {mitsuba.__version__}, "
            f"drjit {drjit.__version__}")


def report(rows: list[dict], *, command: str, machine: str, minutes: float, repeats: int) -> str:
    lo, hi = GOAL_RATIO
    demo = [r for r in rows if r["point"].scene == "demo"]
    ok = all(lo <= r["ratio"] <= hi for r in demo)
    lines = [
        "# Render time: estimate versus measured",
        "",
        f"Generated by `{command}` in {minutes:.1f} min on {dt.date.today().isoformat()}: {machine}. "
        f"Each time is the best of {repeats} warm runs (kernels compiled by a first run); the estimate is "
        "`holocore.plan.estimate.estimate_seconds` with the committed default calibration, which was measured on "
        "the demo scene; the mirror-and-glass box (`holocore.scene.demo.write_cbox_scene`) was not used to "
        "calibrate.",
        "",
        f"Goal (formerly a test): estimate / measured in [{lo}, {hi}] on the demo scene: "
        f"**{'met' if ok else 'not met'}** on this run.",
        "",
        "| scene | pixels | frames | preset | spp | measured s | estimate s | estimate / measured |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        p = r["point"]
        lines.append(f"| {p.scene} | {p.resolution_hw[0]}x{p.resolution_hw[1]} | {p.frames} | {p.preset} | {p.spp} "
                     f"| {r['measured_s']:.3f} | {r['estimate_s']:.3f} | {r['ratio']:.2f} |")
    lines += ["", "The machine is shared (two cores, other work running): a load average above the core count "
              "slows every run by about that factor, and ratios move with it. The calibration's own numbers were "
              "measured on an idle machine.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "estimate_vs_measured.md")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="two points only")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error("--repeats must be >= 1")
    machine = _machine()
    t0 = time.perf_counter()
    rows = measure(_points(args.quick), args.repeats)
    if hasattr(os, "getloadavg"):
        machine += f", {os.getloadavg()[0]:.2f} at the end"
    text = report(rows, command="bench/estimate_vs_measured.py" + (" --quick" if args.quick else ""),
                  machine=machine, minutes=(time.perf_counter() - t0) / 60, repeats=args.repeats)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
