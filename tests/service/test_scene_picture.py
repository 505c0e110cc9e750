"""The scene's picture through its own camera (made by the planner with `holo plan --picture`), and where the
hologram's field of view lies on it (docs/design.md §3: 2 atan(W p / 2f) around the camera's axis) at the scene's
default optics, at an estimate's and at a job's; over HTTP against a real `holo serve`."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

from tests.service.helpers import make_token, upload, wait_for, zip_dir

CAM_FOV_X_DEG = 40.0
FILM_W, FILM_H = 640, 240  # wider than the picture's 320 px: it is scaled down, keeping 8:3
LAMP = (0.3, 0.1, -2.0)  # a small bright sphere right of and above the camera's axis, 2 m away
LAMP_R = 0.05

SCENE_XML = f"""<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="{CAM_FOV_X_DEG}"/>
        <string name="fov_axis" value="x"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, 0, -1" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="{FILM_W}"/><integer name="height" value="{FILM_H}"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.05"/></emitter>
    <shape type="rectangle" id="wall">
        <transform name="to_world"><scale x="3" y="2"/><translate z="-3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>
    </shape>
    <shape type="sphere" id="lamp">
        <point name="center" x="{LAMP[0]}" y="{LAMP[1]}" z="{LAMP[2]}"/><float name="radius" value="{LAMP_R}"/>
        <emitter type="area"><rgb name="radiance" value="50"/></emitter>
    </shape>
</scene>
"""


def _expected_box(res_hw: tuple[int, int], pitch_um: float, f_mm: float = 50.0) -> tuple[float, float, float, float]:
    """x0, y0, x1, y1 from the two views: the hologram's 2 atan(W p / 2f) by 2 atan(H p / 2f), the camera's
    40 deg across by (3/8) tan(20 deg) half-height; a fraction of the image is a ratio of tangents."""
    h, w = res_hw
    holo_x = 2 * math.atan(w * pitch_um * 1e-3 / (2 * f_mm))
    holo_y = 2 * math.atan(h * pitch_um * 1e-3 / (2 * f_mm))
    cam_x = math.radians(CAM_FOV_X_DEG)
    cam_y = 2 * math.atan(math.tan(cam_x / 2) * FILM_H / FILM_W)
    fx = 0.5 * math.tan(holo_x / 2) / math.tan(cam_x / 2)
    fy = 0.5 * math.tan(holo_y / 2) / math.tan(cam_y / 2)
    return 0.5 - fx, 0.5 - fy, 0.5 + fx, 0.5 + fy


def _box(doc: dict) -> tuple[float, float, float, float]:
    b = doc["field_of_view_box"]
    return b["x0"], b["y0"], b["x1"], b["y1"]


@pytest.fixture(scope="module")
def lamp_scene(server, tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("lamp")
    (folder / "scene.xml").write_text(SCENE_XML)
    with server.client("submit") as c:
        r = upload(c, folder)
        assert r.status_code in (200, 201), r.text
        sid = r.json()["id"]
        scene = wait_for(lambda: (lambda s: s if s["plan_state"] in ("ready", "failed") else None)(
            c.get(f"/v1/scenes/{sid}").json()), timeout=120, what="the lamp scene's plan")
    assert scene["plan_state"] == "ready", scene["plan_error"]
    return scene


def _picture(server, scene_id: str) -> np.ndarray:
    from PIL import Image

    with server.client("reader") as c:
        r = c.get(f"/v1/scenes/{scene_id}/picture.png")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png"
    return np.asarray(Image.open(io.BytesIO(r.content)).convert("RGB"), dtype=np.float64)


def test_the_picture_shows_the_scene_through_its_camera(server, lamp_scene):
    assert lamp_scene["picture_url"] == f"/v1/scenes/{lamp_scene['id']}/picture.png"
    img = _picture(server, lamp_scene["id"])
    h, w, _ = img.shape
    assert w == 320 and h == round(320 * FILM_H / FILM_W)  # at most 320 px wide, the camera's 8:3
    lum = img.mean(axis=2)
    assert lum.std() > 5.0 and 0 < np.percentile(lum, 50) < 250  # lit wall, bright lamp: not blank
    # The lamp's pixels lie where the pinhole camera projects its centre: u = 1/2 + tan(x/z) / (2 tan(fov/2))
    # (world +x on the image's right for this lookat), v = 1/2 - (y/z) / (2 tan(fov_y/2)) from the top.
    t = math.tan(math.radians(CAM_FOV_X_DEG) / 2)
    u = 0.5 + 0.5 * (LAMP[0] / -LAMP[2]) / t
    v = 0.5 - 0.5 * (LAMP[1] / -LAMP[2]) / (t * FILM_H / FILM_W)
    bright = lum >= 250
    assert 5 <= bright.sum() < 0.05 * h * w, bright.sum()
    rows, cols = np.nonzero(bright)
    assert cols.mean() / w == pytest.approx(u, abs=0.02) and rows.mean() / h == pytest.approx(v, abs=0.03)
    # ...and nowhere else: the image's left half, the side without the lamp, holds no saturated pixel
    assert not bright[:, : w // 2].any()


def test_the_picture_is_the_owners_and_served_only_once_planned(server, lamp_scene, tmp_path):
    from service.auth import create_token
    from service.db import Database

    other = create_token(Database(server.data_dir / "service.db"), scopes=("read",), owner="another-lab")[1]
    with server.client(other) as c:  # another owner: the same 404 as a scene that does not exist
        r = c.get(f"/v1/scenes/{lamp_scene['id']}/picture.png")
        assert r.status_code == 404 and "no scene" in r.json()["detail"]
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "scene.xml").write_text('<scene version="3.0.0"><sensor type="perspective"/>'
                                      '<shape type="sphere"><float name="radius" value="abc"/></shape></scene>')
    with server.client("submit") as c:
        sid = upload(c, broken).json()["id"]
        wait_for(lambda: c.get(f"/v1/scenes/{sid}").json()["plan_state"] == "failed", timeout=120,
                 what="the broken scene's plan to fail")
        r = c.get(f"/v1/scenes/{sid}/picture.png")
        assert r.status_code == 404 and "plan failed" in r.json()["detail"]
        assert c.get(f"/v1/scenes/{sid}").json()["field_of_view_box"] is None


def test_a_pending_scene_has_no_picture_yet(tmp_path):
    """A server whose planner does not run leaves the scene pending: no picture, and it says why."""
    from fastapi.testclient import TestClient

    from service.api.app import create_app
    from service.settings import ServiceSettings

    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "scene.xml").write_text(SCENE_XML)
    app = create_app(ServiceSettings(data_dir=tmp_path / "data"), start_workers=False)
    tok = make_token(tmp_path / "data", "submit")

    with TestClient(app, headers={"Authorization": f"Bearer {tok}"}) as c:
        r = c.post("/v1/scenes", files={"bundle": ("b.zip", zip_dir(tmp_path / "s"), "application/zip")})
        assert r.status_code == 201, r.text
        doc = r.json()
        assert doc["plan_state"] == "pending" and doc["picture_url"] is None and doc["field_of_view_box"] is None
        r = c.get(f"/v1/scenes/{doc['id']}/picture.png")
        assert r.status_code == 404 and "pending" in r.json()["detail"], r.text


@pytest.mark.parametrize("pitch_um", [8.0, 3.74])
def test_the_field_of_view_box_is_the_displays_view_in_the_cameras(server, lamp_scene, pitch_um):
    """The scene's JSON gives the box at the default display (1080 x 1920 px of 8 µm, f = 50 mm); an estimate
    at its own pitch and resolution. 8 µm: 17.5 deg of the camera's 40 (inside); 3.74 µm: narrower still."""
    x0, y0, x1, y1 = _box(lamp_scene)
    assert (x0, y0, x1, y1) == pytest.approx(_expected_box((1080, 1920), 8.0), abs=1e-9)
    assert lamp_scene["field_of_view_box"]["camera_fov_x_deg"] == pytest.approx(CAM_FOV_X_DEG, abs=1e-3)
    with server.client("submit") as c:
        for res in ((1080, 1920), (540, 960)):
            r = c.post("/v1/jobs/estimate", json={"scene_id": lamp_scene["id"],
                                                   "optics": {"pitch_um": pitch_um, "resolution_hw": list(res)}})
            assert r.status_code == 200, r.text
            box = r.json()["field_of_view_box"]
            assert _box(r.json()) == pytest.approx(_expected_box(res, pitch_um), abs=1e-9)
            assert box["hologram_fov_x_deg"] == pytest.approx(
                math.degrees(2 * math.atan(res[1] * pitch_um * 1e-3 / 100.0)), rel=1e-9)
            assert box["beyond_camera"] is False
            assert f"of the camera's {CAM_FOV_X_DEG:.3g}°" in box["summary"]


def test_a_display_wider_than_the_camera_says_the_box_leaves_the_picture(server, lamp_scene):
    """f = 10 mm: 2 atan(15.4 / 20) = 75 deg across, wider than the camera's 40: the box reaches past both
    edges; fit_camera_fov fits the width exactly."""
    with server.client("submit") as c:
        r = c.post("/v1/jobs/estimate", json={"scene_id": lamp_scene["id"], "optics": {"focal_length_mm": 10.0}})
        assert r.status_code == 200, r.text
        box = r.json()["field_of_view_box"]
        assert _box(r.json()) == pytest.approx(_expected_box((1080, 1920), 8.0, f_mm=10.0), abs=1e-9)
        assert box["x0"] < 0 < 1 < box["x1"] and box["beyond_camera"] is True
        assert "wider and taller than the camera's view" in box["summary"]
        r = c.post("/v1/jobs/estimate", json={"scene_id": lamp_scene["id"], "optics": {"fit_camera_fov": True}})
        box = r.json()["field_of_view_box"]
        assert (box["x0"], box["x1"]) == pytest.approx((0.0, 1.0), abs=1e-9)


def test_a_job_reports_the_box_at_its_own_optics(server, lamp_scene):
    with server.client("submit") as c:
        r = c.post("/v1/jobs", json={"scene_id": lamp_scene["id"], "optics": {"resolution_hw": [48, 64],
                                                                               "pitch_um": 6.0},
                                     "preset": "fast", "frames": 1, "spp": 1, "encoder": "dpac"})
        assert r.status_code == 202, r.text
        jid = r.json()["id"]
        try:
            job = c.get(f"/v1/jobs/{jid}").json()
            assert _box(job) == pytest.approx(_expected_box((48, 64), 6.0), abs=1e-9)
        finally:
            c.delete(f"/v1/jobs/{jid}")
