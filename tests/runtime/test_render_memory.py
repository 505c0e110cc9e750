"""Bounded memory: render, view and evaluate in chunks of frames and colors, streamed to and
from the files, equal to the unchunked path; the budget that sizes the chunks; the streaming file format."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
import torch

from holocore.display.optics import OpticsConfig
from holocore.io import (
    NpyMember,
    NpzWriter,
    ScratchArray,
    load_result,
    load_stack,
    save_result,
    save_stack,
)
from holocore.runtime.membudget import ENV, frames_per_chunk, memory_budget_bytes
from holocore.scene.demo import write_demo_scene

SMALL = 256 << 20  # the smallest budget: one frame per trace pass and per propagation chunk


def _close(a, b, rel=1e-6):
    """Equal to float32 rounding: max |a - b| within rel of max |a|."""
    scale = float(np.abs(a).max())
    assert scale > 0
    assert float(np.abs(a - b).max()) <= rel * scale, float(np.abs(a - b).max()) / scale


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    return write_demo_scene(tmp_path_factory.mktemp("demo") / "scene").parent


@pytest.mark.slow
@pytest.mark.parametrize("method, planes", [("wrp", 1), ("direct", 1), ("wrp", 3)])
def test_streamed_chunked_render_equals_the_unchunked_one(demo, tmp_path, method, planes):
    from holocore.pipeline import RenderOptions, render, render_to_file

    # f = 20 mm: this small view holds the wall and two objects at other depths (several planes have work)
    optics = OpticsConfig(resolution_hw=(36, 48), frames=3, seed=5, **({"focal_length_mm": 20.0} if planes > 1 else {}))
    opts = RenderOptions(preset="fast", method=method, wrp_planes=planes)
    ref = render(demo, optics, opts)  # in memory, default budget: one trace pass, one propagation chunk
    assert ref.meta["memory"]["trace_passes"] == 1 and ref.meta["memory"]["frames_per_propagation_chunk"] == 3
    assert len(ref.meta["wrp_planes_m"]) == planes if planes == 1 else len(ref.meta["wrp_planes_m"]) > 1
    out = tmp_path / "RESULT.npz"
    meta = render_to_file(demo, out, optics, opts, memory_budget_bytes=SMALL)
    mem = meta["memory"]
    assert mem["trace_passes"] == 3 and mem["frames_per_trace_pass"] == 1 and mem["frames_per_propagation_chunk"] == 1
    assert mem["streamed"] and mem["budget_bytes"] == SMALL
    with np.load(out, allow_pickle=False) as z:  # numpy alone reads it
        assert set(z.files) == {"slm_field", "wrp_field", "meta"}
        slm, wrp = z["slm_field"], z["wrp_field"]
    assert slm.dtype == wrp.dtype == np.complex64 and slm.shape == wrp.shape == (3, 3, 36, 48)
    _close(ref.slm_field, slm)
    _close(ref.wrp_field, wrp)
    # each frame has its own random phase: the frames differ, the chunked passes did not repeat frame 0
    assert np.abs(wrp[1] - wrp[0]).max() > 0.1 * np.abs(wrp).max()
    # the same rays: the ray statistics of the first pass are the whole render's
    for k in ("rays", "valid", "escaped", "capped", "delta_paths", "max_delta_seen"):
        assert meta["stats"][k] == ref.meta["stats"][k]
    s2, w2, m2 = load_result(out)
    assert np.array_equal(s2, slm) and m2["z_wrp_m"] == meta["z_wrp_m"]
    assert np.array_equal(NpyMember(out, "wrp_field").read_fc(1, 3, 2), wrp[1:3, 2])


@pytest.mark.slow
def test_the_phase_bank_is_freed_before_the_slm_propagation(demo, tmp_path, monkeypatch):
    # The chunk planner sizes the WRP -> SLM propagation without the trace pass's phase bank (F x C complex64
    # frames: 1.2 GB at the paper's size). A closure that kept it alive put the full-size render 1 GB over
    # the planner's estimate; every ASM of a one-plane render is that propagation, and none may see a bank.
    import gc
    import weakref

    import holocore.optics.propagation as prop
    import holocore.pipeline as pipeline
    import holocore.render_passes as passes

    banks, alive_at_asm = [], []
    make_banks = passes.frame_banks

    def tracked_banks(*a, **k):
        out = make_banks(*a, **k)
        banks.extend(weakref.ref(t) for t in out)
        return out

    def spy(fn):
        def run(*a, **k):
            gc.collect()
            alive_at_asm.append(sum(r() is not None for r in banks))
            return fn(*a, **k)
        return run

    monkeypatch.setattr(passes, "frame_banks", tracked_banks)
    import holocore.render_setup as setup

    for name in ("asm", "asm_to"):  # the plain ASM and the one that gives the cut field and its propagation
        for module in (prop, passes, setup):  # every module that holds the name
            if hasattr(module, name):
                monkeypatch.setattr(module, name, spy(getattr(module, name)))
    optics = OpticsConfig(resolution_hw=(24, 32), frames=2, seed=3)
    pipeline.render_to_file(demo, tmp_path / "RESULT.npz", optics,
                            pipeline.RenderOptions(preset="fast", wrp_planes=1, cone_equaliser=False))
    assert banks and alive_at_asm and max(alive_at_asm) == 0, alive_at_asm


def test_budget_from_keyword_env_and_default(monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    assert memory_budget_bytes() == 8192 << 20
    monkeypatch.setenv(ENV, "3000")
    assert memory_budget_bytes() == 3000 << 20
    assert memory_budget_bytes(1 << 30) == 1 << 30  # the keyword wins
    for bad in ("lots", "10"):
        monkeypatch.setenv(ENV, bad)
        with pytest.raises(ValueError, match=ENV):
            memory_budget_bytes()
    with pytest.raises(ValueError):
        memory_budget_bytes(1 << 20)
    # chunks: as many frames as fit, at least one, at most all
    assert frames_per_chunk(24, per_frame_bytes=100e6, fixed_bytes=1e9, budget_bytes=int(3e9)) == 14
    assert frames_per_chunk(24, per_frame_bytes=100e6, fixed_bytes=1e9, budget_bytes=int(1e9)) == 1
    assert frames_per_chunk(5, per_frame_bytes=1, fixed_bytes=0, budget_bytes=int(1e9)) == 5
    assert frames_per_chunk(24, per_frame_bytes=1, fixed_bytes=0, budget_bytes=int(1e9), cap=4) == 4


def test_npz_writer_streams_a_numpy_readable_file_and_reads_old_ones(tmp_path):
    rng = np.random.default_rng(0)
    a = (rng.standard_normal((4, 3, 5, 7)) + 1j * rng.standard_normal((4, 3, 5, 7))).astype(np.complex64)
    out = tmp_path / "x.npz"
    with ScratchArray(a.shape, a.dtype, dir=tmp_path) as s:
        s.write_rows(0, [0, 1, 2], 0, a[:, :, :2])  # rows 0..1 of every frame and color
        s.write_rows(0, [2, 0, 1], 2, a[:, [2, 0, 1], 2:])  # the rest, colors in another order
        assert np.array_equal(s.read_fc(1, 4, 2), a[1:4, 2])
        with NpzWriter(out) as w:
            st = w.stream("slm_field", a.shape, a.dtype)
            st.write(a[:1])
            st.write(a[1:])
            st.close()
            w.copy_from("wrp_field", s)
            w.add("meta", np.array(json.dumps({"k": 1})))
    assert [p.name for p in tmp_path.iterdir()] == ["x.npz"]  # no scratch or temp file left
    with np.load(out) as z:
        assert np.array_equal(z["slm_field"], a) and np.array_equal(z["wrp_field"], a)
        assert json.loads(str(z["meta"])) == {"k": 1}
    # files written by np.savez (the old format) and np.savez_compressed read slab by slab too
    np.savez(tmp_path / "old.npz", phase=a.real)
    np.savez_compressed(tmp_path / "zip.npz", phase=a.real)
    for name in ("old.npz", "zip.npz"):
        assert np.array_equal(NpyMember(tmp_path / name, "phase").read_fc(2, 4, 1), a.real[2:4, 1])
    # a member left short fails and leaves no file behind
    with pytest.raises(ValueError, match="bytes written"):
        with NpzWriter(tmp_path / "short.npz") as w:
            st = w.stream("x", (2, 3), np.float32)
            st.write(np.zeros(3, np.float32))
            st.close()
    assert not (tmp_path / "short.npz").exists() and len(list(tmp_path.iterdir())) == 3
    with zipfile.ZipFile(out) as zf:
        assert all(i.compress_type == zipfile.ZIP_STORED for i in zf.infolist())


def _stack(tmp_path, F=5, C=3, H=40, W=48):
    rng = np.random.default_rng(1)
    # a smooth phase (a lens focusing 2 mm away) plus noise, and unequal laser powers per frame and color
    y, x = np.mgrid[:H, :W]
    r2 = ((x - W / 2) ** 2 + (y - H / 2) ** 2) * (8e-6) ** 2
    phase = np.stack([np.stack([(-np.pi * r2 / (lam * 2e-3) + rng.uniform(0, 0.5, (H, W)))
                                for lam in (638e-9, 520e-9, 450e-9)[:C]]) for _ in range(F)])
    power = rng.uniform(0.5, 1.5, (F, C))
    meta = {"focal_length_m": 0.05, "z_inf_m": 1e-3, "z_wrp_m": 3e-3, "pitch_m": 8e-6,
            "wavelengths_m": [638e-9, 520e-9, 450e-9][:C], "encoder": {"illumination": power.tolist()}}
    save_stack(tmp_path / "STACK.npz", phase=phase, meta=meta)
    return tmp_path / "STACK.npz", meta


@pytest.mark.slow
def test_chunked_views_equal_the_unchunked_ones(tmp_path):
    from holocore.evaluate.preview import views_rgb
    from holocore.evaluate.scoring import eye_view, load_slm_field
    from holocore.optics.fieldsource import open_slm_field
    from holocore.optics.viewing import simulate_view

    path, meta = _stack(tmp_path)
    full, meta2, kind = load_slm_field(path)  # the whole field in memory (the old path)
    src = open_slm_field(path)
    assert kind == src.kind == "stack" and src.shape == full.shape
    assert np.array_equal(src.to_array(), full)  # chunks hold the same values
    depths = [2e-3, 3e-3]
    # the stack names no display, so no filter: the preview also shows the SLM pixels' diffraction orders
    ref = [simulate_view(torch.from_numpy(full), wavelengths_m=meta["wavelengths_m"], pitch_m=8e-6,
                         focal_length_m=0.05, pupil_diameter_m=3e-3, distance_m=z, pixel_orders=True).numpy()
           for z in depths]
    got = views_rgb(src, meta2, focus_z_m=depths, pupil_diameter_m=3e-3, memory_budget_bytes=SMALL)
    for r, g in zip(ref, got):
        rgb = np.stack([r[0], r[1], r[2]], axis=-1)
        _close(rgb, g, rel=1e-5)
    # the lens focuses at 2 mm: sharper (higher peak) there than at 3 mm
    assert got[0].max() > 3 * got[1].max()
    # an off-axis eye (the shifted view of evaluate), chunked from the file vs in memory
    e = (0.4e-3, -0.3e-3)
    a = eye_view(full, meta2, focus_z_m=2.5e-3, pupil_diameter_m=3e-3, view_offset_m=e)
    b = eye_view(src, meta2, focus_z_m=2.5e-3, pupil_diameter_m=3e-3, view_offset_m=e, memory_budget_bytes=SMALL)
    _close(a, b, rel=1e-5)
    # quantized and equal-power views read the same stack
    q = open_slm_field(path, quantized=True, equal_power=True).chunk(0, 2, 1)
    phase, _, _ = load_stack(path)
    assert np.allclose(np.angle(q * np.exp(-1j * phase[:2, 1])), 0, atol=2 * np.pi / 256)
    assert np.allclose(np.abs(q), 1, atol=1e-6)


def test_phase_bank_chunks_are_slices_of_the_whole():
    from holocore.trace.randomfield import phase_bank

    whole = phase_bank(6, (16, 20), 520e-9, 8e-6, seed=3)
    assert torch.equal(phase_bank(2, (16, 20), 520e-9, 8e-6, seed=3, first_frame=4), whole[4:])


def test_device_choice(monkeypatch):
    from holocore.runtime import device

    monkeypatch.delenv(device.ENV, raising=False)
    assert device.requested_device() == "auto"
    monkeypatch.setenv(device.ENV, "CUDA:1")
    assert device.requested_device() == "cuda:1"
    with pytest.raises(ValueError, match="--device"):
        device.requested_device("gpu")
    assert device.select_device("cpu") == "cpu" and device.requested_device() == "cpu"
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="no CUDA"):
            device.select_device("cuda")
        monkeypatch.setenv(device.ENV, "auto")
        assert device.select_device() == "cpu"


def test_small_results_still_save_and_load(tmp_path):
    a = np.ones((1, 1, 4, 4), np.complex64)
    save_result(tmp_path / "r.npz", slm_field=a, wrp_field=2 * a, meta={"focal_length_m": 1, "z_inf_m": 0,
                                                                        "z_wrp_m": 1, "pitch_m": 1,
                                                                        "wavelengths_m": [5e-7]})
    s, w, m = load_result(tmp_path / "r.npz")
    assert np.array_equal(w, 2 * a) and np.array_equal(NpyMember(tmp_path / "r.npz", "wrp_field").read_fc(0, 1, 0), w[:, 0])


def test_encode_takes_its_device_from_holo_device_like_render(tmp_path, monkeypatch):
    """`holo encode` without --device follows HOLO_DEVICE (one rule for every command): a bad value is one line."""
    from typer.testing import CliRunner

    from holo.app import app

    res_path = tmp_path / "RESULT.npz"
    f = np.zeros((1, 1, 8, 8), np.complex64)
    save_result(res_path, slm_field=f, wrp_field=f, meta={"focal_length_m": 0.05, "z_inf_m": 0.08, "z_wrp_m": 0.081,
                                                          "pitch_m": 8e-6, "wavelengths_m": [5.2e-7]})
    monkeypatch.setenv("HOLO_DEVICE", "gpu")
    out = CliRunner().invoke(app, ["encode", str(res_path), "--out", str(tmp_path / "S.npz"), "--iterations", "1"])
    assert out.exit_code != 0
    assert "HOLO_DEVICE must be auto, cpu, cuda or cuda:N" in out.output and "Traceback" not in out.output


def test_an_error_while_a_member_is_open_is_the_callers_and_leaves_no_file(tmp_path):
    """The writer used to close the zip on the way out with the member still open, and zipfile's "Can't close
    the ZIP file while there is an open writing handle" replaced the real error (a render failed that way)."""
    out = tmp_path / "r.npz"
    with pytest.raises(KeyError, match="the caller's error"):
        with NpzWriter(out) as w:
            s = w.stream("slm_field", (1, 1, 4, 4), np.complex64)
            s.write(np.zeros((1, 1, 2, 4), np.complex64))
            raise KeyError("the caller's error")
    assert list(tmp_path.iterdir()) == []
