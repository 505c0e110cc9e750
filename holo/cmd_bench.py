"""`holo bench calibrate` (measure this machine's rates for the cost estimate), `holo bench accuracy`
(the accuracy-versus-time report, bench/accuracy_report.py) and `holo bench paper` (the paper's figures and the
equal-time table on the paper scenes, bench/paper_report.py)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Optional

import typer

from holo.common import fail

bench_app = typer.Typer(help="Benchmarks: calibrate the cost estimate, accuracy versus time, the paper's figures.",
                        no_args_is_help=True)


def register(app: typer.Typer) -> None:
    app.add_typer(bench_app, name="bench")


@bench_app.command("calibrate")
def calibrate(
    scene: Optional[Path] = typer.Option(None, "--scene", help="Scene to time (default: the built-in demo "
                                                                 "scene, which has a mirror and glass)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Where to write the JSON (default: the user cache, "
                                                            "which `holo render --estimate` reads)."),
    quick: bool = typer.Option(False, "--quick", help="Half the runs (about half the time)."),
    repeats: int = typer.Option(2, "--repeats", help="Runs per configuration; the fastest counts (1..10)."),
    optics_json: Optional[Path] = typer.Option(None, "--optics-json", help="OpticsConfig fields (JSON) every run "
                                                                           "uses, e.g. {\"z_inf_mm\": 4}: calibrate "
                                                                           "with the optics you will render with."),
) -> None:
    """Time small renders, encodings and layer baselines and fit the cost model's rates (about a minute)."""
    if scene is not None and not scene.exists():
        fail(f"scene not found: {scene}")
    optics = None
    if optics_json is not None:
        try:
            optics = json.loads(optics_json.read_text())
        except (OSError, ValueError) as exc:
            fail(f"--optics-json {optics_json}: {exc}")
        if not isinstance(optics, dict):
            fail(f"--optics-json {optics_json}: expected a JSON object of OpticsConfig fields")
    if not 1 <= repeats <= 10:
        fail(f"--repeats must be in 1..10, got {repeats}")
    from holocore.calibration import calibrate as run
    from holocore.plan.estimate import save_calibration

    t0 = time.perf_counter()

    def progress(stage: str, done: int, total: int) -> None:
        typer.echo(f"\r{stage} {done}/{total}", err=True, nl=done == total)

    try:
        cal = run(scene=scene, quick=quick, repeats=repeats, optics=optics, progress=progress)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    path = save_calibration(cal, out)
    r = cal["rates"]
    rays = ", ".join(f"{k} {v * 1e6:.2f} µs" for k, v in sorted(r["ray"].items()))
    typer.echo(f"per ray: {rays}; per ray-frame-color of accumulation {r['acc_frame'] * 1e9:.1f} ns; "
               f"ambient cache {r['cache']:.2f} s")
    typer.echo(f"calibrated on {cal['scene']} in {time.perf_counter() - t0:.0f} s -> {path}", err=True)


def _run_script(name: str, module: str, args: list[str]) -> None:
    script = Path(__file__).resolve().parents[1] / "bench" / name
    if not script.is_file():
        fail(f"{script} not found: the report runs from a source checkout of the project")
    import importlib.util

    spec = importlib.util.spec_from_file_location(module, script)
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    sys.modules[spec.name] = mod  # dataclasses look their module up by name
    spec.loader.exec_module(mod)
    code = mod.main(args)
    if code:
        raise typer.Exit(code)


@bench_app.command("accuracy", context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def accuracy(ctx: typer.Context) -> None:
    """Run bench/accuracy_report.py (options pass through: --scene, --resolution, --out, --repeats, --quick)."""
    _run_script("accuracy_report.py", "holo_accuracy_report", list(ctx.args))


@bench_app.command("paper", context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def paper(ctx: typer.Context) -> None:
    """Regenerate the paper's Figs. 5-7 and the equal-time table on the paper scenes into bench/results/paper/
    (bench/paper_report.py; options pass through: --stages, --scenes, --resolution, --z-inf-mm, --budget-s,
    --out, ...; see --help)."""
    _run_script("paper_report.py", "holo_paper_report", list(ctx.args))


@bench_app.command("show-calibration")
def show_calibration(path: Optional[Path] = typer.Option(None, "--path", help="A calibration JSON file.")) -> None:
    """Print the calibration the estimate uses (the user's, else the committed default)."""
    from holocore.plan.estimate import (
        DEFAULT_CALIBRATION,
        load_calibration,
        user_calibration_path,
    )

    try:
        cal = load_calibration(path)
    except (ValueError, OSError, json.JSONDecodeError) as exc:
        fail(str(exc))
    src = path or (user_calibration_path() if user_calibration_path().is_file() else DEFAULT_CALIBRATION)
    typer.echo(json.dumps({"source": str(src), "scene": cal.get("scene"), "machine": cal.get("machine"),
                           "rates": cal["rates"]}, indent=1))
