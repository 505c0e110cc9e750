"""The options of one hologram, written once: every option a user sets on a render and its encode, with its unit,
its limits and the rules between options. It travels unchanged from the HTTP request (``service.jobfiles.JobFields``
embeds it) through the stored job and the job file to the driver, which hands it to `holo render` and `holo encode`
as one JSON document (``--options-json``); the CLI's flags set the same fields (:data:`CLI_FLAGS`) and
``RenderOptions`` checks its own fields here. ``tests/test_option_layers.py`` fails when a field is missing from a
layer: a CLI, `holo submit`, the page's form, or the option table of docs/options.md (``python -m holocore.options``
prints it).

Light: pydantic only, and no other holocore module (every stage may read the options).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Mapping, Optional, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

__all__ = ["HologramOptions", "PresetName", "RenderMethod", "MAX_WRP_PLANES", "Encoder", "ENCODERS", "WrpPlanes",
           "Optimiser", "OPTIMISERS", "DEFAULT_OPTIMISER",
           "CLI_FLAGS", "MAX_FRAMES", "MAX_SPP", "MAX_ITERATIONS", "QUALITY_DB_RANGE", "bounds", "choices", "explain",
           "check", "option_table"]

PresetName = Literal["fast", "balanced", "reference"]  # their settings: holocore.plan.presets.PRESETS
# "wrp": trace to the wave recording plane(s), then ASM to the SLM; "direct": trace straight to the SLM.
RenderMethod = Literal["wrp", "direct"]
MAX_WRP_PLANES = 8  # the most wave recording planes a render may use (holocore.plan.wrp_planes chooses up to it)
Encoder = Literal["sgd", "dpac"]  # the encoders a job may ask for (`holo encode` also has "naive", for tests)
ENCODERS: tuple[Encoder, ...] = ("sgd", "dpac")
# The SGD encoder's steps: memoryless BFGS for a fixed count (default) or Adam until its stop rule; what each runs
# and costs is holocore.plan.encode_steps.
Optimiser = Literal["lbfgs", "adam"]
OPTIMISERS: tuple[Optimiser, ...] = ("lbfgs", "adam")
DEFAULT_OPTIMISER: Optimiser = "lbfgs"
MAX_FRAMES = 256
MAX_SPP = 1_000_000
MAX_ITERATIONS = 1_000_000
MAX_TIME_LIMIT_S = 1e7
QUALITY_DB_RANGE = (5.0, 40.0)
WrpPlanes = Union[Annotated[int, Field(ge=1, le=MAX_WRP_PLANES)], Literal["auto"]]


class HologramOptions(BaseModel):
    """What a hologram renders and encodes besides its optics. ``None``: chosen (by the preset, the stop rule, the
    display's frames)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    preset: PresetName = Field(default="balanced", description="Quality preset: fast, balanced or reference "
                                                               "(docs/design.md §4).")
    frames: Optional[int] = Field(default=None, ge=1, le=MAX_FRAMES, description="Time-multiplexed frames; "
                                  "overrides the optics' frames.")
    spp: Optional[int] = Field(default=None, ge=1, le=MAX_SPP, description="Rays per WRP pixel (default: chosen "
                               "by the preset; with a time limit, the most).")
    max_spp: Optional[int] = Field(default=None, ge=1, le=MAX_SPP, description="Without spp: the most rays per "
                                   "WRP pixel the preset may choose (a service's cap).")
    render_time_limit_s: Optional[float] = Field(
        default=None, gt=0, lt=MAX_TIME_LIMIT_S, allow_inf_nan=False, description="Render for about this many "
        "seconds: passes of rays until the time is spent (spp is then the most rays per pixel).")
    encoder: Encoder = Field(default="sgd", description="sgd (complex-supervised phase optimisation) or dpac (double "
                                                            "phase).")
    optimiser: Optimiser = Field(default=DEFAULT_OPTIMISER, description="sgd's steps: lbfgs (memoryless BFGS, "
                                 "28 iterations by default) or adam (until its stop rule, about 140-160).")
    iterations: Optional[int] = Field(default=None, ge=0, le=MAX_ITERATIONS, description="Encoder iterations "
                                      "(sgd; default: the optimiser's, lbfgs 28, adam until its stop rule).")
    quality_db: Optional[float] = Field(
        default=None, ge=QUALITY_DB_RANGE[0], le=QUALITY_DB_RANGE[1], allow_inf_nan=False, description="Aim at "
        "this viewer-faithful PSNR, dB: frames (up to frames), spp and iterations predicted to reach it soonest "
        "(holocore.plan.quality_choice); give it without spp, iterations and render_time_limit_s.")
    method: RenderMethod = Field(default="wrp", description="wrp (trace to recording planes, then propagate) or "
                                 "direct (trace straight to the SLM).")
    wrp_planes: WrpPlanes = Field(default="auto", description=f"Wave recording planes: 1..{MAX_WRP_PLANES}, or "
                                  "auto (chosen from the scene depth).")

    @model_validator(mode="after")
    def _target_alone(self):
        given = [k for k in ("spp", "iterations", "render_time_limit_s") if getattr(self, k) is not None]
        if self.quality_db is not None and given:
            raise ValueError(f"quality_db chooses spp and iterations (and frames, up to the frames given): give it "
                             f"without {', '.join(given)}")
        return self

    @model_validator(mode="after")
    def _planes_need_wrp(self):
        if self.method == "direct" and self.wrp_planes not in (1, "auto"):
            raise ValueError("wrp_planes > 1 needs method 'wrp' (the direct method records on the SLM)")
        return self

    def hologram_options(self) -> "HologramOptions":
        """These options alone (a subclass's extra fields dropped)."""
        return HologramOptions.model_validate(self.model_dump(include=set(HologramOptions.model_fields)))


# Each option's flag on the commands that take it: (`holo render` / `holo plan`, `holo encode`, `holo submit`).
# None: that command does not take it (the option belongs to the other stage, or is a service's own cap).
CLI_FLAGS: Mapping[str, tuple[Optional[str], Optional[str], Optional[str]]] = {
    "preset": ("--preset", None, "--preset"),
    "frames": ("--frames", None, "--frames"),
    "spp": ("--spp", None, "--spp"),
    "max_spp": ("--max-spp", None, "--max-spp"),
    "render_time_limit_s": ("--time-limit-s", None, "--time-limit-s"),
    "encoder": (None, "--method", "--encoder"),
    "optimiser": (None, "--optimiser", "--optimiser"),
    "iterations": (None, "--iterations", "--iterations"),
    "quality_db": ("--quality-db", None, "--quality-db"),
    "method": ("--method", None, "--method"),
    "wrp_planes": ("--wrp-planes", None, "--wrp-planes"),
}
_COMMANDS = ("render", "encode", "submit")


def bounds(name: str) -> tuple[Any, Any]:
    """(lowest, highest) of a numeric option (None, None for one that has choices instead; wrp_planes: its count,
    besides its word)."""
    if name == "wrp_planes":
        return 1, MAX_WRP_PLANES
    lo = hi = None
    for meta in HologramOptions.model_fields[name].metadata:
        lo = getattr(meta, "ge", None) if getattr(meta, "ge", None) is not None else lo
        lo = getattr(meta, "gt", None) if getattr(meta, "gt", None) is not None else lo
        hi = getattr(meta, "le", None) if getattr(meta, "le", None) is not None else hi
        hi = getattr(meta, "lt", None) if getattr(meta, "lt", None) is not None else hi
    return lo, hi


def explain(exc: ValidationError, command: Optional[str] = None) -> str:
    """One line for a refused set of options, naming each option as ``command`` (render, encode, submit) spells
    it, else by its field name: "--spp must be in 1..1000000, got 0"."""
    parts = []
    for err in exc.errors():
        loc = [str(p) for p in err["loc"] if not str(p).startswith(("int", "literal", "function"))]
        field = loc[0] if loc else ""
        name = field
        if command is not None and field in CLI_FLAGS:
            name = CLI_FLAGS[field][_COMMANDS.index(command)] or field
        lo, hi = bounds(field) if field in HologramOptions.model_fields else (None, None)
        if not field:
            parts.append(str(err["msg"]).removeprefix("Value error, "))
        elif field == "wrp_planes":
            parts.append(f"{name} must be in 1..{MAX_WRP_PLANES} or auto, got {err['input']!r}")
        elif lo is not None and err["type"] in ("greater_than_equal", "greater_than", "less_than_equal",
                                                 "less_than"):
            rng = f"{lo}..{hi}" if err["type"].endswith("equal") else f"({lo}, {hi})"
            parts.append(f"{name} must be in {rng}, got {err['input']!r}")
        else:
            parts.append(f"{name}: {err['msg']}")
    return "; ".join(dict.fromkeys(parts))


def check(**fields: Any) -> HologramOptions:
    """The options ``fields`` give, checked (ValueError with :func:`explain`'s line when refused)."""
    try:
        return HologramOptions(**fields)
    except ValidationError as exc:
        raise ValueError(explain(exc)) from None


_UNITS = {"_s": "s", "_db": "dB", "spp": "rays per pixel"}


def choices(name: str) -> tuple[Any, ...]:
    """The values an option of choices takes (() for a numeric one; wrp_planes: its word, "auto")."""
    if name == "wrp_planes":
        return ("auto",)
    annotation = HologramOptions.model_fields[name].annotation
    return tuple(get_args(annotation)) if get_origin(annotation) is Literal else ()


def _limits(name: str) -> str:
    """An option's allowed values in words: its range, or its choices."""
    if name == "wrp_planes":
        return f"1..{MAX_WRP_PLANES}, auto"
    lo, hi = (f"{v:,}" if isinstance(v, int) else "None" if v is None else f"{v:g}" for v in bounds(name))
    if lo != "None":
        return f"({lo}, {hi})" if name == "render_time_limit_s" else f"{lo}..{hi}"
    return ", ".join(str(c) for c in choices(name))


def option_table() -> str:
    """The options as a markdown table (docs/options.md holds it; a test keeps the two the same)."""
    rows = ["| option | unit | default | allowed | `holo render` | `holo encode` | `holo submit` | meaning |",
            "|---|---|---|---|---|---|---|---|"]
    for name, field in HologramOptions.model_fields.items():
        unit = next((u for suffix, u in _UNITS.items() if name.endswith(suffix)), "")
        flags = [f"`{f}`" if f else "" for f in CLI_FLAGS[name]]
        default = "chosen" if field.default is None else f"`{field.default}`"
        rows.append(f"| `{name}` | {unit} | {default} | {_limits(name)} | {' | '.join(flags)} | "
                    f"{field.description} |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":
    print(option_table(), end="")
