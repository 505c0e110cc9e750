"""The metadata of RESULT and STACK files, typed (numpy and pydantic only: the display agent imports it).

On disk the metadata stays one JSON object per file (``meta`` member), readable with numpy and ``json`` alone.
Reading goes through :class:`ResultMeta` / :class:`StackMeta`: the numbers every reader needs are typed fields
in SI units, checked once here (one line naming the field when a file is wrong); what only some writers put
(the plan, the analysis, timings, the display profile...) is kept as it was written, so an older file, or a
newer one with keys this version does not know, still loads and is written back unchanged.

Readers use the attributes (``meta.z_wrp_m``); :meth:`ResultMeta.to_dict` gives the JSON object back. The model
is also a read-only mapping (``meta["analysis"]``, ``meta.get("timings")``, ``{**meta}``) for the optional,
free-form parts.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from functools import cached_property
from typing import Any, Optional, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

__all__ = ["MetaLike", "ViewMeta", "ResultMeta", "StackMeta", "MetaError", "parse_view_meta", "parse_result_meta",
           "parse_stack_meta"]

_WAVELENGTH_RANGE_M = (100e-9, 10e-6)  # the formats import nothing else of holocore (the agent's rule)


class MetaError(ValueError):
    """A RESULT/STACK file's metadata is not what the format says (one line)."""


class _Meta(BaseModel, Mapping):
    """What RESULT and STACK metadata share: typed fields in SI units, other keys kept as written."""

    model_config = ConfigDict(extra="allow", frozen=True)

    wavelengths_m: tuple[float, ...] = Field(min_length=1, description="one wavelength per color channel")
    wrp_planes_m: Optional[tuple[float, ...]] = None  # every recording plane when there are several
    shape_fchw: Optional[tuple[int, int, int, int]] = None  # frames, colors, rows, columns
    method: Optional[str] = None  # how the field was made: wrp (ours), layers, focal-stack, ...
    preset: Optional[str] = None
    display_profile: Optional[str] = None  # the display profile's name
    display: Optional[dict[str, Any]] = None  # the profile itself
    optics: Optional[dict[str, Any]] = None  # OpticsConfig as the user gave it
    analysis: Optional[dict[str, Any]] = None
    plan: Optional[dict[str, Any]] = None
    timings: Optional[dict[str, Any]] = None  # seconds per stage
    stats: Optional[dict[str, Any]] = None
    versions: Optional[dict[str, Any]] = None
    device: Optional[str] = None

    @field_validator("wavelengths_m")
    @classmethod
    def _wavelengths_in_range(cls, v):
        lo, hi = _WAVELENGTH_RANGE_M
        if not all(lo < w < hi for w in v):
            raise ValueError(f"must be metres in (100 nm, 10 um), got {list(v)}")
        return v

    @field_validator("pitch_m", check_fields=False)
    @classmethod
    def _pitch_positive(cls, v):
        vals = v if isinstance(v, tuple) else (v,)
        if v is not None and not all(p > 0 for p in vals):
            raise ValueError("must be > 0 m")
        return v

    @property
    def fourier_filter(self) -> bool:
        """True when the display the field was made for has a Fourier filter that passes only each colour's
        recording cone (its profile's ``fourier_filter``); False for a field made without a display profile."""
        return bool((self.display or {}).get("fourier_filter", False))

    def to_dict(self) -> dict[str, Any]:
        """The JSON object as written to the file (optional fields the writer did not set left out); a new dict."""
        return self.model_dump(mode="json", exclude_unset=True)

    @cached_property
    def _json(self) -> dict[str, Any]:
        """:meth:`to_dict` once, for the mapping reads below (the model is frozen)."""
        return self.to_dict()

    def with_fields(self, **fields: Any):
        """A copy with ``fields`` set, checked like a file's (e.g. a stack's ``encoder``)."""
        return type(self).model_validate({**self.to_dict(), **fields})

    # a read-only mapping over the JSON object, for the free-form parts (``meta["analysis"]``, ``{**meta}``)
    def __getitem__(self, key: str) -> Any:
        return self._json[key]  # as stored (lists, not tuples)

    def __iter__(self) -> Iterator[str]:  # type: ignore[override]  (pydantic iterates pairs; a mapping keys)
        return iter(self._json)

    def __len__(self) -> int:
        return len(self._json)

    def __contains__(self, key: object) -> bool:
        return key in self._json

    def get(self, key: str, default: Any = None) -> Any:
        return self._json.get(key, default)


class ViewMeta(_Meta):
    """What an eye's view of a field needs (docs/design.md §3, §7): f, virtual infinity and the pitch, in metres."""

    focal_length_m: float = Field(gt=0, description="eyepiece focal length f (docs/design.md §3)")
    z_inf_m: float = Field(ge=0, description="virtual infinity: where a point at infinity images")
    pitch_m: Union[float, tuple[float, float]] = Field(description="SLM pixel pitch, or (pitch_y, pitch_x)")
    z_wrp_m: Optional[float] = Field(default=None, gt=0)
    scene_scale: float = Field(default=1.0, gt=0, description="the scene as if scaled by this about its camera "
                               "(docs/design.md §3): a world length is this many times as long for the eye")

    @property
    def pitch_yx_m(self) -> tuple[float, float]:
        """(pitch_y, pitch_x) in metres."""
        p = self.pitch_m
        return (float(p[0]), float(p[1])) if isinstance(p, tuple) else (float(p), float(p))


class ResultMeta(ViewMeta):
    """RESULT metadata (docs/design.md §1-3): where the recorded field sits, in metres; every reader needs these."""

    z_wrp_m: float = Field(gt=0, description="the (first) wave recording plane, in front of the SLM")


class StackMeta(_Meta):
    """STACK metadata: what the SLM needs (the wavelengths) and, from a render, its meta carried forward with the
    encoder's record. Viewing a stack needs the render's geometry: :func:`parse_result_meta` of it."""

    focal_length_m: Optional[float] = Field(default=None, gt=0)
    z_inf_m: Optional[float] = Field(default=None, ge=0)
    z_wrp_m: Optional[float] = Field(default=None, gt=0)
    pitch_m: Optional[Union[float, tuple[float, float]]] = None
    encoder: Optional[dict[str, Any]] = None  # method, loss, efficiency, illumination per (frame, color)...


MetaLike = Union["_Meta", Mapping[str, Any]]
"""Typed meta, or the JSON object it parses from (a dict built by hand, an older caller's)."""


def _parse(cls, raw: Any, what: str):
    if isinstance(raw, cls):  # a ResultMeta is already a ViewMeta: nothing to check again
        return raw
    if isinstance(raw, _Meta):
        raw = raw.to_dict()
    if not isinstance(raw, Mapping):
        raise MetaError(f"{what}: meta must be a JSON object")
    try:
        return cls.model_validate(dict(raw))
    except ValidationError as exc:
        e = exc.errors()[0]
        field = ".".join(str(p) for p in e["loc"]) or "meta"
        raise MetaError(f"{what}: meta.{field}: {e['msg']}") from None


def parse_result_meta(raw: Any, *, what: str = "result") -> ResultMeta:
    """A RESULT's meta (a dict from JSON, or typed, a stack's too) -> :class:`ResultMeta`; MetaError naming
    ``what`` when a field the geometry needs is missing or wrong."""
    return _parse(ResultMeta, raw, what)


def parse_view_meta(raw: Any, *, what: str = "field") -> ViewMeta:
    """The geometry an eye's view needs, from a RESULT's or a STACK's meta -> :class:`ViewMeta`."""
    return _parse(ViewMeta, raw, what)


def parse_stack_meta(raw: Any, *, what: str = "stack") -> StackMeta:
    """A STACK's meta -> :class:`StackMeta`; MetaError naming ``what``."""
    return _parse(StackMeta, raw, what)
