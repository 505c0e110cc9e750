"""RESULT.npz (from `holo render`): ``slm_field``, ``wrp_field`` complex64 ``[F, C, H, W]`` and ``meta``, a JSON
string whose top level holds at least ``focal_length_m``, ``z_inf_m``, ``z_wrp_m``, ``pitch_m``,
``wavelengths_m`` (:class:`holocore.formats.meta.ResultMeta`). Written whole here (:func:`save_result`) or
streamed (``holocore.formats.npz.NpzWriter``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Union

import numpy as np

from holocore.formats.meta import ResultMeta, parse_result_meta
from holocore.formats.npz import atomic_savez, require_fchw

__all__ = ["RESULT_META_KEYS", "save_result", "load_result"]

RESULT_META_KEYS = tuple(k for k, f in ResultMeta.model_fields.items() if f.is_required())  # what every RESULT has


def save_result(path: str | Path, *, slm_field: np.ndarray, wrp_field: np.ndarray,
                meta: Union[ResultMeta, Mapping[str, Any]]) -> None:
    """Save a render: complex fields [F, C, H, W] (stored complex64) and JSON metadata (checked as
    :class:`ResultMeta`; MetaError naming the field)."""
    m = parse_result_meta(meta, what=f"result {Path(path).name}")
    slm = np.asarray(slm_field, dtype=np.complex64)
    wrp = np.asarray(wrp_field, dtype=np.complex64)
    require_fchw("slm_field", slm)
    require_fchw("wrp_field", wrp)
    atomic_savez(Path(path), slm_field=slm, wrp_field=wrp, meta=np.array(json.dumps(m.to_dict())))


def load_result(path: str | Path) -> tuple[np.ndarray, np.ndarray, ResultMeta]:
    """Load RESULT.npz -> (slm_field, wrp_field, meta)."""
    with np.load(path, allow_pickle=False) as z:
        if "slm_field" not in z or "meta" not in z:
            raise ValueError(f"{path} is not a render result (needs slm_field, wrp_field, meta)")
        raw = json.loads(str(z["meta"]))
        return z["slm_field"], z["wrp_field"], parse_result_meta(raw, what=f"result {Path(path).name}")
