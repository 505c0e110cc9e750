"""`holo baseline layers`, `holo baseline focal-stack` and `holo baseline light-field`: the layer-based (RGB-D),
the focal-stack and the light-field (stereogram) baseline holograms, in the renderer's RESULT.npz format, so that
`holo view` and `holo evaluate` (and, for the layers and the light field, `holo encode`) treat them like a render."""

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


def _check_adam(iterations: int, lr: float, time_limit_s: Optional[float], device: str) -> None:
    """One-line errors for the options of an Adam fit (the focal stack's, the light field's)."""
    if not 0 <= iterations <= 100_000:
        fail(f"--iterations must be in 0..100000, got {iterations}")
    if time_limit_s is not None and not (time_limit_s > 0 and time_limit_s < 1e7):
        fail(f"--time-limit-s must be in (0, 1e7) s, got {time_limit_s}")
    if not (lr > 0 and lr < 100):
        fail(f"--lr must be in (0, 100), got {lr}")
    if device not in ("cpu", "cuda", "auto"):
        fail(f"--device must be cpu, cuda or auto, got {device!r}")


def _torch_device(device: str) -> str:
    """cpu, cuda or auto (cuda where there is one) -> the torch device to use; cuda without one is an error."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        fail("--device cuda: no CUDA device here")
    return device


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
    profile, optics_cfg = optics.resolve()
    if not 1 <= planes <= 256:
        fail(f"--planes must be in 1..256, got {planes}")
    if not 1 <= spp <= 65536:
        fail(f"--spp must be in 1..65536, got {spp}")
    if not scene.exists():
        fail(f"scene not found: {scene}")
    from holocore.baselines.layers import render_layers
    from holocore.io import save_result
    from holocore.scene.load import load_scene

    t0 = time.perf_counter()
    try:
        result = render_layers(load_scene(scene), optics_cfg, planes=planes, spp=spp, display=profile)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    save_result(out, slm_field=result.slm_field, wrp_field=result.wrp_field, meta=result.meta)
    m = result.meta
    F, C, H, W = m["shape_fchw"]
    used = sum(1 for n in m["layers"]["pixels_per_plane"] if n)
    typer.echo(f"layer baseline {Path(scene).name} for display {profile.name}: {F} frame(s) x {C} color(s) x {H}x{W}, {planes} planes "
               f"({used} hold pixels) from {m['layers']['plane_z_m'][0] * 1e3:.4f} to "
               f"{m['layers']['plane_z_m'][-1] * 1e3:.4f} mm, z_wrp = {m['z_wrp_m'] * 1e3:.3f} mm, "
               f"in {time.perf_counter() - t0:.1f} s -> {out}", err=True)


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
    optics: OpticsOptions = OpticsOptions(),
) -> None:
    """Focal stack: phase-only SGD of the frames on the frame-averaged amplitude at planes across the image
    volume, against Mitsuba thin-lens targets through the eye's pupil (time-multiplexed neural holography)."""
    profile, optics_cfg = optics.resolve()
    if planes is not None and not 1 <= planes <= 64:
        fail(f"--planes must be in 1..64, got {planes}")
    if spacing_mm is not None and not (spacing_mm >= 0 and spacing_mm < 1000):
        fail(f"--spacing-mm must be in [0, 1000) mm, got {spacing_mm}")
    if pupil_mm is not None and not (0 < pupil_mm <= 1000):
        fail(f"--pupil-mm must be in (0, 1000] mm, got {pupil_mm}")
    _check_adam(iterations, lr, time_limit_s, device)
    if not 1 <= gt_spp <= 65536:
        fail(f"--gt-spp must be in 1..65536, got {gt_spp}")
    if not scene.exists():
        fail(f"scene not found: {scene}")
    from holocore.baselines.focal_stack import render_focal_stack, stack_of
    from holocore.io import save_result, save_stack
    from holocore.scene.load import load_scene

    device = _torch_device(device)
    t0 = time.perf_counter()
    try:
        result = render_focal_stack(load_scene(scene), optics_cfg, planes=planes,
                                    spacing_m=spacing_mm * 1e-3 if spacing_mm else None,
                                    pupil_diameter_m=None if pupil_mm is None else pupil_mm * 1e-3,
                                    iterations=iterations, lr=lr, gt_spp=gt_spp, device=device, display=profile,
                                    time_limit_s=time_limit_s)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    save_result(out, slm_field=result.slm_field, wrp_field=result.wrp_field, meta=result.meta)
    if stack is not None:
        phase, smeta = stack_of(result)
        save_stack(stack, phase=phase, meta=smeta)
    m = result.meta
    fs = m["focal_stack"]
    F, C, H, W = m["shape_fchw"]
    zs = fs["plane_z_m"]
    typer.echo(f"focal-stack baseline {Path(scene).name} for display {profile.name}: {F} frame(s) x {C} color(s) x "
               f"{H}x{W}, {len(zs)} planes from {zs[0] * 1e3:.4f} to {zs[-1] * 1e3:.4f} mm, pupil "
               f"{fs['pupil_diameter_m'] * 1e3:.3g} mm, loss {fs['loss_first']:.4g} -> {fs['loss_final']:.4g} in "
               f"{'/'.join(str(n) for n in fs['iterations_done'])} steps (per colour), in "
               f"{time.perf_counter() - t0:.1f} s -> {out}"
               + (f" and {stack}" if stack is not None else ""), err=True)


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
    profile, optics_cfg = optics.resolve()
    if fit not in ("stereogram", "sgd"):
        fail(f"--fit must be stereogram or sgd, got {fit!r}")
    _check_adam(iterations, lr, time_limit_s, device)
    if not 1 <= hogel_px <= 256:
        fail(f"--hogel-px must be in 1..256, got {hogel_px}")
    if not 1 <= spp <= 16384:
        fail(f"--spp must be in 1..16384, got {spp}")
    if rs_mm is not None and not (0 < rs_mm < 1e6):
        fail(f"--rs-mm must be a depth in mm > 0, got {rs_mm}")
    if not scene.exists():
        fail(f"scene not found: {scene}")
    from holocore.baselines.light_field import render_light_field
    from holocore.io import save_result
    from holocore.scene.load import load_scene

    device = _torch_device(device)
    t0 = time.perf_counter()
    try:
        result = render_light_field(load_scene(scene), optics_cfg, hogel_px=hogel_px, spp=spp,
                                    z_rs_m=None if rs_mm is None else rs_mm * 1e-3, fit=fit, iterations=iterations,
                                    lr=lr, time_limit_s=time_limit_s, device=device, display=profile)
    except (ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    save_result(out, slm_field=result.slm_field, wrp_field=result.wrp_field, meta=result.meta)
    m = result.meta
    lf = m["light_field"]
    F, C, H, W = m["shape_fchw"]
    typer.echo(f"light-field baseline {Path(scene).name} for display {profile.name}: {F} frame(s) x {C} color(s) x "
               f"{H}x{W}, {lf['hogels_hw'][0]}x{lf['hogels_hw'][1]} hogels of {hogel_px} px at "
               f"{lf['z_rs_m'] * 1e3:.4f} mm, {spp} rays per sample, "
               + (f"{'/'.join(map(str, lf['iterations_done']))} Adam steps, " if fit == "sgd" else "")
               + f"z_wrp = {m['z_wrp_m'] * 1e3:.3f} mm, in "
               f"{time.perf_counter() - t0:.1f} s -> {out}", err=True)
