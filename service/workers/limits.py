"""Kernel resource limits (``setrlimit``) on the planner and every job process: the backstop for whatever the
bundle check and admission miss. A process under them cannot raise them again, and its children inherit them.

- memory: ``RLIMIT_DATA``, the process's heap and private writable mappings, what it actually fills. Not
  ``RLIMIT_AS``: CUDA and Dr.Jit reserve address space far beyond what they use (inaccessible mappings, which
  ``RLIMIT_DATA`` does not count), so an address-space cap would refuse a GPU render that fits.
- CPU: ``RLIMIT_CPU``, seconds of CPU time per process (all its threads); SIGXCPU at the limit, SIGKILL a few
  seconds later for a process that ignores it.
- open files: ``RLIMIT_NOFILE``; the largest file written: ``RLIMIT_FSIZE``; processes and threads of the
  sandbox uid: ``RLIMIT_NPROC`` (only for a sandbox uid: for the server's own user it would count the server).
- no core dumps (``RLIMIT_CORE`` 0): a crash must not write a dump the size of its memory into the job dir.

The values come from the service's settings (``plan_limits``, ``job_limits``): memory, what the workers may hold
(``worker_memory_mb``; half of it for a plan), CPU, the run's wall-clock cap (``plan_timeout_s``,
``job_timeout_s``) on every core; the largest file a job may write, the most its folder may hold (given by the
scheduler from the job's optics and planes, at least 1 GiB; a render streams its result to the disk, so that is
not bounded by its memory), a plan's 1 GiB (it writes only caches).

``python -m service.workers.limits LIMITS_JSON -- CMD...`` applies them and executes CMD in place (same pid,
so a caller's process group and memory watch stay valid); the planner starts `holo plan` so. The job driver
applies its own at start (``job.json``'s ``limits``, written by the scheduler before the run's uid gets the
folder), so the CLIs it runs inherit them, and words a step they stopped with ``explain_limit``.
"""

from __future__ import annotations

import math
import os
import re
import resource
import signal
import sys
from typing import Optional

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["ProcessLimits", "current_limits", "explain_limit", "wrap_command", "plan_limits", "job_limits"]

CPU_KILL_AFTER_S = 5  # SIGKILL this long after SIGXCPU
OPEN_FILES = 4096
PLAN_FILE_SIZE_BYTES = MIN_FILE_SIZE_BYTES = 1 << 30
# The least memory a plan or job process is held to, whatever the settings say: the interpreter with torch,
# OpenBLAS's per-core buffers and CUDA's host side take about 1.5 GB before any work on a 16-core GPU machine
# (CUDA's address-space reservations and device memory are not counted by RLIMIT_DATA).
MIN_MEMORY_BYTES = 4 << 30


class ProcessLimits(BaseModel):
    """What one process (and each of its children) may use; None: no limit of ours."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    memory_bytes: Optional[int] = Field(default=None, ge=1 << 20)
    cpu_s: Optional[int] = Field(default=None, ge=1)
    open_files: Optional[int] = Field(default=None, ge=64)
    file_size_bytes: Optional[int] = Field(default=None, ge=1 << 20)
    processes: Optional[int] = Field(default=None, ge=16)

    def apply(self) -> None:
        """Set this process's limits to these (never above a hard limit already in force)."""
        _lower(resource.RLIMIT_CORE, 0, 0)
        if self.memory_bytes is not None:
            _lower(resource.RLIMIT_DATA, self.memory_bytes, self.memory_bytes)
        if self.cpu_s is not None:
            _lower(resource.RLIMIT_CPU, self.cpu_s, self.cpu_s + CPU_KILL_AFTER_S)
        if self.open_files is not None:
            _lower(resource.RLIMIT_NOFILE, self.open_files, self.open_files)
        if self.file_size_bytes is not None:
            _lower(resource.RLIMIT_FSIZE, self.file_size_bytes, self.file_size_bytes)
        if self.processes is not None:
            _lower(resource.RLIMIT_NPROC, self.processes, self.processes)

    def to_arg(self) -> str:
        return self.model_dump_json(exclude_none=True)


def _lower(which: int, soft: int, hard: int) -> None:
    """Lower a limit to (``soft``, ``hard``); never raise one an operator already set lower."""
    cur_soft, cur_hard = resource.getrlimit(which)
    if cur_hard != resource.RLIM_INFINITY:
        hard = min(hard, cur_hard)
    soft = min(soft, hard)
    if cur_soft != resource.RLIM_INFINITY:
        soft = min(soft, cur_soft)
    resource.setrlimit(which, (soft, hard))


def _cpus() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _processes() -> int:
    """Processes and threads one sandbox uid may have: Dr.Jit, LLVM and torch start a thread pool per core."""
    return max(1024, 32 * _cpus())


def plan_limits(settings, *, sandboxed: bool) -> ProcessLimits:
    """What `holo plan` may use: half of the workers' memory (at least ``MIN_MEMORY_BYTES``), ``plan_timeout_s``
    of CPU on every core, 1 GiB files; the process count only under a sandbox uid."""
    return ProcessLimits(memory_bytes=max(MIN_MEMORY_BYTES, settings.worker_memory_bytes // 2),
                         cpu_s=math.ceil(settings.plan_timeout_s) * _cpus(), open_files=OPEN_FILES,
                         file_size_bytes=PLAN_FILE_SIZE_BYTES, processes=_processes() if sandboxed else None)


def job_limits(settings, *, sandboxed: bool, largest_file_bytes: Optional[int] = None) -> ProcessLimits:
    """What each process of a job may use: the workers' memory (no job may hold more, whatever it was admitted
    at; at least ``MIN_MEMORY_BYTES``), ``job_timeout_s`` of CPU on every core, files no larger than
    ``largest_file_bytes`` (at least 1 GiB; no limit when not known); the process count only under a sandbox
    uid."""
    memory = max(MIN_MEMORY_BYTES, settings.worker_memory_bytes)
    size = None if largest_file_bytes is None else max(MIN_FILE_SIZE_BYTES, int(largest_file_bytes))
    return ProcessLimits(memory_bytes=memory, cpu_s=math.ceil(settings.job_timeout_s) * _cpus(),
                         open_files=OPEN_FILES, file_size_bytes=size,
                         processes=_processes() if sandboxed else None)


def current_limits() -> ProcessLimits:
    """The limits this process runs under (soft values; None where unlimited), to word a failure."""

    def get(which: int) -> Optional[int]:
        soft = resource.getrlimit(which)[0]
        return None if soft == resource.RLIM_INFINITY else int(soft)

    mem, cpu, files, size = (get(r) for r in (resource.RLIMIT_DATA, resource.RLIMIT_CPU, resource.RLIMIT_NOFILE,
                                              resource.RLIMIT_FSIZE))
    return ProcessLimits.model_construct(memory_bytes=mem, cpu_s=cpu, open_files=files, file_size_bytes=size,
                                         processes=None)


def wrap_command(limits: ProcessLimits, cmd: list[str]) -> list[str]:
    """``cmd`` started under ``limits`` (the same process: the wrapper executes it in place)."""
    return [sys.executable, "-m", "service.workers.limits", limits.to_arg(), "--", *cmd]


_OUT_OF_MEMORY = re.compile(r"MemoryError|Cannot allocate memory|can't allocate memory|bad_alloc|out of memory|"
                            r"memory allocation (?:still )?failed", re.IGNORECASE)


_DEVICE = re.compile(r"CUDA|GPU|device|cuMem|OptiX", re.IGNORECASE)  # the GPU's memory is not ours to limit


def _gb(n: int) -> str:
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.0f} MB"


def explain_limit(what: str, returncode: int, log_tail: str, cpu_used_s: float,
                  limits: ProcessLimits) -> Optional[str]:
    """The one-line reason a process that failed (``returncode`` != 0) was stopped by one of ``limits``, from
    its exit and the end of its output; None when no limit explains it."""
    if limits.cpu_s is not None and (returncode == -signal.SIGXCPU
                                      or (returncode == -signal.SIGKILL and cpu_used_s >= limits.cpu_s)):
        return f"{what} used its {limits.cpu_s} s of CPU time (the service's limit per process) and was stopped"
    if limits.file_size_bytes is not None and ("File too large" in log_tail or returncode == -signal.SIGXFSZ):
        return (f"{what} tried to write a file over {_gb(limits.file_size_bytes)} (the service's limit) "
                "and was stopped")
    if limits.open_files is not None and "Too many open files" in log_tail:
        return f"{what} opened more than {limits.open_files} files at once (the service's limit) and was stopped"
    if limits.memory_bytes is not None and any(_OUT_OF_MEMORY.search(line) and not _DEVICE.search(line)
                                               for line in log_tail.splitlines()):
        return f"{what} needed more than the {_gb(limits.memory_bytes)} of memory a process may use and was stopped"
    return None


def main(argv: list[str]) -> None:
    if len(argv) < 3 or argv[1] != "--":
        sys.exit("usage: python -m service.workers.limits LIMITS_JSON -- CMD...")
    ProcessLimits.model_validate_json(argv[0]).apply()
    for sig in (signal.SIGPIPE, signal.SIGXFSZ):  # as subprocess leaves them for a child (Python ignores both)
        signal.signal(sig, signal.SIG_DFL)
    os.execv(argv[2], argv[2:])


if __name__ == "__main__":
    main(sys.argv[1:])
