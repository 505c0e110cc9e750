"""Optics configuration: one validated model of the display (docs/design.md §2, §3).

Public fields carry their unit in the name and are converted to SI once, by the ``*_m`` properties.
Defaults follow the paper's display (Sec. 5): 640.0 / 516.5 / 455.4 nm, 8 µm pitch, virtual infinity at 80 mm and
an eyepiece of f = 50 mm. f belongs to the display, not to the scene (docs/design.md §3): deriving it from the
scene camera's field of view is the explicit choice ``fit_camera_fov=True`` (or a given ``fov_x_deg``), never the
default. Named
display profiles (:mod:`holocore.display.profiles`) build an OpticsConfig; this model stays the numerics contract.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from holocore.display.phase_modes import frame_phase_modes, get_frame_phases

__all__ = ["OpticsConfig", "MAX_SIDE_PX", "MAX_FRAMES", "DISPLAY_FOCAL_LENGTH_MM", "theta_max_rad", "cone_sine",
           "common_cone_sine", "channel_of", "MIN_SCENE_SCALE", "MAX_SCENE_SCALE"]

MAX_SIDE_PX = 16384
"""Largest SLM or WRP side accepted, in pixels (a 16k×16k complex64 field is 2 GiB)."""
MIN_SCENE_SCALE, MAX_SCENE_SCALE = 1e-4, 1e4
"""The scene scales accepted (dimensionless): a metre-sized scene brought to 0.1 mm or pushed 10 km away."""
MAX_FRAMES = 256
"""Largest number of time-multiplexed frames accepted."""
DISPLAY_FOCAL_LENGTH_MM = 50.0
"""The paper's eyepiece f in mm (its 8 µm, 80 mm display shows 0.5, 0.9 and 10 m at 85, 82.8, 80.25 mm;
docs/design.md §3)."""

MAX_CONE_HALF_ANGLE_RAD = math.radians(89.0)
"""The recording cone's half-angle as the tracer and every estimate use it (rad): rays are kept off exactly grazing,
where cos theta = 0 gives an infinite ray weight r / cos theta (sub-wavelength pitch: lambda >= 2p)."""


def theta_max_rad(wavelength_m: float, pitch_m: float) -> float:
    """Half-angle of the recordable cone (rad), arcsin(lambda / 2p), pi/2 when lambda >= 2p (docs/design.md §4; paper
    Sec. 4.3). The one place this formula lives."""
    s = float(wavelength_m) / (2.0 * float(pitch_m))
    return math.pi / 2 if s >= 1.0 else math.asin(s)


def cone_sine(wavelength_m: float, pitch_m: float) -> float:
    """Direction sine of the recording cone's rim as the tracer uses it: sin(min(theta_max, 89 deg))."""
    return math.sin(min(theta_max_rad(wavelength_m, pitch_m), MAX_CONE_HALF_ANGLE_RAD))


def common_cone_sine(wavelengths_m, pitch_m: float) -> float:
    """The cone every colour shares (its direction sine): the smallest colour's, the display's common eyebox
    (half-width f times this sine at the eye)."""
    return min(cone_sine(float(lam), float(pitch_m)) for lam in wavelengths_m)


def channel_of(wavelength_m: float) -> int:
    """RGB channel of the scene that a laser line shows (docs/design.md §4): R from 590 nm, G 490-590 nm, B below."""
    nm = float(wavelength_m) * 1e9
    return 0 if nm >= 590.0 else (1 if nm >= 490.0 else 2)


Wavelength = Annotated[float, Field(gt=100.0, lt=3000.0, allow_inf_nan=False)]


class OpticsConfig(BaseModel):
    """The holographic display: SLM, wavelengths, eyepiece and frame bank.

    Units are in the field names; ``*_m`` properties give SI values for the numerics.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)

    wavelengths_nm: tuple[Wavelength, ...] = Field(
        default=(640.0, 516.5, 455.4),
        description="Laser lines in nm (100-3000), one per color channel, in channel order.",
    )
    pitch_um: float = Field(
        default=8.0, gt=0.0, le=1000.0, allow_inf_nan=False,
        description="SLM pixel pitch in µm (0 < p <= 1000). Sub-wavelength pitch is legal.",
    )
    resolution_hw: tuple[int, int] = Field(
        default=(1080, 1920), description=f"SLM rows x columns in pixels (each 1..{MAX_SIDE_PX})."
    )
    z_inf_mm: float = Field(
        default=80.0, gt=0.0, le=10_000.0, allow_inf_nan=False,
        description="Distance from the SLM to the eyepiece's front focal plane ('virtual infinity'), mm.",
    )
    focal_length_mm: Optional[float] = Field(
        default=DISPLAY_FOCAL_LENGTH_MM, gt=0.0, le=10_000.0, allow_inf_nan=False,
        description="Eyepiece focal length f in mm, the display's (default: the paper's 50 mm; docs/design.md §3). "
                    "None only with fit_camera_fov or fov_x_deg, which then determine f.",
    )
    fit_camera_fov: bool = Field(
        default=False,
        description="Derive f from the scene camera's horizontal field of view filling the SLM width, "
                    "f = (W p / 2) / tan(fov_x / 2) (docs/design.md §3). Off by default: f is the display's.",
    )
    fov_x_deg: Optional[float] = Field(
        default=None, gt=0.0, lt=180.0, allow_inf_nan=False,
        description="Horizontal field of view in degrees that fills the SLM width and so determines f; "
                    "None: f is focal_length_mm (or the camera's view with fit_camera_fov).",
    )
    scene_scale: float = Field(
        default=1.0, ge=MIN_SCENE_SCALE, le=MAX_SCENE_SCALE, allow_inf_nan=False,
        description="The scene as if scaled by this factor about its camera (0.1: every distance a tenth): depth "
                    "in hologram space goes as 1 / scale, the view is unchanged. Brings content modelled metres "
                    "away to where an eye accommodates (docs/design.md §3, 'Scene scale'); the plan suggests one.",
    )
    frames: int = Field(default=8, ge=1, le=MAX_FRAMES, description=f"Time-multiplexed frames (1..{MAX_FRAMES}).")
    seed: int = Field(default=0, ge=0, lt=2**63, description="Seed of every random choice (rays, phase bank).")
    frame_phases: str = Field(
        default="coded",
        description="Phases of the frames' image points, a registered mode (holocore.display.phase_modes): "
                    + "; ".join(f"'{n}' ({get_frame_phases(n).summary})" for n in frame_phase_modes()) + ".",
    )
    eyebox: Literal["common", "per_colour"] = Field(
        default="common",
        description="Directions each colour's field may leave in: 'common' (every colour cut to the smallest "
                    "colour's cone, so the colour balance an eye sees does not change with its pupil or position; "
                    "red and green lose their wider rims) or 'per_colour' (each colour its own cone "
                    "arcsin(lambda / 2p): a wider eyebox for red, whose image turns redder through pupils larger "
                    "than blue's eyebox). docs/physics.md, 'One eyebox for every colour'.",
    )
    wrp_margin_px: float = Field(
        default=4.0, ge=0.0, le=1000.0, allow_inf_nan=False,
        description="WRP margin in pixel footprints: no image point closer than this many p/tan(theta_max).",
    )
    max_wrp_distance_mm: float = Field(
        default=1000.0, gt=0.0, allow_inf_nan=False,
        description="Largest z_wrp - z_inf accepted (mm); scenes needing more are refused.",
    )

    @field_validator("frame_phases")
    @classmethod
    def _known_frame_phases(cls, v: str) -> str:
        get_frame_phases(v)  # one line naming the registered modes otherwise
        return v

    def frame_phase_mode(self):
        """The :class:`holocore.display.phase_modes.FramePhases` object of ``frame_phases``."""
        return get_frame_phases(self.frame_phases)

    @field_validator("wavelengths_nm")
    @classmethod
    def _some_wavelengths(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if not 1 <= len(v) <= 8:
            raise ValueError(f"wavelengths_nm needs 1 to 8 wavelengths, got {len(v)}")
        return v

    @field_validator("resolution_hw")
    @classmethod
    def _sane_resolution(cls, v: tuple[int, int]) -> tuple[int, int]:
        for name, n in zip(("height", "width"), v):
            if not 1 <= n <= MAX_SIDE_PX:
                raise ValueError(f"resolution_hw {name} must be in 1..{MAX_SIDE_PX} px, got {n}")
        return v

    @model_validator(mode="before")
    @classmethod
    def _f_source_given(cls, data: Any) -> Any:
        """fit_camera_fov or fov_x_deg given without focal_length_mm: they replace the default f. A record that
        sets focal_length_mm to null with neither (the format before fit_camera_fov) meant the camera's view."""
        if not isinstance(data, dict):
            return data
        fit, fov = data.get("fit_camera_fov"), data.get("fov_x_deg")
        if "focal_length_mm" not in data and (fov is not None or fit not in (None, False)):
            return {**data, "focal_length_mm": None}
        if "focal_length_mm" in data and data["focal_length_mm"] is None and fov is None and fit is None:
            return {**data, "fit_camera_fov": True}
        return data

    @model_validator(mode="after")
    def _f_or_fov(self) -> "OpticsConfig":
        given = [name for name, on in (("focal_length_mm", self.focal_length_mm is not None),
                                       ("fov_x_deg", self.fov_x_deg is not None),
                                       ("fit_camera_fov", self.fit_camera_fov)) if on]
        if len(given) > 1:
            raise ValueError(f"give one of focal_length_mm, fov_x_deg, fit_camera_fov, not both "
                             f"{' and '.join(given)} (each determines f)")
        if not given:
            raise ValueError("focal_length_mm is null: give the eyepiece f in mm, or fit_camera_fov true")
        return self

    # ---- SI views -------------------------------------------------------------------------------------
    @property
    def wavelengths_m(self) -> tuple[float, ...]:
        return tuple(w * 1e-9 for w in self.wavelengths_nm)

    @property
    def pitch_m(self) -> float:
        return self.pitch_um * 1e-6

    @property
    def z_inf_m(self) -> float:
        return self.z_inf_mm * 1e-3

    @property
    def height(self) -> int:
        return self.resolution_hw[0]

    @property
    def width(self) -> int:
        return self.resolution_hw[1]

    def focal_length_m(self, scene_fov_x_deg: float | None = None) -> float:
        """Eyepiece focal length in m: the display's focal_length_mm; with fov_x_deg, or with fit_camera_fov the
        scene camera's ``scene_fov_x_deg``, the f at which that view fills the SLM width (docs/design.md §3)."""
        if self.focal_length_mm is not None:
            return self.focal_length_mm * 1e-3
        fov = self.fov_x_deg if self.fov_x_deg is not None else scene_fov_x_deg
        if fov is None or not (0.0 < fov < 180.0):
            raise ValueError("focal length unknown: fit_camera_fov needs the scene camera's FOV (or set "
                             "focal_length_mm or fov_x_deg)")
        return (self.width * self.pitch_m / 2.0) / math.tan(math.radians(fov) / 2.0)

    def field_of_view_x_deg(self, scene_fov_x_deg: float | None = None) -> float:
        """Horizontal field of view the hologram shows, 2 atan(W p / 2f), in degrees (docs/design.md §3)."""
        return math.degrees(2.0 * math.atan(self.width * self.pitch_m / (2.0 * self.focal_length_m(scene_fov_x_deg))))

    def eyebox_sine(self) -> float | None:
        """The direction sine every colour's field is cut to (:func:`common_cone_sine`), None with a per-colour
        eyebox (each colour's own cone, nothing cut)."""
        return common_cone_sine(self.wavelengths_m, self.pitch_m) if self.eyebox == "common" else None

    def theta_max(self, wavelength_m: float) -> float:
        """Half-angle of the recordable cone (rad): :func:`theta_max_rad` at this pitch (docs/design.md §4)."""
        return theta_max_rad(wavelength_m, self.pitch_m)
