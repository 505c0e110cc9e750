"""Helpers shared by the `holo` subcommands (light: no torch, Mitsuba or Dr.Jit here)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Callable, NoReturn, Optional

import typer

__all__ = ["fail", "optics_from_options", "progress_writer", "parse_hw"]


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


def optics_from_options(*, optics_json: Optional[Path] = None, **overrides) -> "object":
    """OpticsConfig from an optional JSON file plus CLI overrides (None = keep). Errors exit with code 2."""
    from pydantic import ValidationError

    from holocore.config import OpticsConfig

    data: dict = {}
    if optics_json is not None:
        try:
            data = json.loads(Path(optics_json).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            fail(f"cannot read --optics-json {optics_json}: {exc}")
        if not isinstance(data, dict):
            fail("--optics-json must hold a JSON object")
    if overrides.get("resolution"):
        data["resolution_hw"] = parse_hw(overrides.pop("resolution"))
    overrides.pop("resolution", None)
    wl = overrides.pop("wavelengths_nm", None)
    if wl:
        try:
            data["wavelengths_nm"] = [float(v) for v in wl.split(",")]
        except ValueError:
            fail(f"--wavelengths-nm must be numbers separated by commas, got {wl!r}")
    for key, value in overrides.items():
        if value is not None:
            data[key] = value
    try:
        return OpticsConfig(**data)
    except ValidationError as exc:
        msgs = "; ".join(f"{'.'.join(str(p) for p in e['loc']) or 'optics'}: {e['msg']}" for e in exc.errors())
        fail(f"invalid optics: {msgs}")


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


def stderr_is_tty() -> bool:
    return sys.stderr.isatty()
