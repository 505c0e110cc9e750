"""Helpers shared by the `holo` subcommands (light: no torch, Mitsuba or Dr.Jit here)."""

from __future__ import annotations

import functools
import inspect
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, NoReturn, Optional

import typer


if TYPE_CHECKING:
    from holocore.display.optics import OpticsConfig
    from holocore.display.profiles import DisplayProfile
    from holocore.options import HologramOptions

__all__ = ["fail", "optics_from_options", "progress_writer", "parse_hw", "OpticsOptions", "with_optics_options",
           "OPTICS_OPTIONS", "hologram_options"]


def fail(message: str, code: int = 2) -> NoReturn:
    """One clear line on stderr, then exit (2: bad input)."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def parse_hw(text: str) -> tuple[int, int]:
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        fail(f"resolution must look like HxW (e.g. 1080x1920), got {text!r}")
    return h, w


@dataclass(frozen=True)
class OpticsOptions:
    """The optics options every rendering command shares (:func:`with_optics_options`), as the user gave them
    (None: not given). :meth:`resolve` turns them into the display profile and the OpticsConfig."""

    display: Optional[str] = None
    resolution: Optional[str] = None
    pitch_um: Optional[float] = None
    wavelengths_nm: Optional[str] = None
    z_inf_mm: Optional[float] = None
    focal_length_mm: Optional[float] = None
    frames: Optional[int] = None
    fit_camera_fov: bool = False
    scene_scale: Optional[float] = None
    seed: Optional[int] = None
    frame_phases: Optional[str] = None
    eyebox: Optional[str] = None
    optics_json: Optional[Path] = None

    def resolve(self, **command_defaults: Any) -> tuple["DisplayProfile", "OpticsConfig"]:
        """(profile, optics): the display profile (default ``paper``), then ``command_defaults`` (a command's
        own defaults, e.g. the demo's small SLM, used where the user gave nothing), then --optics-json, then
        the explicit options. Bad input exits with one line (code 2)."""
        from holocore.display.profiles import DisplayError, display_optics, load_display

        if self.fit_camera_fov and self.focal_length_mm is not None:
            fail("give --focal-length-mm or --fit-camera-fov, not both (each determines the eyepiece f)")
        try:
            profile = load_display(self.display)
        except DisplayError as exc:
            fail(str(exc))
        given = {"resolution_hw": parse_hw(self.resolution) if self.resolution else None,
                 "pitch_um": self.pitch_um, "wavelengths_nm": _parse_wavelengths(self.wavelengths_nm),
                 "z_inf_mm": self.z_inf_mm, "focal_length_mm": self.focal_length_mm, "frames": self.frames,
                 "fit_camera_fov": True if self.fit_camera_fov else None, "scene_scale": self.scene_scale,
                 "seed": self.seed,
                 "frame_phases": self.frame_phases, "eyebox": self.eyebox}
        defaults = {k: v for k, v in command_defaults.items() if given.get(k) is None}
        if "resolution_hw" in defaults and isinstance(defaults["resolution_hw"], str):
            defaults["resolution_hw"] = parse_hw(defaults["resolution_hw"])
        fields = {**defaults, **_read_optics_json(self.optics_json)}
        try:
            return profile, display_optics(profile, optics_fields=fields, overrides=given)
        except DisplayError as exc:
            fail(str(exc))


def _parse_wavelengths(text: Optional[str]) -> Optional[list[float]]:
    if not text:
        return None
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        fail(f"--wavelengths-nm must be numbers separated by commas, got {text!r}")


def _read_optics_json(path: Optional[Path]) -> dict:
    return _read_json_object(path, "--optics-json", "of OpticsConfig fields")


def _read_json_object(path: Optional[Path], flag: str, what: str) -> dict:
    """The JSON object in the file ``flag`` names ({} without one); anything else exits with one line."""
    if path is None:
        return {}
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        fail(f"cannot read {flag} {path}: {exc}")
    if not isinstance(data, dict):
        fail(f"{flag} must hold a JSON object {what}")
    return data


# The shared option set: (name, type, typer.Option). `holo render`, `plan`, `demo` and `baseline` take exactly
# these, through with_optics_options, so they cannot drift apart.
OPTICS_OPTIONS: tuple[tuple[str, Any, Any], ...] = (
    ("display", Optional[str], typer.Option(
        None, "--display", help="Display profile: a built-in name (default: paper: 1080x1920, 8 µm, "
                                "f = 50 mm, 24 frames) or a .json/.toml profile file (docs/display_profiles.md).")),
    ("resolution", Optional[str], typer.Option(None, "--resolution", help="SLM size HxW in pixels, e.g. 1080x1920.")),
    ("pitch_um", Optional[float], typer.Option(None, "--pitch-um", help="SLM pixel pitch in µm.")),
    ("wavelengths_nm", Optional[str], typer.Option(None, "--wavelengths-nm", help="Laser lines in nm, e.g. "
                                                                                     "640,516.5,455.4")),
    ("z_inf_mm", Optional[float], typer.Option(None, "--z-inf-mm", help="SLM to virtual infinity (the "
                                                                          "eyepiece's front focal plane), mm.")),
    ("focal_length_mm", Optional[float], typer.Option(None, "--focal-length-mm", help="Eyepiece f in mm "
                                                                                        "(default: the display's).")),
    ("frames", Optional[int], typer.Option(None, "--frames", help="Time-multiplexed frames (default: the "
                                                                    "display's).")),
    ("fit_camera_fov", bool, typer.Option(False, "--fit-camera-fov", help="Derive f from the scene camera's "
                                          "field of view filling the SLM width, instead of the display's f.")),
    ("scene_scale", Optional[float], typer.Option(None, "--scene-scale", help="Render the scene as if scaled by "
                                                  "this about its camera (0.1: every distance a tenth), so that "
                                                  "content modelled metres away sits where an eye focuses; the "
                                                  "plan suggests one (docs/design.md §3).")),
    ("seed", Optional[int], typer.Option(None, "--seed", help="Seed of rays and random-phase bank.")),
    ("frame_phases", Optional[str], typer.Option(None, "--frame-phases", help="How the frames phase the image "
                                                 "points: coded (default), independent, directional, or a mode "
                                                 "registered with holocore.display.phase_modes (docs/physics.md); "
                                                 "an unknown name is refused with the list.")),
    ("eyebox", Optional[str], typer.Option(None, "--eyebox", help="common (default: every colour cut to the "
                                           "smallest colour's cone, so the colour an eye sees does not change "
                                           "with its pupil) or per_colour (each colour its own cone).")),
    ("optics_json", Optional[Path], typer.Option(None, "--optics-json", help="OpticsConfig fields as a JSON "
                                                 "file (over the profile, under the options above).")),
)


def with_optics_options(func: Callable[..., Any]) -> Callable[..., Any]:
    """Give a typer command the shared optics options; it receives them as ``optics: OpticsOptions``."""
    sig = inspect.signature(func, eval_str=True)
    if "optics" not in sig.parameters:
        raise TypeError(f"{func.__name__} needs a parameter 'optics: OpticsOptions'")
    own = [p for p in sig.parameters.values() if p.name != "optics"]
    clash = {p.name for p in own} & {name for name, _, _ in OPTICS_OPTIONS}
    if clash:
        raise TypeError(f"{func.__name__} defines shared optics options itself: {sorted(clash)}")
    added = [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=opt, annotation=tp)
             for name, tp, opt in OPTICS_OPTIONS]

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        opts = OpticsOptions(**{name: kwargs.pop(name) for name, _, _ in OPTICS_OPTIONS if name in kwargs})
        return func(*args, optics=opts, **kwargs)

    params = own + added
    wrapper.__signature__ = sig.replace(parameters=params)  # type: ignore[attr-defined]
    wrapper.__annotations__ = {p.name: p.annotation for p in params}
    del wrapper.__wrapped__  # typer reads the signature above, not the wrapped function's
    return wrapper


def optics_from_options(*, optics_json: Optional[Path] = None, display: Optional[str] = None,
                        **overrides: Any) -> "OpticsConfig":
    """OpticsConfig from the display profile (default ``paper``), an optional OpticsConfig JSON file and CLI
    overrides (None = keep; ``resolution`` as HxW, ``wavelengths_nm`` as a comma list). Errors exit with code 2."""
    return OpticsOptions(display=display, optics_json=optics_json, **overrides).resolve()[1]


def _wrp_planes_value(text: Optional[str]) -> Any:
    """--wrp-planes as the options model reads it: an integer, or the word (checked there)."""
    if text is None:
        return None
    t = text.strip().lower()
    return int(t) if t.isdigit() else t


def hologram_options(options_json: Optional[Path], command: str, **given: Any) -> "HologramOptions":
    """The hologram's options (holocore.options): those of ``--options-json`` (one JSON document, as a service's
    job hands them over), then the flags given (None: not given), checked once there. Bad input exits with one
    line naming the flags as ``command`` (render, encode, submit) spells them."""
    from pydantic import ValidationError

    from holocore.options import HologramOptions, explain

    doc = _read_json_object(options_json, "--options-json", "of holocore.options.HologramOptions fields")
    if "wrp_planes" in given:
        given["wrp_planes"] = _wrp_planes_value(given["wrp_planes"])
    try:
        return HologramOptions.model_validate({**doc, **{k: v for k, v in given.items() if v is not None}})
    except ValidationError as exc:
        fail(explain(exc, command))


def progress_writer(path: Optional[Path]) -> Callable[[str, int, int], None]:
    """A progress callback appending JSON lines {"stage", "done", "total", "t"} to path (no-op if None)."""
    if path is None:
        return lambda stage, done, total: None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)

    def write(stage: str, done: int, total: int) -> None:
        with path.open("a") as fh:
            fh.write(json.dumps({"stage": stage, "done": int(done), "total": int(total), "t": time.time()}) + "\n")

    return write

