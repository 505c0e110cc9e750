"""L-BFGS on the encoder's phase, for one color and a block of frames: the same objective, gradient, stop rule
and outcome as Adam (:mod:`holocore.encode.sgd`), in fewer iterations.

Why: one iteration is four padded FFTs whichever optimiser takes the step, so the optimiser that needs fewer
of them wins outright. On this objective (a smooth function of the phase, ill-conditioned across the band)
memoryless BFGS (L-BFGS with one (s, y) pair: three or five pairs do no better here) reaches in 20 iterations the
field SNR Adam reaches in 30, and in 30 what Adam reaches in about 45 (bench/results/encode.md). Its step needs
no tuning after the first: the first step of an item moves its largest pixel by ``lr`` rad along the negative
gradient, later ones are the quasi-Newton step of length 1 (Nocedal & Wright, Numerical Optimization, Eq. 7.19
with m = 1 and the initial Hessian scaled by s.y / y.y), written out in closed form (:meth:`_Pair.step`).

Safeguard instead of a line search: a step that does not lower an item's objective is not taken (nor is its
pair kept), and that item's next iteration tries half of it (a backtracking step spread over
iterations). On the encoder's targets this happens a few times in the first iterations and rarely after, so
every iteration costs one evaluation, as Adam's does.

Every number is per (frame, color) item (dots, steps, pairs, the stop rule), so a block's result does not
depend on which other items share it, as with Adam.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np
import torch

from holocore.encode.operator import Operator, flip
from holocore.encode.sgd import CHECK_EVERY, Items, SgdOutcome, Work, objective_grad
from holocore.runtime.heap import heap_reuse

__all__ = ["optimise_lbfgs"]

def _dots(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """<a_i, b_i> per item [B] (one BLAS dot each, no temporaries), for real [B, H, W]."""
    return torch.stack([torch.dot(a[i].reshape(-1), b[i].reshape(-1)) for i in range(a.shape[0])])


def _col(v: torch.Tensor) -> torch.Tensor:
    return v[:, None, None]


class _Pair:
    """The last taken step s and its gradient change y of every item, with s.y and y.y (s.y = 0 where an item
    has no usable pair: none taken yet, or s.y <= 0)."""

    def __init__(self, like: torch.Tensor) -> None:
        b = like.shape[0]
        self.s, self.y = torch.zeros_like(like), torch.zeros_like(like)
        self.sy, self.yy = like.new_zeros(b), like.new_zeros(b)

    def update(self, d: torch.Tensor, g_new: torch.Tensor, g: torch.Tensor, taken: torch.Tensor) -> None:
        """Keep (d, g_new - g) for the ``taken`` items whose curvature s.y is positive."""
        y = torch.sub(g_new, g)
        sy, yy = _dots(d, y), _dots(y, y)
        use = taken & (sy > 0) & (yy > 0)
        if bool(use.all()):
            self.s, self.y, self.sy, self.yy = d, y, sy, yy
            return
        self.s = torch.where(_col(use), d, self.s)
        self.y = torch.where(_col(use), y, self.y)
        self.sy, self.yy = torch.where(use, sy, self.sy), torch.where(use, yy, self.yy)

    def select(self, sel: torch.Tensor) -> None:
        self.s, self.y = self.s.index_select(0, sel), self.y.index_select(0, sel)
        self.sy, self.yy = self.sy.index_select(0, sel), self.yy.index_select(0, sel)

    def step(self, g: torch.Tensor, first: float) -> torch.Tensor:
        """d = -H g, H the BFGS update of gamma I by the pair (gamma = s.y / y.y): with rho = 1 / s.y,
        a = rho s.g and b = rho gamma (y.g - a y.y), d = -gamma g + gamma a y - (a - b) s, one pass. Items
        without a pair: -g scaled so that the largest pixel moves by ``first`` (rad)."""
        has = self.sy > 0
        one = torch.ones_like(self.sy)
        rho = torch.where(has, one / torch.where(has, self.sy, one), torch.zeros_like(self.sy))
        if bool(has.all()):
            gamma = self.sy / self.yy
        else:
            peak = g.abs().amax(dim=(-2, -1)).clamp_min(1e-30)
            gamma = torch.where(has, self.sy / torch.where(has, self.yy, one), first / peak)
        d = torch.mul(g, _col(-gamma))
        if bool(has.any()):
            a = rho * _dots(self.s, g)
            b = rho * gamma * (_dots(self.y, g) - a * self.yy)
            d.addcmul_(self.y, _col(gamma * a)).addcmul_(self.s, _col(b - a))
        return d


def optimise_lbfgs(phi0: torch.Tensor, t_unit: torch.Tensor, op: Operator, *, lit: np.ndarray, iterations: int,
                   lr: float, stop_db: Optional[float], tol: Optional[float], efficiency_weight: float,
                   progress: Optional[Callable[[int], None]] = None) -> SgdOutcome:
    """L-BFGS on phi [B, H, W] against unit-norm targets t [B, H, W] through ``op``; the arguments and the
    outcome are :func:`holocore.encode.sgd.optimise`'s (``lr``: the first step's largest pixel change, rad)."""
    run = Items(phi0, t_unit, op, lit, iterations)
    if run.idle:
        return run.out
    dev, w_eff = phi0.device, float(efficiency_weight)
    phi = phi0.index_select(0, run.idx).contiguous()
    t = flip(t_unit.index_select(0, run.idx))  # J t: the WRP side is held flipped (operator, Eq. 1)
    with torch.no_grad(), heap_reuse(dev.type == "cpu"):
        work = Work.like(phi, t)
        f, rho2 = objective_grad(phi, t, op, w_eff, work)  # f: O at phi, the point the steps start from
        run.out.loss_init[run.active] = (1.0 - rho2.double().clamp(0, 1)).cpu().numpy()
        g = work.grad.clone()  # HW dO/dphi at phi
        first = float(lr)  # the first step's largest pixel change (rad)
        pair = _Pair(phi)
        retry = None  # the halved step of the items whose last step was not taken (None: every step was)
        missed = torch.zeros_like(f, dtype=torch.bool)
        for it in range(1, iterations + 1):
            d = pair.step(g, first)
            if retry is not None:
                d = torch.where(_col(missed), retry, d)
            phi.add_(d)  # the trial point, in place
            f_new, _ = objective_grad(phi, t, op, w_eff, work)
            taken = f_new < f  # strictly: a step the objective cannot tell from none is not taken
            pair.update(d, work.grad, g, taken)
            missed = ~taken
            if bool(missed.any()):
                phi.addcmul_(d, _col(missed.to(d.dtype)), value=-1.0)  # back to where the missed items were
                retry = 0.5 * d
                g = torch.where(_col(taken), work.grad, g)
            else:
                retry = None
                g, work.grad = work.grad, g  # the new gradient is kept; its old buffer takes the next one
            f = torch.where(taken, f_new, f)
            run.out.iterations[run.active] = it
            if it % CHECK_EVERY and it != iterations:
                continue
            sel = run.check(f, phi, stop_db=stop_db, tol=tol)
            if progress is not None:
                progress(it)
            if sel is not None:
                if run.active.size == 0:
                    break
                phi, g, f, t = (v.index_select(0, sel) for v in (phi, g, f, t))
                if retry is not None:
                    retry, missed = retry.index_select(0, sel), missed.index_select(0, sel)
                pair.select(sel)
                work = work.narrow(len(sel))
        return run.finish(phi)
