"""The baselines behind one interface with a registry, as Mitsuba registers integrators: each method is a
:class:`Baseline` with a name, a one-line summary, an options model (its fields carry their units and limits:
the one validator of every option) and ``render(loaded, optics, options) -> RenderResult`` in the renderer's
RESULT format. ``holo baseline`` and the paper report find them here; a new baseline is one module that
defines its options and its class, declared as an entry point of group ``holocore.baselines`` by the package
that holds it (holocore.plugins; the built-ins are declared so in the project's pyproject.toml and found on the
first lookup).
"""

from __future__ import annotations

from typing import Any, ClassVar, Optional

from pydantic import BaseModel, ConfigDict, ValidationError

from holocore.plugins import BASELINES, register_discovered

__all__ = ["Baseline", "BaselineOptions", "BaselineOptionsError", "register_baseline", "baseline_names",
           "get_baseline"]



class BaselineOptions(BaseModel):
    """A baseline's options: frozen, unknown names refused. Subclasses declare fields with units in their
    names (``spacing_mm``, ``time_limit_s``) and their limits."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class BaselineOptionsError(ValueError):
    """A refused option: ``field`` (the option's name) and ``reason`` (one line); str() is "field: reason"."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field, self.reason = field, reason


class Baseline:
    """One baseline method. Subclasses set ``name``, ``summary`` and ``Options`` and implement :meth:`render`."""

    name: ClassVar[str]
    summary: ClassVar[str]
    Options: ClassVar[type[BaselineOptions]] = BaselineOptions

    def options(self, **values: Any) -> BaselineOptions:
        """The checked options (defaults for what is not given); :class:`BaselineOptionsError` names the first
        option refused."""
        try:
            return self.Options(**{k: v for k, v in values.items() if v is not None})
        except ValidationError as exc:
            err = exc.errors()[0]
            field = ".".join(str(p) for p in err.get("loc", ())) or "options"
            got = f" (got {err['input']!r})" if "input" in err and not isinstance(err["input"], dict) else ""
            raise BaselineOptionsError(field, f"{err.get('msg', 'invalid')}{got}") from None

    def describe(self, meta: dict) -> str:
        """One line about a result of this baseline (its meta), for the command line."""
        F, C, H, W = meta["shape_fchw"]
        return f"{F} frame(s) x {C} color(s) x {H}x{W}, z_wrp = {meta['z_wrp_m'] * 1e3:.3f} mm"

    def render(self, loaded: Any, optics: Any, options: BaselineOptions, *, display: Optional[Any] = None,
               progress: Optional[Any] = None) -> Any:
        """``loaded`` (a :class:`holocore.scene.load.LoadedScene`) through ``optics`` (OpticsConfig) ->
        :class:`holocore.render_meta.RenderResult`; ``display`` is recorded in the meta as the renderer does."""
        raise NotImplementedError


_REGISTRY: dict[str, type[Baseline]] = {}


def register_baseline(cls: type[Baseline]) -> type[Baseline]:
    """Class decorator: make ``cls`` available by its ``name``."""
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not name or not name.replace("-", "").isalnum():
        raise ValueError(f"a baseline needs a name of letters, digits and dashes, got {name!r}")
    if name in _REGISTRY and _REGISTRY[name] is not cls:
        raise ValueError(f"baseline {name!r} is registered already ({_REGISTRY[name].__module__})")
    if not issubclass(cls, Baseline) or not issubclass(cls.Options, BaselineOptions):
        raise TypeError(f"baseline {name!r} must subclass Baseline, its Options BaselineOptions")
    _REGISTRY[name] = cls
    return cls


_DISCOVERED: list[bool] = []


def _discover() -> None:
    """Register the baselines installed packages declare (entry point group ``holocore.baselines``, the
    built-ins among them: holocore.plugins), once; one that is not a baseline, or clashes, is left out with a
    warning."""
    if _DISCOVERED:
        return
    _DISCOVERED.append(True)
    register_discovered(BASELINES, register_baseline, Baseline, "baseline")


def baseline_names() -> tuple[str, ...]:
    """Every registered baseline's name, the project's own first, each part by name."""
    _discover()
    return tuple(sorted(_REGISTRY, key=lambda n: (not _REGISTRY[n].__module__.startswith("holocore."), n)))


def get_baseline(name: str) -> Baseline:
    """The baseline called ``name``; ValueError (with the names there are) for any other."""
    _discover()
    if name not in _REGISTRY:
        raise ValueError(f"unknown baseline {name!r}: one of {', '.join(baseline_names())}")
    return _REGISTRY[name]()
