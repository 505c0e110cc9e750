"""Kernels that call into a Mitsuba scene are recorded with Python's automatic garbage collection paused.

Why: Dr.Jit (1.5) names each callable of a virtual call ``func_<hash of its code>``, but its table of callables
tells a call with one target from a call with several. When a Mitsuba object leaves its registry while a kernel
is being recorded (the collector freeing an old scene held in a reference cycle, between two steps of a wave path),
one call site in the kernel sees two shapes and the next sees one: the same shape's code is emitted twice under
one name, LLVM refuses the module ("invalid redefinition of function") and Dr.Jit aborts the whole process, which
no ``except`` can catch. Paused collection frees nothing behind the recording's back; what the collector would
have freed is freed once the last recording in the process ends. Objects dropped by their last reference are
freed at once as ever: holocore holds the scene it traces for the whole trace.

Use :func:`recording_kernels` as a decorator (or ``with``) on each function that records and evaluates kernels
with scene calls (``ray_intersect``, BSDF and emitter calls, an integrator's ``sample``, ``mi.render``). Nesting
and threads are counted: collection resumes when the outermost recording ends, and only if it was on before.
"""

from __future__ import annotations

import gc
import threading
from contextlib import ContextDecorator

__all__ = ["recording_kernels"]


class _Pause:
    """How many recordings are open in this process, and whether collection was on before the first."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.depth = 0
        self.was_enabled = False

    def enter(self) -> None:
        with self.lock:
            if self.depth == 0:
                self.was_enabled = gc.isenabled()
                gc.disable()
            self.depth += 1

    def leave(self) -> None:
        with self.lock:
            self.depth -= 1
            if self.depth == 0 and self.was_enabled:
                gc.enable()


_PAUSE = _Pause()


class recording_kernels(ContextDecorator):
    """Pauses automatic garbage collection while Dr.Jit kernels with scene calls are recorded (see module doc)."""

    def __enter__(self) -> "recording_kernels":
        _PAUSE.enter()
        return self

    def __exit__(self, *exc: object) -> bool:
        _PAUSE.leave()
        return False
