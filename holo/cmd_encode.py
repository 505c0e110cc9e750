"""`holo encode`: a render (RESULT.npz) to a phase-only SLM stack (STACK.npz), docs/design.md §6."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from holo.common import fail, hologram_options, progress_writer


def register(app: typer.Typer) -> None:
    app.command("encode")(encode)


def encode(
    result: Path = typer.Argument(..., help="RESULT.npz from `holo render`."),
    out: Path = typer.Option(..., "--out", help="Where to write STACK.npz."),
    method: Optional[str] = typer.Option(None, help="sgd (complex-supervised, default) | dpac (double phase) | naive "
                                                    "(arg of the ideal SLM field, for tests)."),
    iterations: Optional[int] = typer.Option(None, help="Most sgd steps (0..1000000; default: the optimiser's, "
                                                        "lbfgs 28, adam 500 and stops earlier once converged)."),
    options_json: Optional[Path] = typer.Option(None, "--options-json", help="The hologram's options as one JSON "
                                                "document (docs/options.md): its encoder and iterations; the flags "
                                                "above override them."),
    optimiser: Optional[str] = typer.Option(None, help="sgd's steps: lbfgs (default; memoryless BFGS: Adam's "
                                                       "error in about 1/1.4 of its iterations) | adam."),
    lr: float = typer.Option(0.2, help="sgd's step, rad (> 0): Adam's, or lbfgs's first largest pixel change."),
    stop_db: float = typer.Option(0.05, "--stop-db", help="sgd stops a (frame, color) once its field SNR gained "
                                                         "less than this many dB over 30 steps (0: run every step)."),
    tol: Optional[float] = typer.Option(None, help="Instead of --stop-db: stop when the loss falls by less than "
                                                   "this fraction over 30 steps (0: run every step)."),
    fourier_filter: Optional[bool] = typer.Option(
        None, "--fourier-filter/--no-fourier-filter",
        help="Whether the display's Fourier filter passes only the recording cone (default: the RESULT's display; "
             "on when it names none). Off: light outside the cone is visible and counts as error."),
    memory_limit_gb: float = typer.Option(8.0, "--memory-limit-gb", help="Peak memory to plan for (GiB): frames "
                                                                         "are encoded in blocks that fit."),
    efficiency_weight: float = typer.Option(0.0, "--efficiency-weight",
                                            help="0..1: > 0 keeps more light in the viewing cone (brighter, less "
                                                 "accurate); 0 is pure complex supervision."),
    lut: Optional[Path] = typer.Option(None, "--lut", help="Per-wavelength 8-bit lookup table: JSON "
                                                           "{\"luts\": [{\"wavelength_nm\", \"table\"}]} or .npy "
                                                           "[C, 256] / [256]."),
    device: Optional[str] = typer.Option(None, help="auto (CUDA when available) | cpu | cuda | cuda:N; default: "
                                                    "HOLO_DEVICE, else auto."),
    progress_jsonl: Optional[Path] = typer.Option(None, "--progress-jsonl", help="Append progress as JSON lines."),
    init: Optional[Path] = typer.Option(None, "--init", help="sgd: start from this STACK.npz's phases (same frames, "
                                                             "colours and pixels): a re-render of the scene, or an "
                                                             "encode stopped early, goes on from there."),
) -> None:
    """Encode a render's WRP field into a phase-only stack: phase [F, C, H, W] in [0, 2pi) and 8-bit frames."""
    naive = method == "naive"  # a test encoder, outside the hologram's options
    hopts = hologram_options(options_json, "encode", encoder=None if naive else method, iterations=iterations,
                             optimiser=optimiser)
    method = "naive" if naive else hopts.encoder
    if not result.is_file():
        fail(f"result not found: {result}")
    if init is not None and not init.is_file():
        fail(f"start stack not found: {init}")

    from holocore.encode import encoder as encoding
    from holocore.runtime.device import torch_device

    try:
        dev = torch_device(device)  # --device, else HOLO_DEVICE, else auto (one rule for every command)
    except (ValueError, RuntimeError) as exc:
        fail(str(exc))
    if not memory_limit_gb > 0:
        fail(f"--memory-limit-gb must be > 0, got {memory_limit_gb}")
    from holocore.encode.stream import encode_file, read_meta

    try:
        meta = read_meta(result)
    except (ValueError, OSError, KeyError) as exc:
        fail(f"cannot read {result}: {exc}")
    try:
        lut_table = None if lut is None else encoding.load_lut(lut, wavelengths_m=meta.wavelengths_m)
    except ValueError as exc:
        fail(str(exc))
    write_progress = progress_writer(progress_jsonl)
    write_progress("load", 1, 1)
    options = dict(iterations=hopts.iterations, lr=lr, tol=tol, stop_db=stop_db, efficiency_weight=efficiency_weight,
                   optimiser=hopts.optimiser) if method == "sgd" else {}
    t0 = time.perf_counter()
    try:
        res, _ = encode_file(result, out, method=method, fourier_filter=fourier_filter,
                             memory_limit_bytes=int(memory_limit_gb * 2**30), device=dev, lut=lut_table,
                             lut_source=None if lut is None else lut.name, progress=write_progress,
                             init_path=init, **options)
    except (ValueError, OSError) as exc:
        fail(str(exc))
    write_progress("save", 1, 1)
    _print_summary(res, result.name, method, time.perf_counter() - t0, out)


def _print_summary(res, name: str, method: str, seconds: float, out: Path) -> None:
    """What the encode did in one line (display, supervision, blocks, errors, light, iterations) and notes."""
    s = res.summary()
    F, C, H, W = len(res.black), len(res.black[0]), *res.phase.shape[-2:]
    msg = (f"encoded {name} with {method} for a display {'with' if s['fourier_filter'] else 'without'} a "
           f"Fourier filter ({s['fourier_filter_source']}; {s['supervision']} supervision): {F} frame(s) x {C} "
           f"color(s) x {H}x{W} in blocks of {s['block_frames']} frame(s), complex-field error {s['loss_mean']:.4f} "
           f"(start {s['loss_init_mean']:.4f}; in the cone {s['loss_cone_mean']:.4f}, whole field "
           f"{s['loss_full_mean']:.4f}), light in the cone {s['efficiency_mean']:.0%}, in the target "
           f"{s['efficiency_target_mean']:.0%}")
    if method == "sgd":
        msg += f", {res.iterations} iteration(s){' (converged)' if res.converged else ''}"
    typer.echo(f"{msg}, {seconds:.1f} s -> {out}", err=True)
    if res.black.any():
        typer.echo(f"  - {int(res.black.sum())} black (frame, color) target(s): nothing to match (error 1 by "
                   "definition), phase left at its start", err=True)
