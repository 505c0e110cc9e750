"""The encoder's propagation operator and its optimiser, for one color and a block of frames (DESIGN.md §6).

Operator. A_z u = crop( IFFT{ M . FFT{pad(u)} } ), M = H_z . K: the band-limited ASM transfer function
(``propagation.transfer_function``; Matsushima & Shimobaba 2009, Eq. 13) times K, the recording cone's disc
(``supervision="cone"``: a display with a Fourier filter) or 1 (``"full"``: everything the SLM sends). The
inverse DFT is a forward one read backwards, IFFT(X)[n] = FFT(X)[-n mod N] / N, so no ifft is ever called
(torch 2.13's CPU ifft2 is wrong on some grids, see ``propagation.ifft2``) and no conjugation pass is needed.
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
        self.mult = tf.div_(self.hp * self.wp)  # M / N: the inverse's 1/N folded in
        self.mult_adj = self.mult.conj().resolve_conj()
        self.rows = (-torch.arange(self.h, device=device)) % self.hp  # IFFT read as FFT at -n mod N
        self.cols = (-torch.arange(self.w, device=device)) % self.wp
        self._pad: Optional[torch.Tensor] = None
        self._spec: Optional[torch.Tensor] = None

    def _buffers(self, b: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        if self._pad is None or self._pad.shape[0] < b:
            self._pad = torch.zeros((b, self.hp, self.wp), dtype=torch.complex64, device=device)
            self._spec = torch.empty_like(self._pad)
        return self._pad[:b], self._spec[:b]  # type: ignore[index]

    def share_buffers(self, other: "Operator") -> None:
        """Use ``other``'s workspaces (same grid): one set per color, whatever the number of operators."""
        assert (self.hp, self.wp) == (other.hp, other.wp)
        self._pad, self._spec = other._pad, other._spec
        self._owner = other

    def __call__(self, u: torch.Tensor, *, adjoint: bool = False) -> torch.Tensor:
        """A u (or A^H u) for u complex64 [B, H, W]; a new [B, H, W] tensor."""
        owner = getattr(self, "_owner", None)
        pad, spec = (owner or self)._buffers(u.shape[0], u.device)
        pad[:, :self.h, :self.w].copy_(u)  # the rest of the workspace stays zero
        torch.fft.fft2(pad, out=spec)
        spec.mul_(self.mult_adj if adjoint else self.mult)
        out = torch.fft.fft2(spec)
        return out.index_select(-2, self.rows).index_select(-1, self.cols)


def _sums(x: torch.Tensor) -> torch.Tensor:
    """Per-item sum over H, W of [B, H, W], item by item: the same numbers whatever B is (chunking is exact)."""
    return torch.stack([x[i].sum() for i in range(x.shape[0])])


def inner_energy(t: torch.Tensor, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """a = <t, p> (complex [B]) and e = ||p||^2 (float [B]) per item."""
    return _sums(t.conj() * p), _sums(p.real.square() + p.imag.square())


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
    m = torch.zeros_like(phi)
    v = torch.zeros_like(phi)
    b1, b2 = _BETAS
    w_eff = float(efficiency_weight)
    with torch.no_grad():
        for it in range(1, iterations + 1):
            u = torch.polar(torch.ones_like(phi), phi)
            p = op(u)
            a, e = inner_energy(t, p)
            e = e.clamp_min(1e-30)
            rho2 = (a.real.square() + a.imag.square()) / e
            q = (e / hw) ** w_eff if w_eff > 0 else torch.ones_like(e)
            obj = 1.0 - q * rho2
            if it == 1:
                loss_init[active] = (1.0 - rho2.double().clamp(0, 1)).cpu().numpy()
            c1 = -(q / e) * a * hw  # dO/dp* = c1 t + c2 p, times HW
            c2 = ((q / e) * (1.0 - w_eff) * rho2 * hw).to(p.dtype)
            gp = t * c1[:, None, None] + p * c2[:, None, None]
            gu = op(gp, adjoint=True)
            grad = (u.conj() * gu).imag.mul_(2.0)
            m.mul_(b1).add_(grad, alpha=1 - b1)
            v.mul_(b2).addcmul_(grad, grad, value=1 - b2)
            denom = (v / (1 - b2 ** it)).sqrt_().add_(_EPS)
            phi.addcdiv_(m, denom, value=-lr / (1 - b1 ** it))
            iters[active] = it
            if it % CHECK_EVERY and it != iterations:
                continue
            objs = obj.double().cpu().numpy()
            keep = []
            for j, k in enumerate(active):
                trace[k].append(float(objs[j]))
                hist = trace[k]
                done = False
                if len(hist) > WINDOW_CHECKS:
                    old, new = hist[-1 - WINDOW_CHECKS], hist[-1]
                    if tol is not None:
                        done = tol > 0 and (old - new <= tol * max(old, 1e-12) or new <= 1e-7)
                    elif stop_db:
                        snr = lambda o: 10 * math.log10(max(1 - o, 1e-30) / max(o, 1e-30))  # noqa: E731
                        done = snr(new) - snr(old) < stop_db or new <= 1e-7
                conv[k] = done
                keep.append(not done)
            if progress is not None:
                progress(it)
            if not all(keep):
                finished = [j for j, kp in enumerate(keep) if not kp]
                fi = torch.tensor(finished, device=dev)
                phi_out.index_copy_(0, idx.index_select(0, fi), phi.index_select(0, fi))
                sel = torch.tensor([j for j, kp in enumerate(keep) if kp], dtype=torch.long, device=dev)
                active = active[np.asarray(keep)]
                if active.size == 0:
                    break
                idx = idx.index_select(0, sel)
                phi, t, m, v = (x.index_select(0, sel).contiguous() for x in (phi, t, m, v))
        if active.size:
            phi_out.index_copy_(0, idx, phi)
    return SgdOutcome(phi_out, iters, conv, trace, loss_init)
