"""A finished job's phase frames over HTTP against a real `holo serve`: the index names the stack's frames,
colours (with the job's wavelengths) and SLM size; each (frame, colour) PNG decodes to exactly the 8-bit frame
the SLM is driven with (frames.zip's member, the stack's frames_u8, the stack's phase quantised as
round(phase / 2pi * 256) mod 256); a frame or colour past the stack's is a one-line 404, a negative one 422;
another owner's job is 404 and an unfinished one 409."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

from tests.service.helpers import finished_job, planned_scene, zip_dir

# Two frames, three colours, an SLM wider than tall: a swapped H and W, frame or colour axis shows.
JOB = {"optics": {"resolution_hw": [24, 40], "seed": 5, "wavelengths_nm": [638.0, 520.0, 450.0]}, "preset": "fast",
       "frames": 2, "spp": 4, "encoder": "dpac"}


@pytest.fixture(scope="module")
def done(server, tmp_path_factory) -> dict:
    from holocore.scene.demo import write_demo_scene

    folder = tmp_path_factory.mktemp("phase") / "demo"
    write_demo_scene(folder)
    sid = planned_scene(server, zip_dir(folder))["id"]
    job = finished_job(server, {"scene_id": sid, **JOB})
    with server.client("submit") as c:
        stack = c.get(f"/v1/jobs/{job['id']}/stack").content
        frames = c.get(f"/v1/jobs/{job['id']}/frames.zip").content
    with np.load(io.BytesIO(stack), allow_pickle=False) as z:
        phase, u8 = z["phase"], z["frames_u8"]
    return {"job": job, "scene_id": sid, "phase": phase, "u8": u8, "zip": zipfile.ZipFile(io.BytesIO(frames))}


def _grey(png: bytes) -> np.ndarray:
    from PIL import Image

    img = Image.open(io.BytesIO(png))
    assert img.mode == "L", img.mode  # one 8-bit grey channel: the level itself, no palette or colour
    return np.asarray(img)


def test_the_index_names_the_stacks_frames_colours_and_size(server, done):
    jid = done["job"]["id"]
    with server.client("reader") as c:
        r = c.get(f"/v1/jobs/{jid}/phase")
        job = c.get(f"/v1/jobs/{jid}").json()
    assert r.status_code == 200, r.text
    idx = r.json()
    assert idx["shape"] == [2, 3, 24, 40] == list(done["phase"].shape)
    assert (idx["frames"], idx["height_px"], idx["width_px"]) == (2, 24, 40)
    assert [(c["index"], c["name"], c["wavelength_nm"]) for c in idx["colours"]] == [
        (0, "red", 638.0), (1, "green", 520.0), (2, "blue", 450.0)]
    assert idx["levels_per_2pi"] == 256
    assert idx["frame_url"].format(frame=1, colour=2) == f"/v1/jobs/{jid}/phase/1/2.png"
    assert job["links"]["phase"] == f"/v1/jobs/{jid}/phase"


def test_each_png_is_the_8_bit_frame_the_slm_gets(server, done):
    from holocore.formats.levels import phase_to_u8

    jid = done["job"]["id"]
    quantised = phase_to_u8(done["phase"])
    assert np.array_equal(quantised, done["u8"])  # the stack's own 8-bit frames are its phase quantised
    seen = {}
    with server.client("reader") as c:
        for f in range(2):
            for col in range(3):
                r = c.get(f"/v1/jobs/{jid}/phase/{f}/{col}.png")
                assert r.status_code == 200 and r.headers["content-type"] == "image/png", r.text
                grey = _grey(r.content)
                assert grey.shape == (24, 40) and grey.dtype == np.uint8
                assert np.array_equal(grey, _grey(done["zip"].read(f"f{f:03d}_c{col}.png")))
                assert np.array_equal(grey, quantised[f, col]), (f, col)
                seen[f, col] = grey
                again = c.get(f"/v1/jobs/{jid}/phase/{f}/{col}.png", headers={"If-None-Match": r.headers["etag"]})
                assert again.status_code == 304
    # every frame and colour is its own pattern (a route that ignored an index would repeat one), and the
    # levels span the phase circle rather than a sliver of it
    assert len({g.tobytes() for g in seen.values()}) == 6
    assert all(g.max() - g.min() > 128 for g in seen.values())


@pytest.mark.parametrize("frame, colour, status, words", [
    (2, 0, 404, "has 2 frame(s), 0..1; no frame 2"),
    (0, 3, 404, "has 3 colour(s), 0..2; no colour 3"),
    (1000, 0, 404, "no frame 1000"),
    (-1, 0, 422, "frame"),
    (0, -1, 422, "colour"),
    ("one", 0, 422, "frame"),
])
def test_a_frame_or_colour_outside_the_stack_is_a_one_line_refusal(server, done, frame, colour, status, words):
    with server.client("reader") as c:
        r = c.get(f"/v1/jobs/{done['job']['id']}/phase/{frame}/{colour}.png")
    assert r.status_code == status, r.text
    detail = r.json()["detail"]
    assert words in detail and "\n" not in detail and "Traceback" not in detail, detail


def test_another_owners_job_is_not_found_and_an_unfinished_one_has_no_frames(server, done):
    from service.auth import create_token
    from service.db import Database

    jid = done["job"]["id"]
    other = create_token(Database(server.data_dir / "service.db"), scopes=["submit"], name="t", owner="lab2")[1]
    with server.client(other) as c:
        for path in (f"/v1/jobs/{jid}/phase", f"/v1/jobs/{jid}/phase/0/0.png"):
            r = c.get(path)
            assert r.status_code == 404 and r.json()["detail"] == f"no job {jid!r}", r.text
    with server.client("submit") as c:
        r = c.post("/v1/jobs", json={"scene_id": done["scene_id"], **JOB, "frames": 1, "render_time_limit_s": 300})
        assert r.status_code == 202, r.text
        queued = r.json()["id"]
        assert c.delete(f"/v1/jobs/{queued}").status_code == 202
        for path in (f"/v1/jobs/{queued}/phase", f"/v1/jobs/{queued}/phase/0/0.png"):
            r = c.get(path)
            assert r.status_code == 409 and "is cancelled" in r.json()["detail"], r.text
    with server.client(None) as c:
        assert c.get(f"/v1/jobs/{jid}/phase/0/0.png").status_code == 401


def _vm_hwm_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return next(int(ln.split()[1]) for ln in fh if ln.startswith("VmHWM:"))


def _as_the_job_left_it(server, jid: str, name: str, data: bytes):
    """Put ``data`` in the job's folder as ``name`` with the hash the scheduler would have recorded had the job
    written it so (whatever a job leaves is hashed as it is); a context manager restoring the original."""
    import contextlib
    import hashlib

    from service.db import Database

    db = Database(server.data_dir / "service.db")
    row = db.get_job(jid)
    path = server.data_dir / "jobs" / jid / name
    before, was = path.read_bytes(), {k: row[k] for k in ("artifacts", "stack_sha256")}
    sha = hashlib.sha256(data).hexdigest()
    path.write_bytes(data)
    db.update_job(jid, artifacts={**row["artifacts"], name: {"sha256": sha, "bytes": len(data)}},
                  **({"stack_sha256": sha} if name == "stack.npz" else {}))

    @contextlib.contextmanager
    def restored():
        try:
            yield
        finally:
            path.write_bytes(before)
            db.update_job(jid, **was)
    return restored()


@pytest.mark.parametrize("bomb", ["deflated", "stored"])
def test_a_frame_member_past_what_the_jobs_size_allows_is_refused_before_it_is_inflated(server, done, bomb):
    """A 1 MB frames.zip whose member inflated to 1 GiB took the API from 76 MB to 2.2 GB on one frame request:
    a member is checked (stored, as the worker writes it, and no larger than a 24 x 40 PNG can be) first."""
    jid = done["job"]["id"]
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name in done["zip"].namelist():
            big = name == "f000_c0.png"
            data = b"\0" * ((256 << 20) if bomb == "deflated" else (2 << 20)) if big else done["zip"].read(name)
            zf.writestr(name, data, compress_type=zipfile.ZIP_DEFLATED if bomb == "deflated" and big
                        else zipfile.ZIP_STORED)
    assert len(buf.getvalue()) < 3 << 20
    hwm = _vm_hwm_kb(server.proc.pid)
    with _as_the_job_left_it(server, jid, "frames.zip", buf.getvalue()), server.client("reader") as c:
        r = c.get(f"/v1/jobs/{jid}/phase/0/0.png")
        assert r.status_code == 409, r.status_code
        assert ("compressed" if bomb == "deflated" else "more than the job's size allows") in r.json()["detail"]
        ok = c.get(f"/v1/jobs/{jid}/phase/1/2.png")  # the job's other members are served as they are
        assert ok.status_code == 200 and ok.content == done["zip"].read("f001_c2.png")
    assert _vm_hwm_kb(server.proc.pid) - hwm < 128 << 10  # never near the member's 256 MiB


def test_a_stack_with_compressed_members_has_no_phase_index(server, done):
    """The index read the stack's frames_u8 header; a compressed member was loaded whole to find it."""
    jid = done["job"]["id"]
    buf = io.BytesIO()
    with server.client("reader") as c:
        stack = c.get(f"/v1/jobs/{jid}/stack").content
    with np.load(io.BytesIO(stack), allow_pickle=False) as z:
        np.savez_compressed(buf, **{k: z[k] for k in z.files})
    with _as_the_job_left_it(server, jid, "stack.npz", buf.getvalue()), server.client("reader") as c:
        r = c.get(f"/v1/jobs/{jid}/phase")
        assert r.status_code == 409 and "compressed" in r.json()["detail"], r.text
    with server.client("reader") as c:
        assert c.get(f"/v1/jobs/{jid}/phase").json()["shape"] == [2, 3, 24, 40]
