"""The project's files with numpy alone (no torch, Mitsuba or Dr.Jit; docs/design.md §1): RESULT.npz and STACK.npz
(:mod:`.result`, :mod:`.stack`, streamed .npz members in :mod:`.npz`), phase -> 8-bit SLM levels
(:mod:`.levels`), their typed metadata (:mod:`.meta`), SLM lookup-table files (:mod:`.lut`) and file hashes
(:mod:`.hashing`). The display agent imports these; ``holocore.io`` re-exports the file functions for the core."""

from holocore.formats.hashing import file_sha256
from holocore.formats.levels import phase_levels, phase_to_u8
from holocore.formats.lut import LutEntry, check_lut_table, load_lut_file
from holocore.formats.meta import (
    MetaError,
    MetaLike,
    ResultMeta,
    StackMeta,
    ViewMeta,
    parse_result_meta,
    parse_stack_meta,
    parse_view_meta,
)
from holocore.formats.npz import (
    NpyMember,
    NpzWriter,
    PieceSource,
    atomic_savez,
    npz_members,
    read_npz_meta,
)
from holocore.formats.result import RESULT_META_KEYS, load_result, save_result
from holocore.formats.stack import (
    MAX_STACK_BYTES,
    Stack,
    StackError,
    check_stack,
    load_stack,
    open_stack,
    save_stack,
)

__all__ = [
    "file_sha256", "phase_levels", "phase_to_u8", "LutEntry", "check_lut_table", "load_lut_file", "NpyMember",
    "NpzWriter", "PieceSource", "atomic_savez", "npz_members", "read_npz_meta", "RESULT_META_KEYS", "load_result",
    "save_result", "MetaError", "ResultMeta", "StackMeta", "ViewMeta", "parse_result_meta", "parse_stack_meta",
    "parse_view_meta", "MetaLike", "MAX_STACK_BYTES", "Stack", "StackError", "check_stack", "load_stack",
    "open_stack", "save_stack",
]
