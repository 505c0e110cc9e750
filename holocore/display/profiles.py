"""Display profiles: a named, frozen description of a holographic display (docs/design.md §3), and the OpticsConfig
it builds.

A profile is what a lab knows about its display: SLM size and pitch, laser lines, where the eyepiece's front
focal plane ("virtual infinity") lies, the eyepiece's focal length f, how many frames it time-multiplexes and
whether a Fourier filter passes only the recording cone. f belongs to the display, not to the scene: the
hologram shows the display's field of view, 2 atan(W p / 2f), around the scene camera's axis. The built-in
profile ``paper`` (the paper's Sec. 5 display, f = 50 mm) is the default of every `holo` command.

User profiles are JSON or TOML files holding the same fields (units in the names)::

    name = "lab-slm"
    resolution_hw = [1080, 1920]
    pitch_um = 8.0
    wavelengths_nm = [638.0, 520.0, 450.0]
    z_inf_mm = 80.0
    focal_length_mm = 50.0
    frames = 24
    fourier_filter = true

Numbers are checked by OpticsConfig's own validators (one set of rules); every problem is one line.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Mapping, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from holocore.display.optics import DISPLAY_FOCAL_LENGTH_MM, OpticsConfig

__all__ = ["DisplayProfile", "DisplayError", "PAPER", "BUILTIN_DISPLAYS", "DEFAULT_DISPLAY", "load_display",
           "load_display_file", "save_display", "display_optics", "display_meta", "field_of_view_report",
           "field_of_view_box"]

PROFILE_SUFFIXES = (".json", ".toml")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
# The profile fields that are OpticsConfig fields too (same names, same units, same validators).
OPTICS_FIELDS = ("resolution_hw", "pitch_um", "wavelengths_nm", "z_inf_mm", "focal_length_mm", "frames")


class DisplayError(ValueError):
    """A display profile that cannot be used; the message is one line that says what to change."""


def _one_line(exc: ValidationError) -> str:
    parts = []
    for e in exc.errors():
        loc = ".".join(str(p) for p in e["loc"])
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = f"unknown field (profile fields: {', '.join(DisplayProfile.model_fields)})"
        parts.append(f"{loc}: {msg}" if loc else msg)
    return "; ".join(parts)


class DisplayProfile(BaseModel):
    """One holographic display. Units are in the field names; :meth:`optics` gives the OpticsConfig."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(description="Profile name: letters, digits, '.', '_' or '-', 1-64 characters.")
    resolution_hw: tuple[int, int] = Field(description="SLM rows x columns in pixels.")
    pitch_um: float = Field(description="SLM pixel pitch in µm.")
    wavelengths_nm: tuple[float, ...] = Field(description="Laser lines in nm, one per color channel.")
    z_inf_mm: float = Field(description="SLM to the eyepiece's front focal plane ('virtual infinity'), mm.")
    focal_length_mm: float = Field(description="Eyepiece focal length f in mm (sets depth and field of view).")
    frames: int = Field(description="Time-multiplexed frames the display shows per image.")
    fourier_filter: bool = Field(description="True if a Fourier filter passes only the recording cone "
                                             "(light the encoder parks outside the cone is then invisible).")
    description: str = Field(default="", max_length=500, description="Free text: where the numbers come from.")

    @model_validator(mode="after")
    def _physical(self) -> "DisplayProfile":
        if not _NAME.match(self.name):
            raise ValueError(f"name must be 1-64 letters, digits, '.', '_' or '-' (starting with a letter or "
                             f"digit), got {self.name!r}")
        try:  # one set of rules: OpticsConfig's
            OpticsConfig(**{k: getattr(self, k) for k in OPTICS_FIELDS})
        except ValidationError as exc:
            raise ValueError(_one_line(exc)) from None
        return self

    def optics(self, **overrides: Any) -> OpticsConfig:
        """The OpticsConfig of this display, with ``overrides`` (OpticsConfig fields; None = keep the profile's).
        ``fit_camera_fov=True`` or ``fov_x_deg`` replace the profile's f (docs/design.md §3: an explicit choice)."""
        return display_optics(self, overrides=overrides)

    def field_of_view_x_deg(self) -> float:
        """Horizontal field of view the display shows, 2 atan(W p / 2f), degrees."""
        return math.degrees(2.0 * math.atan(self.resolution_hw[1] * self.pitch_um * 1e-3
                                            / (2.0 * self.focal_length_mm)))


PAPER = DisplayProfile(
    name="paper", resolution_hw=(1080, 1920), pitch_um=8.0, wavelengths_nm=(640.0, 516.5, 455.4), z_inf_mm=80.0,
    focal_length_mm=DISPLAY_FOCAL_LENGTH_MM, frames=24, fourier_filter=True,
    description="The paper's display (Sec. 5): 1080x1920 px at 8 µm, 640.0/516.5/455.4 nm, virtual infinity at "
                "80 mm; f = 50 mm puts 10 m, 0.9 m and 0.5 m at 80.25, 82.8 and 85 mm (docs/design.md §3); 24 frames; "
                "a Fourier filter passes only the recording cone.",
)
BUILTIN_DISPLAYS: dict[str, DisplayProfile] = {PAPER.name: PAPER}
DEFAULT_DISPLAY = PAPER.name


def load_display_file(path: str | Path) -> DisplayProfile:
    """A profile from a .json or .toml file (``name`` defaults to the file's stem). Raises DisplayError."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in PROFILE_SUFFIXES:
        raise DisplayError(f"display profile {path}: expected a .json or .toml file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DisplayError(f"cannot read display profile {path}: {exc}") from None
    try:
        if suffix == ".json":
            data = json.loads(text)
        else:
            import tomllib

            data = tomllib.loads(text)
    except json.JSONDecodeError as exc:
        raise DisplayError(f"display profile {path}: not valid JSON: {exc}") from None
    except ValueError as exc:  # tomllib.TOMLDecodeError
        raise DisplayError(f"display profile {path}: not valid TOML: {exc}") from None
    if not isinstance(data, dict):
        raise DisplayError(f"display profile {path}: expected an object of profile fields, got {type(data).__name__}")
    data.setdefault("name", path.stem)
    try:
        return DisplayProfile(**data)
    except ValidationError as exc:
        raise DisplayError(f"display profile {path}: {_one_line(exc)}") from None


def load_display(spec: Optional[str | Path] = None) -> DisplayProfile:
    """A built-in profile by name (None: the default, ``paper``) or a profile file. Raises DisplayError."""
    if spec is None:
        return BUILTIN_DISPLAYS[DEFAULT_DISPLAY]
    text = str(spec)
    if text in BUILTIN_DISPLAYS:
        return BUILTIN_DISPLAYS[text]
    path = Path(text)
    if path.suffix.lower() in PROFILE_SUFFIXES or path.exists():
        return load_display_file(path)
    raise DisplayError(f"unknown display {text!r}: give a built-in profile ({', '.join(BUILTIN_DISPLAYS)}) or a "
                       f".json/.toml profile file")


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a JSON string is a valid TOML basic string
    return "[" + ", ".join(_toml_value(x) for x in v) + "]"


def save_display(profile: DisplayProfile, path: str | Path) -> Path:
    """Write ``profile`` as .json or .toml (by the suffix); :func:`load_display_file` reads it back equal."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in PROFILE_SUFFIXES:
        raise DisplayError(f"display profile {path}: expected a .json or .toml file name")
    data = profile.model_dump(mode="json")
    if suffix == ".json":
        text = json.dumps(data, indent=2, ensure_ascii=False) + "\n"
    else:
        text = "".join(f"{k} = {_toml_value(v)}\n" for k, v in data.items())
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


_F_KEYS = ("focal_length_mm", "fov_x_deg", "fit_camera_fov")


def _sets_f(layer: Mapping[str, Any]) -> bool:
    """Whether a layer of options chooses where f comes from (an explicit null f is the old 'fit' record)."""
    return ("focal_length_mm" in layer or layer.get("fov_x_deg") is not None
            or layer.get("fit_camera_fov") not in (None, False))


def display_optics(profile: DisplayProfile, *, overrides: Optional[Mapping[str, Any]] = None,
                   optics_fields: Optional[Mapping[str, Any]] = None) -> OpticsConfig:
    """The OpticsConfig of ``profile``, then ``optics_fields`` (e.g. an OpticsConfig JSON file), then
    ``overrides`` (explicit options; None values keep what is there). A later layer that sets the source of f
    (focal_length_mm, fov_x_deg or fit_camera_fov) replaces the earlier layers' source. Raises DisplayError."""
    data: dict[str, Any] = {k: getattr(profile, k) for k in OPTICS_FIELDS}
    for layer in (dict(optics_fields or {}), {k: v for k, v in (overrides or {}).items() if v is not None}):
        if _sets_f(layer):
            for k in _F_KEYS:
                data.pop(k, None)
        data.update(layer)
    try:
        return OpticsConfig(**data)
    except ValidationError as exc:
        raise DisplayError(f"invalid optics: {_one_line(exc)}") from None


def display_meta(profile: DisplayProfile, optics: OpticsConfig) -> dict[str, Any]:
    """What a RESULT or STACK records of its display: ``display_profile`` (the name) and ``display`` (the profile,
    and which of its fields the optics that were used override)."""
    used = {"resolution_hw": tuple(optics.resolution_hw), "pitch_um": optics.pitch_um,
            "wavelengths_nm": tuple(optics.wavelengths_nm), "z_inf_mm": optics.z_inf_mm,
            "focal_length_mm": optics.focal_length_mm, "frames": optics.frames}
    overridden = [k for k in OPTICS_FIELDS if used[k] != getattr(profile, k)]
    return {"display_profile": profile.name,
            "display": {**profile.model_dump(mode="json"), "overridden": overridden}}


def field_of_view_box(optics: OpticsConfig, camera_fov_x_deg: float,
                      camera_film_hw: tuple[int, int]) -> dict[str, Any]:
    """Where the hologram's view lies in the scene camera's image (docs/design.md §3): the hologram shows
    2 atan(W p / 2f) by 2 atan(H p / 2f) around the camera's axis, the camera tan(fov_x / 2) across half its
    width (square pixels: h / w of that across half its height). Lateral position is linear in the tangent of
    the view angle on both, so the box's edges are the ratios of the tangents: ``x0, y0, x1, y1`` are fractions
    of the camera image's width and height from its top-left corner, and lie outside 0..1 where the display
    sees more than the camera (``beyond_camera``: the hologram's edges then show what the camera never
    rendered)."""
    h_px, w_px = (int(v) for v in camera_film_hw)
    cam_x = float(camera_fov_x_deg)
    if not (h_px > 0 and w_px > 0 and 0.0 < cam_x < 180.0):
        raise ValueError(f"camera film {h_px}x{w_px} px at {cam_x} deg is not usable")
    f = optics.focal_length_m(cam_x)
    t_cam_x = math.tan(math.radians(cam_x) / 2.0)
    t_cam_y = t_cam_x * h_px / w_px
    t_holo_x = optics.width * optics.pitch_m / (2.0 * f)
    t_holo_y = optics.resolution_hw[0] * optics.pitch_m / (2.0 * f)
    fx, fy = 0.5 * t_holo_x / t_cam_x, 0.5 * t_holo_y / t_cam_y
    box = {"x0": 0.5 - fx, "y0": 0.5 - fy, "x1": 0.5 + fx, "y1": 0.5 + fy}
    eps = 1e-9
    return {**box,
            "hologram_fov_x_deg": optics.field_of_view_x_deg(cam_x),
            "hologram_fov_y_deg": math.degrees(2.0 * math.atan(t_holo_y)),
            "camera_fov_x_deg": cam_x, "camera_fov_y_deg": math.degrees(2.0 * math.atan(t_cam_y)),
            "camera_film_hw_px": [h_px, w_px],
            "beyond_camera": fx > 0.5 + eps or fy > 0.5 + eps}


def field_of_view_report(optics: OpticsConfig, camera_fov_x_deg: float,
                         camera_film_hw: Optional[tuple[int, int]] = None) -> dict[str, Any]:
    """The hologram's horizontal field of view against the scene camera's (docs/design.md §3): the hologram shows
    2 atan(W p / 2f) around the camera's axis. ``differs`` when they differ by more than 0.1 % (or 0.01 deg);
    ``summary`` says so in one line. With the camera's film size, ``camera_film_hw_px`` and ``box``
    (:func:`field_of_view_box`: where the hologram's view lies in the camera's image) too."""
    f = optics.focal_length_m(camera_fov_x_deg)
    holo = optics.field_of_view_x_deg(camera_fov_x_deg)
    cam = float(camera_fov_x_deg)
    source = ("fit_camera_fov" if optics.fit_camera_fov else "fov_x_deg" if optics.fov_x_deg is not None
              else "display")
    differs = abs(holo - cam) > max(0.01, 1e-3 * cam)
    f_fit = (optics.width * optics.pitch_m / 2.0) / math.tan(math.radians(cam) / 2.0) if 0 < cam < 180 else None
    if source == "fit_camera_fov":
        line = (f"view: f = {f * 1e3:.3g} mm fitted to the scene camera's {cam:.3g} deg view (fit_camera_fov; "
                f"hologram depth goes as f^2, so this f, not the display's, sets the depth range)")
    elif not differs:
        line = f"view: the hologram's {holo:.3g} deg (f = {f * 1e3:.3g} mm) matches the scene camera's view"
    else:
        word = "narrower" if holo < cam else "wider"
        line = (f"view: the display (f = {f * 1e3:.3g} mm, {optics.width} px x {optics.pitch_um:g} µm) shows "
                f"{holo:.3g} deg around the scene camera's axis, the camera {cam:.3g} deg: the hologram sees a "
                f"{word} view than the camera")
        if f_fit:
            line += (f" (fit_camera_fov, --fit-camera-fov in holo, fits the camera's view instead: f = "
                     f"{f_fit * 1e3:.3g} mm, hologram depth x {(f_fit / f) ** 2:.2g})")
    out = {"hologram_fov_x_deg": holo, "camera_fov_x_deg": cam, "differs": differs, "focal_length_m": f,
           "focal_length_source": source, "summary": line}
    if camera_film_hw is not None:
        box = field_of_view_box(optics, cam, camera_film_hw)
        out["camera_film_hw_px"] = box["camera_film_hw_px"]
        out["box"] = {k: box[k] for k in ("x0", "y0", "x1", "y1", "beyond_camera")}
    return out
