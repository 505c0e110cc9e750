"""User hooks: a shell command or a Python callable, for the camera trigger and the laser channel switch.

Spec forms: ``py:package.module:function`` (called with keyword arguments) or a shell command line whose
``{name}`` fields are filled from the same keyword arguments (e.g. ``gphoto2 --capture-image --filename
plane{plane}.jpg``); the command runs without a shell, must exit 0 within ``timeout_s``.
"""

from __future__ import annotations

import importlib
import shlex
import subprocess
from typing import Any, Callable

__all__ = ["HookError", "make_hook"]


class HookError(RuntimeError):
    """A hook failed (non-zero exit, timeout, exception, or a bad spec)."""


def make_hook(spec: str, *, timeout_s: float = 30.0) -> Callable[..., None]:
    """A callable ``hook(**fields)`` from a spec (see module doc)."""
    if not spec or not spec.strip():
        raise ValueError("hook spec must be 'py:module:function' or a command line, got an empty string")
    if not (timeout_s > 0):
        raise ValueError(f"timeout_s must be > 0 seconds, got {timeout_s}")
    if spec.startswith("py:"):
        mod_name, _, func_name = spec[3:].rpartition(":")
        if not mod_name or not func_name:
            raise ValueError(f"python hook must be py:module:function, got {spec!r}")
        try:
            func = getattr(importlib.import_module(mod_name), func_name)
        except (ImportError, AttributeError) as exc:
            raise ValueError(f"cannot load hook {spec!r}: {exc}") from exc
        if not callable(func):
            raise ValueError(f"hook {spec!r} is not callable")

        def call_py(**fields: Any) -> None:
            try:
                func(**fields)
            except Exception as exc:  # noqa: BLE001 - user code
                raise HookError(f"hook {spec} raised {type(exc).__name__}: {exc}") from exc

        return call_py
    try:
        template = shlex.split(spec)
    except ValueError as exc:
        raise ValueError(f"cannot parse hook command {spec!r}: {exc}") from exc

    def call_cmd(**fields: Any) -> None:
        try:
            argv = [t.format(**fields) for t in template]
        except (KeyError, IndexError, ValueError) as exc:
            raise HookError(f"hook command {spec!r} uses an unknown field: {exc} (have {sorted(fields)})") from exc
        try:
            res = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise HookError(f"hook command {argv[0]!r} failed: {exc}") from exc
        if res.returncode != 0:
            tail = (res.stderr or res.stdout).strip().splitlines()[-1:] or [""]
            raise HookError(f"hook command {argv[0]!r} exited {res.returncode}: {tail[0][:200]}")

    return call_cmd
