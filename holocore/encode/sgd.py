"""The phase-only encoder's optimiser, for one color and a block of frames (docs/design.md §6).

The operator A_z (band-limited ASM on the encoder's padded grid, its adjoint, and why less than 2x padding is
exact) is :mod:`holocore.encode.operator`; ``Operator``, ``encoder_grid`` and ``spread_px`` are re-exported here.

Loss and gradient, per (frame, color) b, with t the unit-norm band-limited target and p = A_z u:
a = <t, p>, e = ||p||^2, rho^2 = |a|^2 / e, q = (e / HW)^w (w: ``efficiency_weight``), objective
O = 1 - q rho^2 (w = 0: E = 1 - rho^2). Its Wirtinger gradient is dO/dp* = -(q/e)(a t - (1 - w) rho^2 p), so
dO/du* = A^H dO/dp* and, with u = exp(i phi), dO/dphi = 2 Im(conj(u) dO/du*). Written out this way one
iteration is four padded ``fft2`` (Eqs. 1-2 of :mod:`holocore.encode.operator`), two multiplies on the padded grid
and ten passes over H x W: cos, sin, u = exp(i phi) straight into the FFT input, the crop copy of J p, the
dots (one BLAS dot each), dO/dp* straight into the adjoint's input (two), the gradient (two), fused Adam.
No autograd tape. The WRP-side fields (t, p, dO/dp*) are held flipped (J; the dots do not depend on the
order), the SLM side (phi, u, the gradient) in natural order. The gradient is HW dO/dphi
(the adjoint returns 2 HW dO/du*, and dO/dphi = 2 Im(conj(u) dO/du*)), scaled so that Adam's eps stays
negligible at every size (Adam is otherwise scale-free).

Adam, per element (Kingma & Ba 2015; the same update as ``torch.optim.Adam``). Each (frame, color) has its
own stop rule: every 10 iterations its field SNR, 10 log10((1 - O) / O) dB, is compared with the value 30
iterations before; once it gained less than ``stop_db`` (default 0.05 dB: far below what a viewer notices) it
is frozen and leaves the batch. No number is shared between (frame, color) pairs, so the result does not depend
on how frames are grouped into blocks (chunking is exact).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import torch

import holocore.runtime.torch_runtime  # noqa: F401  (reproducible CPU vector math; see its docstring)
from holocore.encode.operator import Operator, encoder_grid, flip, spread_px
from holocore.runtime.heap import heap_reuse

__all__ = ["Operator", "encoder_grid", "spread_px", "inner_energy", "optimise", "SgdOutcome"]

CHECK_EVERY = 10  # iterations between stop-rule checks
WINDOW_CHECKS = 3  # the stop rule compares with the value this many checks (30 iterations) before
_BETAS = (0.9, 0.999)
_EPS = 1e-8


def inner_energy(t: torch.Tensor, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """a = <t, p> (complex [B]) and e = ||p||^2 (float [B]), item by item (one BLAS dot each, no temporaries):
    the same numbers whatever B is, so chunking is exact."""
    a = torch.stack([torch.vdot(t[i].reshape(-1), p[i].reshape(-1)) for i in range(t.shape[0])])
    e = torch.stack([torch.vdot(p[i].reshape(-1), p[i].reshape(-1)).real for i in range(p.shape[0])])
    return a, e


@dataclass
class Work:
    """The H x W buffers of one evaluation, reused across iterations: cos and sin of phi, J A u, and dO/dphi."""

    cos: torch.Tensor
    sin: torch.Tensor
    p: torch.Tensor
    grad: torch.Tensor

    @classmethod
    def like(cls, phi: torch.Tensor, t: torch.Tensor) -> "Work":
        return cls(torch.empty_like(phi), torch.empty_like(phi), torch.empty_like(t), torch.empty_like(phi))

    def narrow(self, n: int) -> "Work":
        return Work(self.cos[:n], self.sin[:n], self.p[:n], self.grad[:n])


def objective_grad(phi: torch.Tensor, t: torch.Tensor, op: Operator, w_eff: float,
                   work: Work) -> tuple[torch.Tensor, torch.Tensor]:
    """O and rho^2 ([B]) at phi, with HW dO/dphi written into ``work.grad`` (module docstring): four padded
    ``fft2``, two multiplies on the padded grid, the passes over H x W listed there. t and ``work.p`` are
    flipped (J)."""
    n, dev = phi.shape[0], phi.device
    hw = float(phi.shape[-2] * phi.shape[-1])
    cos, sin, p = work.cos, work.sin, work.p
    torch.cos(phi, out=cos)
    torch.sin(phi, out=sin)
    torch.complex(cos, sin, out=op.window("in", n, dev))  # u = exp(i phi), straight into the FFT input
    p.copy_(op.apply("in", n, dev))  # J A u (the crop copy; the padded result is freed)
    a, e = inner_energy(t, p)
    e = e.clamp_min(1e-30)
    rho2 = (a.real.square() + a.imag.square()) / e
    q = (e / hw) ** w_eff if w_eff > 0 else torch.ones_like(e)
    c1 = (-2.0 * hw * (q / e) * a)[:, None, None]  # 2 HW dO/dp* = c1 t + c2 p, flipped like t and p
    c2 = (2.0 * hw * (q / e) * (1.0 - w_eff) * rho2)[:, None, None]  # real: a cheaper multiply
    torch.mul(p, c2, out=op.window("adj", n, dev)).addcmul_(t, c1)
    gu = op.apply("adj", n, dev, adjoint=True)  # 2 HW dO/du*, natural order (Eq. 2)
    # dO/dphi = 2 Im(conj(u) dO/du*) = 2 (cos Im g - sin Re g); the 2 rides on c1, c2
    torch.mul(cos, gu.imag, out=work.grad).addcmul_(sin, gu.real, value=-1.0)
    return 1.0 - q * rho2, rho2


def _adam(phi: torch.Tensor, lr: float, state: Optional[dict]) -> torch.optim.Adam:
    """torch's Adam on phi (fused on CPU and CUDA: one pass per step), optionally with a given state."""
    phi.requires_grad_(False)
    opt = torch.optim.Adam([phi], lr=lr, betas=_BETAS, eps=_EPS, fused=phi.device.type in ("cpu", "cuda"))
    if state is not None:
        opt.state[phi] = state
    return opt


def _stop(hist: list[float], stop_db: Optional[float], tol: Optional[float]) -> bool:
    """The per-item stop rule on the objective at the checks so far (module docstring)."""
    if len(hist) <= WINDOW_CHECKS:
        return False
    old, new = hist[-1 - WINDOW_CHECKS], hist[-1]
    if new <= 1e-7:
        return True
    if tol is not None:
        return tol > 0 and old - new <= tol * max(old, 1e-12)
    if not stop_db:
        return False

    def snr(o: float) -> float:
        return 10.0 * math.log10(max(1.0 - o, 1e-30) / max(o, 1e-30))

    return snr(new) - snr(old) < stop_db


@dataclass
class SgdOutcome:
    phase: torch.Tensor  # [B, H, W] rad
    iterations: np.ndarray  # int [B]
    converged: np.ndarray  # bool [B]
    trace: list[list[float]]  # objective of each item at every check (before that check's step)
    loss_init: np.ndarray  # float64 [B]


class Items:
    """The bookkeeping both optimisers share: the outcome filled item by item, the lit items still stepping
    (``active``, and ``idx`` on the device), the stop rule at every check and the retiring of stopped items."""

    def __init__(self, phi0: torch.Tensor, t_unit: torch.Tensor, op: Operator, lit: np.ndarray,
                 iterations: int) -> None:
        b_all = phi0.shape[0]
        self.out = SgdOutcome(phi0.clone(), np.zeros(b_all, np.int64), ~lit.copy(), [[] for _ in range(b_all)],
                              np.ones(b_all))
        self.active = np.flatnonzero(lit)
        self.idx = torch.from_numpy(self.active).to(phi0.device)
        self.idle = iterations == 0 or self.active.size == 0  # nothing to step: the outcome is final now
        if self.idle:
            self.out.converged[:] = self.out.converged | (iterations == 0)
            if self.active.size:
                act = self.active
                with torch.no_grad():
                    a, e = inner_energy(t_unit[act], op(torch.polar(torch.ones_like(phi0[act]), phi0[act])))
                rho2 = (a.abs().square() / e.clamp_min(1e-30)).double().clamp(0, 1)
                self.out.loss_init[act] = (1 - rho2).cpu().numpy()

    def check(self, obj: torch.Tensor, phi: torch.Tensor, *, stop_db: Optional[float],
              tol: Optional[float]) -> Optional[torch.Tensor]:
        """At a check: each active item's objective into its trace and the stop rule; stopped items' phases out.
        Returns the positions in the batch of the items that go on when some stopped (None: all go on)."""
        objs = obj.double().cpu().numpy()
        keep = []
        for j, k in enumerate(self.active):
            self.out.trace[k].append(float(objs[j]))
            self.out.converged[k] = _stop(self.out.trace[k], stop_db, tol)
            keep.append(not self.out.converged[k])
        if all(keep):
            return None
        dev = phi.device
        done = torch.tensor([j for j, kp in enumerate(keep) if not kp], device=dev)
        self.out.phase.index_copy_(0, self.idx.index_select(0, done), phi.index_select(0, done))
        sel = torch.tensor([j for j, kp in enumerate(keep) if kp], dtype=torch.long, device=dev)
        self.active = self.active[np.asarray(keep)]
        self.idx = self.idx.index_select(0, sel)
        return sel

    def finish(self, phi: torch.Tensor) -> SgdOutcome:
        if self.active.size:
            self.out.phase.index_copy_(0, self.idx, phi)
        return self.out


def optimise(phi0: torch.Tensor, t_unit: torch.Tensor, op: Operator, *, lit: np.ndarray, iterations: int,
             lr: float, stop_db: Optional[float], tol: Optional[float], efficiency_weight: float,
             progress: Optional[Callable[[int], None]] = None) -> SgdOutcome:
    """Adam on phi [B, H, W] against unit-norm targets t [B, H, W] through ``op`` (module docstring). Items that
    are not ``lit`` (black targets) are never updated. ``stop_db`` / ``tol`` (relative objective decrease over
    30 iterations; used when given): per-item stop rules, 0 never stops."""
    run = Items(phi0, t_unit, op, lit, iterations)
    if run.idle:
        return run.out
    dev = phi0.device
    phi = phi0.index_select(0, run.idx).contiguous()
    t = flip(t_unit.index_select(0, run.idx))  # J t: the WRP side is held flipped (encoding_op, Eq. 1)
    opt = _adam(phi, lr, None)
    w_eff = float(efficiency_weight)
    with torch.no_grad(), heap_reuse(dev.type == "cpu"):
        work = Work.like(phi, t)
        for it in range(1, iterations + 1):
            obj, rho2 = objective_grad(phi, t, op, w_eff, work)
            if it == 1:
                run.out.loss_init[run.active] = (1.0 - rho2.double().clamp(0, 1)).cpu().numpy()
            phi.grad = work.grad
            opt.step()
            run.out.iterations[run.active] = it
            if it % CHECK_EVERY and it != iterations:
                continue
            sel = run.check(obj, phi, stop_db=stop_db, tol=tol)
            if progress is not None:
                progress(it)
            if sel is not None:
                if run.active.size == 0:
                    break
                state = opt.state[phi]
                phi = phi.index_select(0, sel).contiguous()
                opt = _adam(phi, lr, {k: (v.index_select(0, sel).contiguous() if v.dim() else v.clone())
                                      for k, v in state.items()})
                t = t.index_select(0, sel).contiguous()
                work = work.narrow(len(sel))
        return run.finish(phi)
