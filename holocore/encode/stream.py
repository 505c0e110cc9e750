"""Encode RESULT.npz to STACK.npz in bounded memory: read blocks of frames of one color from the file, encode
them (holocore.encode.block), and stream the phase and 8-bit frames into the output zip as they come.

Peak memory is the block's working set (:func:`bytes_per_frame` per frame of the block) plus one frame-block
of output, whatever the number of frames; the block size follows from ``memory_limit_bytes``. The output
file is the one ``io.save_stack`` writes (uncompressed .npz members ``phase``, ``frames_u8``, ``meta``),
written next to its destination and renamed into place.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any, Callable, Optional, Union

import numpy as np
import torch

from holocore import validate
from holocore.encode.block import encode_block, make_operators
from holocore.encode.core import wrap_phase
from holocore.encode.encoder import (
    Assembler,
    EncodeResult,
    sgd_options,
    small_ops_on_one_thread,
    supervision_for,
)
from holocore.encode.output import quantize, stack_meta
from holocore.encode.sgd import encoder_grid
from holocore.formats.meta import ResultMeta, parse_result_meta, parse_stack_meta
from holocore.formats.npz import MemberShapeError
from holocore.io import NpyMember
from holocore.plan.encode_steps import DEFAULT_OPTIMISER
from holocore.runtime.heap import heap_reuse

BASE_BYTES = 1 << 30  # interpreter, torch, transfer functions and slack outside the per-frame working set


def read_meta(path: Union[str, Path]) -> ResultMeta:
    """A RESULT's meta, typed (MetaError, a ValueError, naming the field when it is wrong)."""
    with np.load(path, allow_pickle=False) as z:
        if "meta" not in z or "wrp_field" not in z:
            raise ValueError(f"{path} is not a render result (needs wrp_field, meta)")
        return parse_result_meta(json.loads(str(z["meta"])), what=str(path))


# What L-BFGS holds beyond Adam per SLM pixel: the gradient kept between steps, the (s, y) pair, the step, and the
# step's and the kept gradient's temporaries when some items' steps are not taken. Measured: at 1080x1920 x 24
# frames a block of 24 frames peaked 1.77 GiB above Adam's, 38 bytes per pixel (bench/results/encode.md).
LBFGS_EXTRA_BYTES_PER_PIXEL = 40


def bytes_per_frame(shape_hw: tuple[int, int], grid: tuple[int, int], optimiser: Optional[str] = None) -> int:
    """Working set of one frame of a block: ~100 bytes per SLM pixel (target, ideal field, phase, Adam state,
    fields and gradients, output; L-BFGS: ``LBFGS_EXTRA_BYTES_PER_PIXEL`` more) and three complex64 padded grids
    (workspace, spectrum, FFT output)."""
    px = 100 + (LBFGS_EXTRA_BYTES_PER_PIXEL if (optimiser or DEFAULT_OPTIMISER) == "lbfgs" else 0)
    return px * shape_hw[0] * shape_hw[1] + 24 * grid[0] * grid[1]


def frames_per_block(shape_hw: tuple[int, int], frames: int, grid: tuple[int, int], memory_limit_bytes: int,
                     optimiser: Optional[str] = None, *, colours: int = 1) -> int:
    """Frames per block: as few blocks as ``memory_limit_bytes`` allows while ``colours`` colors' operators are
    kept (four complex64 multipliers on the grid each), the frames shared evenly between them (blocks of 12 and
    12 rather than 18 and 6: a block steps its items together, and a small one costs more per item)."""
    per = bytes_per_frame(shape_hw, grid, optimiser)
    fixed = BASE_BYTES + 32 * grid[0] * grid[1] * max(1, int(colours))
    n = int((memory_limit_bytes - fixed) // per)
    if n < 1:
        need = (fixed + per) / 2**30
        raise ValueError(f"a memory limit of {memory_limit_bytes / 2**30:.2f} GiB cannot hold one frame of "
                         f"{shape_hw[0]}x{shape_hw[1]} (needs about {need:.2f} GiB)")
    blocks = math.ceil(frames / min(frames, n))
    return math.ceil(frames / blocks)


class _StreamedNpy:
    """One .npy member written into an open zip in pieces of a known total shape."""

    def __init__(self, zf: zipfile.ZipFile, name: str, shape: tuple[int, ...], dtype: np.dtype) -> None:
        self.fh = zf.open(name + ".npy", "w", force_zip64=True)
        np.lib.format.write_array_header_2_0(self.fh, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)),
                                                       "fortran_order": False, "shape": shape})

    def write(self, arr: np.ndarray) -> None:
        self.fh.write(np.ascontiguousarray(arr).tobytes())

    def close(self) -> None:
        self.fh.close()


def encode_file(result_path: Union[str, Path], out_path: Union[str, Path], *, method: str = "sgd",
                fourier_filter: Optional[bool] = None, memory_limit_bytes: int = 8 * 2**30,
                block_frames: Optional[int] = None, device: Union[str, torch.device] = "cpu",
                lut: Optional[np.ndarray] = None, lut_source: Optional[str] = None,
                progress: Optional[Callable[[str, int, int], None]] = None,
                init_path: Optional[Union[str, Path]] = None,
                **sgd: Any) -> tuple[EncodeResult, dict]:
    """Encode ``result_path``'s ``wrp_field`` into STACK.npz at ``out_path`` block by block; returns the result
    (``phase`` left empty: it is in the file) and the stack's meta. ``fourier_filter`` None: the RESULT meta's
    display decides (True when it names none). ``block_frames`` None: as many frames as ``memory_limit_bytes``
    allows. ``init_path``: a STACK.npz of the same shape whose phases the SGD starts from (a warm start: the
    stack of an earlier render of the same scene and display, or an encode stopped early, goes on from where it
    was instead of from the naive phase; the stop rule ends it once it gains no more)."""
    t0, result_path, out_path = time.perf_counter(), Path(result_path), Path(out_path)
    meta, src = read_meta(result_path), NpyMember(result_path, "wrp_field")
    if len(src.shape) != 4:
        raise ValueError(f"{result_path}: wrp_field must be [F, C, H, W], got {src.shape}")
    F, C, H, W = src.shape
    z = validate.bounded("z_wrp_m", meta.z_wrp_m, low=0.0, low_inclusive=False, unit="m")
    lams, pitch = validate.wavelengths(meta.wavelengths_m, C), meta.pitch_m
    fourier_filter, source = _fourier_filter(meta.display, fourier_filter)
    sup = supervision_for(fourier_filter)
    sgd_opts = sgd_options(**{"iterations": None, "lr": 0.2, "tol": None, "stop_db": 0.05,
                               "efficiency_weight": 0.0, "optimiser": None, **sgd}) if method == "sgd" else {}
    init_src = None if init_path is None else _start_phase(init_path, (F, C, H, W), method)
    grid = max((encoder_grid((H, W), z, lam, pitch) for lam in lams), key=lambda g: g[0] * g[1])
    fb = block_frames or frames_per_block((H, W), F, grid, int(memory_limit_bytes), sgd_opts.get("optimiser"),
                                          colours=C)
    total = sgd_opts.get("iterations", 0) * math.ceil(F / fb) * C  # iterations of every block and color
    acc = Assembler(F, C)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out_path.parent, prefix=f".{out_path.name}.", suffix=".tmp")
    fd_u8, tmp_u8 = tempfile.mkstemp(dir=out_path.parent, prefix=f".{out_path.name}.", suffix=".u8")
    os.close(fd_u8)
    held = _threads_and_heap(method, device, min(fb, F) * grid[0] * grid[1])
    try:
        with os.fdopen(fd, "wb") as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as zf, \
                open(tmp_u8, "wb") as u8f:
            ph_out, ops = _StreamedNpy(zf, "phase", (F, C, H, W), np.float32), {}  # ops: each color's, kept
            for bi, f0 in enumerate(range(0, F, fb)):
                f1 = min(F, f0 + fb)
                block = np.empty((f1 - f0, C, H, W), np.float32)
                for c, lam in enumerate(lams):
                    done = (bi * C + c) * sgd_opts.get("iterations", 0)
                    cb = None if progress is None or method != "sgd" else \
                        (lambda it, _d=done: progress("encode", _d + it, total))
                    t, phi0 = _block_inputs(src, init_src, f0, f1, c, device=device, what=(result_path, init_path))
                    ops[c] = ops.get(c) or make_operators((H, W), z, lam, pitch, torch.device(device))  # once
                    blk = encode_block(method, t, z_m=z, wavelength_m=lam, pitch_m=pitch, supervision=sup,
                                       operators=ops[c], progress=cb, init=phi0, **sgd_opts)
                    del t
                    block[:, c] = wrap_phase(blk.phase)  # [0, 2pi) float32, as quantize's levels want it
                    acc.add(f0, c, blk)
                ph_out.write(block)
                u8f.write(quantize(block, lut=lut, wrapped=True).tobytes())
                del block
            ph_out.close()
            u8f.flush()
            u8_out = _StreamedNpy(zf, "frames_u8", (F, C, H, W), np.uint8)
            with open(tmp_u8, "rb") as rf:
                for piece in iter(lambda: rf.read(64 << 20), b""):
                    u8_out.fh.write(piece)
            u8_out.close()
            opts = {"fourier_filter": bool(fourier_filter), "fourier_filter_source": source,
                    "block_frames": int(fb), "memory_limit_bytes": int(memory_limit_bytes), "streamed": True,
                    "grid": [list(encoder_grid((H, W), z, lam, pitch)) for lam in lams], "device": str(device),
                    **_sgd_meta(sgd_opts, init_path)}
            res = acc.result(method, np.empty((0, C, H, W), np.float32), sup, t0, opts)
            out_meta = parse_stack_meta(stack_meta(meta, res, lut=lut, lut_source=lut_source), what=str(out_path))
            with zf.open("meta.npy", "w") as mf:
                np.lib.format.write_array(mf, np.array(json.dumps(out_meta.to_dict())), allow_pickle=False)
        os.replace(tmp, out_path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        Path(tmp_u8).unlink(missing_ok=True)
        held.close()
    return res, out_meta


def _threads_and_heap(method: str, device: Union[str, torch.device], elements: int) -> contextlib.ExitStack:
    """Entered: the block's thread setting (encoder.small_ops_on_one_thread) and one heap for the whole file,
    so that the pages a block's transforms freed serve the next block's (each block's own heap_reuse would hand
    them back to the kernel at its end, and the next block would fault them in again)."""
    held = contextlib.ExitStack()
    held.enter_context(small_ops_on_one_thread(method, device, elements))
    held.enter_context(heap_reuse(torch.device(device).type == "cpu"))
    return held


def _sgd_meta(sgd_opts: dict, init_path: Optional[Union[str, Path]]) -> dict:
    """What the stack's meta says of the SGD's options and its start (nothing for another encoder)."""
    if not sgd_opts:
        return {}
    return {"optimiser": sgd_opts["optimiser"], "lr": sgd_opts["lr"], "tol": sgd_opts["tol"],
            "stop_db": sgd_opts["stop_db"],
            "efficiency_weight": sgd_opts["efficiency_weight"], "max_iterations": sgd_opts["iterations"],
            "init": "naive" if init_path is None else f"stack {Path(init_path).name}"}


def _fourier_filter(display: Optional[dict], asked: Optional[bool]) -> tuple[bool, str]:
    """(whether the display's Fourier filter passes only the recording cone, where that was decided): the option,
    else the RESULT's display, else on."""
    if asked is not None:
        return bool(asked), "option"
    if display is not None and "fourier_filter" in display:
        return bool(display["fourier_filter"]), "display"
    return True, "default"


def _start_phase(init_path: Union[str, Path], shape: tuple[int, int, int, int], method: str) -> NpyMember:
    """The warm start's phase member, its shape checked from its header before a compressed one is inflated."""
    if method != "sgd":
        raise ValueError(f"a start phase (init) applies to method 'sgd' only, not {method!r}")
    try:
        return NpyMember(init_path, "phase", shape=shape)
    except MemberShapeError as exc:
        raise ValueError(f"the start stack {Path(init_path).name} holds phase {list(exc.shape)}, but the "
                         f"render is {list(shape)}: a warm start needs the same frames, colours and pixels") from None
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"cannot read the start phase from {Path(init_path).name}: {exc}") from None


def _block_inputs(src: NpyMember, init_src: Optional[NpyMember], f0: int, f1: int, c: int, *, device, what):
    """(frames f0..f1 of colour c of the target on ``device``, their start phases or None), both checked finite."""
    result_path, init_path = what
    t = torch.from_numpy(src.read_fc(f0, f1, c)).to(device=device, dtype=torch.complex64)
    if not bool(torch.isfinite(torch.view_as_real(t)).all()):
        raise ValueError(f"{result_path}: wrp_field contains NaN or infinite values")
    if init_src is None:
        return t, None
    phi0 = torch.from_numpy(np.ascontiguousarray(init_src.read_fc(f0, f1, c), np.float32))
    if not bool(torch.isfinite(phi0).all()):
        raise ValueError(f"the start stack {Path(init_path).name} holds NaN or infinite phases")
    return t, phi0
