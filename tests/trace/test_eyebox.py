"""One eyebox for every colour (``OpticsConfig.eyebox``, docs/physics.md "One eyebox for every colour").

Each colour's recording cone is arcsin(lambda / 2p): red's is 1.4x wider than blue's at the paper's display, and
random phases fill it. An eye whose pupil holds more than blue's eyebox then gathers all of blue's light and
more and more of red's: the image turns redder as the pupil opens, by (s_red / s_blue)^2 = 1.98 once it holds
every colour's cone. With ``eyebox="common"`` (the default) every colour's field is cut to the smallest cone, so
the colour an eye sees does not depend on its pupil. Checked with the tracer and the eye model on a glowing white
plate, and on the fields' angular spectra.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from holocore.display.optics import OpticsConfig, common_cone_sine, cone_sine
from holocore.optics.propagation import asm

LAMS = (640e-9, 516.5e-9, 455.4e-9)


def _outside_share(field: np.ndarray, lam: float, pitch: float, sine: float) -> float:
    """Energy share of a field [..., H, W] in directions of sine > ``sine`` (a little margin for the grid)."""
    H, W = field.shape[-2:]
    fy = np.fft.fftfreq(H, d=pitch)[:, None]
    fx = np.fft.fftfreq(W, d=pitch)[None, :]
    out = (fx * fx + fy * fy) * lam * lam > (sine * 1.02) ** 2
    spec = np.abs(np.fft.fft2(field)) ** 2
    return float(spec[..., out].sum() / spec.sum())


def test_the_cut_keeps_plane_waves_inside_the_cone_and_drops_those_outside():
    H, W, p, lam = 64, 64, 8e-6, 640e-9
    y, x = np.mgrid[:H, :W] * p
    inside = np.exp(2j * np.pi * (4 / (W * p)) * x)  # sine 4 lambda / (W p) = 0.005
    outside = np.exp(2j * np.pi * (30 / (W * p)) * y)  # sine 0.0375, beyond blue's 0.0285
    u = torch.from_numpy((inside + outside).astype(np.complex64))
    s = common_cone_sine(LAMS, p)
    v = asm(u, 0.0, lam, p, cone_sine=s).numpy()
    core = (slice(16, 48), slice(16, 48))  # away from the edges' diffraction
    assert np.abs(v[core] - inside[core]).max() < 0.1
    assert _outside_share(asm(u, 2e-3, lam, p, cone_sine=s).numpy(), lam, p, s) < 1e-3
    assert torch.equal(asm(u, 0.0, lam, p), u)  # no cut, no distance: a copy
    with pytest.raises(ValueError, match="cone_sine"):
        asm(u, 0.0, lam, p, cone_sine=1.5)


def test_the_common_eyebox_is_the_bluest_cone_and_the_default():
    o = OpticsConfig()
    assert o.eyebox == "common"
    assert o.eyebox_sine() == pytest.approx(455.4e-9 / 16e-6)
    assert OpticsConfig(eyebox="per_colour").eyebox_sine() is None
    assert cone_sine(640e-9, 8e-6) > o.eyebox_sine()
    with pytest.raises(ValueError):
        OpticsConfig(eyebox="blue")


def _plate(eyebox: str):
    from holocore.display.profiles import PAPER
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.paper import paper_fov_x_deg
    from tests.trace.scenes import camera, emitting_plane, scene

    loaded = scene(sensor=camera(fov=paper_fov_x_deg()), plate=emitting_plane(-0.5, size=0.2))
    opt = PAPER.optics(resolution_hw=(96, 128), frames=4, z_inf_mm=4.0).model_copy(update={"eyebox": eyebox})
    return render_loaded(loaded, opt, RenderOptions(preset="balanced", spp=128, wrp_planes=1), display=PAPER)


@pytest.fixture(scope="module")
def plates():
    return {e: _plate(e) for e in ("common", "per_colour")}


def _colour(res, pupil_m: float) -> np.ndarray:
    from holocore.evaluate.scoring import eye_view, lit_margin_px

    meta = res.meta
    f = meta["focal_length_m"]
    z = meta["z_inf_m"] + f * f / 0.5
    img = eye_view(res.slm_field, meta, focus_z_m=z, pupil_diameter_m=pupil_m, view_offset_m=(0.0, 0.0))
    m = min(lit_margin_px(meta, focus_z_m=z, pupil_diameter_m=pupil_m, view_offset_m=(0.0, 0.0)), 30)
    inner = img[:, m:-m, m:-m]
    assert np.all(np.isfinite(inner))
    return inner.reshape(3, -1).mean(axis=1)


@pytest.mark.slow
def test_every_colour_leaves_within_the_common_cone(plates):
    res = plates["common"]
    s = common_cone_sine(LAMS, 8e-6)
    for c, lam in enumerate(LAMS):
        for fld in (res.slm_field, res.wrp_field):  # what is left: the field's own edges, cut on a wider grid
            assert _outside_share(np.asarray(fld[:, c]), lam, 8e-6, s) < 0.02, (lam,)
    # each colour's own cone, not cut: red sends a large part of its light beyond blue's cone
    assert _outside_share(np.asarray(plates["per_colour"].slm_field[:, 0]), LAMS[0], 8e-6, s) > 0.3


def test_a_white_plate_keeps_its_colour_as_the_pupil_opens(plates):
    """Through a centred 2 mm pupil (inside every colour's eyebox) both layouts show the same colour; through
    6 mm (more than every eyebox) each colour's own cone turns the plate redder by (s_r / s_b)^2 = 1.98 and
    greener by 1.29, the common eyebox keeps it."""
    small = {e: _colour(r, 2e-3) for e, r in plates.items()}
    large = {e: _colour(r, 6e-3) for e, r in plates.items()}
    for c in (0, 1):
        assert small["common"][c] / small["common"][2] == pytest.approx(
            small["per_colour"][c] / small["per_colour"][2], rel=0.05)
    drift = {e: (large[e][:2] / large[e][2]) / (small[e][:2] / small[e][2]) for e in plates}
    assert np.all(np.abs(drift["common"] - 1.0) < 0.08), drift
    want = np.array([(LAMS[0] / LAMS[2]) ** 2, (LAMS[1] / LAMS[2]) ** 2])
    assert np.allclose(drift["per_colour"], want, rtol=0.15), (drift, want)
