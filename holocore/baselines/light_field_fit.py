"""The light-field baseline as the paper runs it (Table 1, "SGD-based w/ light fields"; Choi et al. 2022): phase-only
SGD of F frames on the light field, instead of encoding a stereogram.

Model (per colour c): frame m's SLM field exp(i phi_m) goes by band-limited ASM (docs/design.md §5, 2x padding)
from the SLM (z = 0) to the ray-sampling plane z_rs; there it is cut into the stereogram's hogels (B x B pixels,
:mod:`holocore.baselines.light_field`) and each hogel's spectrum on the same B x B frequency grid is taken,

    S_m(hogel, f) = DFT_B{ v_m(hogel) exp(i pi (B - 1) (r + s) / B) },

the exact inverse of the stereogram's synthesis, so a stereogram's own field gives back its spectra. The light field
the frames show is the frame average P(hogel, f) = mean_m |S_m|^2, and the loss is

    sum over the cone's directions of || s_c sqrt(P) - sqrt(T) ||^2 / n,

T the stereogram's target power (B^4 L / n_in a_c^2, :func:`holocore.baselines.light_field.stereogram_colours`),
s_c the least-squares scale of the previous step (no gradient through it), Adam on all frames' phases together
(only the frame average is supervised). Colours are balanced by laser power as the focal stack's are
(:class:`holocore.baselines.focal_stack.FocalStackFit`, whose type the fit returns).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Optional, Sequence

import numpy as np

from holocore import validate
from holocore.baselines.adam_budget import AdamOptions, StepBudget
from holocore.baselines.focal_stack_fit import FocalStackFit

if TYPE_CHECKING:
    import torch

__all__ = ["light_field_of", "optimise_light_field"]

_EPS = 1e-10  # inside sqrt(P): a finite gradient where no light arrives


def light_field_of(slm: "torch.Tensor", *, hogel_px: int, z_rs_m: float, wavelength_m: float, pitch_m: float,
                   transfer: Optional["torch.Tensor"] = None) -> "torch.Tensor":
    """The light field P [Hh B, Wh B] (hogel-major) that SLM frames ``slm`` (complex [F, H, W]) show on the RS plane
    ``z_rs_m`` (m): mean over frames of |S_m|^2 (module docstring). Differentiable. ``transfer``: the ASM transfer
    function on the padded grid (:func:`holocore.optics.propagation.transfer_function`), if already made."""
    import torch

    from holocore.optics.propagation import padded_shape, transfer_function

    F, H, W = slm.shape
    B = int(hogel_px)
    Hh, Wh = -(-H // B), -(-W // B)
    hp, wp = padded_shape((H, W))
    tf = transfer if transfer is not None else transfer_function((hp, wp), z_rs_m, wavelength_m, pitch_m,
                                                                 device=slm.device)
    ramp = torch.polar(torch.ones(B), torch.from_numpy(math.pi * (B - 1) / B * np.arange(B)).float())
    deramp = (ramp[:, None] * ramp[None, :]).to(slm.device, torch.complex64)  # conj of the synthesis ramp
    spec = torch.fft.fft2(slm, s=(hp, wp))
    # inverse DFT as conj(FFT(conj(.))) / N, out of place (holocore.optics.propagation.ifft2 says why)
    v = torch.conj(torch.fft.fft2(torch.conj(spec * tf)))[..., :H, :W] / (hp * wp)
    v = torch.nn.functional.pad(v, (0, Wh * B - W, 0, Hh * B - H))
    S = torch.fft.fft2(v.reshape(F, Hh, B, Wh, B).permute(0, 1, 3, 2, 4) * deramp)  # [F, Hh, Wh, B, B]
    P = (S.real.square() + S.imag.square()).mean(dim=0)
    return P.permute(0, 2, 1, 3).reshape(Hh * B, Wh * B)


def optimise_light_field(targets: np.ndarray, *, shape_hw: tuple[int, int], hogel_px: int, z_rs_m: float,
                         wavelengths_m: Sequence[float], pitch_m: float, frames: int, iterations: int = 200,
                         lr: float = 0.05, seed: int = 0, device: str = "cpu",
                         time_limit_s: Optional[float] = None) -> FocalStackFit:
    """Fit ``frames`` phase-only SLM frames per colour to the light field ``targets`` [C, Hh B, Wh B] (power per
    hogel and direction on the hogel-major grid, 0 outside the cone; H x W = ``shape_hw`` pixels, B =
    ``hogel_px``) on the RS plane ``z_rs_m`` (m) from the SLM. Adam (``lr``, ``iterations`` steps) from phases
    uniform in [0, 2pi) drawn from ``seed``; ``time_limit_s``: each colour gets an equal share of what is left
    and a step is taken only if its mean duration still fits."""
    import torch

    from holocore.optics.propagation import padded_shape, transfer_function

    H, W = (int(v) for v in shape_hw)
    B = validate.integer("hogel_px", hogel_px, 1, 256)
    Hh, Wh = -(-H // B), -(-W // B)
    T = np.asarray(targets, dtype=np.float64)
    lams = [validate.positive("wavelengths_m", v, unit="") for v in wavelengths_m]
    if T.shape != (len(lams), Hh * B, Wh * B):
        raise ValueError(f"targets must be [{len(lams)}, {Hh * B}, {Wh * B}] (colours, hogel-major grid), "
                         f"got {T.shape}")
    if not np.all(np.isfinite(T)) or T.min() < 0:
        raise ValueError("targets must be finite powers >= 0")
    p = validate.positive("pitch_m", pitch_m, unit="")
    z_rs = validate.positive("z_rs_m", z_rs_m, unit="")
    opts = AdamOptions.check(frames=frames, iterations=iterations, lr=lr, time_limit_s=time_limit_s)
    frames, iterations, lr = opts.frames, opts.iterations, opts.lr
    dev = torch.device(device)
    hp, wp = padded_shape((H, W))
    C = len(lams)
    budget = StepBudget(opts.time_limit_s, colours=C)
    gen = torch.Generator(device="cpu").manual_seed(int(seed) % (2**63))
    phase_out = np.zeros((frames, C, H, W), dtype=np.float32)
    scales = np.zeros(C, dtype=np.float64)
    loss_total = np.zeros(iterations + 1, dtype=np.float64)
    steps = [0] * C
    for c, lam in enumerate(lams):
        budget.start_colour(c)  # an equal share of the time left
        amp = torch.from_numpy(np.sqrt(T[c])).to(dev, torch.float32)  # [Hh B, Wh B]
        lit = amp > 0
        n = max(1, int(lit.sum()))
        energy = float(amp.square().sum()) or 1.0
        tf = transfer_function((hp, wp), z_rs, lam, p, device=dev)
        phi = (torch.rand((frames, H, W), generator=gen, dtype=torch.float32) * (2 * math.pi)).to(dev)
        phi.requires_grad_(True)
        opt = torch.optim.Adam([phi], lr=lr)

        def light_field() -> "torch.Tensor":
            return light_field_of(torch.polar(torch.ones_like(phi), phi), hogel_px=B, z_rs_m=z_rs, wavelength_m=lam,
                                  pitch_m=p, transfer=tf)

        with torch.no_grad():
            r = torch.sqrt(light_field() + _EPS)
            den = float(r[lit].square().sum())
            s = float((r[lit] * amp[lit]).sum()) / den if den > 0 else 1.0
        budget.begin_steps()
        for it in range(iterations + 1):
            opt.zero_grad(set_to_none=True)
            last = budget.last(it, iterations)  # the final loss only, no step after it
            with torch.set_grad_enabled(not last):
                r = torch.sqrt(light_field() + _EPS)
                loss = (s * r[lit] - amp[lit]).square().sum() / n
            rd = r.detach()[lit]
            if last:
                loss_total[it:] += float(loss) * n / energy
                steps[c] = it
                break
            loss.backward()
            loss_total[it] += float(loss.detach()) * n / energy
            opt.step()
            den = float(rd.square().sum())
            s = float((rd * amp[lit]).sum()) / den if den > 0 else s
        with torch.no_grad():
            phase_out[:, c] = torch.remainder(phi.detach(), 2 * math.pi).cpu().numpy()
        scales[c] = s
    return FocalStackFit.of_run(phase_out, scales, loss_total, steps, budget.t0)
