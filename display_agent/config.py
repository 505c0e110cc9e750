"""Agent configuration: defaults < config file (TOML or JSON) < environment ``HOLO_AGENT_*`` < CLI options.

Every field can be set from the environment as ``HOLO_AGENT_<FIELD>`` (e.g. ``HOLO_AGENT_SERVER_URL``,
``HOLO_AGENT_RATE_HZ``); the short names ``HOLO_AGENT_SERVER``, ``HOLO_AGENT_FOCUS`` and ``HOLO_AGENT_CONFIG``
(the file) work too. A TOML file may hold the fields at top level or in an ``[agent]`` table.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any, Literal, Mapping, Optional, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["AgentConfig", "load_config", "ConfigError", "ENV_PREFIX"]

ENV_PREFIX = "HOLO_AGENT_"
_ENV_ALIASES = {"SERVER": "server_url", "FOCUS": "focus_url"}


class ConfigError(ValueError):
    """The configuration (file, environment or options) is invalid; the message names the field."""


class AgentConfig(BaseModel):
    """All settings of the display agent (units in the names)."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    server_url: Optional[str] = Field(None, description="Service base URL, http(s)://host:port")
    token: Optional[str] = Field(None, description="Bearer token (scope agent)")
    token_file: Optional[Path] = Field(None, description="File holding the token (first line)")
    display: str = Field("default", pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$", description="Display name")
    slm: str = Field("window:0", description="SLM backend: sim:DIR | window[:MONITOR[:WxH]] | null")
    focus_url: Optional[str] = Field(None, description="Focus controller: serial port or serial_for_url URL")
    policy: Literal["loop", "once", "capture"] = Field(
        "loop", description="loop: play the newest stack continuously; once: one pass per new stack then blank; "
                            "capture: a capture sequence per new stack")
    rate_hz: float = Field(60.0, ge=0.0, le=10_000.0, description="SLM frame slots per second (0 = SLM's pace)")
    lut: Optional[Path] = Field(None, description="Per-wavelength lookup table (JSON or .npy)")
    levels_per_2pi: Union[int, list[int]] = Field(256, description="Gray level meaning 2pi (one or per colour)")
    laser_hook: Optional[str] = Field(None, description="Hook run on colour change: py:mod:func or command {color}")
    planes: int = Field(5, ge=1, le=64, description="Capture: focus planes 0..planes-1")
    passes_per_plane: int = Field(1, ge=1, le=100_000, description="Capture: stack passes per plane")
    trigger: Optional[str] = Field(None, description="Capture: camera trigger hook (py:mod:func or command)")
    trigger_at: Literal["before_play", "after_play"] = "after_play"
    hook_timeout_s: float = Field(30.0, gt=0.0, le=3600.0)
    settle_timeout_s: float = Field(30.0, gt=0.0, le=3600.0)
    focus_reply_timeout_s: float = Field(2.0, gt=0.0, le=60.0)
    focus_ready_timeout_s: float = Field(10.0, gt=0.0, le=120.0)
    focus_reconnect_timeout_s: float = Field(30.0, ge=0.0, le=3600.0)
    baudrate: int = Field(115200, ge=300, le=4_000_000)
    cache_dir: Path = Field(Path("~/.cache/holo-agent"), description="Local stack cache")
    cache_max_stacks: int = Field(8, ge=1, le=1000)
    poll_interval_s: float = Field(2.0, gt=0.0, le=3600.0, description="How often to ask the service")
    heartbeat_interval_s: float = Field(10.0, gt=0.0, le=3600.0)
    request_timeout_s: float = Field(10.0, gt=0.0, le=600.0)
    backoff_base_s: float = Field(0.5, gt=0.0, le=60.0)
    backoff_cap_s: float = Field(30.0, gt=0.0, le=3600.0)
    backoff_jitter: float = Field(0.5, ge=0.0, le=1.0)
    log_file: Optional[Path] = None

    @field_validator("server_url")
    @classmethod
    def _url(cls, v: Optional[str]) -> Optional[str]:
        if v is not None and not v.startswith(("http://", "https://")):
            raise ValueError("must start with http:// or https://")
        return v.rstrip("/") if v else v

    @field_validator("levels_per_2pi")
    @classmethod
    def _levels(cls, v: Union[int, list[int]]) -> Union[int, list[int]]:
        vals = [v] if isinstance(v, int) else v
        if not vals or any(not 2 <= x <= 256 for x in vals):
            raise ValueError("must be in [2, 256] (one value, or one per colour)")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> "AgentConfig":
        if self.backoff_cap_s < self.backoff_base_s:
            raise ValueError("backoff_cap_s must be >= backoff_base_s")
        if self.lut is not None and self.levels_per_2pi != 256:
            raise ValueError("give either lut or levels_per_2pi, not both")
        return self

    def resolved_token(self) -> Optional[str]:
        """The token, read from ``token_file`` if set there."""
        if self.token:
            return self.token
        if self.token_file is not None:
            try:
                return Path(self.token_file).expanduser().read_text().strip().splitlines()[0]
            except (OSError, IndexError) as exc:
                raise ConfigError(f"cannot read token_file {self.token_file}: {exc}") from exc
        return None


def _read_file(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc}") from exc
    try:
        data = tomllib.loads(text) if path.suffix.lower() == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"config file {path} is not valid {'TOML' if path.suffix == '.toml' else 'JSON'}: "
                          f"{exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path} must hold an object/table")
    if isinstance(data.get("agent"), dict):
        data = data["agent"]
    return data


def _from_env(env: Mapping[str, str]) -> dict[str, Any]:
    fields = AgentConfig.model_fields
    out: dict[str, Any] = {}
    for key, value in env.items():
        if not key.startswith(ENV_PREFIX) or key == ENV_PREFIX + "CONFIG":
            continue
        name = key[len(ENV_PREFIX):]
        field = _ENV_ALIASES.get(name, name.lower())
        if field not in fields:
            raise ConfigError(f"unknown environment variable {key} (fields: {', '.join(sorted(fields))})")
        if field == "levels_per_2pi" and "," in value:
            out[field] = [v.strip() for v in value.split(",")]
        else:
            out[field] = value if value != "" else None
    return out


def load_config(path: Optional[Union[str, Path]] = None, *, env: Optional[Mapping[str, str]] = None,
                overrides: Optional[Mapping[str, Any]] = None) -> AgentConfig:
    """Merge defaults, the file (``path`` or ``$HOLO_AGENT_CONFIG``), the environment and ``overrides``
    (None values are ignored). Raises ConfigError with the offending field named."""
    env = os.environ if env is None else env
    data: dict[str, Any] = {}
    file = path if path is not None else env.get(ENV_PREFIX + "CONFIG")
    if file:
        data.update(_read_file(Path(file)))
    data.update(_from_env(env))
    data.update({k: v for k, v in (overrides or {}).items() if v is not None})
    try:
        cfg = AgentConfig(**data)
    except ValidationError as exc:
        msgs = "; ".join(f"{'.'.join(str(p) for p in e['loc']) or 'config'}: {e['msg']}" for e in exc.errors())
        raise ConfigError(f"invalid agent configuration: {msgs}") from exc
    cfg.cache_dir = cfg.cache_dir.expanduser()
    return cfg
