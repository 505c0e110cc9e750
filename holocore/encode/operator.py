"""The phase-only encoder's propagation operator A_z on one H x W window, with no conjugation pass and no ifft.

Plain form (docs/design.md §5). A_z u = C IFFT{ M . FFT{P u} }, P zero-pads u to the top-left of the padded grid
N = (Hp, Wp), C crops the top-left H x W window back, M = H_z . K is the band-limited ASM transfer function
(``propagation.transfer_function``; Matsushima & Shimobaba 2009, Eq. 13) times K, the recording cone's disc
(``cone=True``: a display with a Fourier filter) or 1. A_z is a circular convolution with k = IFFT(M); the
padding makes it the linear one on the window ("Padding" below). Its adjoint is
A_z^H g = C IFFT{ conj(M) . FFT{P g} } (A_-z for the full band: H_-z = conj H_z on the propagating part).

Two forward DFTs instead of a DFT and an inverse one. With F the unnormalised forward DFT (``torch.fft.fft2``),
R the index reversal (R x)[n] = x[-n mod N] and |N| = Hp Wp, F F = |N| R (the DFT applied twice reverses), so
IFFT = R F / |N| and F{ X . F x } = |N| R (IFFT(X) (*) x). The reversal lands in the cropped window as a flip
J of the window, (J v)[j] = v[s - j] with s = (H - 1, W - 1), if the multipliers carry the shift by s (the DFT
shift theorem, ramp[k] = exp(+2 pi i k.s / N) moves the kernel by -s):

    forward:  C F{ M2 . F{P u} }     = J A_z u,      M2 = ramp . M / |N|                      (1)
    adjoint:  C F{ M3 . F{P J g} }   = A_z^H g,      M3 = ramp . R(conj M) / |N|              (2)

(1): IFFT(ramp M) = k shifted by -s, k[n + s], so F{M2 F x}[j] = (k[. + s] (*) x)[-j] = (k (*) x)[s - j].
(2): substituting m' = s - m in the sum over the window gives the kernel k3[n] = k*[-(n + s)] with
k* = IFFT(conj M), whose DFT is M3. So the optimiser keeps
the WRP-side fields (target, prediction, dO/dp*) in the flipped order J and the SLM-side ones (phase,
gradient) in the natural order: no flip, no conjugation and no ifft in the loop, only the crop. (1) and (2)
hold for any M; the equality with the plain operator and the adjoint identity are tested in complex128.
torch 2.13's CPU ifft2 is wrong on some grids (``propagation.ifft2``); it is never called.

Padding (why less than 2x is exact). A plane wave of spatial frequency (f_x, f_y) travels with direction
cosines (lambda f_x, lambda f_y) (the angular spectrum, Goodman, Introduction to Fourier Optics, Eq. 3-59), so
over a distance z it moves sideways by z lambda f_x / sqrt(1 - lambda^2 (f_x^2 + f_y^2)). On the SLM's grid
|f_x|, |f_y| <= 1/(2p): with s = lambda / (2p) the spread is at most

    r = z s / sqrt(1 - 2 s^2)   (the cone alone: z s / sqrt(1 - s^2); s^2 << 1 gives lambda z / (2p))

The ASM is a circular convolution on the padded period N_p. An output pixel inside the H x W window receives
from input pixels at most r away; a wrapped contribution lands inside the window only if N_p < n + r. So
N_p >= n + r (+ a few pixels for the tails of the hard band edge) is exact, and when n >= r it also keeps
Eq. 13's limit, tan(theta_lim) = N_p p / (2 z), beyond the band (N_p >= 2r). We take the smallest fast FFT
size (``grids.fast_fft_size``) >= n + r + 8 + n/64, and never more than the 2x grid of ``propagation.padded_shape``.

Measured against other layouts (bench/results/encode.md): transforms restricted to the H nonzero input rows and
the cropped output rows (a "pruned" 2-D FFT from 1-D FFTs) are slower on CPU than one ``fft2`` of the whole
padded grid (MKL's strided column pass costs more than the rows it saves), so the grid is transformed whole.
"""

from __future__ import annotations

import math
from typing import Optional

import torch

from holocore.optics.grids import encoder_grid, spread_px  # noqa: F401  (re-exported: the encoder's grid)
from holocore.optics.propagation import PitchLike, transfer_function
from holocore.trace.randomfield import passband_mask


def flip(x: torch.Tensor) -> torch.Tensor:
    """J: the window flipped in both axes, (J x)[..., i, j] = x[..., H-1-i, W-1-j] (a copy); J = J^-1 = J^H."""
    return torch.flip(x, dims=(-2, -1))


def _reverse(m: torch.Tensor) -> torch.Tensor:
    """R on the padded grid: (R m)[k] = m[-k mod N] over the last two axes."""
    return torch.roll(torch.flip(m, dims=(-2, -1)), shifts=(1, 1), dims=(-2, -1))


def _ramp(shape: tuple[int, int], shift: tuple[int, int], device: torch.device) -> torch.Tensor:
    """exp(+2 pi i (k_y s_y / N_y + k_x s_x / N_x)) [Ny, Nx] in complex128, phases reduced exactly mod N."""
    parts = []
    for n, s in zip(shape, shift):
        k = torch.arange(n, dtype=torch.int64, device=device)
        frac = torch.remainder(k * s, n).to(torch.float64) / n  # exact integer product, then one rounding
        parts.append(torch.polar(torch.ones_like(frac), (2.0 * math.pi) * frac))
    return parts[0][:, None] * parts[1][None, :]


class Operator:
    """A_z for one color on a fixed H x W window and padded grid (Hp, Wp), with reusable zero-padded inputs.

    Hot path (the optimiser): write into :meth:`window` and call :meth:`apply`. Forward: the window holds u in
    natural order, the result is J A_z u. Adjoint: the window holds J g, the result is A_z^H g (natural).
    Plain path: ``op(u)`` = A_z u and ``op(g, adjoint=True)`` = A_z^H g, both natural (two flip copies).
    """

    def __init__(self, shape_hw: tuple[int, int], z_m: float, wavelength_m: float, pitch_m: PitchLike, *,
                 cone: bool, device: torch.device, grid: Optional[tuple[int, int]] = None,
                 dtype: torch.dtype = torch.complex64) -> None:
        self.h, self.w = shape_hw
        self.hp, self.wp = grid or encoder_grid(shape_hw, z_m, wavelength_m, pitch_m)
        self.dtype = dtype
        m = transfer_function((self.hp, self.wp), z_m, wavelength_m, pitch_m, device=device, dtype=torch.complex128)
        if cone:
            m.mul_(torch.from_numpy(passband_mask((self.hp, self.wp), wavelength_m, pitch_m)).to(device))
        ramp = _ramp((self.hp, self.wp), (self.h - 1, self.w - 1), m.device).div_(self.hp * self.wp)
        self.mult = (m * ramp).to(dtype)  # M2, Eq. (1)
        self.mult_adj = (_reverse(m).conj_physical_().mul_(ramp)).to(dtype)  # M3, Eq. (2)
        self._ws: dict[str, torch.Tensor] = {}
        self._owner: Optional["Operator"] = None

    def share_buffers(self, other: "Operator") -> None:
        """Use ``other``'s workspaces (same grid): one set per color, whatever the number of operators."""
        assert (self.hp, self.wp, self.dtype) == (other.hp, other.wp, other.dtype)
        self._owner = other

    def release_buffers(self) -> None:
        """Free the workspaces (the multipliers stay): the next use allocates them anew."""
        (self._owner or self)._ws.clear()

    def workspace(self, name: str, b: int, device: torch.device) -> torch.Tensor:
        """Zero-padded [b, Hp, Wp] buffer ``name``; only its [:, :H, :W] window is ever written, so the rest
        stays zero."""
        ws = (self._owner or self)._ws
        buf = ws.get(name)
        if buf is None or buf.shape[0] < b:
            buf = ws[name] = torch.zeros((b, self.hp, self.wp), dtype=self.dtype, device=device)
        return buf[:b]

    def window(self, name: str, b: int, device: torch.device) -> torch.Tensor:
        """The [b, H, W] window of workspace ``name``: write an input there and call :meth:`apply`."""
        return self.workspace(name, b, device)[:, :self.h, :self.w]

    def apply(self, name: str, b: int, device: torch.device, *, adjoint: bool = False) -> torch.Tensor:
        """Eq. (1) (or (2) with ``adjoint``) of what workspace ``name`` holds: a [b, H, W] view into a new
        padded tensor, J A u (or A^H g when the window holds J g). Two ``fft2`` and one multiply in place."""
        spec = torch.fft.fft2(self.workspace(name, b, device))  # a fresh output: fft2's out= adds a copy
        spec.mul_(self.mult_adj if adjoint else self.mult)
        return torch.fft.fft2(spec)[..., :self.h, :self.w]

    def __call__(self, u: torch.Tensor, *, adjoint: bool = False) -> torch.Tensor:
        """A u (or A^H u) for u [B, H, W] in natural order; a new contiguous [B, H, W] tensor."""
        b = u.shape[0]
        win = self.window("in", b, u.device)
        if adjoint:
            for i in range(b):  # J u frame by frame: a temporary of one frame, not of the block
                win[i].copy_(flip(u[i]))
        else:
            win.copy_(u)
        out = self.apply("in", b, u.device, adjoint=adjoint)
        return out.contiguous() if adjoint else flip(out)
