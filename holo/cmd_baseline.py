"""`holo baseline layers`, `holo baseline focal-stack` and `holo baseline light-field`: the layer-based (RGB-D),
the focal-stack and the light-field (stereogram) baseline holograms, in the renderer's RESULT.npz format, so that
`holo view` and `holo evaluate` (and, for the layers and the light field, `holo encode`) treat them like a render.
`holo baseline run NAME` runs any baseline of the registry (`holocore.baselines.registry`) with its options as
NAME=VALUE, `holo baseline list` lists them. The options are checked by each baseline's options model, the one
place their limits live."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from holo.common import OpticsOptions, fail, with_optics_options

baseline_app = typer.Typer(help="Baseline holograms to compare against (same RESULT.npz format).",
                           no_args_is_help=True)


def register(app: typer.Typer) -> None:
    app.add_typer(baseline_app, name="baseline")


def _run(name: str, scene: Path, out: Path, optics: OpticsOptions, values: dict,
         stack: Optional[Path] = None) -> None:
    """Check ``values`` with the baseline's options (a refusal names its flag), render, write RESULT.npz (and
    STACK.npz where asked) and say what was made in one line."""
    from holocore.baselines.registry import BaselineOptionsError, get_baseline

    profile, optics_cfg = optics.resolve()
    try:
        baseline = get_baseline(name)
        options = baseline.options(**values)
    except BaselineOptionsError as exc:
        fail(f"--{exc.field.replace('_', '-')}: {exc.reason}")
    except ValueError as exc:
        fail(str(exc))
    if not scene.exists():
        fail(f"scene not found: {scene}")
    from holocore.io import save_result, save_stack
    from holocore.scene.load import load_scene

    t0 = time.perf_counter()
    try:
        result = baseline.render(load_scene(scene), optics_cfg, options, display=profile)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    save_result(out, slm_field=result.slm_field, wrp_field=result.wrp_field, meta=result.meta)
    if stack is not None:
        from holocore.baselines.focal_stack import stack_of

        phase, smeta = stack_of(result)
        save_stack(stack, phase=phase, meta=smeta)
    typer.echo(f"{name} baseline {Path(scene).name} for display {profile.name}: {baseline.describe(result.meta)}, "
               f"in {time.perf_counter() - t0:.1f} s -> {out}" + (f" and {stack}" if stack is not None else ""),
               err=True)


@baseline_app.command("list")
def list_baselines() -> None:
    """Every baseline there is, with its options (name, default) and what it does."""
    from holocore.baselines.registry import baseline_names, get_baseline

    for name in baseline_names():
        b = get_baseline(name)
        opts = ", ".join(f"{k}={f.default!r}" for k, f in b.Options.model_fields.items())
        typer.echo(f"{name}: {b.summary}\n    options: {opts}")


@baseline_app.command("run")
@with_optics_options
def run(
    name: str = typer.Argument(..., help="The baseline's name (holo baseline list)."),
    scene: Path = typer.Argument(..., help="Scene folder (a bundle) or its Mitsuba XML file."),
    out: Path = typer.Option(..., "--out", help="Where to write RESULT.npz."),
    option: list[str] = typer.Option([], "--option", "-o", help="An option of the baseline as NAME=VALUE "
                                     "(repeat it; holo baseline list names them)."),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """Any registered baseline by name, its options as NAME=VALUE."""
    values = {}
    for item in option:
        key, sep, value = item.partition("=")
        if not sep or not key:
            fail(f"--option wants NAME=VALUE, got {item!r}")
        values[key.strip().replace("-", "_")] = value.strip()
    _run(name, scene, out, optics, values)


@baseline_app.command("layers")
@with_optics_options
def layers(
    scene: Path = typer.Argument(..., help="Scene folder (a bundle) or its Mitsuba XML file."),
    out: Path = typer.Option(..., "--out", help="Where to write RESULT.npz."),
    planes: int = typer.Option(8, "--planes", help="Depth layers, uniform in dioptres (1..256)."),
    spp: int = typer.Option(64, "--spp", help="Mitsuba samples per pixel of the RGB-D image (1..65536)."),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """RGB-D layers: sqrt(image) per depth bin with random phase per frame, ASM to the WRP and the SLM."""
    _run("layers", scene, out, optics, dict(planes=planes, spp=spp))


@baseline_app.command("focal-stack")
@with_optics_options
def focal_stack(
    scene: Path = typer.Argument(..., help="Scene folder (a bundle) or its Mitsuba XML file."),
    out: Path = typer.Option(..., "--out", help="Where to write RESULT.npz (slm_field = sqrt(P_c) exp(i phase))."),
    planes: Optional[int] = typer.Option(None, "--planes", help="Focal-stack planes (1..64; default: as many "
                                         "as the image volume holds, up to 5, no two closer than the pupil's "
                                         "depth of focus; 5 with --spacing-mm)."),
    spacing_mm: Optional[float] = typer.Option(None, "--spacing-mm", help="Plane spacing in hologram depth, mm "
                                               "(the paper used 1.25), centred on the image volume; default or "
                                               "0: the planes spread uniformly from the far to the near end of "
                                               "the image volume."),
    pupil_mm: Optional[float] = typer.Option(None, "--pupil-mm", help="Eye pupil of the targets and the model, "
                                             "mm (default: the one `holo evaluate` uses by default)."),
    iterations: int = typer.Option(200, "--iterations", help="Adam steps (0..100000)."),
    time_limit_s: Optional[float] = typer.Option(None, "--time-limit-s", help="Wall time of the whole baseline, s "
                                                 "(targets included): the Adam steps stop early to keep it, each "
                                                 "colour an equal share; --iterations stays the most."),
    lr: float = typer.Option(0.05, "--lr", help="Adam learning rate on the phases (rad)."),
    gt_spp: int = typer.Option(64, "--gt-spp", help="Mitsuba samples per pixel of each target (1..65536)."),
    stack: Optional[Path] = typer.Option(None, "--stack", help="Also write the phases as STACK.npz (8-bit frames, "
                                         "laser powers in meta.encoder.illumination)."),
    device: str = typer.Option("cpu", "--device", help="torch device of the optimisation: cpu, cuda or auto."),
    fit: str = typer.Option("pupil-aware", "--fit", help="pupil-aware: targets and model through the viewer-"
                            "faithful score's pupils (1.6-6 mm) x a jittered eye grid, one view per Adam step; "
                            "centred: one centred pupil (--pupil-mm), one target per plane."),
    eye_grid: int = typer.Option(3, "--eye-grid", help="--fit pupil-aware: n x n eye positions per pupil (1..9); "
                                 "the targets are pupils x n^2 x planes Mitsuba renders."),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """Focal stack: phase-only SGD of the frames on the frame-averaged amplitude at planes across the image
    volume, against Mitsuba thin-lens targets through the eye's pupil (time-multiplexed neural holography)."""
    _run("focal-stack", scene, out, optics, dict(planes=planes, spacing_mm=spacing_mm, pupil_mm=pupil_mm,
                                                 iterations=iterations, time_limit_s=time_limit_s, lr=lr,
                                                 gt_spp=gt_spp, device=device, fit=fit, eye_grid=eye_grid),
         stack=stack)


@baseline_app.command("light-field")
@with_optics_options
def light_field(
    scene: Path = typer.Argument(..., help="Scene folder (a bundle) or its Mitsuba XML file."),
    out: Path = typer.Option(..., "--out", help="Where to write RESULT.npz."),
    hogel_px: int = typer.Option(3, "--hogel-px", help="Hogel side in SLM pixels (1..256): its directions are a "
                                 "hogel_px x hogel_px grid over each colour's cone."),
    spp: int = typer.Option(16, "--spp", help="Jittered Mitsuba rays per light-field sample (1..16384)."),
    rs_mm: Optional[float] = typer.Option(None, "--rs-mm", help="Hologram depth of the ray-sampling plane, mm "
                                          "(default: the middle of the image volume)."),
    fit: str = typer.Option("stereogram", "--fit", help="stereogram: a complex field for `holo encode`; sgd: "
                            "phase-only frames fitted by Adam to the light field (the paper's LF)."),
    iterations: int = typer.Option(200, "--iterations", help="--fit sgd: Adam steps (0..100000)."),
    lr: float = typer.Option(0.05, "--lr", help="--fit sgd: Adam learning rate on the phases (rad)."),
    time_limit_s: Optional[float] = typer.Option(None, "--time-limit-s", help="--fit sgd: wall time of the whole "
                                                 "baseline, s; the Adam steps stop early to keep it."),
    device: str = typer.Option("cpu", "--device", help="--fit sgd: torch device, cpu, cuda or auto."),
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """Light field: a holographic stereogram on a ray-sampling plane (one plane wave per hogel and direction,
    random phase per frame, radiance from Mitsuba), ASM to the WRP and the SLM; or phase-only frames fitted to
    that light field (--fit sgd)."""
    _run("light-field", scene, out, optics, dict(hogel_px=hogel_px, spp=spp, rs_mm=rs_mm, fit=fit,
                                                 iterations=iterations, lr=lr, time_limit_s=time_limit_s,
                                                 device=device))
