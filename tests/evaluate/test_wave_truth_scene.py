"""The wave-optical ground truth's depth layers on the project's paper scenes (Mitsuba): a mirror's image lies
at the unfolded distance, a glass ball's at its lens image, the sky at optical infinity, and the layers hold the
light a pinhole render of the reference path tracer sees, split by depth, none lost; an off-centre eye sees a
mirror image move by its geometric parallax."""

from __future__ import annotations

import numpy as np
import pytest

from holocore.display.optics import OpticsConfig
from holocore.evaluate.wave_truth import WaveGroundTruth, depth_layers
from holocore.pipeline import RenderOptions, render_loaded
from holocore.scene.load import from_mitsuba_scene
from holocore.scene.paper import scene_facts, write_paper_scene
from tests.trace import test_far_image_parallax as far

F_EYE, Z_INF = 0.05, 0.08
H, W = 54, 96
P = 8e-6 * 1920 / W  # the paper display's field of view on a small grid
SPACING = 1e-4


def _layers(name: str, tmp_path, spp: int = 16):
    from holocore.scene.load import load_scene

    loaded = load_scene(write_paper_scene(name, tmp_path / name))
    m = np.array(loaded.sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
    lay = depth_layers(loaded.scene, sensor_to_world=m, focal_length_m=F_EYE, z_inf_m=Z_INF, pitch_m=P,
                       shape_hw=(H, W), spacing_m=SPACING, spp=spp)
    return loaded, m, lay


def _z(zc_m: float) -> float:
    return Z_INF + F_EYE * F_EYE / zc_m


def _centre_depth(lay, half: int = 3) -> float:
    """The hologram depth the image's central block gets most of its light from (the light-weighted depth of
    the brightest layer and its neighbours: a glass ball also reflects 4 % of the room from its surface)."""
    block = lay.rgb[:, :, H // 2 - half:H // 2 + half, W // 2 - half:W // 2 + half].sum(axis=(1, 2, 3))
    k = int(np.argmax(block))
    near = slice(max(0, k - 1), k + 2)
    return float((block[near] * lay.z_m[near]).sum() / block[near].sum())


def test_the_mirror_shows_its_image_at_the_unfolded_distance_and_the_light_is_all_there(tmp_path):
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.scene.features import reference_integrator

    facts = scene_facts("mirror")
    loaded, m, lay = _layers("mirror", tmp_path)
    assert lay.lost == 0.0
    # the middle of the view is the mirror: its light comes from the poster's image, 2 m away, not from 0.5 m
    assert _centre_depth(lay) == pytest.approx(_z(facts["mirror_image_zc_m"]), abs=SPACING)
    # the far wall and the sky sit at (or next to) optical infinity
    far = np.abs(lay.z_m - _z(facts["far_wall_zc_m"])) <= SPACING
    assert lay.z_m[0] == Z_INF and float(lay.rgb[far].sum()) > 0.2 * float(lay.rgb.sum())
    # summed over depth, the layers are the reference path tracer's pinhole render
    mi = mitsuba()
    sensor = mi.load_dict({"type": "perspective", "fov": 2 * np.degrees(np.arctan(W * P / (2 * F_EYE))),
                           "fov_axis": "x", "near_clip": 1e-3, "to_world": mi.ScalarTransform4f(m.tolist()),
                           "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"},
                                    "pixel_format": "rgb"},
                           "sampler": {"type": "independent", "sample_count": 64}})
    ref = np.array(mi.render(loaded.scene, sensor=sensor, spp=64,
                             integrator=mi.load_dict(reference_integrator(loaded.scene, max_depth=12))))
    ref = np.moveaxis(ref[..., :3], -1, 0)
    total = lay.rgb.sum(axis=0)
    blocks = lambda a: a.reshape(3, H // 6, 6, W // 6, 6).mean(axis=(2, 4))  # noqa: E731
    assert float(total.sum()) == pytest.approx(float(ref.sum()), rel=0.03)
    rel = np.abs(blocks(total) - blocks(ref)) / (blocks(ref).mean() + 1e-12)
    assert float(np.median(rel)) < 0.05


@pytest.mark.slow  # its kernels compile for about a minute on 2 cores
def test_the_glass_ball_shows_the_card_at_its_lens_image(tmp_path):
    facts = scene_facts("glass")
    _, _, lay = _layers("glass", tmp_path, spp=8)
    assert lay.lost < 0.01
    # the paraxial image of the card through the ball (the unfolded path would put it 5 m further)
    assert _centre_depth(lay, half=2) == pytest.approx(_z(facts["paraxial_image_zc_m"]), rel=0.002)


def test_a_mirror_images_parallax_is_the_geometric_one_for_an_off_centre_eye():
    """A glowing ball 1.5 m away seen in a tilted plane mirror (tests/trace/test_far_image_parallax.py's scene):
    between eyes 0.8 mm left and right of the centre, the wave truth moves its image by the geometric parallax
    -2 e (z - z_inf) / (f p) of its hologram depth z, focused on it or 0.8 mm in front of it (a 1 mm pupil, inside
    the display's band: the pupil's own centre sets the parallax)."""
    loaded = from_mitsuba_scene(far._scene())
    optics = OpticsConfig(**{**far.OPTICS, "frames": 1})
    meta = render_loaded(loaded, optics, RenderOptions(preset="fast", spp=4, cone_equaliser=False)).meta
    truth = WaveGroundTruth(loaded, meta, shape_hw=(far.H, far.W), spp=32)
    want = -2 * 0.8e-3 * (far.Z_BALL - far.Z_INF) / (far.F_M * far.P)  # -6.67 px
    for focus in (far.Z_BALL, far.Z_BALL - 0.8e-3):
        cols = []
        for e in far.EYES:
            view = truth.channels(focus_z_m=focus, pupil_diameter_m=1e-3, view_offset_m=(e, 0.0))
            cols.append(far._centroid_x(view, view))
        assert abs((cols[1] - cols[0]) - want) < 0.3, (focus, cols, want)
