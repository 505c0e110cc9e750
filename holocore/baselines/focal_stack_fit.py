"""The focal-stack baseline's fit (holocore.baselines.focal_stack has the method and its physics): phase-only
SGD of F frames on a focal stack's amplitude, through the centred pupil (steps 1-3 there) or pupil-aware over
a bank of the viewer score's views (steps 1'-3')."""

from __future__ import annotations

import math
import time
from typing import Callable, Optional, Sequence

import numpy as np

from holocore import validate
from holocore.baselines.adam_budget import AdamOptions, StepBudget
from holocore.evaluate.scoring import view_shift_px

__all__ = ["FocalStackFit", "optimise_focal_stack"]

_EPS = 1e-10  # inside sqrt(I): a finite gradient where no light arrives


class FocalStackFit:
    """What :func:`optimise_focal_stack` returns: phases [F, C, H, W] in [0, 2pi), per-colour scales s_c
    (target ~ s_c^2 x frame-averaged intensity of the unit-amplitude SLM), loss per iteration (summed over
    colours, each normalised by its target's energy) and seconds spent."""

    def __init__(self, phase: np.ndarray, scale: np.ndarray, loss: list[float], seconds: float,
                 iterations: Optional[list[int]] = None) -> None:
        self.phase = phase
        self.scale = scale
        self.loss = loss
        self.seconds = seconds
        self.iterations = iterations  # Adam steps taken per colour (fewer than asked under a time limit)

    @classmethod
    def of_run(cls, phase: np.ndarray, scale: np.ndarray, loss_total: np.ndarray, steps: list[int],
               t0: float) -> "FocalStackFit":
        """The fit an Adam run ended with: its loss history cut where the longest colour stopped, its time since
        ``t0`` (``time.perf_counter``)."""
        return cls(phase=phase, scale=scale, loss=[float(v) for v in loss_total[:max(steps) + 1]],
                   seconds=time.perf_counter() - t0, iterations=steps)

    @property
    def illumination(self) -> np.ndarray:
        """Relative laser power per colour [C], the brightest 1: (s_c / max s)^2."""
        s = np.asarray(self.scale, dtype=np.float64)
        top = float(s.max()) if s.size and s.max() > 0 else 1.0
        return (s / top) ** 2


def _fit_inputs(T: np.ndarray, plane_z_m: Sequence[float], wavelengths_m: Sequence[float], pitch_m: float,
                focal_length_m: float) -> tuple[list[float], list[float], float, float]:
    """(plane depths, wavelengths, pitch, f) of a fit, checked against targets T [..., K, C, H, W]."""
    if not np.all(np.isfinite(T)) or T.min() < 0:
        raise ValueError("targets must be finite intensities >= 0")
    K, C = T.shape[-4:-2]
    zs = [float(z) for z in plane_z_m]
    if len(zs) != K or not all(math.isfinite(z) for z in zs):
        raise ValueError(f"plane_z_m must be {K} finite depths (one per target plane), got {plane_z_m!r}")
    lams = [validate.positive("wavelengths_m", v, unit="") for v in wavelengths_m]
    if len(lams) != C:
        raise ValueError(f"{len(lams)} wavelengths for {C} target channels")
    return (zs, lams, validate.positive("pitch_m", pitch_m, unit=""),
            validate.positive("focal_length_m", focal_length_m, unit=""))


def optimise_focal_stack(targets: np.ndarray, plane_z_m: Sequence[float], *, wavelengths_m: Sequence[float],
                         pitch_m: float, focal_length_m: float, pupil_diameter_m: Optional[float], frames: int,
                         iterations: int = 200, lr: float = 0.05, seed: int = 0, device: str = "cpu",
                         progress: Optional[Callable[[str, int, int], None]] = None,
                         time_limit_s: Optional[float] = None,
                         views: Optional[Sequence[tuple[float, tuple[float, float]]]] = None,
                         z_inf_m: Optional[float] = None, fourier_filter: bool = False) -> FocalStackFit:
    """Optimise ``frames`` phase-only SLM frames per colour so that their frame-averaged intensity at each
    plane (SLM at z = 0 -> ASM to ``plane_z_m[k]`` through the centred pupil of ``pupil_diameter_m``) matches
    ``targets[k]`` ([K, C, H, W], intensities >= 0, one channel per wavelength) up to one scale per colour.

    Pupil-aware (``views`` given, a bank of (pupil diameter m, eye offset (e_x, e_y) m), ``targets``
    [V, K, C, H, W], ``z_inf_m`` the display's optical infinity): each Adam step draws one view of the bank
    (from ``seed``) and compares, at every plane, the view :func:`holocore.evaluate.scoring.eye_view` takes
    (:func:`holocore.optics.viewing.simulate_view` with its pupil, eye offset, content shift and, with
    ``fourier_filter``, the display's cone filter) divided by the pupil's
    :func:`holocore.evaluate.viewer.aperture_share`, with the target of that view; one scale per colour for
    the whole bank (least squares over the recent steps), as the viewer-faithful score fits one.
    ``pupil_diameter_m`` is then unused.

    Adam on the phases (learning rate ``lr``, ``iterations`` steps), initialised uniform in [0, 2pi) from
    ``seed`` (a different draw per frame and colour). See the module docstring for the loss.
    ``time_limit_s``: stop a colour's steps early so that the whole fit takes about this many seconds (each
    colour gets an equal share of what is left, and a step is started only if its mean duration still fits);
    ``iterations`` stays the most. The loss history then holds each colour's final loss from its last step on.
    """
    T = np.asarray(targets, dtype=np.float64 if views is None else np.float32)
    if views is not None:
        return _optimise_pupil_aware(T, plane_z_m, views, wavelengths_m=wavelengths_m, pitch_m=pitch_m,
                                     focal_length_m=focal_length_m, z_inf_m=z_inf_m, fourier_filter=fourier_filter,
                                     frames=frames, iterations=iterations, lr=lr, seed=seed, device=device,
                                     progress=progress, time_limit_s=time_limit_s)
    return _optimise_centred(T, plane_z_m, wavelengths_m=wavelengths_m, pitch_m=pitch_m, focal_length_m=focal_length_m,
                             pupil_diameter_m=pupil_diameter_m, frames=frames, iterations=iterations, lr=lr,
                             seed=seed, device=device, progress=progress, time_limit_s=time_limit_s)


def _optimise_centred(T: np.ndarray, plane_z_m: Sequence[float], *, wavelengths_m: Sequence[float], pitch_m: float,
                      focal_length_m: float, pupil_diameter_m: Optional[float], frames: int, iterations: int,
                      lr: float, seed: int, device: str, progress: Optional[Callable[[str, int, int], None]],
                      time_limit_s: Optional[float]) -> FocalStackFit:
    """:func:`optimise_focal_stack` through the centred pupil (its docstring): the inputs checked, then each
    colour fitted in turn (:func:`_centred_colour`) from one phase generator."""
    import torch

    if pupil_diameter_m is None:
        raise ValueError("the centred fit needs pupil_diameter_m")
    if T.ndim != 4:
        raise ValueError(f"targets must be [K, C, H, W], got shape {T.shape}")
    K, C, H, W = T.shape
    zs, lams, p, f = _fit_inputs(T, plane_z_m, wavelengths_m, pitch_m, focal_length_m)
    D = validate.positive("pupil_diameter_m", pupil_diameter_m, unit="")
    opts = AdamOptions.check(frames=frames, iterations=iterations, lr=lr, time_limit_s=time_limit_s)
    frames, iterations, lr = opts.frames, opts.iterations, opts.lr
    dev = torch.device(device)
    budget = StepBudget(opts.time_limit_s, colours=C)
    gen = torch.Generator(device="cpu").manual_seed(int(seed) % (2**63))
    phase_out = np.zeros((frames, C, H, W), dtype=np.float32)
    scales = np.zeros(C, dtype=np.float64)
    loss_total = np.zeros(iterations + 1, dtype=np.float64)
    steps = [0] * C
    for c, lam in enumerate(lams):
        budget.start_colour(c)  # an equal share of the time left
        phase_out[:, c], scales[c], steps[c] = _centred_colour(
            T, c, zs, lam, p, f, D, frames=frames, iterations=iterations, lr=lr, gen=gen, dev=dev, budget=budget,
            loss_total=loss_total, progress=progress)
    return FocalStackFit.of_run(phase_out, scales, loss_total, steps, budget.t0)


def _centred_colour(T: np.ndarray, c: int, zs: list[float], lam: float, p: float, f: float, D: float, *,
                    frames: int, iterations: int, lr: float, gen, dev, budget: StepBudget, loss_total: np.ndarray,
                    progress: Optional[Callable[[str, int, int], None]]) -> tuple[np.ndarray, float, int]:
    """Colour ``c``'s centred fit: Adam on its frames' phases against the plane amplitudes sqrt(T[:, c]), its loss
    (over its target's energy) added to ``loss_total`` -> (phases [F, H, W] in [0, 2pi), its scale, the steps
    it took)."""
    import torch

    from holocore.optics.propagation import padded_shape, transfer_function
    from holocore.optics.viewing import pupil_mask

    K, C, H, W = T.shape
    hp, wp = padded_shape((H, W))
    step = 0
    amp = torch.from_numpy(np.sqrt(T[:, c])).to(dev, torch.float32)  # [K, H, W]
    energy = float(amp.square().sum()) or 1.0
    mask = pupil_mask((hp, wp), lam, p, focal_length_m=f, pupil_diameter_m=D, device=dev).to(torch.float32)
    filt = [transfer_function((hp, wp), z, lam, p, device=dev) * mask for z in zs]
    phi = (torch.rand((frames, H, W), generator=gen, dtype=torch.float32) * (2 * math.pi)).to(dev)
    phi.requires_grad_(True)
    opt = torch.optim.Adam([phi], lr=lr)

    def spectrum() -> "torch.Tensor":
        return torch.fft.fft2(torch.polar(torch.ones_like(phi), phi), s=(hp, wp))  # [F, Hp, Wp]

    def recon(spec: "torch.Tensor", k: int) -> "torch.Tensor":
        # inverse DFT as conj(FFT(conj(.))) / N, out of place (see holocore.optics.propagation.ifft2 for why)
        v = torch.conj(torch.fft.fft2(torch.conj(spec * filt[k])))[..., :H, :W] / (hp * wp)
        return (v.real.square() + v.imag.square()).mean(dim=0)  # frame average [H, W]

    with torch.no_grad():  # the first scale: least squares on the initial reconstruction
        sp = spectrum()
        r = [torch.sqrt(recon(sp, k) + _EPS) for k in range(K)]
        num = sum(float((rk * amp[k]).sum()) for k, rk in enumerate(r))
        den = sum(float(rk.square().sum()) for rk in r)
    s = num / den if den > 0 else 1.0
    budget.begin_steps()
    for it in range(iterations + 1):
        opt.zero_grad(set_to_none=True)
        num = den = loss_sum = 0.0
        # the final loss only, no step: at the last iteration, or when one more step would pass the deadline
        last = budget.last(it, iterations)
        with torch.set_grad_enabled(not last):
            sp = spectrum()
        for k in range(K):  # one plane's graph at a time (the shared spectrum kept); gradients add up
            with torch.set_grad_enabled(not last):
                rk = torch.sqrt(recon(sp, k) + _EPS)
                lk = (s * rk - amp[k]).square().sum() / (K * H * W)
            if not last:
                lk.backward(retain_graph=k < K - 1)
            rd = rk.detach()
            num += float((rd * amp[k]).sum())
            den += float(rd.square().sum())
            loss_sum += float(lk.detach())
        if last:  # this colour's final loss, held to the end of the history if it stopped early
            loss_total[it:] += loss_sum * (K * H * W) / energy
            step = it
            break
        loss_total[it] += loss_sum * (K * H * W) / energy
        opt.step()
        s = num / den if den > 0 else s
        if progress is not None:
            progress("focal-stack", c * iterations + it + 1, C * iterations)
    with torch.no_grad():
        phase = torch.remainder(phi.detach(), 2 * math.pi).cpu().numpy()
    return phase, s, step


def _optimise_pupil_aware(T: np.ndarray, plane_z_m: Sequence[float], views: Sequence[tuple[float, tuple[float, float]]],
                          *, wavelengths_m: Sequence[float], pitch_m: float, focal_length_m: float,
                          z_inf_m: Optional[float], fourier_filter: bool, frames: int, iterations: int, lr: float,
                          seed: int, device: str, progress: Optional[Callable[[str, int, int], None]],
                          time_limit_s: Optional[float]) -> FocalStackFit:
    """:func:`optimise_focal_stack` with a bank of views (its docstring). The model is the score's own view
    function, not a re-derivation of it, so that what the fit sees is exactly what the score will see."""
    import torch

    from holocore.evaluate.viewer import aperture_share

    if T.ndim != 5:
        raise ValueError(f"pupil-aware targets must be [V, K, C, H, W], got shape {T.shape}")
    V, K, C, H, W = T.shape
    zs, lams, p, f = _fit_inputs(T, plane_z_m, wavelengths_m, pitch_m, focal_length_m)
    bank = [(validate.positive("pupil_diameter_m", D, unit=""), (float(e[0]), float(e[1]))) for D, e in views]
    if len(bank) != V or V < 1:
        raise ValueError(f"{len(bank)} views for {V} target views")
    if z_inf_m is None:
        raise ValueError("the pupil-aware fit needs z_inf_m (the eye's view shift grows with z - z_inf)")
    zi = validate.positive("z_inf_m", z_inf_m, unit="")
    opts = AdamOptions.check(frames=frames, iterations=iterations, lr=lr, time_limit_s=time_limit_s)
    frames, iterations, lr = opts.frames, opts.iterations, opts.lr
    dev = torch.device(device)
    vmeta = {"focal_length_m": f, "pitch_m": p, "z_inf_m": zi, "wavelengths_m": lams}
    # The score divides every view by the pupil's share of the eyebox and fits one scale for all of them: a
    # larger pupil's extra light is no error, but brightness that steps with the eye is; the fit does the same.
    share = [max(aperture_share(vmeta, pupil_diameter_m=D, eye_offset_m=e), 1e-12) for D, e in bank]
    shift = [[view_shift_px(vmeta, focus_z_m=z, view_offset_m=e) for z in zs] for _D, e in bank]
    budget = StepBudget(opts.time_limit_s, colours=C)
    gen = torch.Generator(device="cpu").manual_seed(int(seed) % (2**63))
    draw = np.random.default_rng(np.random.SeedSequence([int(seed), 0xFB4]))  # the views, apart from the phases
    phase_out = np.zeros((frames, C, H, W), dtype=np.float32)
    scales = np.zeros(C, dtype=np.float64)
    loss_total = np.zeros(iterations + 1, dtype=np.float64)
    steps = [0] * C
    for c, lam in enumerate(lams):
        budget.start_colour(c)
        phase_out[:, c], scales[c], steps[c] = _pupil_aware_colour(
            T, c, lam, bank, share, shift, zs, p, f, fourier_filter=fourier_filter, frames=frames,
            iterations=iterations, lr=lr, gen=gen, draw=draw, dev=dev, budget=budget, loss_total=loss_total,
            progress=progress)
    return FocalStackFit.of_run(phase_out, scales, loss_total, steps, budget.t0)


def _pupil_aware_colour(T: np.ndarray, c: int, lam: float, bank: list, share: list[float], shift: list,
                        zs: list[float], p: float, f: float, *, fourier_filter: bool, frames: int, iterations: int,
                        lr: float, gen, draw: np.random.Generator, dev, budget: StepBudget, loss_total: np.ndarray,
                        progress: Optional[Callable[[str, int, int], None]]) -> tuple[np.ndarray, float, int]:
    """Colour ``c``'s pupil-aware fit: Adam on its frames' phases, each step against one view of the bank drawn
    from ``draw``, its loss (over the drawn target's energy) added to ``loss_total`` -> (phases [F, H, W] in
    [0, 2pi), its scale, the steps it took)."""
    import torch

    from holocore.optics.viewing import simulate_view

    V, K, C, H, W = T.shape
    # the scale: least squares over about one bank's worth of recent steps (exponentially weighted)
    keep = 1.0 - 1.0 / V
    step = 0
    phi = (torch.rand((frames, H, W), generator=gen, dtype=torch.float32) * (2 * math.pi)).to(dev)
    phi.requires_grad_(True)
    opt = torch.optim.Adam([phi], lr=lr)

    def view(v: int, k: int) -> "torch.Tensor":
        D, e = bank[v]
        u = torch.polar(torch.ones_like(phi), phi)[:, None]  # [F, 1, H, W]
        i = simulate_view(u, wavelengths_m=[lam], pitch_m=p, focal_length_m=f, pupil_diameter_m=D,
                          distance_m=zs[k], view_offset_m=e, shift_px=shift[v][k],
                          fourier_filter=fourier_filter, pixel_orders=None)[0]
        return torch.sqrt(i.clamp(min=0.0) / share[v] + _EPS)

    order = draw.integers(0, V, size=iterations + 1)
    num_acc = den_acc = 0.0
    s = None
    budget.begin_steps()
    for it in range(iterations + 1):
        opt.zero_grad(set_to_none=True)
        v = int(order[it])
        amp = torch.from_numpy(np.sqrt(T[v, :, c])).to(dev, torch.float32)  # [K, H, W]
        energy = float(amp.square().sum()) or 1.0
        last = budget.last(it, iterations)
        if s is None:  # the first scale: least squares on the first view's initial reconstruction
            with torch.no_grad():
                r = [view(v, k) for k in range(K)]
                num_acc = sum(float((rk * amp[k]).sum()) for k, rk in enumerate(r))
                den_acc = sum(float(rk.square().sum()) for rk in r)
            s = num_acc / den_acc if den_acc > 0 else 1.0
        num = den = loss_sum = 0.0
        for k in range(K):  # one plane's graph at a time; gradients add up
            with torch.set_grad_enabled(not last):
                rk = view(v, k)
                lk = (s * rk - amp[k]).square().sum() / (K * H * W)
            if not last:
                lk.backward()
            rd = rk.detach()
            num += float((rd * amp[k]).sum())
            den += float(rd.square().sum())
            loss_sum += float(lk.detach())
        if last:
            loss_total[it:] += loss_sum * (K * H * W) / energy
            step = it
            break
        loss_total[it] += loss_sum * (K * H * W) / energy
        opt.step()
        num_acc, den_acc = keep * num_acc + num, keep * den_acc + den
        s = num_acc / den_acc if den_acc > 0 else s
        if progress is not None:
            progress("focal-stack", c * iterations + it + 1, C * iterations)
    with torch.no_grad():
        phase = torch.remainder(phi.detach(), 2 * math.pi).cpu().numpy()
    return phase, s, step
