"""Uploaded scene bundles: unpack a zip or write multipart files into a staging folder, safely.

Zip members with absolute paths, ``..``, drive letters, symbolic links or encryption are refused; the declared
sizes, the member count and each member's compression ratio are checked before anything is written, and the
bytes are then streamed with a budget (a member whose data outgrows its declared size is refused, so a
lying header cannot get past the caps). Before any of that, the central directory is sized from the
end-of-central-directory record and its entries are counted from the raw bytes, so a zip listing hundreds of
thousands of members is refused before Python builds an object for each. Nothing here follows a path outside
the staging folder.
"""

from __future__ import annotations

import re
import shutil
import stat
import struct
import zipfile
import zlib
from pathlib import Path, PurePosixPath
from typing import BinaryIO, Iterable

from service.settings import UploadLimits

__all__ = ["UploadError", "safe_member_path", "unpack_zip", "write_files", "bundle_root"]

_CHUNK = 1 << 20


class UploadError(ValueError):
    """The upload is refused; the message says why (the API answers 4xx with it)."""

    def __init__(self, message: str, status: int = 422) -> None:
        super().__init__(message)
        self.status = status


def safe_member_path(name: str) -> PurePosixPath:
    """A relative, normalised path for an archive member or uploaded file name; UploadError if it could leave
    the bundle (absolute, ``..``, drive letter, NUL, control characters)."""
    if not isinstance(name, str) or not name or len(name) > 1024:
        raise UploadError("file name: empty or longer than 1024 characters")
    if any(ord(ch) < 32 for ch in name):
        raise UploadError(f"file name {name[:80]!r}: control characters are not allowed")
    norm = name.replace("\\", "/")
    if norm.startswith("/") or re.match(r"^[A-Za-z]:", norm):
        raise UploadError(f"file name {name[:80]!r}: absolute paths are not allowed")
    parts = [p for p in norm.split("/") if p not in ("", ".")]
    if any(p == ".." for p in parts):
        raise UploadError(f"file name {name[:80]!r}: '..' would leave the bundle")
    if not parts:
        raise UploadError(f"file name {name[:80]!r} names no file")
    long = next((p for p in parts if len(p.encode("utf-8", "surrogateescape")) > 255), None)
    if long is not None:
        raise UploadError(f"file name {name[:80]!r}...: a folder or file name is longer than 255 bytes")
    if len(parts) > 32:
        raise UploadError(f"file name {name[:80]!r}...: nested deeper than 32 folders")
    return PurePosixPath(*parts)


def _copy_with_budget(src: BinaryIO, dest: Path, *, declared: int | None, budget: list[int], what: str) -> None:
    written = 0
    with open(dest, "xb") as out:  # "x": a second member with the same name is refused, never overwrites
        while True:
            chunk = src.read(_CHUNK)
            if not chunk:
                break
            written += len(chunk)
            budget[0] -= len(chunk)
            if declared is not None and written > declared:
                raise UploadError(f"{what}: holds more bytes than its header declares (zip bomb?)", 413)
            if budget[0] < 0:
                raise UploadError("upload unpacks to more bytes than allowed", 413)
            out.write(chunk)


def _target(staging: Path, rel: PurePosixPath) -> Path:
    dest = staging.joinpath(*rel.parts)
    parent = dest.parent
    for i in range(1, len(rel.parts)):  # a folder on the way that is a file already: d, then d/e.txt
        if staging.joinpath(*rel.parts[:i]).is_file():
            raise UploadError(f"file name {rel}: {PurePosixPath(*rel.parts[:i])} is a file and a folder")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UploadError(f"file name {rel}: cannot be created ({exc.strerror or type(exc).__name__})") from None
    if not parent.resolve().is_relative_to(staging.resolve()):
        raise UploadError(f"file name {rel}: leaves the bundle")
    if dest.is_dir():
        raise UploadError(f"file name {rel}: is a file and a folder")
    if dest.exists():
        raise UploadError(f"file name {rel}: given twice")
    return dest


# Most bytes one central-directory entry may take on average: its 46-byte record, a name of at most 1024
# bytes (safe_member_path) and room for extra fields and a comment.
_MAX_CD_ENTRY_BYTES = 46 + 1024 + 256


def _central_directory_entries(fh: BinaryIO, limits: UploadLimits) -> None:
    """Refuse a zip whose central directory is too large for ``limits`` before ``zipfile`` reads it: the entry
    count and size from the end record (zip64 too, found the way ``zipfile`` finds them), then the entries
    counted by walking the raw records (``zipfile`` reads as many as the size covers, whatever the count says).
    Directories are entries too, so up to twice ``max_files`` entries are allowed."""
    max_entries = 2 * limits.max_files
    try:
        end = zipfile._EndRecData(fh)  # the very record (and zip64 record) ZipFile will use
    except (OSError, zipfile.BadZipFile, struct.error) as exc:
        raise UploadError(f"bundle: not a zip file ({exc})") from None
    if not end:
        raise UploadError("bundle: not a zip file (no end of central directory record)")
    count, size, location = end[zipfile._ECD_ENTRIES_TOTAL], end[zipfile._ECD_SIZE], end[zipfile._ECD_LOCATION]
    if count > max_entries:
        raise UploadError(f"bundle: zip lists {count} entries, more than {max_entries} (at most "
                          f"{limits.max_files} files)", 413)
    if size > max_entries * _MAX_CD_ENTRY_BYTES:
        raise UploadError(f"bundle: zip central directory is {size} bytes, more than {max_entries} entries need",
                          413)
    start = location - size
    if end[zipfile._ECD_SIGNATURE] == zipfile.stringEndArchive64:
        start -= zipfile.sizeEndCentDir64 + zipfile.sizeEndCentDir64Locator
    if start < 0:
        raise UploadError("bundle: not a zip file (bad central directory offset)")
    fh.seek(start)
    data = fh.read(size)
    pos = n = 0
    while pos + 46 <= len(data):
        if data[pos:pos + 4] != b"PK\x01\x02":
            break  # zipfile will refuse it with its own message
        name_len, extra_len, comment_len = struct.unpack_from("<HHH", data, pos + 28)
        pos += 46 + name_len + extra_len + comment_len
        n += 1
        if n > max_entries:
            raise UploadError(f"bundle: zip holds more than {max_entries} entries (at most {limits.max_files} "
                              "files)", 413)
    fh.seek(0)


def unpack_zip(src: str | Path | BinaryIO, staging: Path, *, limits: UploadLimits) -> list[str]:
    """Unpack a zip into ``staging`` (an empty folder); returns the relative paths written."""
    try:
        if isinstance(src, (str, Path)):
            with open(src, "rb") as fh:
                _central_directory_entries(fh, limits)
        else:
            _central_directory_entries(src, limits)
    except OSError as exc:
        raise UploadError(f"bundle: not a zip file ({exc})") from None
    try:
        zf = zipfile.ZipFile(src)
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise UploadError(f"bundle: not a zip file ({exc})") from None
    with zf:
        infos = zf.infolist()
        files = [i for i in infos if not i.is_dir()]
        if len(files) > limits.max_files:
            raise UploadError(f"bundle: zip holds {len(files)} files, more than {limits.max_files}", 413)
        declared = 0
        seen: set[str] = set()
        for info in infos:
            rel = safe_member_path(info.filename)
            mode = info.external_attr >> 16
            if stat.S_ISLNK(mode):
                raise UploadError(f"bundle: {info.filename[:80]!r} is a symbolic link; links are not allowed")
            if info.flag_bits & 0x1:
                raise UploadError(f"bundle: {info.filename[:80]!r} is encrypted")
            if info.is_dir():
                continue
            key = rel.as_posix()
            if key in seen:
                raise UploadError(f"bundle: {key!r} appears twice in the zip")
            seen.add(key)
            declared += info.file_size
            if declared > limits.max_total_bytes:
                raise UploadError(f"bundle: zip declares more than {limits.max_total_bytes} bytes unpacked", 413)
            ratio = info.file_size / max(1, info.compress_size)
            if info.file_size > (1 << 20) and ratio > limits.max_ratio:
                raise UploadError(f"bundle: {key!r} compresses {ratio:.0f}:1, more than {limits.max_ratio:.0f}:1 "
                                  "(zip bomb?)", 413)
        budget = [limits.max_total_bytes]
        written = []
        for info in infos:
            rel = safe_member_path(info.filename)
            if info.is_dir():
                _target(staging, rel / "_").parent.mkdir(parents=True, exist_ok=True)
                continue
            dest = _target(staging, rel)
            try:
                with zf.open(info) as fh:
                    _copy_with_budget(fh, dest, declared=info.file_size, budget=budget, what=rel.as_posix())
            except (zipfile.BadZipFile, zlib.error, NotImplementedError, EOFError) as exc:
                raise UploadError(f"bundle: cannot unpack {rel.as_posix()!r}: {exc}") from None
            written.append(rel.as_posix())
    return written


def write_files(items: Iterable[tuple[str, BinaryIO]], staging: Path, *, limits: UploadLimits) -> list[str]:
    """Write uploaded (relative name, stream) pairs into ``staging``; returns the relative paths."""
    budget = [limits.max_total_bytes]
    written = []
    for name, stream in items:
        rel = safe_member_path(name)
        if len(written) >= limits.max_files:
            raise UploadError(f"files: more than {limits.max_files} files", 413)
        _copy_with_budget(stream, _target(staging, rel), declared=None, budget=budget, what=rel.as_posix())
        written.append(rel.as_posix())
    if not written:
        raise UploadError("no files: send a 'bundle' zip or 'files' fields")
    return written


def bundle_root(staging: Path) -> Path:
    """The folder that holds the scene: ``staging`` itself, or its single top folder when a zip wrapped the
    whole bundle in one (``__MACOSX`` metadata folders are dropped)."""
    junk = staging / "__MACOSX"
    if junk.is_dir() and not junk.is_symlink():
        shutil.rmtree(junk)
    entries = list(staging.iterdir())
    if len(entries) == 1 and entries[0].is_dir() and not entries[0].is_symlink():
        return entries[0]
    return staging
