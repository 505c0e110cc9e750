"""Phase-only encoding of a WRP field into an SLM phase stack (DESIGN.md §6, paper Sec. 5.3).

Hologram space: SLM at z = 0, WRP at z = z_wrp > 0. The ideal (complex) SLM field is u0 = ASM(U_t, -z_wrp);
a phase-only SLM shows exp(i phi), whose WRP field is U_p = ASM(exp(i phi), +z_wrp) (band-limited ASM, §5).

"The band-limited WRP field". B projects a field onto each color's recording cone, the disc of radius
sin(theta_max) / lambda = 1/(2p) in the spectrum (DESIGN §4; the passband of the random-phase bank). Every
traced field lives there (what lies outside, in the corners of the spectrum, is Monte Carlo noise), and a
viewer whose pupil stays inside the cone sees nothing else. The supervised target is
U_b = B ASM(u0, +z_wrp): what a perfect complex SLM of the same aperture produces, in the cone. The
prediction is compared as B U_p, so the corners are free: the optimiser may put there the light that a
phase-only SLM cannot help sending (as double-phase coding does, at the Nyquist corner).

Loss (complex-amplitude supervision with a phase-shift-invariant scale): with s = <U_b, BU_p> / <U_b, U_b>
the best complex scale (it absorbs the global phase and the brightness),

    ||BU_p - s U_b||^2 = ||BU_p||^2 (1 - rho^2),   rho^2 = |<U_b, BU_p>|^2 / (||U_b||^2 ||BU_p||^2).

Divided by ||BU_p||^2 (or fitting the scale the other way, s' BU_p against U_b, divided by ||U_b||^2: the
same) this is E = 1 - rho^2 per (frame, color), in [0, 1]. E is invariant to any complex scale of the target and
of the prediction, so a scaled target gives the same phase up to a global offset. Left undivided, the loss
would reward sending light out of the cone (its minimum would be a dark SLM); divided by the SLM's total
light instead, it would charge for that light and land near the naive encoding (for a unitary propagation,
the SLM-plane error |exp(i phi) - s u0| is the WRP error, minimised by phi = arg u0). E ignores how much light
stays in the cone; ``efficiency_weight`` w > 0 minimises 1 - e^w rho^2 instead, e that fraction (reported
as ``efficiency``), trading accuracy for brightness.

A black target (U_b = 0) has nothing to match: E = 1 by definition, zero gradient, the phase stays at the
initial one, no division by zero. Frames and colors are independent terms of one summed loss, and Adam
scales every phase pixel on its own. One ASM per color per iteration (the wavelength differs), frames
batched; the device is the target's.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np
import torch

from holocore.io import phase_to_u8, save_stack
from holocore.propagation import PitchLike, _pitch_pair, asm, ifft2
from holocore.randomfield import passband_mask

__all__ = [
    "EncodeResult",
    "encode_sgd",
    "encode_naive",
    "encode_dpac",
    "encode",
    "METHODS",
    "ideal_slm_field",
    "propagate_to_wrp",
    "passband_filter",
    "field_error",
    "reach_margin_px",
    "wrap_phase",
    "load_lut",
    "quantize",
    "save_encoded",
]

METHODS = ("sgd", "dpac", "naive")
TWO_PI = 2.0 * math.pi
ProgressFn = Callable[[str, int, int], None]
ArrayLike = Union[np.ndarray, torch.Tensor]

_CHECK_EVERY = 10  # iterations between convergence checks (one device sync each)
_WINDOW_CHECKS = 3  # tol is the relative loss decrease over this many checks (30 iterations)


@dataclass(frozen=True)
class EncodeResult:
    """A phase stack and how it was obtained.

    ``phase``: float32 [F, C, H, W] in [0, 2pi) (rad). ``loss``/``loss_init``: float64 [F, C], the complex-field
    error E = 1 - rho^2 against the band-limited target at the end and at the start (module docstring).
    ``black``: bool [F, C], targets with no light (their E is 1 by definition). ``efficiency``: [F, C], the
    fraction of the SLM's light in the passband at the WRP. ``illumination``: [F, C] in [0, 1], the relative
    laser power per frame and color that restores the target's colour balance (see ``_illumination``); a
    display shows frame f, color c with sqrt(P) exp(i phi).
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

    def summary(self) -> dict[str, Any]:
        """JSON-able description for a stack's meta (``meta["encoder"]``)."""
        lit = ~self.black
        mean = float(self.loss[lit].mean()) if lit.any() else 1.0
        mean0 = float(self.loss_init[lit].mean()) if lit.any() else 1.0
        return {
            "method": self.method,
            "iterations": int(self.iterations),
            "converged": bool(self.converged),
            "seconds": float(self.seconds),
            "loss": self.loss.tolist(),
            "loss_init": self.loss_init.tolist(),
            "loss_mean": mean,
            "loss_init_mean": mean0,
            "black": self.black.tolist(),
            "efficiency": self.efficiency.tolist(),
            "illumination": self.illumination.tolist(),
            "loss_definition": "E = 1 - |<U_b,BU_p>|^2/(|U_b|^2 |BU_p|^2) on the WRP; B: recording-cone passband, "
                               "U_b = B ASM(ASM(U_t,-z_wrp),z_wrp), U_p = ASM(exp(i phase),z_wrp)",
            "history": [float(v) for v in self.history],
            **self.options,
        }


# ---- validation --------------------------------------------------------------------------------------------
def _finite(name: str, value: object, *, low: float, low_inclusive: bool, unit: str) -> float:
    if isinstance(value, (bool, str, bytes)):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    ok = math.isfinite(v) and (v >= low if low_inclusive else v > low)
    if not ok:
        raise ValueError(f"{name} must be finite and {'>=' if low_inclusive else '>'} {low} {unit}, got {value!r}")
    return v


def _wavelengths(wavelengths_m: Sequence[float], n_colors: int) -> list[float]:
    try:
        lams = [float(v) for v in wavelengths_m]
    except (TypeError, ValueError):
        raise ValueError(f"wavelengths_m must be a sequence of numbers (m), got {wavelengths_m!r}") from None
    if len(lams) != n_colors:
        raise ValueError(f"wavelengths_m has {len(lams)} entries but the target has {n_colors} colors")
    for i, lam in enumerate(lams):
        if not math.isfinite(lam) or not 0.0 < lam < 1e-5:
            raise ValueError(f"wavelengths_m[{i}] must be in (0, 1e-5) m, got {lam!r}")
    return lams


def _as_field(target: ArrayLike, device: Optional[Union[str, torch.device]]) -> torch.Tensor:
    """complex64 [F, C, H, W] on the chosen device (default: the input's, CPU for numpy)."""
    if isinstance(target, torch.Tensor):
        t = target.detach()
    else:
        arr = np.asarray(target)
        if not np.issubdtype(arr.dtype, np.number) or arr.dtype == bool:
            raise ValueError(f"target_wrp must be a numeric array, got dtype {arr.dtype}")
        t = torch.from_numpy(np.ascontiguousarray(arr))
    if t.dim() != 4:
        raise ValueError(f"target_wrp must be [F, C, H, W], got shape {tuple(t.shape)}")
    if min(t.shape) < 1:
        raise ValueError(f"target_wrp must have every axis >= 1, got shape {tuple(t.shape)}")
    t = t.to(device=device if device is not None else t.device, dtype=torch.complex64)
    if not bool(torch.isfinite(torch.view_as_real(t)).all()):
        raise ValueError("target_wrp contains NaN or infinite values")
    return t


def _common(target_wrp: ArrayLike, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
            device: Optional[Union[str, torch.device]]) -> tuple[torch.Tensor, float, list[float]]:
    t = _as_field(target_wrp, device)
    z = _finite("z_wrp_m", z_wrp_m, low=0.0, low_inclusive=False, unit="m (WRP in front of the SLM)")
    lams = _wavelengths(wavelengths_m, t.shape[1])
    _pitch_pair(pitch_m)
    return t, z, lams


# ---- propagation helpers -----------------------------------------------------------------------------------
def _per_color(u: torch.Tensor, distance_m: float, lams: list[float], pitch_m: PitchLike) -> torch.Tensor:
    """ASM of [F, C, H, W] by distance_m, one wavelength per color, frames batched (differentiable)."""
    return torch.stack([asm(u[:, c], distance_m, lam, pitch_m) for c, lam in enumerate(lams)], dim=1)


def ideal_slm_field(target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
                    device: Optional[Union[str, torch.device]] = None) -> torch.Tensor:
    """u0 = ASM(U_t, -z_wrp) per color: the complex SLM field [F, C, H, W] (complex64) a perfect SLM would show."""
    t, z, lams = _common(target_wrp, z_wrp_m, wavelengths_m, pitch_m, device)
    with torch.no_grad():
        return _per_color(t, -z, lams, pitch_m)


def propagate_to_wrp(slm_field: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
                     device: Optional[Union[str, torch.device]] = None) -> torch.Tensor:
    """U = ASM(u, +z_wrp) per color: the WRP field [F, C, H, W] (complex64) of an SLM field u."""
    u, z, lams = _common(slm_field, z_wrp_m, wavelengths_m, pitch_m, device)
    with torch.no_grad():
        return _per_color(u, z, lams, pitch_m)


def _band_masks(shape_hw: tuple[int, int], lams: list[float], pitch_m: PitchLike,
                device: torch.device) -> torch.Tensor:
    """Bool [C, H, W] passband of each color on the unshifted DFT grid: the recording cone, radius
    sin(theta_max) / lambda = 1/(2p) (DESIGN §4, ``randomfield.passband_mask``). The spectrum's corners lie
    outside every traced field; the encoder may put light there."""
    return torch.stack([torch.from_numpy(passband_mask(shape_hw, lam, pitch_m)) for lam in lams]).to(device)


def _band(u: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
    """Project [F, C, H, W] onto the passband (periodic H x W grid; an orthogonal projection)."""
    return ifft2(torch.fft.fft2(u) * masks.to(u.real.dtype))


def passband_filter(field: ArrayLike, *, wavelengths_m: Sequence[float], pitch_m: PitchLike) -> torch.Tensor:
    """A WRP/SLM field [F, C, H, W] with the light outside each color's recording cone removed (complex64)."""
    u = _as_field(field, None)
    lams = _wavelengths(wavelengths_m, u.shape[1])
    _pitch_pair(pitch_m)
    with torch.no_grad():
        return _band(u, _band_masks(tuple(u.shape[-2:]), lams, pitch_m, u.device))


def _unit(u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """u / ||u|| per (frame, color) over H, W (all-zero ones left at zero), and ||u||^2 (float64 [F, C])."""
    n2 = (u.real.square() + u.imag.square()).sum(dim=(-2, -1), dtype=torch.float64)
    n = torch.sqrt(n2)
    black = n == 0
    scale = torch.where(black, torch.zeros_like(n), 1.0 / torch.where(black, torch.ones_like(n), n))
    return u * scale.to(torch.float32)[..., None, None], n2


def _rho2(t_unit: torch.Tensor, pred: torch.Tensor) -> torch.Tensor:
    """|<t, p>|^2 / ||p||^2 per (frame, color), t of unit norm: rho^2 in [0, 1] (0 where p or t is zero)."""
    inner = (t_unit.conj() * pred).sum(dim=(-2, -1))
    energy = (pred.real.square() + pred.imag.square()).sum(dim=(-2, -1))
    return (inner.real.square() + inner.imag.square()) / energy.clamp_min(torch.finfo(energy.dtype).tiny)


def field_error(pred: ArrayLike, target: ArrayLike, *, margin_px: int = 0) -> np.ndarray:
    """Scale-free complex-field error E = 1 - rho^2 per (frame, color), float64 [F, C], in [0, 1].

    rho^2 = |<t, p>|^2 / (||t||^2 ||p||^2) over the interior that remains after cropping ``margin_px`` pixels
    from each side; equal to ||p - s t||^2 / ||p||^2 with the best complex scale s (DESIGN §6). 1 where either
    field is zero there.
    """
    if isinstance(margin_px, bool) or not isinstance(margin_px, (int, np.integer)) or margin_px < 0:
        raise ValueError(f"margin_px must be an integer >= 0, got {margin_px!r}")
    p = torch.as_tensor(pred.detach().cpu().numpy() if isinstance(pred, torch.Tensor) else np.asarray(pred))
    t = torch.as_tensor(target.detach().cpu().numpy() if isinstance(target, torch.Tensor) else np.asarray(target))
    if p.shape != t.shape or p.dim() != 4:
        raise ValueError(f"pred and target must both be [F, C, H, W] of one shape, got {tuple(p.shape)} "
                         f"and {tuple(t.shape)}")
    h, w = p.shape[-2:]
    if 2 * margin_px >= min(h, w):
        raise ValueError(f"margin_px must leave an interior (2 * margin_px < {min(h, w)} for a {h}x{w} field), "
                         f"got {margin_px}")
    sl = (..., slice(margin_px, h - margin_px), slice(margin_px, w - margin_px))
    p = p[sl].to(torch.complex128)
    t = t[sl].to(torch.complex128)
    inner = (t.conj() * p).sum(dim=(-2, -1)).abs().square()
    tt = t.abs().square().sum(dim=(-2, -1))
    pp = p.abs().square().sum(dim=(-2, -1))
    den = tt * pp
    rho2 = torch.where(den > 0, inner / torch.where(den > 0, den, torch.ones_like(den)), torch.zeros_like(den))
    return (1.0 - rho2.clamp(0.0, 1.0)).numpy()


def reach_margin_px(*, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike) -> int:
    """Width in pixels of the WRP border the SLM cannot fully reach: ceil(z_wrp tan(theta_max) / p).

    theta_max = arcsin(lambda / 2p) (DESIGN §4) for the longest wavelength (the widest cone), p the larger
    pitch. A WRP pixel closer to the edge than this misses part of its cone of SLM pixels.
    """
    z = _finite("z_wrp_m", z_wrp_m, low=0.0, low_inclusive=True, unit="m")
    py, px = _pitch_pair(pitch_m)
    lams = _wavelengths(wavelengths_m, len(list(wavelengths_m)))
    if not lams:
        raise ValueError("wavelengths_m must not be empty")
    p = max(py, px)
    s = min(max(lams) / (2.0 * min(py, px)), 1.0)
    tan = s / math.sqrt(1.0 - s * s) if s < 1.0 else math.inf
    if not math.isfinite(tan):
        raise ValueError("theta_max is 90 degrees (lambda >= 2p): the whole WRP is within reach of every pixel "
                         "only in the far field; no finite margin")
    return int(math.ceil(z * tan / p - 1e-9))


def wrap_phase(phase: ArrayLike) -> np.ndarray:
    """Phase (rad) wrapped to [0, 2pi) as float32 numpy; float32 rounding never yields 2pi (mapped to 0)."""
    ph = phase.detach().cpu().numpy() if isinstance(phase, torch.Tensor) else np.asarray(phase)
    out = np.mod(ph.astype(np.float64), TWO_PI).astype(np.float32)
    out[out >= np.float32(TWO_PI)] = 0.0
    return out


# ---- encoders ----------------------------------------------------------------------------------------------
def _illumination(target_energy: torch.Tensor, matched_energy: torch.Tensor, black: torch.Tensor) -> torch.Tensor:
    """Relative laser power P [F, C] in [0, 1] that gives every (frame, color) the target's brightness.

    A unit-amplitude SLM sends the same light in every frame and color, whatever the scene's colors: the
    target's colour balance (and the balance between frames) is lost unless the illumination restores it. The
    part of B U_p that matches the target, s U_b with |s|^2 = rho^2 ||BU_p||^2 / ||U_b||^2, scales with
    sqrt(P); equal |s| sqrt(P) everywhere needs P ~ ||U_b||^2 / (rho^2 ||BU_p||^2), normalised to max 1.
    Black targets (and ones nothing matches) get 0: the laser is off.
    """
    ok = (~black) & (matched_energy > 0)
    p = torch.where(ok, target_energy / torch.where(ok, matched_energy, torch.ones_like(matched_energy)),
                    torch.zeros_like(target_energy))
    peak = p.max()
    return p / peak if float(peak) > 0 else p


def _finish(method: str, phi: torch.Tensor, pb: _Problem, t0: float, *, loss_init: Optional[np.ndarray] = None,
            iterations: int = 0, converged: bool = True, options: Optional[dict] = None,
            history: Sequence[float] = ()) -> EncodeResult:
    with torch.no_grad():
        pred = pb.forward(phi)
        rho2 = _rho2(pb.t_band, pred).double().clamp(0.0, 1.0)
        loss = (1.0 - rho2).cpu().numpy()
        energy = (pred.real.square() + pred.imag.square()).sum(dim=(-2, -1), dtype=torch.float64)
        eff = (energy / (phi.shape[-2] * phi.shape[-1])).cpu().numpy()
        illum = _illumination(pb.t_energy, rho2 * energy, pb.black).cpu().numpy()
    return EncodeResult(phase=wrap_phase(phi), loss=loss, loss_init=loss if loss_init is None else loss_init,
                        black=pb.black.cpu().numpy(), efficiency=eff, illumination=illum, method=method,
                        iterations=int(iterations),
                        seconds=time.perf_counter() - t0, converged=bool(converged), options=dict(options or {}),
                        history=tuple(float(v) for v in history))


@dataclass
class _Problem:
    u0: torch.Tensor  # ideal complex SLM field [F, C, H, W]
    t_band: torch.Tensor  # band-limited target U_b, unit norm per (frame, color)
    t_energy: torch.Tensor  # ||U_b||^2 before normalising, float64 [F, C]
    black: torch.Tensor  # bool [F, C]
    masks: torch.Tensor  # bool [C, H, W] passbands
    z: float
    lams: list[float]
    pitch_m: PitchLike

    def forward(self, phi: torch.Tensor) -> torch.Tensor:
        """In-band WRP field B ASM(exp(i phi), z_wrp) [F, C, H, W] (differentiable)."""
        return _band(_per_color(torch.polar(torch.ones_like(phi), phi), self.z, self.lams, self.pitch_m), self.masks)


def _prepare(target_wrp, z_wrp_m, wavelengths_m, pitch_m, device) -> _Problem:
    t, z, lams = _common(target_wrp, z_wrp_m, wavelengths_m, pitch_m, device)
    peak = float(t.abs().max())
    if peak > 0:  # one global scale (the loss is scale-free; ratios between frames and colors are kept)
        t = t / peak
    masks = _band_masks(tuple(t.shape[-2:]), lams, pitch_m, t.device)
    with torch.no_grad():
        u0 = _per_color(t, -z, lams, pitch_m)
        t_band, t_energy = _unit(_band(_per_color(u0, z, lams, pitch_m), masks))
        black = (t_energy == 0) | (t_band.abs().amax(dim=(-2, -1)) == 0)
    return _Problem(u0=u0, t_band=t_band, t_energy=t_energy, black=black, masks=masks, z=z, lams=lams,
                    pitch_m=pitch_m)


def encode_naive(target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
                 device: Optional[Union[str, torch.device]] = None) -> EncodeResult:
    """Naive encoding: phi = arg ASM(U_t, -z_wrp) (the ideal SLM field's phase, its amplitude dropped)."""
    t0 = time.perf_counter()
    pb = _prepare(target_wrp, z_wrp_m, wavelengths_m, pitch_m, device)
    return _finish("naive", torch.angle(pb.u0), pb, t0)


def encode_dpac(target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
                device: Optional[Union[str, torch.device]] = None) -> EncodeResult:
    """Double-phase amplitude coding of u0 = ASM(U_t, -z_wrp) (Hsueh & Sawchuk 1978; Maimone et al. 2017).

    A e^{i theta} with A = |u0| / max|u0| per (frame, color) in [0, 1] equals the mean of e^{i(theta +- acos A)};
    the two phases go to the two kinds of squares of a checkerboard ((row + col) even: +). Black targets give +-pi/2,
    whose mean is zero.
    """
    t0 = time.perf_counter()
    pb = _prepare(target_wrp, z_wrp_m, wavelengths_m, pitch_m, device)
    u0 = pb.u0
    amp = u0.abs()
    peak = amp.amax(dim=(-2, -1), keepdim=True)
    a = torch.where(peak > 0, amp / torch.where(peak > 0, peak, torch.ones_like(peak)), torch.zeros_like(amp))
    offset = torch.arccos(a.clamp(0.0, 1.0))
    h, w = u0.shape[-2:]
    rows = torch.arange(h, device=u0.device)[:, None]
    cols = torch.arange(w, device=u0.device)[None, :]
    sign = 1.0 - 2.0 * ((rows + cols) % 2).to(offset.dtype)  # +1 on even, -1 on odd squares
    phi = torch.angle(u0) + sign * offset
    return _finish("dpac", phi, pb, t0)


def encode_sgd(target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float], pitch_m: PitchLike,
               iterations: int = 500, lr: float = 0.2, init: Optional[ArrayLike] = None, tol: float = 1e-3,
               efficiency_weight: float = 0.0, device: Optional[Union[str, torch.device]] = None,
               progress: Optional[ProgressFn] = None) -> EncodeResult:
    """Optimise the SLM phase [F, C, H, W] so that ASM(exp(i phi), z_wrp) matches the target in amplitude and
    phase up to one complex scale per (frame, color) (DESIGN §6; loss in the module docstring).

    ``target_wrp`` complex [F, C, H, W] (numpy or torch) on the WRP at ``z_wrp_m`` (m, > 0) from the SLM;
    ``wavelengths_m`` one per color; ``pitch_m`` (m). Adam with step ``lr`` (rad, > 0) for at most
    ``iterations`` (>= 0) steps; stops early once the mean loss falls by less than the fraction ``tol`` (>= 0;
    0 never stops early) over 30 iterations. ``init``: phase [F, C, H, W] in rad, default the naive encoding
    arg ASM(U_t, -z_wrp). Runs on ``device`` (default: the target's). ``progress(stage, done, total)``.
    ``efficiency_weight`` w in [0, 1]: minimise 1 - e^w rho^2 instead, e the fraction of the SLM's light that
    stays in the passband (w = 0: pure complex supervision; larger w: brighter, less accurate).
    """
    t0 = time.perf_counter()
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or not 0 <= iterations <= 10**6:
        raise ValueError(f"iterations must be an integer in 0..1000000, got {iterations!r}")
    lr = _finite("lr", lr, low=0.0, low_inclusive=False, unit="rad")
    tol = _finite("tol", tol, low=0.0, low_inclusive=True, unit="(relative loss change)")
    efficiency_weight = _finite("efficiency_weight", efficiency_weight, low=0.0, low_inclusive=True, unit="")
    if efficiency_weight > 1.0:
        raise ValueError(f"efficiency_weight must be in [0, 1], got {efficiency_weight!r}")
    pb = _prepare(target_wrp, z_wrp_m, wavelengths_m, pitch_m, device)
    u0 = pb.u0
    if init is None:
        phi0 = torch.angle(u0)
    else:
        phi0 = torch.as_tensor(init.detach() if isinstance(init, torch.Tensor) else np.asarray(init))
        if phi0.is_complex() or phi0.dtype == torch.bool:
            raise ValueError(f"init must be a real phase array (rad), got dtype {phi0.dtype}")
        if tuple(phi0.shape) != tuple(u0.shape):
            raise ValueError(f"init must have the target's shape {tuple(u0.shape)}, got {tuple(phi0.shape)}")
        phi0 = phi0.to(device=u0.device, dtype=torch.float32)
        if not bool(torch.isfinite(phi0).all()):
            raise ValueError("init contains NaN or infinite values")
    phi = phi0.clone().requires_grad_(True)
    opt = torch.optim.Adam([phi], lr=lr)
    lit = (~pb.black).to(torch.float32)
    n_lit = max(1.0, float(lit.sum()))
    history: list[float] = []
    loss_init: Optional[np.ndarray] = None
    converged = iterations == 0
    done = 0
    for it in range(iterations):
        opt.zero_grad(set_to_none=True)
        pred = pb.forward(phi)
        per_fc = 1.0 - _rho2(pb.t_band, pred)
        if efficiency_weight > 0:  # 1 - e^w rho^2: also asks for light in the band
            eff = (pred.real.square() + pred.imag.square()).sum(dim=(-2, -1)) / (phi.shape[-1] * phi.shape[-2])
            obj = 1.0 - (1.0 - per_fc) * eff.clamp_min(1e-12) ** efficiency_weight
        else:
            obj = per_fc  # black targets: rho^2 = 0 exactly, zero gradient
        if loss_init is None:
            loss_init = per_fc.detach().clamp(0.0, 1.0).double().cpu().numpy()
        total = (obj * lit).sum()
        total.backward()
        opt.step()
        done = it + 1
        if done % _CHECK_EVERY == 0 or done == iterations:
            mean = float(total.detach()) / n_lit  # loss before this step (one device sync per check)
            history.append(mean)
            if progress is not None:
                progress("encode", done, iterations)
            if tol > 0 and len(history) > _WINDOW_CHECKS:
                old = history[-1 - _WINDOW_CHECKS]
                if old - mean <= tol * max(old, 1e-12) or mean <= 1e-7:
                    converged = True
                    break
    options = {"lr": lr, "tol": tol, "efficiency_weight": efficiency_weight, "max_iterations": int(iterations),
               "device": str(u0.device), "init": "naive" if init is None else "given"}
    return _finish("sgd", phi.detach(), pb, t0, loss_init=loss_init, iterations=done, converged=converged,
                   options=options, history=history)


def encode(method: str, target_wrp: ArrayLike, *, z_wrp_m: float, wavelengths_m: Sequence[float],
           pitch_m: PitchLike, device: Optional[Union[str, torch.device]] = None, **sgd_options: Any) -> EncodeResult:
    """Dispatch to :func:`encode_sgd`, :func:`encode_dpac` or :func:`encode_naive` by ``method``."""
    common = dict(z_wrp_m=z_wrp_m, wavelengths_m=wavelengths_m, pitch_m=pitch_m, device=device)
    if method == "sgd":
        return encode_sgd(target_wrp, **common, **sgd_options)
    if sgd_options:
        raise ValueError(f"options {sorted(sgd_options)} apply to method 'sgd' only, not {method!r}")
    if method == "dpac":
        return encode_dpac(target_wrp, **common)
    if method == "naive":
        return encode_naive(target_wrp, **common)
    raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")


# ---- 8-bit output and lookup tables ------------------------------------------------------------------------
def _check_table(name: str, table: object) -> np.ndarray:
    arr = np.asarray(table)
    if arr.shape != (256,):
        raise ValueError(f"{name} must have 256 entries (input level 0..255 -> output level), got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or arr.dtype == bool:
        raise ValueError(f"{name} must hold numbers, got dtype {arr.dtype}")
    if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)) or arr.min() < 0 or arr.max() > 255:
        raise ValueError(f"{name} entries must be integers in 0..255")
    return arr.astype(np.uint8)


def load_lut(source: Union[str, Path, ArrayLike], *, wavelengths_m: Sequence[float]) -> np.ndarray:
    """Per-color 8-bit lookup tables, uint8 [C, 256] (row c: SLM level for phase level 0..255 of color c).

    ``source``: an array [256] (shared) or [C, 256]; a ``.npy`` file holding one; or a JSON calibration file
    ``{"luts": [{"wavelength_nm": 640.0, "table": [256 integers]}, ...]}`` matched to each wavelength within
    1 nm (a single entry without ``wavelength_nm`` applies to every color).
    """
    lams_nm = [float(v) * 1e9 for v in wavelengths_m]
    if not lams_nm:
        raise ValueError("wavelengths_m must not be empty")
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():
            raise ValueError(f"lookup table file not found: {path}")
        if path.suffix.lower() == ".npy":
            return load_lut(np.load(path, allow_pickle=False), wavelengths_m=wavelengths_m)
        try:
            doc = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"cannot read lookup table {path}: {exc}") from None
        entries = doc.get("luts") if isinstance(doc, dict) else None
        if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
            raise ValueError(f"{path}: a JSON lookup table needs a non-empty list 'luts' of "
                             "{'wavelength_nm': ..., 'table': [256 levels]} objects")
        if len(entries) == 1 and "wavelength_nm" not in entries[0]:
            return np.stack([_check_table(f"{path}: luts[0].table", entries[0].get("table"))] * len(lams_nm))
        rows = []
        for lam in lams_nm:
            match = [e for e in entries if isinstance(e.get("wavelength_nm"), (int, float))
                     and abs(float(e["wavelength_nm"]) - lam) <= 1.0]
            if len(match) != 1:
                have = [e.get("wavelength_nm") for e in entries]
                raise ValueError(f"{path}: need exactly one table within 1 nm of {lam:.1f} nm, have {have}")
            rows.append(_check_table(f"{path}: table for {lam:.1f} nm", match[0].get("table")))
        return np.stack(rows)
    arr = np.asarray(source.detach().cpu().numpy() if isinstance(source, torch.Tensor) else source)
    if arr.ndim == 1:
        return np.stack([_check_table("lut", arr)] * len(lams_nm))
    if arr.ndim != 2 or arr.shape[0] != len(lams_nm):
        raise ValueError(f"lut must be [256] or [C={len(lams_nm)}, 256], got shape {arr.shape}")
    return np.stack([_check_table(f"lut[{c}]", arr[c]) for c in range(arr.shape[0])])


def quantize(phase: ArrayLike, *, lut: Optional[np.ndarray] = None) -> np.ndarray:
    """8-bit SLM frames uint8 [F, C, H, W]: round(phase / 2pi * 256) mod 256 (DESIGN §2, ``io.phase_to_u8``),
    then, if given, each color's row of ``lut`` (uint8 [C, 256] from :func:`load_lut`)."""
    ph = phase.detach().cpu().numpy() if isinstance(phase, torch.Tensor) else np.asarray(phase)
    if ph.ndim != 4:
        raise ValueError(f"phase must be [F, C, H, W], got shape {ph.shape}")
    levels = phase_to_u8(wrap_phase(ph))
    if lut is None:
        return levels
    table = np.asarray(lut)
    if table.shape != (ph.shape[1], 256) or table.dtype != np.uint8:
        raise ValueError(f"lut must be uint8 [C={ph.shape[1]}, 256] (see load_lut), got {table.dtype} {table.shape}")
    out = np.empty_like(levels)
    for c in range(ph.shape[1]):
        out[:, c] = table[c][levels[:, c]]
    return out


def save_encoded(path: Union[str, Path], result: EncodeResult, *, meta: dict, lut: Optional[np.ndarray] = None,
                 lut_source: Optional[str] = None) -> None:
    """Write STACK.npz (``io.save_stack``): the phase, its 8-bit frames (through ``lut`` if given) and
    ``meta`` (the render's, carried forward) with ``meta["encoder"]`` = the result's summary."""
    if not isinstance(meta, dict):
        raise ValueError(f"meta must be a dict, got {type(meta).__name__}")
    enc = result.summary()
    enc["lut"] = None if lut is None else {"source": lut_source or "array",
                                            "identity": bool(np.all(np.asarray(lut) == np.arange(256)))}
    out_meta = {**meta, "encoder": enc}
    save_stack(path, phase=result.phase, meta=out_meta, frames_u8=quantize(result.phase, lut=lut))
