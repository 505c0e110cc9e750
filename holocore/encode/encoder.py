"""Phase-only encoding of a WRP field into an SLM phase stack (docs/design.md §6, paper Sec. 5.3; docs/encoding.md).

Hologram space: SLM at z = 0, WRP at z = z_wrp > 0. The ideal (complex) SLM field is u0 = ASM(U_t, -z_wrp);
a phase-only SLM shows exp(i phi), whose WRP field is U_p = ASM(exp(i phi), +z_wrp) (band-limited ASM, §5).

The target is always the band-limited WRP field U_b = B ASM(u0, +z_wrp), B the recording cone (the disc of
radius sin(theta_max)/lambda = 1/(2p) in the spectrum: every traced field lives there, what the tracer puts
outside is Monte Carlo noise). What it is compared with depends on the display (``fourier_filter``):

- with a Fourier filter that passes only the cone (``supervision="cone"``): B U_p. The spectrum's corners
  are free; the optimiser parks there the light a phase-only SLM cannot help sending, and the filter removes it.
- without one (``"full"``): U_p itself, all the SLM sends into the WRP window. Light outside the cone reaches
  the eye as noise, so it counts as error.

Loss per (frame, color), scale-free: E = 1 - rho^2, rho^2 = |<U_b, P>|^2 / (||U_b||^2 ||P||^2), P the compared
field; equal to ||P - s U_b||^2 / ||P||^2 with the best complex scale s. ``efficiency_weight`` w minimises
1 - e^w rho^2 instead, e = ||P||^2 / HW. Black targets have E = 1, zero gradient and keep their start phase.
The optimiser (manual-gradient Adam, less padding where z allows it, a per-item stop rule in dB) is in
:mod:`holocore.encode.sgd`; blocks of frames of one color (chunking, exact) in :mod:`holocore.encode.block`.
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np
import torch

from holocore import validate
from holocore.encode.block import OPTIMISERS, SUPERVISIONS, BlockResult, encode_block, make_operators
from holocore.encode.core import (
    TWO_PI,
    ArrayLike,
    field_error,
    ideal_slm_field,
    passband_filter,
    propagate_to_wrp,
    reach_margin_px,
    wrap_phase,
)
from holocore.encode.output import load_lut, quantize, save_encoded
from holocore.encode.sgd import encoder_grid, spread_px
from holocore.optics.propagation import PitchLike
from holocore.plan.encode_steps import DEFAULT_OPTIMISER, default_iterations
from holocore.plan.estimate import stop_iterations
from holocore.runtime.heap import heap_reuse

__all__ = ["EncodeResult", "encode_sgd", "encode_naive", "encode_dpac", "encode", "METHODS", "SUPERVISIONS",
           "ideal_slm_field", "propagate_to_wrp", "passband_filter", "field_error", "reach_margin_px", "wrap_phase",
           "load_lut", "quantize", "save_encoded", "encoder_grid", "spread_px", "supervision_for", "Assembler",
           "TWO_PI"]

METHODS = ("sgd", "dpac", "naive")
ProgressFn = Callable[[str, int, int], None]


def supervision_for(fourier_filter: bool) -> str:
    """'cone' for a display whose Fourier filter passes only the recording cone, else 'full'."""
    return "cone" if fourier_filter else "full"


@dataclass(frozen=True)
class EncodeResult:
    """A phase stack and how it was obtained; every array but ``phase`` is [F, C].

    ``phase`` float32 [F, C, H, W] in [0, 2pi). ``loss``/``loss_init``: E under the supervision used, at the end
    and the start; ``loss_cone``/``loss_full``: E against B U_p and against U_p. ``efficiency``: fraction of the
    SLM's light in the cone at the WRP; ``efficiency_target``: in the matched field s U_b. ``illumination``:
    relative laser power (max 1) that restores the target's colour balance; a display shows sqrt(P) exp(i phi).
    """

    phase: np.ndarray
    loss: np.ndarray
    loss_init: np.ndarray
    black: np.ndarray
    efficiency: np.ndarray
    illumination: np.ndarray
    method: str
    iterations: int
    seconds: float
    converged: bool
    options: dict = field(default_factory=dict)
    history: tuple[float, ...] = ()
    loss_cone: Optional[np.ndarray] = None
    loss_full: Optional[np.ndarray] = None
    efficiency_target: Optional[np.ndarray] = None
    in_window: Optional[np.ndarray] = None
    iterations_per_target: Optional[np.ndarray] = None
    supervision: str = "cone"

    def summary(self) -> dict[str, Any]:
        """JSON-able description for a stack's meta (``meta["encoder"]``)."""
        lit = ~self.black

        def mean(a):
            return float(np.asarray(a)[lit].mean()) if lit.any() and a is not None else (1.0 if a is not None else None)

        def lst(a):
            return None if a is None else np.asarray(a).tolist()

        compared = "B U_p (the Fourier filter removes the rest)" if self.supervision == "cone" else \
            "U_p (no Fourier filter: light outside the cone reaches the eye and counts as error)"
        return {
            "method": self.method, "iterations": int(self.iterations), "converged": bool(self.converged),
            "seconds": float(self.seconds), "supervision": self.supervision,
            "loss": lst(self.loss), "loss_init": lst(self.loss_init), "loss_mean": mean(self.loss),
            "loss_init_mean": mean(self.loss_init), "loss_cone": lst(self.loss_cone), "loss_full": lst(self.loss_full),
            "loss_cone_mean": mean(self.loss_cone), "loss_full_mean": mean(self.loss_full),
            "black": lst(self.black), "efficiency": lst(self.efficiency), "efficiency_mean": mean(self.efficiency),
            "efficiency_target": lst(self.efficiency_target), "efficiency_target_mean": mean(self.efficiency_target),
            "light_in_window": lst(self.in_window), "illumination": lst(self.illumination),
            "iterations_per_target": lst(self.iterations_per_target),
            "loss_definition": f"E = 1 - |<U_b,P>|^2/(|U_b|^2 |P|^2) on the WRP, P = {compared}; B: recording-cone "
                               "passband, U_b = B ASM(ASM(U_t,-z_wrp),z_wrp), U_p = ASM(exp(i phase),z_wrp)",
            "history": [float(v) for v in self.history],
            **self.options,
        }


def _illumination(target_energy: np.ndarray, matched_energy: np.ndarray, black: np.ndarray) -> np.ndarray:
    """Relative laser power P [F, C] in [0, 1]: P ~ ||U_b||^2 / |<U_b/||U_b||, U_p>|^2 gives the matched part of
    every (frame, color), s U_b, the same scale; normalised to max 1; 0 (laser off) where nothing is matched."""
    ok = (~black) & (matched_energy > 0)
    p = np.where(ok, target_energy / np.where(ok, matched_energy, 1.0), 0.0)
    peak = p.max() if p.size else 0.0
    return p / peak if peak > 0 else p


class Assembler:
    """Collects block results into [F, C] arrays (and the per-item objective traces) in any block order."""

    KEYS = ("loss_init", "loss_cone", "loss_full", "black", "efficiency", "efficiency_target", "in_window",
            "target_energy", "matched_energy", "iterations", "converged")

    def __init__(self, frames: int, colors: int) -> None:
        self.arr = {k: np.zeros((frames, colors), bool if k in ("black", "converged") else
                                np.int64 if k == "iterations" else np.float64) for k in self.KEYS}
        self.trace: list[list[list[float]]] = [[[] for _ in range(colors)] for _ in range(frames)]

    def add(self, f0: int, c: int, blk: BlockResult) -> None:
        for k in self.KEYS:
            self.arr[k][f0:f0 + blk.black.shape[0], c] = getattr(blk, k)
        for j, tr in enumerate(blk.trace):
            self.trace[f0 + j][c] = tr

    def history(self) -> list[float]:
        """Mean objective over the lit targets at every check; a stopped target counts with its last value."""
        lit = [(f, c) for f in range(len(self.trace)) for c in range(len(self.trace[0])) if not self.arr["black"][f, c]]
        n = max((len(self.trace[f][c]) for f, c in lit), default=0)
        return [float(np.mean([self.trace[f][c][min(k, len(self.trace[f][c]) - 1)] for f, c in lit
                               if self.trace[f][c]])) for k in range(n)] if lit else []

    def result(self, method: str, phase: np.ndarray, supervision: str, t0: float, options: dict) -> EncodeResult:
        a = self.arr
        loss = a["loss_cone"] if supervision == "cone" else a["loss_full"]
        return EncodeResult(
            phase=phase, loss=loss, loss_init=a["loss_init"], black=a["black"], efficiency=a["efficiency"],
            illumination=_illumination(a["target_energy"], a["matched_energy"], a["black"]), method=method,
            iterations=int(a["iterations"].max()) if a["iterations"].size else 0, seconds=time.perf_counter() - t0,
            converged=bool(a["converged"][~a["black"]].all()) if method == "sgd" else True, options=options,
            history=tuple(self.history()), loss_cone=a["loss_cone"], loss_full=a["loss_full"],
            efficiency_target=a["efficiency_target"], in_window=a["in_window"],
            iterations_per_target=a["iterations"].copy(), supervision=supervision)


def _check_target(target: ArrayLike) -> ArrayLike:
    t = target.detach() if isinstance(target, torch.Tensor) else np.asarray(target)
    if not isinstance(t, torch.Tensor) and (not np.issubdtype(t.dtype, np.number) or t.dtype == bool):
        raise ValueError(f"target_wrp must be a numeric array, got dtype {t.dtype}")
    if t.ndim != 4:
        raise ValueError(f"target_wrp must be [F, C, H, W], got shape {tuple(t.shape)}")
    if min(t.shape) < 1:
        raise ValueError(f"target_wrp must have every axis >= 1, got shape {tuple(t.shape)}")
    return t


def _block(t: ArrayLike, f0: int, f1: int, c: int, device) -> torch.Tensor:
    x = t[f0:f1, c]
    x = x if isinstance(x, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(x))
    x = x.to(device=device if device is not None else x.device, dtype=torch.complex64)
    if not bool(torch.isfinite(torch.view_as_real(x)).all()):
        raise ValueError("target_wrp contains NaN or infinite values")
    return x.contiguous()


def _run(method: str, target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
         fourier_filter: bool, device, chunk_frames: Optional[int], init: Optional[ArrayLike] = None,
         sgd: Optional[dict] = None, progress: Optional[ProgressFn] = None,
         options: Optional[dict] = None) -> EncodeResult:
    t0 = time.perf_counter()
    t = _check_target(target_wrp)
    z = validate.bounded("z_wrp_m", z_wrp_m, low=0.0, low_inclusive=False, unit="m (WRP in front of the SLM)")
    lams = validate.wavelengths(wavelengths_m, t.shape[1])
    validate.pitch_pair(pitch_m)
    if not isinstance(fourier_filter, (bool, np.bool_)):
        raise ValueError(f"fourier_filter must be True or False, got {fourier_filter!r}")
    F, C, H, W = t.shape
    if chunk_frames is None:
        chunk_frames = F
    if isinstance(chunk_frames, bool) or not isinstance(chunk_frames, (int, np.integer)) or chunk_frames < 1:
        raise ValueError(f"chunk_frames must be an integer >= 1, got {chunk_frames!r}")
    if init is not None:
        phi_init = torch.as_tensor(init.detach() if isinstance(init, torch.Tensor) else np.asarray(init))
        if phi_init.is_complex() or phi_init.dtype == torch.bool:
            raise ValueError(f"init must be a real phase array (rad), got dtype {phi_init.dtype}")
        if tuple(phi_init.shape) != (F, C, H, W):
            raise ValueError(f"init must have the target's shape {(F, C, H, W)}, got {tuple(phi_init.shape)}")
        if not bool(torch.isfinite(phi_init).all()):
            raise ValueError("init contains NaN or infinite values")
    sup = supervision_for(bool(fourier_filter))
    dev = t.device if isinstance(t, torch.Tensor) and device is None else device
    phase = np.empty((F, C, H, W), np.float32)
    acc = Assembler(F, C)
    sgd = dict(sgd or {})
    total = sgd.get("iterations", 0)
    n_blocks = C * math.ceil(F / chunk_frames)
    grid = max((encoder_grid((H, W), z, lam, pitch_m) for lam in lams), key=lambda g: g[0] * g[1])
    on_cpu = dev is None or torch.device(dev).type == "cpu"  # one heap for every block (as stream.encode_file)
    with small_ops_on_one_thread(method, dev, min(chunk_frames, F) * grid[0] * grid[1]), heap_reuse(on_cpu):
        _encode_blocks(method, t, lams, F, chunk_frames, z, pitch_m, sup, dev, init, phi_init if init is not None
                       else None, sgd, progress, total, n_blocks, phase, acc)
    opts = {"fourier_filter": bool(fourier_filter), "chunk_frames": int(chunk_frames),
            "grid": [list(encoder_grid((H, W), z, lam, pitch_m)) for lam in lams], **(options or {})}
    return acc.result(method, phase, sup, t0, opts)


# Below this many complex elements per operation (frames of a block x the padded grid) one SGD step is
# hundreds of small ops of well under a millisecond each, and splitting each over threads costs more at
# their barriers than it saves; on a CPU shared with other work (a second job, the browser watching it) a
# thread that waits for a descheduled one made the 96x128, 2-frame encode of a service job take 55 s
# instead of 2-3 s (the estimate's 4 s was right). Larger grids keep torch's threads.
SMALL_OPS_ELEMENTS = 1 << 19


@contextlib.contextmanager
def small_ops_on_one_thread(method: str, dev, elements: int):
    """torch on one thread while the SGD encoder works on ``elements`` per operation below SMALL_OPS_ELEMENTS
    on the CPU (the thread count is restored after)."""
    on_cpu = dev is None or torch.device(dev).type == "cpu"
    if method != "sgd" or not on_cpu or elements >= SMALL_OPS_ELEMENTS or torch.get_num_threads() == 1:
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _encode_blocks(method, t, lams, F, chunk_frames, z, pitch_m, sup, dev, init, phi_init, sgd, progress, total,
                   n_blocks, phase, acc) -> None:
    # The progress counts the iterations expected to run: with a stop rule, its median at this size (not the cap
    # of 500, which made a 3-colour encode count to 1500 and jump); a block that runs longer raises the total.
    stops = bool(sgd.get("stop_db")) or bool(sgd.get("tol"))
    expect = min(total, stop_iterations(t.shape[-2], t.shape[-1])) if stops else total
    ran = 0  # iterations of the blocks done
    k = 0
    for c, lam in enumerate(lams):
        ops = None  # the color's operators, built with its first block and kept for the others
        for f0 in range(0, F, chunk_frames):
            f1 = min(F, f0 + chunk_frames)
            cb = None if progress is None or method != "sgd" else _block_progress(progress, ran, expect,
                                                                                    left=n_blocks - k - 1)
            target = _block(t, f0, f1, c, dev)
            ops = ops or make_operators(tuple(target.shape[-2:]), z, lam, pitch_m, target.device)
            blk = encode_block(method, target, z_m=z, wavelength_m=lam, pitch_m=pitch_m, supervision=sup,
                               init=None if init is None else phi_init[f0:f1, c], progress=cb, operators=ops, **sgd)
            phase[f0:f1, c] = wrap_phase(blk.phase)
            acc.add(f0, c, blk)
            ran += int(np.max(blk.iterations)) if np.size(blk.iterations) else 0
            k += 1
    if progress is not None and method == "sgd" and ran:
        progress("encode", ran, ran)


def sgd_options(iterations, lr, tol, stop_db, efficiency_weight, optimiser=None) -> dict:
    """The SGD's options checked, each refusal one line; ``optimiser`` None: the default
    (:mod:`holocore.plan.encode_steps`), ``iterations`` None: that optimiser's default count."""
    optimiser = DEFAULT_OPTIMISER if optimiser is None else optimiser
    if optimiser not in OPTIMISERS:
        raise ValueError(f"optimiser must be one of {', '.join(OPTIMISERS)}, got {optimiser!r}")
    iterations = default_iterations(optimiser, iterations)
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or not 0 <= iterations <= 10**6:
        raise ValueError(f"iterations must be an integer in 0..1000000, got {iterations!r}")
    lr = validate.bounded("lr", lr, low=0.0, low_inclusive=False, unit="rad")
    if tol is not None:
        tol = validate.bounded("tol", tol, low=0.0, low_inclusive=True, unit="(relative loss change)")
    stop_db = validate.bounded("stop_db", stop_db, low=0.0, low_inclusive=True, unit="dB")
    w = validate.bounded("efficiency_weight", efficiency_weight, low=0.0, low_inclusive=True, unit="")
    if w > 1.0:
        raise ValueError(f"efficiency_weight must be in [0, 1], got {efficiency_weight!r}")
    return dict(iterations=int(iterations), lr=lr, tol=tol, stop_db=stop_db, efficiency_weight=w,
                optimiser=optimiser)


def _block_progress(progress: ProgressFn, ran: int, expect: int, *, left: int):
    """A block's progress callback: its iterations after the ``ran`` of the blocks before, out of what the blocks
    are expected to run (a block that runs longer raises the total)."""
    return lambda it: progress("encode", ran + it, ran + max(expect, it) + left * expect)


def encode_sgd(target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
               iterations: Optional[int] = None, lr: float = 0.2, init: Optional[ArrayLike] = None,
               tol: Optional[float] = None, stop_db: float = 0.05, efficiency_weight: float = 0.0,
               optimiser: Optional[str] = None,
               fourier_filter: bool = True,
               chunk_frames: Optional[int] = None, device: Optional[Union[str, torch.device]] = None,
               progress: Optional[ProgressFn] = None) -> EncodeResult:
    """Optimise the SLM phase [F, C, H, W] so that ASM(exp(i phi), z_wrp) matches the target in amplitude and
    phase up to one complex scale per (frame, color) (docs/design.md §6; module docstring).

    ``target_wrp`` complex [F, C, H, W] on the WRP at ``z_wrp_m`` (m, > 0); ``wavelengths_m`` one per color;
    ``pitch_m`` (m). ``optimiser`` (None: the default, :mod:`holocore.plan.encode_steps`; lbfgs: memoryless BFGS,
    :mod:`holocore.encode.lbfgs`, ``lr`` its first step's largest change; adam: Adam with step ``lr``, rad) for
    at most ``iterations`` steps (None: the optimiser's default count, 30 for lbfgs, 500 for adam);
    each (frame, color) stops once its field SNR 10 log10((1-E)/E) gained less than ``stop_db`` dB over 30
    iterations (0: never), or, if ``tol`` is given, once E fell by less than that fraction over 30 iterations
    (0: never). ``init``: phase in rad (default arg u0). ``fourier_filter``: the display's (module docstring).
    ``chunk_frames``: frames per block (default all; the result does not depend on it). ``progress(stage, done,
    total)``.
    """
    sgd = sgd_options(iterations, lr, tol, stop_db, efficiency_weight, optimiser)
    opts = {"optimiser": sgd["optimiser"], "lr": sgd["lr"], "tol": sgd["tol"], "stop_db": sgd["stop_db"],
            "efficiency_weight": sgd["efficiency_weight"],
            "max_iterations": sgd["iterations"], "init": "naive" if init is None else "given",
            "device": str(device if device is not None else (target_wrp.device if isinstance(target_wrp, torch.Tensor)
                                                             else "cpu"))}
    return _run("sgd", target_wrp, z_wrp_m=z_wrp_m, wavelengths_m=wavelengths_m, pitch_m=pitch_m,
                fourier_filter=fourier_filter, device=device, chunk_frames=chunk_frames, init=init, sgd=sgd,
                progress=progress, options=opts)


def encode_naive(target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
                 fourier_filter: bool = True, chunk_frames: Optional[int] = None,
                 device: Optional[Union[str, torch.device]] = None) -> EncodeResult:
    """Naive encoding: phi = arg ASM(U_t, -z_wrp) (the ideal SLM field's phase, its amplitude dropped)."""
    return _run("naive", target_wrp, z_wrp_m=z_wrp_m, wavelengths_m=wavelengths_m, pitch_m=pitch_m,
                fourier_filter=fourier_filter, device=device, chunk_frames=chunk_frames)


def encode_dpac(target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
                fourier_filter: bool = True, chunk_frames: Optional[int] = None,
                device: Optional[Union[str, torch.device]] = None) -> EncodeResult:
    """Double-phase amplitude coding of u0 = ASM(U_t, -z_wrp) (Hsueh & Sawchuk 1978; Maimone et al. 2017).

    A e^{i theta} with A = |u0| / max|u0| per (frame, color) is the mean of e^{i(theta +- acos A)}; the two
    phases go to the two kinds of squares of a checkerboard ((row + col) even: +). Black targets give +-pi/2.
    """
    return _run("dpac", target_wrp, z_wrp_m=z_wrp_m, wavelengths_m=wavelengths_m, pitch_m=pitch_m,
                fourier_filter=fourier_filter, device=device, chunk_frames=chunk_frames)


def encode(method: str, target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float],
           pitch_m: PitchLike, device: Optional[Union[str, torch.device]] = None, fourier_filter: bool = True,
           chunk_frames: Optional[int] = None, **sgd_options: Any) -> EncodeResult:
    """Dispatch to :func:`encode_sgd`, :func:`encode_dpac` or :func:`encode_naive` by ``method``."""
    common = dict(z_wrp_m=z_wrp_m, wavelengths_m=wavelengths_m, pitch_m=pitch_m, device=device,
                  fourier_filter=fourier_filter, chunk_frames=chunk_frames)
    if method == "sgd":
        return encode_sgd(target_wrp, **common, **sgd_options)
    if sgd_options:
        raise ValueError(f"options {sorted(sgd_options)} apply to method 'sgd' only, not {method!r}")
    if method == "dpac":
        return encode_dpac(target_wrp, **common)
    if method == "naive":
        return encode_naive(target_wrp, **common)
    raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
