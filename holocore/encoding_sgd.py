"""The encoder's propagation operator and its optimiser, for one color and a block of frames (DESIGN.md §6).

Operator. A_z u = crop( IFFT{ M . FFT{pad(u)} } ), M = H_z . K: the band-limited ASM transfer function
(``propagation.transfer_function``; Matsushima & Shimobaba 2009, Eq. 13) times K, the recording cone's disc
(``supervision="cone"``: a display with a Fourier filter) or 1 (``"full"``: everything the SLM sends). The
inverse DFT is a forward one, IFFT(X) = conj(FFT(conj X)) / N, so no ifft is ever called (torch 2.13's CPU
ifft2 is wrong on some grids, see ``propagation.ifft2``); the last conjugation rides on the crop copy.
A_-z = A_z^H for the full band (H_-z = conj H_z on the propagating components), so the ideal SLM field
u0 = A_-z U_t and the gradient use the same two multipliers.

Padding (why less than 2x is exact). A plane wave of spatial frequency (f_x, f_y) travels with direction
cosines (lambda f_x, lambda f_y) (the angular spectrum, Goodman, Introduction to Fourier Optics, Eq. 3-59), so
over a distance z it moves sideways by z lambda f_x / sqrt(1 - lambda^2 (f_x^2 + f_y^2)). On the SLM's grid
|f_x|, |f_y| <= 1/(2p): with s = lambda / (2p) the spread is at most

    r = z s / sqrt(1 - 2 s^2)   (the cone alone: z s / sqrt(1 - s^2); s^2 << 1 gives lambda z / (2p))

The ASM is a circular convolution on the padded period N_p. An output pixel inside the H x W window receives
from input pixels at most r away; a wrapped contribution lands inside the window only if N_p < n + r. So
N_p >= n + r (+ a few pixels for the tails of the hard band edge) is exact, and when n >= r it also keeps
Eq. 13's limit, tan(theta_lim) = N_p p / (2 z), beyond the band (N_p >= 2r). We take the smallest 7-smooth
size >= n + r + 8 + n/64, and never more than the 2x grid of ``propagation.padded_shape``.

Loss and gradient, per (frame, color) b, with t the unit-norm band-limited target and p = A_z u:
a = <t, p>, e = ||p||^2, rho^2 = |a|^2 / e, q = (e / HW)^w (w: ``efficiency_weight``), objective
O = 1 - q rho^2 (w = 0: E = 1 - rho^2). Its Wirtinger gradient is dO/dp* = -(q/e)(a t - (1 - w) rho^2 p), so
dO/du* = A^H dO/dp* and, with u = exp(i phi), dO/dphi = 2 Im(conj(u) dO/du*). Written out this way one
iteration is two padded FFT pairs (forward, adjoint) and a few passes over the H x W grid: no autograd tape.
The gradient is scaled by HW so that Adam's eps stays negligible at every size (Adam is otherwise scale-free).

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

from holocore.propagation import PitchLike, _pitch_pair, _smooth_at_least, padded_shape, transfer_function
from holocore.randomfield import passband_mask

CHECK_EVERY = 10  # iterations between stop-rule checks
WINDOW_CHECKS = 3  # the stop rule compares with the value this many checks (30 iterations) before
_BETAS = (0.9, 0.999)
_EPS = 1e-8


def spread_px(z_m: float, wavelength_m: float, pitch_m: PitchLike) -> int:
    """Sideways reach r (pixels) of the full-band ASM over |z|: ceil(|z| s / (p sqrt(1 - 2 s^2))), s = lambda/2p
    (module docstring); -1 when the band contains evanescent corners (2 s^2 >= 1): no finite bound."""
    py, px = _pitch_pair(pitch_m)
    p = min(py, px)
    s = wavelength_m / (2.0 * p)
    if 2.0 * s * s >= 1.0:
        return -1
    return int(math.ceil(abs(z_m) * s / (p * math.sqrt(1.0 - 2.0 * s * s)) - 1e-9))


def encoder_grid(shape_hw: tuple[int, int], z_m: float, wavelength_m: float, pitch_m: PitchLike) -> tuple[int, int]:
    """Padded FFT grid (rows, cols) of the encoder's ASM: the smallest 7-smooth n + r + 8 + n/64, at most 2x."""
    full = padded_shape(shape_hw, 2)
    r = spread_px(z_m, wavelength_m, pitch_m)
    if r < 0:
        return full
    return tuple(min(_smooth_at_least(n + r + 8 + n // 64), m) for n, m in zip(shape_hw, full))  # type: ignore


class Operator:
    """A_z for one color on a fixed H x W window and padded grid, with reusable zero-padded workspaces."""

    def __init__(self, shape_hw: tuple[int, int], z_m: float, wavelength_m: float, pitch_m: PitchLike, *,
                 cone: bool, device: torch.device, grid: Optional[tuple[int, int]] = None) -> None:
        self.h, self.w = shape_hw
        self.hp, self.wp = grid or encoder_grid(shape_hw, z_m, wavelength_m, pitch_m)
        tf = transfer_function((self.hp, self.wp), z_m, wavelength_m, pitch_m, device=device)
        if cone:
            tf.mul_(torch.from_numpy(passband_mask((self.hp, self.wp), wavelength_m, pitch_m)).to(device))
        # IFFT(S M) = conj(FFT(conj(S) conj(M))) / N: the multipliers hold conj(M) / N (and M / N for A^H).
        self.mult = tf.conj_physical_().div_(self.hp * self.wp)
        self.mult_adj = self.mult.conj().resolve_conj()
        self._ws: dict[str, torch.Tensor] = {}
        self._owner: Optional["Operator"] = None

    def share_buffers(self, other: "Operator") -> None:
        """Use ``other``'s workspaces (same grid): one set per color, whatever the number of operators."""
        assert (self.hp, self.wp) == (other.hp, other.wp)
        self._owner = other

    def workspace(self, name: str, b: int, device: torch.device) -> torch.Tensor:
        """Zero-padded [b, Hp, Wp] buffer ``name`` ('in', 'adj' or 'spec'); only [:, :H, :W] is ever written
        into the input ones, so the rest stays zero."""
        ws = (self._owner or self)._ws
        buf = ws.get(name)
        if buf is None or buf.shape[0] < b:
            buf = ws[name] = torch.zeros((b, self.hp, self.wp), dtype=torch.complex64, device=device)
        return buf[:b]

    def window(self, name: str, b: int, device: torch.device) -> torch.Tensor:
        """The [b, H, W] window of workspace ``name``: write an input there and call :meth:`apply`."""
        return self.workspace(name, b, device)[:, :self.h, :self.w]

    def apply(self, name: str, b: int, device: torch.device, *, adjoint: bool = False) -> torch.Tensor:
        """A (or A^H) of what workspace ``name`` holds; a new [b, H, W] tensor."""
        spec = self.workspace("spec", b, device)
        torch.fft.fft2(self.workspace(name, b, device), out=spec)
        spec.conj_physical_().mul_(self.mult_adj if adjoint else self.mult)
        return torch.conj_physical(torch.fft.fft2(spec)[..., :self.h, :self.w])

    def __call__(self, u: torch.Tensor, *, adjoint: bool = False) -> torch.Tensor:
        """A u (or A^H u) for u complex64 [B, H, W]; a new [B, H, W] tensor."""
        b = u.shape[0]
        self.window("in", b, u.device).copy_(u)
        return self.apply("in", b, u.device, adjoint=adjoint)


def inner_energy(t: torch.Tensor, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """a = <t, p> (complex [B]) and e = ||p||^2 (float [B]), item by item (one BLAS dot each, no temporaries):
    the same numbers whatever B is, so chunking is exact."""
    a = torch.stack([torch.vdot(t[i].reshape(-1), p[i].reshape(-1)) for i in range(t.shape[0])])
    e = torch.stack([torch.vdot(p[i].reshape(-1), p[i].reshape(-1)).real for i in range(p.shape[0])])
    return a, e


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


def optimise(phi0: torch.Tensor, t_unit: torch.Tensor, op: Operator, *, lit: np.ndarray, iterations: int,
             lr: float, stop_db: Optional[float], tol: Optional[float], efficiency_weight: float,
             progress: Optional[Callable[[int], None]] = None) -> SgdOutcome:
    """Adam on phi [B, H, W] against unit-norm targets t [B, H, W] through ``op`` (module docstring). Items that
    are not ``lit`` (black targets) are never updated. ``stop_db`` / ``tol`` (relative objective decrease over
    30 iterations; used when given): per-item stop rules, 0 never stops."""
    b_all, h, w = phi0.shape
    hw = float(h * w)
    phi_out = phi0.clone()
    iters = np.zeros(b_all, np.int64)
    conv = ~lit.copy()
    trace: list[list[float]] = [[] for _ in range(b_all)]
    loss_init = np.ones(b_all)
    active = np.flatnonzero(lit)
    if iterations == 0 or active.size == 0:
        conv[:] = conv | (iterations == 0)
        if active.size:
            with torch.no_grad():
                a, e = inner_energy(t_unit[active], op(torch.polar(torch.ones_like(phi0[active]), phi0[active])))
                loss_init[active] = (1 - (a.abs().square() / e.clamp_min(1e-30)).double().clamp(0, 1)).cpu().numpy()
        return SgdOutcome(phi_out, iters, conv, trace, loss_init)
    dev = phi0.device
    idx = torch.from_numpy(active).to(dev)
    phi = phi0.index_select(0, idx).contiguous()
    t = t_unit.index_select(0, idx).contiguous()
    opt = _adam(phi, lr, None)
    w_eff = float(efficiency_weight)
    with torch.no_grad():
        cos, sin = torch.empty_like(phi), torch.empty_like(phi)
        for it in range(1, iterations + 1):
            n = phi.shape[0]
            torch.cos(phi, out=cos)
            torch.sin(phi, out=sin)
            torch.complex(cos, sin, out=op.window("in", n, dev))  # u = exp(i phi), straight into the workspace
            p = op.apply("in", n, dev)
            a, e = inner_energy(t, p)
            e = e.clamp_min(1e-30)
            rho2 = (a.real.square() + a.imag.square()) / e
            q = (e / hw) ** w_eff if w_eff > 0 else torch.ones_like(e)
            obj = 1.0 - q * rho2
            if it == 1:
                loss_init[active] = (1.0 - rho2.double().clamp(0, 1)).cpu().numpy()
            c1 = (-(q / e) * a * hw)[:, None, None]  # dO/dp* = c1 t + c2 p, times HW
            c2 = ((q / e) * (1.0 - w_eff) * rho2 * hw).to(p.dtype)[:, None, None]
            torch.mul(p, c2, out=op.window("adj", n, dev)).addcmul_(t, c1)
            gu = op.apply("adj", n, dev, adjoint=True)
            grad = torch.mul(cos, gu.imag)  # dO/dphi = 2 Im(conj(u) dO/du*) = 2 (cos Im g - sin Re g)
            phi.grad = grad.addcmul_(sin, gu.real, value=-1.0).mul_(2.0)
            opt.step()
            iters[active] = it
            if it % CHECK_EVERY and it != iterations:
                continue
            objs = obj.double().cpu().numpy()
            keep = []
            for j, k in enumerate(active):
                trace[k].append(float(objs[j]))
                done = _stop(trace[k], stop_db, tol)
                conv[k] = done
                keep.append(not done)
            if progress is not None:
                progress(it)
            if not all(keep):
                finished = torch.tensor([j for j, kp in enumerate(keep) if not kp], device=dev)
                phi_out.index_copy_(0, idx.index_select(0, finished), phi.index_select(0, finished))
                sel = torch.tensor([j for j, kp in enumerate(keep) if kp], dtype=torch.long, device=dev)
                active = active[np.asarray(keep)]
                if active.size == 0:
                    break
                idx = idx.index_select(0, sel)
                state = opt.state[phi]
                phi = phi.index_select(0, sel).contiguous()
                opt = _adam(phi, lr, {k: (v.index_select(0, sel).contiguous() if v.dim() else v.clone())
                                      for k, v in state.items()})
                t = t.index_select(0, sel).contiguous()
                cos, sin = cos[: len(sel)], sin[: len(sel)]
        if active.size:
            phi_out.index_copy_(0, idx, phi)
    return SgdOutcome(phi_out, iters, conv, trace, loss_init)
