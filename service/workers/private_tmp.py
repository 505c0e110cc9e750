"""Start a sandboxed job with temporary folders of its own: ``python -m service.workers.private_tmp DIR UID GID --
CMD...`` runs as root, gives itself a mount and IPC namespace of its own where ``/tmp``, ``/var/tmp`` and
``/dev/shm`` are bind mounts of ``DIR`` (the job's ``tmp/``, on the data dir's disk, counted with the job's
folder) and System V IPC is private, then drops to ``UID``:``GID`` (no supplementary groups, umask 077) and
executes CMD in place (same pid, so the caller's process group and kills still hold).

Slot uids otherwise share those folders while their runs overlap (a run can leave a file where another slot's
code looks, or fill /dev/shm, which is memory), and SysV segments outlive their processes. Making the namespace
needs CAP_SYS_ADMIN: without it (the sandbox's systemd unit does not grant it) the job runs with the shared
folders, as before, and what its uid leaves there is removed when its run ends (engine.remove_leftovers). A
folder that holds what the job needs by absolute path (the job's folder, the interpreter, the code: a data dir
under /tmp) is left shared, since a mount over it would hide them.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from typing import Iterable

__all__ = ["TARGETS", "can_make_private", "private_targets", "make_private", "main"]

TARGETS = ("/tmp", "/var/tmp", "/dev/shm")
_CLONE_NEWNS = 0x00020000
_CLONE_NEWIPC = 0x08000000
_MS_BIND = 4096
_MS_REC = 16384
_MS_PRIVATE = 1 << 18


def can_make_private() -> bool:
    """Whether this process may make the namespaces (CAP_SYS_ADMIN in its effective set)."""
    try:
        with open("/proc/self/status") as fh:
            eff = next(int(ln.split()[1], 16) for ln in fh if ln.startswith("CapEff:"))
    except (OSError, StopIteration, ValueError):
        return False
    return bool(eff >> 21 & 1)


def _under(path: str, folder: str) -> bool:
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def private_targets(needed: Iterable[str], targets: Iterable[str] = TARGETS) -> list[str]:
    """The folders of ``targets`` that may be replaced: existing folders that hold none of ``needed`` (paths
    the job reaches by absolute path)."""
    needed = [p for p in needed if p]
    return [t for t in targets if os.path.isdir(t) and not os.path.islink(t)
            and not any(_under(p, t) for p in needed)]


def make_private(folder: str, targets: list[str]) -> str:
    """Enter a new mount and IPC namespace and bind ``folder`` over each of ``targets``; returns what was done,
    in words (for the job's log)."""
    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    if libc.unshare(_CLONE_NEWNS | _CLONE_NEWIPC) != 0:
        return f"shared temporary folders (no namespace of its own: {os.strerror(ctypes.get_errno())})"
    if libc.mount(None, b"/", None, _MS_REC | _MS_PRIVATE, None) != 0:  # nothing of ours reaches the host
        raise OSError(ctypes.get_errno(), "making the mounts private")
    # the folder by a descriptor: once /tmp is mounted over, a path under /tmp names something else
    fd = os.open(folder, os.O_PATH | os.O_DIRECTORY | os.O_NOFOLLOW)
    done = []
    try:
        for target in targets:
            if libc.mount(f"/proc/self/fd/{fd}".encode(), target.encode(), None, _MS_BIND, None) != 0:
                raise OSError(ctypes.get_errno(), f"bind mount over {target}")
            done.append(target)
    finally:
        os.close(fd)
    return "private " + (", ".join(done) if done else "nothing") + " and System V IPC"


def main(argv: list[str]) -> int:
    if len(argv) < 5 or argv[3] != "--":
        print("usage: python -m service.workers.private_tmp DIR UID GID -- CMD...", file=sys.stderr)
        return 2
    folder, uid, gid, cmd = argv[0], int(argv[1]), int(argv[2]), argv[4:]
    if os.geteuid() != 0 or uid == 0 or gid == 0:
        print("private_tmp: must start as root and drop to a non-root uid and gid", file=sys.stderr)
        return 2
    needed = [os.getcwd(), sys.executable, os.path.realpath(sys.executable), sys.prefix, sys.base_prefix,
              os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
              *os.environ.get("PYTHONPATH", "").split(os.pathsep)]
    try:
        how = make_private(folder, private_targets(needed))
    except OSError as exc:  # a half-made namespace: refuse to run rather than run with a surprise
        print(f"private_tmp: {exc}", file=sys.stderr)
        return 1
    print(f"sandbox: {how}", file=sys.stderr, flush=True)
    os.setgroups([])
    os.setgid(gid)
    os.setuid(uid)
    os.umask(0o077)
    os.execvp(cmd[0], cmd)
    return 127  # not reached


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
