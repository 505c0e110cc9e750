"""A hall of four facing mirrors: chains of delta bounces run past the cap, and the plan and the result's meta say
what share of the rays the cap drops; the pre-pass raises the cap until little is lost; the plan counts the
mirrors per shape and names them by their ids in the scene file."""

from __future__ import annotations

import pytest

from holocore.display.optics import OpticsConfig
from holocore.pipeline import RenderOptions, plan_scene, render_loaded
from holocore.scene.load import load_scene

# Walls at x = +-0.5 and y = +-0.5 facing inwards; the camera looks down -z from the hall's middle at a diffuse
# card 28 m away, the view tilted towards a wall so that most rays bounce between the mirrors on their way.
_MIRROR = '<shape type="rectangle" id="{id}"><transform name="to_world"><scale {size}/>' \
          '<rotate {axis}="1" angle="{angle}"/><translate {pos}/></transform><ref id="metal"/></shape>'
_ALONG_X, _ALONG_Y = 'x="16" y="0.5"', 'x="0.5" y="16"'  # 32 m long once turned to run along z
_WALLS = [("mirror_east", _ALONG_X, 'y', -90, 'x="0.5" z="-14"'), ("mirror_west", _ALONG_X, 'y', 90, 'x="-0.5" z="-14"'),
          ("mirror_north", _ALONG_Y, 'x', 90, 'y="0.5" z="-14"'), ("mirror_south", _ALONG_Y, 'x', -90, 'y="-0.5" z="-14"')]
HALL = f"""<scene version="3.0.0">
  <bsdf type="conductor" id="metal"/>
  <sensor type="perspective"><float name="fov" value="60"/><string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="0, 0, 0" target="0.45, 0.3, -1" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="48"/></film></sensor>
  {''.join(_MIRROR.format(id=i, size=z, axis=a, angle=g, pos=p) for i, z, a, g, p in _WALLS)}
  <shape type="rectangle" id="far_card"><transform name="to_world"><scale value="0.5"/>
    <translate z="-28"/></transform><bsdf type="diffuse"/></shape>
  <shape type="sphere" id="lamp"><point name="center" x="0" y="0" z="-26"/><float name="radius" value="0.1"/>
    <emitter type="area"><rgb name="radiance" value="20"/></emitter></shape>
  <emitter type="constant"><rgb name="radiance" value="0.2"/></emitter>
</scene>
"""

OPTICS = OpticsConfig(resolution_hw=(16, 24), wavelengths_nm=(520.0,), frames=1, focal_length_mm=2.0)


@pytest.fixture(scope="module")
def hall(tmp_path_factory):
    d = tmp_path_factory.mktemp("hall")
    (d / "scene.xml").write_text(HALL)
    return load_scene(d / "scene.xml")


def test_plan_counts_mirrors_per_shape_by_their_ids(hall):
    pl = plan_scene(hall, OPTICS, RenderOptions(preset="fast"))
    assert sorted(pl.inventory.mirrors) == sorted(w[0] for w in _WALLS)
    line = next(s for s in pl.plan.summary if s.startswith("mirror reflection"))
    assert "4 surface(s)" in line and "mirror_east" in line
    assert not any("mesh#" in s for s in pl.plan.summary)


def test_prepass_raises_the_cap_past_the_surfaces_count(hall):
    # every chain here needs 17-25 bounces: the cap the mirrors' count allows (16) would drop all of them
    pl = plan_scene(hall, OPTICS, RenderOptions(preset="fast"))
    assert pl.plan.max_delta > 16 and pl.plan.delta_capped_share <= 0.005
    assert any(s.startswith("delta chains capped at") and "raised from 16" in s for s in pl.plan.summary)
    asked = plan_scene(hall, OPTICS, RenderOptions(preset="fast", max_delta=16))
    assert asked.plan.max_delta == 16 and asked.plan.delta_capped_share > 0.9


@pytest.mark.slow
def test_capped_share_is_reported_and_falls_as_the_cap_rises(hall):
    shares = {}
    for cap in (16, 21, None):
        res = render_loaded(hall, OPTICS, RenderOptions(preset="fast", spp=4, max_delta=cap))
        dc = res.meta["delta_capped"]
        shares[cap] = dc["rays_capped_share"]
        assert dc["rays_capped"] == res.meta["stats"]["capped"]
        assert dc["max_delta"] == res.meta["plan"]["max_delta"]
        assert any("delta chains capped at" in s for s in res.meta["plan"]["summary"])
    assert shares[16] > 0.5  # the cap the mirrors' count allows drops most of the light
    assert 0 < shares[21] < shares[16]
    assert shares[None] < min(0.05, shares[21])
