"""Entry point of `holo`. Every module `holo/cmd_*.py` defines `register(app)`; they are found here, so
adding a subcommand touches only its own file. Modules import torch, Mitsuba or Dr.Jit inside the command
functions only, so `holo agent` and `holo serve` start fast where those are absent (docs/design.md §1)."""

from __future__ import annotations

import importlib
import pkgutil

import typer

import holo

app = typer.Typer(
    name="holo",
    help="Wave path tracing for holographic displays: render, encode, view, serve, play.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

for _mod in sorted(m.name for m in pkgutil.iter_modules(holo.__path__) if m.name.startswith("cmd_")):
    importlib.import_module(f"holo.{_mod}").register(app)


def main() -> None:
    app()
