"""Optics configuration: one validated model of the display (DESIGN.md §2, §3).

Public fields carry their unit in the name and are converted to SI once, by the ``*_m`` properties.
Defaults follow the paper (Sec. 5): 640.0 / 516.5 / 455.4 nm, 8 µm pitch, virtual infinity at 80 mm.
"""

from __future__ import annotations

import math
from typing import Annotated, Optional

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

__all__ = ["OpticsConfig", "MAX_SIDE_PX", "MAX_FRAMES"]

MAX_SIDE_PX = 16384
"""Largest SLM or WRP side accepted, in pixels (a 16k×16k complex64 field is 2 GiB)."""
MAX_FRAMES = 256
"""Largest number of time-multiplexed frames accepted."""

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
        default=None, gt=0.0, le=10_000.0, allow_inf_nan=False,
        description="Eyepiece focal length f in mm; None derives it from the field of view (DESIGN §3).",
    )
    fov_x_deg: Optional[float] = Field(
        default=None, gt=0.0, lt=180.0, allow_inf_nan=False,
        description="Horizontal field of view in degrees; None takes the scene camera's.",
    )
    frames: int = Field(default=8, ge=1, le=MAX_FRAMES, description=f"Time-multiplexed frames (1..{MAX_FRAMES}).")
    seed: int = Field(default=0, ge=0, lt=2**63, description="Seed of every random choice (rays, phase bank).")
    wrp_margin_px: float = Field(
        default=4.0, ge=0.0, le=1000.0, allow_inf_nan=False,
        description="WRP margin in pixel footprints: no image point closer than this many p/tan(theta_max).",
    )
    max_wrp_distance_mm: float = Field(
        default=1000.0, gt=0.0, allow_inf_nan=False,
        description="Largest z_wrp - z_inf accepted (mm); scenes needing more are refused.",
    )

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

    @model_validator(mode="after")
    def _f_or_fov(self) -> "OpticsConfig":
        if self.focal_length_mm is not None and self.fov_x_deg is not None:
            raise ValueError("give focal_length_mm or fov_x_deg, not both (one determines the other)")
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
        """Eyepiece focal length in m: explicit, else from the FOV filling the SLM width (DESIGN §3)."""
        if self.focal_length_mm is not None:
            return self.focal_length_mm * 1e-3
        fov = self.fov_x_deg if self.fov_x_deg is not None else scene_fov_x_deg
        if fov is None or not (0.0 < fov < 180.0):
            raise ValueError("focal length unknown: set focal_length_mm or fov_x_deg, or give a scene camera FOV")
        return (self.width * self.pitch_m / 2.0) / math.tan(math.radians(fov) / 2.0)

    def theta_max(self, wavelength_m: float) -> float:
        """Half-angle of the recordable cone (rad): arcsin(lambda / 2p), pi/2 when lambda >= 2p (DESIGN §4)."""
        s = wavelength_m / (2.0 * self.pitch_m)
        return math.pi / 2 if s >= 1.0 else math.asin(s)
