"""One block of the encoder: the frames [f0, f1) of one color, prepared, encoded and measured on their own.

Everything here is per (frame, color): the target is scaled by its own peak (the loss is scale-free; its
energy is recorded in the input's scale for the illumination), black targets are found per item, and the
optimiser shares no number between items. A stack encoded block by block is therefore the stack encoded at
once (tests/encode/test_encoding.py checks it), and memory grows with the block, not with the stack.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import torch

from holocore.encode.lbfgs import optimise_lbfgs
from holocore.encode.sgd import Operator, encoder_grid, inner_energy, optimise
from holocore.optics.propagation import PitchLike
from holocore.plan.encode_steps import DEFAULT_OPTIMISER, default_iterations
from holocore.runtime.heap import heap_reuse

SUPERVISIONS = ("cone", "full")
OPTIMISERS = {"adam": optimise, "lbfgs": optimise_lbfgs}


@dataclass
class BlockResult:
    """Per-item ([B]) outcome of one block; ``phase`` float32 [B, H, W] (rad, not wrapped)."""

    phase: np.ndarray
    loss_init: np.ndarray
    loss_cone: np.ndarray
    loss_full: np.ndarray
    black: np.ndarray
    efficiency: np.ndarray  # fraction of the SLM's light inside the recording cone at the WRP
    efficiency_target: np.ndarray  # fraction of the SLM's light in the matched field s U_b
    in_window: np.ndarray  # fraction of the SLM's light that reaches the H x W WRP window at all
    target_energy: np.ndarray  # ||U_b||^2 in the input's scale (float64)
    matched_energy: np.ndarray  # |<U_b/||U_b||, U_p>|^2 for the unit-amplitude SLM (float64)
    iterations: np.ndarray
    converged: np.ndarray
    trace: list


def _peaks(t: torch.Tensor) -> torch.Tensor:
    return torch.stack([t[i].abs().max() for i in range(t.shape[0])]).double()


def dpac_phase(u0: torch.Tensor) -> torch.Tensor:
    """Double-phase coding of u0 [B, H, W]: theta +- acos(|u0| / max|u0|) on the two checkerboard squares."""
    amp = u0.abs()
    peak = amp.amax(dim=(-2, -1), keepdim=True)
    a = torch.where(peak > 0, amp / torch.where(peak > 0, peak, torch.ones_like(peak)), torch.zeros_like(amp))
    offset = torch.arccos(a.clamp(0.0, 1.0))
    h, w = u0.shape[-2:]
    rows = torch.arange(h, device=u0.device)[:, None]
    cols = torch.arange(w, device=u0.device)[None, :]
    sign = 1.0 - 2.0 * ((rows + cols) % 2).to(offset.dtype)  # +1 on even, -1 on odd squares
    return torch.angle(u0) + sign * offset


def make_operators(shape_hw: tuple[int, int], z_m: float, wavelength_m: float, pitch_m: PitchLike,
                   device: torch.device) -> tuple[Operator, Operator]:
    """A color's operators on its encoder grid, full band and recording cone, sharing one set of workspaces
    (building them is about a second at the paper's size: the transfer function and the cone's disc in float64)."""
    grid = encoder_grid(shape_hw, z_m, wavelength_m, pitch_m)
    op_full = Operator(shape_hw, z_m, wavelength_m, pitch_m, cone=False, device=device, grid=grid)
    op_cone = Operator(shape_hw, z_m, wavelength_m, pitch_m, cone=True, device=device, grid=grid)
    op_cone.share_buffers(op_full)
    return op_full, op_cone


def _on_reused_heap(fn):
    """``fn(method, target, **options)`` with every FFT output on reused heap pages on a CPU (holocore.runtime.heap):
    the set-up's and the final check's transforms as much as the optimiser's, which on fresh pages took twice as
    long."""
    @functools.wraps(fn)
    def run(method: str, target: torch.Tensor, **kw):
        with heap_reuse(target.device.type == "cpu"):
            return fn(method, target, **kw)
    return run


@_on_reused_heap
def encode_block(method: str, target: torch.Tensor, *, z_m: float, wavelength_m: float, pitch_m: PitchLike,
                 supervision: str = "cone", init: Optional[torch.Tensor] = None, iterations: Optional[int] = None,
                 lr: float = 0.2, stop_db: Optional[float] = 0.05, tol: Optional[float] = None,
                 efficiency_weight: float = 0.0, optimiser: Optional[str] = None,
                 progress: Optional[Callable[[int], None]] = None,
                 operators: Optional[tuple[Operator, Operator]] = None) -> BlockResult:
    """Encode target [B, H, W] (complex64, one color) with ``method`` (sgd | naive | dpac); sgd's steps are
    ``optimiser``'s (lbfgs | adam; None: the default, :mod:`holocore.plan.encode_steps`), ``iterations`` None: its
    default count. ``operators``: the color's :func:`make_operators`, kept by a caller that encodes several
    blocks of it (built here otherwise); their workspaces are freed at the end."""
    if supervision not in SUPERVISIONS:
        raise ValueError(f"supervision must be one of {SUPERVISIONS}, got {supervision!r}")
    optimiser = DEFAULT_OPTIMISER if optimiser is None else optimiser
    if optimiser not in OPTIMISERS:
        raise ValueError(f"optimiser must be one of {', '.join(OPTIMISERS)}, got {optimiser!r}")
    iterations = default_iterations(optimiser, iterations)
    b, h, w = target.shape
    dev = target.device
    op_full, op_cone = operators or make_operators((h, w), z_m, wavelength_m, pitch_m, dev)
    with torch.no_grad():
        peak = _peaks(target)
        scale = torch.where(peak > 0, 1.0 / torch.where(peak > 0, peak, torch.ones_like(peak)), torch.zeros_like(peak))
        t = target * scale.to(torch.float32)[:, None, None]
        u0 = op_full(t, adjoint=True)  # ideal SLM field A_-z U_t (A_-z = A_z^H, full band)
        tb = op_cone(u0)  # U_b = B A_z u0: what a perfect SLM of this aperture sends into the cone
        _, e_t = inner_energy(tb, tb)
        e_t = e_t.real.double()
        black_t = (e_t == 0) | (peak == 0)
        norm = torch.where(black_t, torch.zeros_like(e_t),
                           1.0 / torch.sqrt(torch.where(black_t, torch.ones_like(e_t), e_t)))
        t_unit = tb * norm.to(torch.float32)[:, None, None]
        del tb, t
        if init is not None:
            phi0 = init.to(device=dev, dtype=torch.float32)
        elif method == "dpac":
            phi0 = dpac_phase(u0)
        else:
            phi0 = torch.angle(u0)
        del u0
    black = black_t.cpu().numpy()
    op = op_cone if supervision == "cone" else op_full
    if method == "sgd":
        out = OPTIMISERS[optimiser](phi0, t_unit, op, lit=~black, iterations=iterations, lr=lr, stop_db=stop_db,
                                    tol=tol, efficiency_weight=efficiency_weight, progress=progress)
        phi, iters, conv, trace = out.phase, out.iterations, out.converged, out.trace
    else:
        phi, iters, conv, trace = phi0, np.zeros(b, np.int64), np.ones(b, bool), [[] for _ in range(b)]
    with torch.no_grad():
        u = torch.polar(torch.ones_like(phi), phi)
        a_c, e_c = inner_energy(t_unit, op_cone(u))
        a_f, e_f = inner_energy(t_unit, op_full(u))
        a_c2, a_f2 = a_c.abs().double().square(), a_f.abs().double().square()
        e_c, e_f = e_c.double(), e_f.double()
        loss_cone = torch.where(black_t, torch.ones_like(e_c), 1 - (a_c2 / e_c.clamp_min(1e-300)).clamp(0, 1))
        loss_full = torch.where(black_t, torch.ones_like(e_f), 1 - (a_f2 / e_f.clamp_min(1e-300)).clamp(0, 1))
        hw = float(h * w)
        matched = torch.where(black_t, torch.zeros_like(a_c2), a_c2)
        res = BlockResult(
            phase=phi.cpu().numpy().astype(np.float32, copy=False),
            loss_init=np.ones(b), loss_cone=loss_cone.cpu().numpy(), loss_full=loss_full.cpu().numpy(),
            black=black, efficiency=(e_c / hw).cpu().numpy(), efficiency_target=(matched / hw).cpu().numpy(),
            in_window=(e_f / hw).cpu().numpy(), target_energy=(e_t * peak.square()).cpu().numpy(),
            matched_energy=matched.cpu().numpy(), iterations=iters, converged=conv, trace=trace)
    op_full.release_buffers()
    if method == "sgd":
        res.loss_init = np.where(black, 1.0, out.loss_init)
    else:
        res.loss_init = res.loss_cone if supervision == "cone" else res.loss_full
    return res
