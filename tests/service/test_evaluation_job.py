"""A job that asks for an evaluation against ground truth (``evaluate: true``), over HTTP against a real `holo
serve`: it succeeds, its evaluation has one entry per depth of the focal sweep the page's slider walks (each
with the sweep's picture at that depth), a 3 x 3 view grid and the viewer-faithful score (two frames); the
numbers it reports for a depth are those of that depth (the test renders the ground truth and views the served
stack itself, and decodes the served PNGs); a job without it, or not finished, answers 404; the estimate counts it.

The job is small (96 x 128 px, two frames, the fast preset at 16 rays per pixel, 40 SGD iterations) with virtual
infinity at 4 mm, so that the SLM lights part of every view (at the paper display's 80 mm an image point
gathers light from 160 px around through the evaluation's 1.6 mm pupil). At 64 rows the demo scene renders with
blue 100x too dark (a renderer matter outside this test), hence 96. At this size the hologram's views are
dominated by Monte Carlo noise (about 6.5 dB against the ground truth) and score no better in focus than out of
it (6.5 dB focused on the wall at 1.5 m, 6.9 dB at 0.28 m, where the ground truth blurs as much as the noise):
so the test asserts what is physically true here, that the ground truth is sharpest where the wall is in focus.
"""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest


EVAL_JOB = {"optics": {"resolution_hw": [96, 128], "seed": 3, "z_inf_mm": 4}, "preset": "fast", "frames": 2,
            "spp": 16, "encoder": "sgd", "iterations": 40, "wrp_planes": 1, "name": "evaluated"}


# The session's one evaluated job (tests/service/conftest.py), which tests/service/test_web_evaluation.py can share.
@pytest.fixture(scope="module")
def server(evaluation_server):
    return evaluation_server


@pytest.fixture(scope="module")
def demo(evaluation_demo):
    return evaluation_demo


@pytest.fixture(scope="module")
def scene(evaluation_scene):
    return evaluation_scene


@pytest.fixture(scope="module")
def evaluated(evaluated_job) -> dict:
    """The finished evaluated job, and what its evaluation route answered right after the submit."""
    return evaluated_job


def _index(server, job_id: str) -> dict:
    with server.client("reader") as c:
        r = c.get(f"/v1/jobs/{job_id}/evaluation")
        assert r.status_code == 200, r.text
        return r.json()


def _png(server, url: str) -> np.ndarray:
    from PIL import Image

    with server.client("reader") as c:
        r = c.get(url)
        assert r.status_code == 200 and r.headers["content-type"] == "image/png", (url, r.status_code, r.text[:200])
        return np.asarray(Image.open(io.BytesIO(r.content)).convert("RGB"))


@pytest.mark.slow
def test_an_evaluated_job_scores_every_depth_of_its_sweep(server, evaluated):
    job = evaluated["job"]
    early = evaluated["early"]
    assert early.status_code == 404 and "when it has succeeded" in early.json()["detail"], early.text
    assert not [w for w in (job["plan"] or {}).get("warnings", []) if "evaluation" in w or "viewer" in w]
    assert job["links"]["evaluation"] == f"/v1/jobs/{job['id']}/evaluation"
    assert job["timings"]["evaluate_s"] > 0 and job["options"]["evaluate"] is True
    idx = _index(server, job["id"])
    with server.client("reader") as c:
        sweep = c.get(f"/v1/jobs/{job['id']}/pictures").json()["sweep"]["pictures"]
        logs = {x["step"] for x in c.get(f"/v1/jobs/{job['id']}/logs").json()["logs"]}
        log = c.get(f"/v1/jobs/{job['id']}/logs/evaluate").text
    assert "evaluate" in logs and "mean over 17 cells" in log and "one scale per colour" in log
    # one entry per slider position, at the sweep picture's own depth
    assert [f["index"] for f in idx["focus"]] == list(range(len(sweep))) and len(sweep) == 9
    for f, p in zip(idx["focus"], sweep):
        assert f["z_mm"] == p["z_mm"] and f["words"] == p["words"] and f["sweep_url"].endswith("/" + p["file"])
        assert f["skipped"] is None and math.isfinite(f["psnr_db"]) and 0 < f["ssim"] <= 1
        assert f["truth_url"].endswith(f"truth-f{f['index']:02d}-v04.png")
        assert f["hologram_url"].endswith(f"recon-f{f['index']:02d}-v04.png")
    assert 1.0 < idx["pupil_mm"] < 2.0 and idx["gt_spp"] == 32 and idx["views"] == 3
    # the view grid at the middle depth: nine eyes, the centre one the middle depth's centre view
    grid = idx["view_grid"]
    assert len(grid) == 9 and {(v["col"], v["row"]) for v in grid} == {(c, r) for c in range(3) for r in range(3)}
    mid = idx["focus"][4]
    assert all(v["focus_mm"] == mid["z_mm"] for v in grid)
    centre = next(v for v in grid if (v["col"], v["row"]) == (1, 1))
    assert centre["offset_mm"] == [0.0, 0.0] and centre["psnr_db"] == mid["psnr_db"]
    assert next(v for v in grid if (v["col"], v["row"]) == (0, 0))["offset_mm"][0] < 0  # left, up
    assert next(v for v in grid if (v["col"], v["row"]) == (0, 0))["offset_mm"][1] > 0
    # two frames: the viewer-faithful score, over 2 pupils x a 3 x 3 eye grid at the middle depth
    v = idx["viewer"]
    assert v is not None and v["cells"] == 18 and [p["pupil_mm"] for p in v["pupils"]] == [2.0, 4.0]
    assert v["focus_mm"] == [mid["z_mm"]] and math.isfinite(v["mean_psnr_db"]) and v["scale_spread"] >= 1


@pytest.mark.slow
def test_the_scores_of_a_depth_are_those_of_its_pictures(server, evaluated, demo):
    """For the sweep's far end, middle and near end: the test renders the ground truth at the entry's depth and
    views the served stack there itself; the reported PSNR and SSIM are theirs, and the served PNGs are those two
    images (one white level, gamma 2.2). A ground truth or view of another depth (a sweep read near to far, an
    index off by one) fails: neighbouring depths' ground truths differ by far more than a grey level."""
    from holocore.evaluate.preview import to_png8
    from holocore.evaluate.score_files import to_rgb
    from holocore.evaluate.scoring import compare, eye_view
    from holocore.io import load_stack
    from holocore.evaluate.truths import DEFAULT_TRUTH, ground_truth
    from holocore.scene.load import load_scene
    from service.workers.evaluation import GT_SPP

    job = evaluated["job"]
    idx = _index(server, job["id"])
    with server.client("reader") as c:
        r = c.get(job["links"]["stack"])
        assert r.status_code == 200
    stack = demo["tmp"] / "evaluated-stack.npz"
    stack.write_bytes(r.content)
    phase, _, meta = load_stack(stack)
    field = np.exp(1j * phase.astype(np.float32)).astype(np.complex64)
    field *= np.sqrt(np.asarray(meta["encoder"]["illumination"], dtype=np.float32))[..., None, None]
    # the truth `holo evaluate` takes by default, as the service runs it
    truth = ground_truth(DEFAULT_TRUTH, load_scene(demo["dir"]), meta, shape_hw=tuple(phase.shape[-2:]), spp=GT_SPP)
    lams = meta["wavelengths_m"]
    pupil = idx["pupil_mm"] * 1e-3
    white, gamma = idx["white"], idx["gamma"]
    reported = {}
    for i in (0, 4, 8):
        f = idx["focus"][i]
        z = f["z_mm"] * 1e-3
        rec = eye_view(field, meta, focus_z_m=z, pupil_diameter_m=pupil)
        gt = truth.channels(focus_z_m=z, pupil_diameter_m=pupil)
        m = f["margin_px"]
        H, W = rec.shape[-2:]
        score = compare(rec[:, m:H - m, m:W - m], gt[:, m:H - m, m:W - m])
        assert score.psnr_db == pytest.approx(f["psnr_db"], abs=0.02), (i, score, f)
        assert score.ssim == pytest.approx(f["ssim"], abs=0.002), (i, score, f)
        served_truth, served_holo = _png(server, f["truth_url"]), _png(server, f["hologram_url"])
        own_truth = to_png8(to_rgb(gt, lams), white=white)
        own_holo = to_png8(to_rgb(rec * score.scale, lams), white=white)
        assert np.abs(served_truth.astype(int) - own_truth).max() <= 1, i
        assert np.abs(served_holo.astype(int) - own_holo).max() <= 1, i
        # the two served PNGs alone give the reported PSNR, to their 8 bits
        lin = [(x.astype(np.float64) / 255.0) ** gamma for x in (served_holo, served_truth)]
        r_, g_ = (np.moveaxis(x, -1, 0)[:, m:H - m, m:W - m] for x in lin)
        assert compare(r_, g_).psnr_db == pytest.approx(f["psnr_db"], abs=0.3), i
        reported[i] = (own_truth, gt)
    # a neighbouring depth's ground truth is no stand-in: far more than a grey level apart
    assert np.abs(reported[0][0].astype(int) - reported[4][0]).max() > 8
    # the ground truth is sharpest focused on the wall (the far end, 1.5 m), blurred at the near end

    def sharpness(img):
        lum = img.mean(axis=0)[27:-27, 27:-27]
        gy, gx = np.gradient(lum)
        return float(np.mean(gx ** 2 + gy ** 2))

    assert idx["focus"][0]["words"] == "scene distance 1.5 m"
    assert sharpness(reported[0][1]) > 1.3 * sharpness(reported[8][1])


@pytest.mark.slow
def test_a_job_without_an_evaluation_answers_404_and_the_files_are_checked(server, scene, evaluated):
    from service.auth import create_token
    from service.db import Database

    jid = evaluated["job"]["id"]
    with server.client("submit") as c:
        plain = c.post("/v1/jobs", json={"scene_id": scene["id"], **EVAL_JOB, "name": "plain"}).json()
        r = c.get(f"/v1/jobs/{plain['id']}/evaluation")
        assert r.status_code == 404 and "did not ask for an evaluation" in r.json()["detail"], r.text
        assert c.get(f"/v1/jobs/{plain['id']}/evaluation/truth-f00-v04.png").status_code == 404
        assert c.delete(f"/v1/jobs/{plain['id']}").status_code == 202
        assert c.get(f"/v1/jobs/{plain['id']}").json()["links"].get("evaluation") is None
        for bad in ("truth-f00-v04.png.bak", "..%2Findex.json", "index.json", "truth-f0-v04.png", "TRUTH-f00-v04.png"):
            assert c.get(f"/v1/jobs/{jid}/evaluation/{bad}").status_code in (404, 422), bad
        assert c.get(f"/v1/jobs/{jid}/evaluation/truth-f09-v04.png").status_code == 404  # no such cell
        ok = c.get(f"/v1/jobs/{jid}/evaluation/truth-f04-v00.png")
        assert ok.status_code == 200 and ok.content.startswith(b"\x89PNG\r\n\x1a\n")
        assert ok.headers["content-disposition"].startswith("inline")
        assert c.get(f"/v1/jobs/{jid}/evaluation/truth-f04-v00.png",
                     headers={"If-None-Match": ok.headers["etag"]}).status_code == 304
    other = create_token(Database(server.data_dir / "service.db"), scopes=["read"], name="t", owner="lab2")[1]
    with server.client(other) as c:
        assert c.get(f"/v1/jobs/{jid}/evaluation").status_code == 404
        assert c.get(f"/v1/jobs/{jid}/evaluation/truth-f04-v00.png").status_code == 404
    # a picture altered on disk is not served
    folder = server.data_dir / "jobs"
    path = next(folder.rglob("evaluation/pairs/truth-f04-v00.png"))
    data = path.read_bytes()
    try:
        path.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))
        with server.client("reader") as c:
            assert c.get(f"/v1/jobs/{jid}/evaluation/truth-f04-v00.png").status_code == 409
    finally:
        path.write_bytes(data)


@pytest.mark.slow
def test_the_estimate_counts_the_evaluation(server, scene):
    with server.client("submit") as c:
        without = c.post("/v1/jobs/estimate", json={"scene_id": scene["id"], **EVAL_JOB})
        with_ev = c.post("/v1/jobs/estimate", json={"scene_id": scene["id"], **EVAL_JOB, "evaluate": True})
    assert without.status_code == 200 and with_ev.status_code == 200, (without.text, with_ev.text)
    a, b = without.json()["estimate"], with_ev.json()["estimate"]
    assert "evaluate_s" not in a and b["evaluate_s"] > 0
    assert b["seconds"] > a["seconds"] and b["seconds"] == pytest.approx(a["seconds"] + b["evaluate_s"], abs=0.15)


def test_progress_gives_the_evaluation_its_share(tmp_path):
    """A job with an evaluation: the other steps fill 75 % of the bar, its two parts (cells, viewer) the rest."""
    from service.workers.runfiles import EVALUATE_WEIGHT, read_progress

    (tmp_path / "job.json").write_text(json.dumps({"evaluate": True}))
    (tmp_path / "step.json").write_text(json.dumps({"step": "encode"}))
    (tmp_path / "progress-encode.jsonl").write_text(json.dumps({"stage": "encode", "done": 1, "total": 2}) + "\n")
    assert read_progress(tmp_path)["fraction"] == pytest.approx((0.75 + 0.15 * 0.5) * (1 - EVALUATE_WEIGHT), abs=1e-4)
    (tmp_path / "step.json").write_text(json.dumps({"step": "evaluate", "stages": ["evaluate", "viewer"], "part": 1}))
    (tmp_path / "progress-evaluate.jsonl").write_text(json.dumps({"stage": "load", "done": 1, "total": 1}) + "\n")
    assert read_progress(tmp_path)["fraction"] == pytest.approx(1 - EVALUATE_WEIGHT / 2, abs=1e-4)
    with open(tmp_path / "progress-evaluate.jsonl", "a") as fh:
        fh.write(json.dumps({"stage": "viewer", "done": 9, "total": 18}) + "\n")
    assert read_progress(tmp_path)["fraction"] == pytest.approx(1 - EVALUATE_WEIGHT / 4, abs=1e-4)
    (tmp_path / "job.json").write_text(json.dumps({"evaluate": False}))
    (tmp_path / "step.json").write_text(json.dumps({"step": "preview"}))
    (tmp_path / "progress-preview.jsonl").write_text(json.dumps({"stage": "sweep", "done": 18, "total": 18}) + "\n")
    assert read_progress(tmp_path)["fraction"] == 0.999


def test_the_estimate_warns_when_the_slm_is_too_small_to_evaluate(server, scene):
    """On the paper display (virtual infinity 80 mm) the scored border of a 1.6 mm pupil is about 160 px at
    every depth, so a 270x480 SLM has nothing to score: the estimate says so before the submit, and names the
    smallest side that has; at the test job's optics (virtual infinity 4 mm) it says nothing."""
    import re

    from holocore.display.profiles import load_display
    from service.workers.evaluation import evaluation_too_small

    small = {"scene_id": scene["id"], "optics": {"resolution_hw": [270, 480]}, "frames": 2, "preset": "fast",
             "evaluate": True}
    with server.client("submit") as c:
        warned = c.post("/v1/jobs/estimate", json=small).json()["warnings"]
        quiet = c.post("/v1/jobs/estimate", json={"scene_id": scene["id"], **EVAL_JOB, "evaluate": True}).json()
        unasked = c.post("/v1/jobs/estimate", json={**small, "evaluate": False}).json()
    # (the estimate's other warnings are of the quality the options buy: service/quality.py)
    warned = [w for w in warned if "evaluation" in w]
    assert len(warned) == 1 and "no evaluation at 270x480 px" in warned[0], warned
    assert not [w for w in quiet["warnings"] + unasked["warnings"] if "evaluation" in w]
    need = int(re.search(r"at least (\d+) px", warned[0]).group(1))
    paper = load_display("paper")
    assert evaluation_too_small(paper.optics(resolution_hw=(need - 1, 2 * need))) is not None
    assert evaluation_too_small(paper.optics(resolution_hw=(need, 2 * need))) is None
    assert 300 < need < 400  # 2 ceil(80 mm x 0.0161 / 8 um) + 16
