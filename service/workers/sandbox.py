"""Privilege separation (``--sandbox``): when the service runs as root, scene planning and each running job run
as dedicated unprivileged numeric uids (no /etc/passwd entry needed): the planner as ``base``, job slot ``k``
as ``base + 1 + k``, each with the same gid, no supplementary groups and umask 077, in a folder of its own
(its HOME and TMPDIR) that only it may enter. The helpers here resolve the setting, check that those users
can reach the interpreter, the code and the data dir, set the data dir's permissions, hand folders to a
sandbox user and take them back (dropping links and anything but plain files and folders), and kill and sweep
what a sandbox user left behind. The engine (:mod:`service.workers.engine`) runs the jobs under them.
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import stat
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

__all__ = ["SandboxUnavailable", "RunAs", "driver_env", "sandbox_env", "sandbox_blockers", "resolve_sandbox",
           "secure_data_dir", "give_tree", "reclaim_tree", "remove_leftovers", "uid_alive", "kill_uids", "SHARED_TMP"]

_REPO = Path(__file__).resolve().parents[2]
log = logging.getLogger("holo.service.sandbox")


class SandboxUnavailable(RuntimeError):
    """``--sandbox on`` (or a uid base) was asked for and this platform or data dir cannot give it."""


@dataclass(frozen=True)
class RunAs:
    """A sandbox user: a numeric uid and gid (no passwd entry), no supplementary groups, umask 077."""

    uid: int
    gid: int

    def popen_kwargs(self) -> dict[str, Any]:
        return {"user": self.uid, "group": self.gid, "extra_groups": [], "umask": 0o077}


# What a sandboxed process may inherit: an allow-list (a deny-list of secret-looking names misses the ones it
# did not foresee, e.g. a cloud SDK's or a proxy URL with a password in it).
_SANDBOX_ENV = frozenset({
    "PATH", "LANG", "LANGUAGE", "TZ", "PYTHONPATH", "PYTHONUNBUFFERED", "PYTHONSAFEPATH", "PYTHONHASHSEED",
    "LD_LIBRARY_PATH", "DRJIT_LIBLLVM_PATH", "CUDA_VISIBLE_DEVICES", "CUDA_DEVICE_ORDER", "OMP_NUM_THREADS",
    "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS",
    "HOLO_DEVICE", "HOLO_MEMORY_BUDGET_MB", "HOLO_MI_VARIANT", "HOLO_NO_CUDA"})
_SANDBOX_ENV_PREFIXES = ("LC_", "NVIDIA_")


def driver_env() -> dict[str, str]:
    """The environment of a job driver: ours, with the repository importable."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(_REPO), env.get("PYTHONPATH", "")) if p)
    env.setdefault("PYTHONUNBUFFERED", "1")
    env["PYTHONSAFEPATH"] = "1"  # `python -m` never imports from its working dir (a job dir, a bundle)
    return env


def sandbox_env(home: Path) -> dict[str, str]:
    """A sandboxed process's environment: the allow-listed variables of the driver's, and HOME and TMPDIR (so
    Dr.Jit's and Mitsuba's caches) inside its own folder ``home``."""
    env = {k: v for k, v in driver_env().items() if k in _SANDBOX_ENV or k.startswith(_SANDBOX_ENV_PREFIXES)}
    env.update(HOME=str(home / "home"), TMPDIR=str(home / "tmp"), XDG_CACHE_HOME=str(home / "home" / ".cache"))
    return env


def _others_can_traverse(path: Path) -> Optional[Path]:
    """The first folder from / down to ``path`` (included when a folder) that others cannot enter, or None."""
    path = Path(os.path.realpath(path))
    chain = [*reversed(path.parents), path] if path.is_dir() else list(reversed(path.parents))
    for d in chain:
        try:
            if not os.stat(d).st_mode & stat.S_IXOTH:
                return d
        except OSError:
            return d
    return None


def sandbox_blockers(data_dir: Path) -> list[str]:
    """Why a sandbox user could not run jobs here: folders others cannot enter on the way to the data dir, the
    interpreter, the standard library or the code (empty when nothing stands in the way)."""
    import sys as _sys

    out: list[str] = []
    # the data dir itself is made 0711 on start; the folders above it must already be enterable
    targets = [data_dir / "service.db", Path(_sys.executable), Path(os.path.realpath(_sys.executable)),
               Path(_sys.prefix), Path(_sys.base_prefix), _REPO]
    seen: set[Path] = set()
    for t in targets:
        bad = _others_can_traverse(t.parent if t.parent == data_dir else t)
        if bad == Path(os.path.realpath(data_dir)):
            bad = None
        if bad is not None and bad not in seen:
            seen.add(bad)
            out.append(f"{bad} (on the way to {t}) is not traversable by other users: chmod o+x {bad}")
    exe = Path(os.path.realpath(_sys.executable))
    try:
        if not os.stat(exe).st_mode & stat.S_IXOTH:
            out.append(f"{exe} is not executable by other users: chmod o+rx {exe}")
    except OSError as exc:
        out.append(f"cannot stat the interpreter {exe}: {exc}")
    return out


def resolve_sandbox(settings) -> Optional[int]:
    """The sandbox uid base when sandboxing applies, else None; records the answer in ``settings.sandbox``
    ("on" / "off") so later calls agree. ``auto`` is on when the service runs as root and the sandbox users can
    reach everything they need (else a warning and off); ``on`` (or a uid base) makes it mandatory:
    ``SandboxUnavailable`` says why it cannot be."""
    mode = str(settings.sandbox)
    if mode == "off":
        return None
    mandatory = mode != "auto"
    if mode.isdigit():
        settings.sandbox_uid_base = int(mode)
    why: list[str] = []
    if os.geteuid() != 0:
        why = [f"the service runs as uid {os.geteuid()}, not root (it cannot switch users)"]
    elif not hasattr(os, "setgroups"):
        why = ["this platform cannot switch users"]
    else:
        why = sandbox_blockers(settings.data_dir)
    top = settings.sandbox_uid_base + settings.workers
    if not why and not 1 <= settings.sandbox_uid_base <= top <= 2 ** 31 - 2:
        why = [f"uids {settings.sandbox_uid_base}..{top} are out of range (1..{2 ** 31 - 2})"]
    if why:
        if mandatory:
            raise SandboxUnavailable("--sandbox on: cannot run jobs as unprivileged users: " + "; ".join(why)
                                     + " (or start with --sandbox off)")
        if os.geteuid() == 0:
            log.warning("running as root WITHOUT privilege separation (--sandbox auto): %s. Fix that, or make "
                        "it mandatory with --sandbox on; --sandbox off silences this", "; ".join(why))
        settings.sandbox = "off"
        return None
    settings.sandbox = "on"
    return settings.sandbox_uid_base


def secure_data_dir(settings) -> None:
    """Permissions of the data dir when sandboxing: the dir 0711 (enter, not list), ``service.db`` and its
    -wal/-shm and ``server.lock`` 0600, ``scenes/`` 0700, ``jobs/`` and ``sandbox/`` 0711, each job dir 0700."""
    d = settings.data_dir
    os.chmod(d, 0o711)
    for name in ("service.db", "service.db-wal", "service.db-shm", "server.lock"):
        try:
            os.chmod(d / name, 0o600)
        except FileNotFoundError:
            pass
    for sub, mode in ((settings.scenes_dir, 0o700), (settings.jobs_dir, 0o711), (d / "sandbox", 0o711)):
        sub.mkdir(parents=True, exist_ok=True)
        os.chmod(sub, mode)
    with os.scandir(settings.jobs_dir) as it:
        for entry in it:
            if entry.is_dir(follow_symlinks=False):
                os.chmod(entry.path, 0o700)
    for entry in os.scandir(d):
        if entry.is_file(follow_symlinks=False) and entry.name.startswith("service.db"):
            os.chmod(entry.path, 0o600)


def give_tree(root: Path, who: RunAs) -> None:
    """Hand ``root`` and everything under it to ``who``: owner, folders 0700, files 0600 (links untouched)."""
    for dirpath, dirnames, filenames in os.walk(root):
        os.chown(dirpath, who.uid, who.gid, follow_symlinks=False)
        os.chmod(dirpath, 0o700)
        for name in filenames + [n for n in dirnames if os.path.islink(os.path.join(dirpath, n))]:
            p = os.path.join(dirpath, name)
            st = os.lstat(p)
            os.chown(p, who.uid, who.gid, follow_symlinks=False)
            if stat.S_ISREG(st.st_mode):
                os.chmod(p, 0o600)


def reclaim_tree(root: Path, *, remove: tuple[str, ...] = ()) -> list[str]:
    """Take ``root`` back from a sandbox user (whose processes must all be gone): every folder and file owned
    by this process again (folders 0700, files 0600), the subfolders ``remove`` deleted, and every entry that is
    not a plain file or folder (a symlink, a fifo) or a file with other hard links removed, so nothing in it
    leads the service elsewhere. Returns what it removed (relative paths)."""
    uid, gid = os.geteuid(), os.getegid()
    dropped: list[str] = []
    if root.is_symlink() or not root.is_dir():
        return dropped
    for name in remove:
        p = root / name
        if p.is_symlink() or (p.exists() and not p.is_dir()):
            p.unlink()
        elif p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
    for dirpath, dirnames, filenames in os.walk(root):  # walk never follows a symlinked folder
        os.chown(dirpath, uid, gid, follow_symlinks=False)
        os.chmod(dirpath, 0o700)
        for name in filenames + list(dirnames):
            p = os.path.join(dirpath, name)
            st = os.lstat(p)
            if stat.S_ISDIR(st.st_mode):
                continue
            if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
                os.unlink(p)
                dropped.append(os.path.relpath(p, root))
                continue
            os.chown(p, uid, gid, follow_symlinks=False)
            os.chmod(p, 0o600)
        dirnames[:] = [n for n in dirnames if not os.path.islink(os.path.join(dirpath, n))]
    return dropped


def _uid_pids(uids: set[int]) -> list[int]:
    pids = []
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/status", "rb") as fh:
                text = fh.read().decode(errors="replace")
        except OSError:
            continue
        uid_line = next((ln for ln in text.splitlines() if ln.startswith("Uid:")), "")
        state = next((ln for ln in text.splitlines() if ln.startswith("State:")), "")
        fields = uid_line.split()[1:]
        if fields and any(int(f) in uids for f in fields) and " Z " not in state + " ":
            pids.append(int(entry.name))
    return pids


# Folders every user may create entries in: what a sandbox user leaves there outlives its run (and /dev/shm is
# memory), so it is removed once the user's processes are gone (the uid's next run may be another owner's).
SHARED_TMP = ("/tmp", "/var/tmp", "/dev/shm", "/dev/mqueue")


def remove_leftovers(uids, roots: tuple[str, ...] = SHARED_TMP, *, max_entries: int = 200_000) -> list[str]:
    """Remove every entry the sandbox users ``uids`` own in the shared temporary folders ``roots`` (also in
    world-writable folders below them, e.g. one another user made 0777), and their System V shared memory
    segments, which outlive their processes too. Their processes must be gone. Every step goes through folder
    descriptors, never a path: another sandbox user, still running, may own a folder on the way and swap it for
    a link elsewhere. Returns what it removed."""
    uids = set(uids)
    removed: list[str] = []
    left = [max_entries]  # a folder of millions of entries is not walked to its end
    flags = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW

    def sweep(fd: int, where: str, dev: int) -> None:
        with os.scandir(fd) as it:
            entries = list(it)
        for entry in entries:
            left[0] -= 1
            if left[0] < 0:
                return
            path = f"{where}/{entry.name}"
            try:
                st = entry.stat(follow_symlinks=False)
            except OSError:
                continue
            try:
                if st.st_uid in uids:
                    if stat.S_ISDIR(st.st_mode):
                        shutil.rmtree(entry.name, dir_fd=fd)  # fd-based: links inside are removed, not followed
                    else:
                        os.unlink(entry.name, dir_fd=fd)
                    removed.append(path)
                elif stat.S_ISDIR(st.st_mode) and st.st_mode & stat.S_IWOTH and st.st_dev == dev:
                    sub = os.open(entry.name, flags, dir_fd=fd)  # anyone may create entries in it
                    try:
                        sweep(sub, path, dev)
                    finally:
                        os.close(sub)
            except OSError as exc:
                log.warning("could not remove %s left by a sandbox user: %s", path, exc)

    for root in roots:
        try:
            fd = os.open(root, flags)
        except OSError:
            continue
        try:
            sweep(fd, root.rstrip("/"), os.fstat(fd).st_dev)
        finally:
            os.close(fd)
    removed.extend(_remove_shm_segments(uids))
    return removed


def _remove_shm_segments(uids: set[int]) -> list[str]:
    try:
        with open("/proc/sysvipc/shm") as fh:
            rows = [ln.split() for ln in fh.read().splitlines()[1:]]
    except OSError:
        return []
    ids = [int(r[1]) for r in rows if len(r) > 7 and int(r[7]) in uids]
    if not ids:
        return []
    import ctypes
    import ctypes.util

    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    out = []
    for shmid in ids:
        if libc.shmctl(ctypes.c_int(shmid), ctypes.c_int(0), None) == 0:  # IPC_RMID
            out.append(f"shm:{shmid}")
    return out


def uid_alive(uid: int) -> bool:
    """Whether any (non-zombie) process runs as ``uid``."""
    return bool(_uid_pids({uid}))


def kill_uids(uids, *, timeout_s: float = 5.0) -> bool:
    """SIGKILL every process of the sandbox users ``uids`` (whatever group or session it moved to) until none
    is left, then remove what they left in the shared temporary folders (:func:`remove_leftovers`: a run's
    files there would reach the uid's next run, maybe another owner's); returns whether no process is left."""
    uids = set(uids)
    deadline = time.monotonic() + timeout_s
    while True:
        pids = _uid_pids(uids)
        if not pids:
            gone = remove_leftovers(uids)
            if gone:
                log.info("removed what sandbox uids %s left in shared folders: %s", sorted(uids), gone[:20])
            return True
        if time.monotonic() > deadline:
            log.error("processes of sandbox uids %s survive SIGKILL: %s", sorted(uids), pids)
            return False
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        time.sleep(0.02)
