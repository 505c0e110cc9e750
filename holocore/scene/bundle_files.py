"""The files of a scene bundle, for the bundle check (:mod:`holocore.scene.bundle`): listing them (regular
files only, no link out of the bundle, every file of a kind a scene reads, judged by its content, no
shared-object name), resolving a reference as Mitsuba does, and the bundle's content address. Pure Python."""

from __future__ import annotations

import hashlib
import os
import re
import stat
import struct
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Optional

from holocore.scene.errors import BundleError
from holocore.scene.filekinds import FileKindError, sniff_kind

if TYPE_CHECKING:
    from holocore.scene.bundle import BundleLimits

__all__ = ["SHARED_OBJECT", "rel_name", "inside", "check_reference", "file_reference", "list_files", "content_sha256"]


# Shared objects by name (``libx.so.1``, ``x.dylib``, ``x.dll``, ``x.pyd``): Mitsuba looks plugins up as
# ``plugins/<type>.so`` through its file resolver, so no such name may sit in a bundle, whatever it holds.
SHARED_OBJECT = re.compile(r"\.(?:so(?:\.[0-9]+)*|dylib|dll|pyd)$", re.IGNORECASE)


def rel_name(root: Path, p: Path) -> str:
    return p.relative_to(root).as_posix()


def inside(root: Path, target: Path) -> bool:
    try:
        target.relative_to(root)
        return True
    except ValueError:
        return False


def check_reference(root: Path, base: Path, value: str, what: str) -> Path:
    """Resolve a reference as Mitsuba does (against the entry's folder ``base``); refuse escapes and misses."""
    if not value or "\x00" in value or len(value) > 4096:
        raise BundleError(f"{what}: empty or invalid file reference")
    shown = value[:120]
    if value.startswith(("/", "~")) or re.match(r"^[A-Za-z]:", value) or "://" in value:
        raise BundleError(f"{what}: absolute path {shown!r} is not allowed; paths must be relative to the bundle")
    if "$" in value:
        raise BundleError(f"{what}: {shown!r} uses an undefined $parameter")
    if "\\" in value:
        raise BundleError(f"{what}: {shown!r} holds a backslash; use '/' between folders")
    parts = PurePosixPath(value).parts
    if ".." in parts:
        raise BundleError(f"{what}: {shown!r} leaves the scene bundle ('..' is not allowed in references)")
    target = base.joinpath(*parts)
    try:
        resolved = target.resolve()
        is_file = target.is_file()
    except (OSError, RuntimeError) as exc:  # a name too long, a link loop: it names no file of the bundle
        raise BundleError(f"{what}: {shown!r} is not a file of the bundle ({getattr(exc, 'strerror', None) or exc})"
                          ) from None
    if not inside(root, resolved):
        raise BundleError(f"{what}: {shown!r} leaves the scene bundle (a link points outside)")
    if not is_file:
        raise BundleError(f"{what}: {shown!r} is referenced but not in the bundle (references are relative to the "
                          "scene file's folder, also inside includes)")
    return resolved


def file_reference(tag: str, attrs: dict[str, str]) -> Optional[str]:
    """The file path an element names, if any: a ``filename`` attribute, or a string property whose name
    says it is a file (``filename``, ``*_filename``, ``*file``)."""
    if "filename" in attrs:
        return attrs["filename"]
    if tag == "string":
        pname = attrs.get("name", "").lower()
        if pname.endswith("filename") or pname.endswith("file"):
            return attrs.get("value", "")
    return None


def list_files(root: Path, limits: BundleLimits) -> tuple[list[Path], int, dict[str, str]]:
    files: list[Path] = []
    kinds: dict[str, str] = {}
    total = 0
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        d = Path(dirpath)
        for name in list(dirnames):
            p = d / name
            if p.is_symlink() and not inside(root, p.resolve()):
                raise BundleError(f"{rel_name(root, p)}: symbolic link leaves the bundle")
        for name in filenames:
            p = d / name
            rel = rel_name(root, p)
            if p.is_symlink() and not inside(root, p.resolve()):
                raise BundleError(f"{rel}: symbolic link leaves the bundle")
            try:
                st = p.stat()
            except OSError:
                raise BundleError(f"{rel}: dangling symbolic link or unreadable file") from None
            if not stat.S_ISREG(st.st_mode):
                raise BundleError(f"{rel}: not a regular file (devices, FIFOs and sockets are refused)")
            files.append(p)
            total += st.st_size
            if len(files) > limits.max_files:
                raise BundleError(f"bundle holds more than {limits.max_files} files")
            if total > limits.max_total_bytes:
                raise BundleError(f"bundle is larger than {limits.max_total_bytes} bytes")
            try:
                kinds[rel] = sniff_kind(p, rel)
            except FileKindError as exc:
                raise BundleError(str(exc)) from None
            if SHARED_OBJECT.search(name):  # by name too: whatever it holds, it is no scene data
                raise BundleError(f"{rel}: shared-object names (.so, .dylib, .dll, .pyd) are not allowed in a "
                                  "scene bundle")
    return files, total, kinds


def content_sha256(root: Path, files: list[Path]) -> str:
    """Names and contents hashed unambiguously: for each file in name order, the byte length of its UTF-8
    name, the name, the byte length of its content, the content (8-byte big-endian lengths)."""
    h = hashlib.sha256(b"holo-bundle-v2\0")
    for p in sorted(files, key=lambda q: rel_name(root, q)):
        name = rel_name(root, p).encode("utf-8", "surrogateescape")
        h.update(struct.pack(">Q", len(name)) + name + struct.pack(">Q", p.stat().st_size))
        with p.open("rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()
