"""Stack checks (never accept a damaged or inconsistent file), the cache, and the backoff schedule."""

from __future__ import annotations

import io
import json
import random
import zipfile

import numpy as np
import pytest

from display_agent.backoff import Backoff
from display_agent.cache import StackCache, safe_job_id
from holocore.formats import StackError, open_stack
from holocore.io import file_sha256, save_stack
from tests.agent.helpers import WAVELENGTHS_M, make_phase


@pytest.fixture()
def stack_file(tmp_path):
    p = tmp_path / "s.npz"
    save_stack(p, phase=make_phase((2, 3, 12, 10), seed=1), meta={"wavelengths_m": WAVELENGTHS_M})
    return p


def test_open_stack_accepts_a_service_stack(stack_file):
    st = open_stack(stack_file, expected_sha256=file_sha256(stack_file))
    assert st.shape == (2, 3, 12, 10) and st.sha256 == file_sha256(stack_file)
    assert st.wavelengths_m == WAVELENGTHS_M and st.phase.dtype == np.float32


def test_open_stack_refuses_damage(stack_file, tmp_path):
    data = stack_file.read_bytes()
    with pytest.raises(StackError, match="differs from the expected"):
        open_stack(stack_file, expected_sha256="0" * 64)
    (tmp_path / "half.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(StackError, match="not a readable npz"):
        open_stack(tmp_path / "half.npz")
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0xFF  # inside the phase array: zip CRC catches it
    (tmp_path / "flip.npz").write_bytes(bytes(flipped))
    with pytest.raises(StackError):
        open_stack(tmp_path / "flip.npz")
    (tmp_path / "empty.npz").write_bytes(b"")
    with pytest.raises(StackError):
        open_stack(tmp_path / "empty.npz")


def _npz(path, **arrays):
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.write_bytes(buf.getvalue())
    return path


@pytest.mark.parametrize("case, match", [
    ("u8_shape", "frames_u8 must be uint8 of shape"),
    ("nan", "NaN"),
    ("range", r"must lie in \[0, 2pi\)"),
    ("wavelengths", "must list 3 wavelengths"),
    ("nometa", "lacks"),
    ("three_d", "non-empty"),
    ("object", "not a readable npz"),
])
def test_open_stack_refuses_inconsistent_content(tmp_path, case, match):
    ph = make_phase((1, 3, 4, 4), seed=2).astype(np.float32)
    u8 = np.zeros(ph.shape, np.uint8)
    meta = np.array(json.dumps({"wavelengths_m": WAVELENGTHS_M}))
    arrays = {"phase": ph, "frames_u8": u8, "meta": meta}
    if case == "u8_shape":
        arrays["frames_u8"] = u8[:, :2]
    elif case == "nan":
        ph[0, 0, 0, 0] = np.nan
    elif case == "range":
        ph[0, 0, 0, 0] = 7.0
    elif case == "wavelengths":
        arrays["meta"] = np.array(json.dumps({"wavelengths_m": WAVELENGTHS_M[:2]}))
    elif case == "nometa":
        del arrays["meta"]
    elif case == "three_d":
        arrays["phase"] = ph[0]
    elif case == "object":
        arrays["phase"] = np.array([{"x": 1}], dtype=object)  # would need pickles: refused
    with pytest.raises(StackError, match=match):
        open_stack(_npz(tmp_path / "x.npz", **arrays))


def test_cache_install_lookup_evict_and_damage(tmp_path, stack_file):
    cache = StackCache(tmp_path / "cache", max_stacks=2)
    shas = []
    for i in range(3):
        src = tmp_path / f"in{i}.npz"
        save_stack(src, phase=make_phase((1, 3, 4, 4), seed=10 + i), meta={"wavelengths_m": WAVELENGTHS_M})
        sha = file_sha256(src)
        shas.append(sha)
        e = cache.install(f"job{i}", src, sha256=sha, etag=f'"{sha}"')
        assert e.path.name == f"{sha}.npz" and not src.exists()  # moved, not copied
    assert cache.lookup("job0") is None and not (cache.stacks / f"{shas[0]}.npz").exists()  # evicted oldest
    assert cache.open("job2").sha256 == shas[2]
    # the index survives a restart
    again = StackCache(tmp_path / "cache", max_stacks=2)
    assert again.lookup("job1").etag == f'"{shas[1]}"'
    # a damaged cached file is detected on open and removed, never returned
    p = again.lookup("job1").path
    b = bytearray(p.read_bytes())
    b[100] ^= 1
    p.write_bytes(bytes(b))
    with pytest.raises(StackError, match="differs from the expected"):
        again.open("job1")
    assert again.lookup("job1") is None and not p.exists()


@pytest.mark.parametrize("bad", ["../x", "", ".hidden", "a/b", "x" * 200, "a..b"])
def test_job_ids_that_could_escape_the_cache_are_refused(bad):
    with pytest.raises(ValueError, match="job id"):
        safe_job_id(bad)


def test_backoff_grows_caps_jitters_and_resets():
    b = Backoff(base_s=0.5, factor=2.0, cap_s=4.0, jitter=0.0)
    assert [b.next_delay() for _ in range(6)] == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    b.reset()
    assert b.next_delay() == 0.5
    j = Backoff(base_s=1.0, cap_s=8.0, jitter=0.5, rng=random.Random(7))
    for n in range(200):  # each delay within [(1 - jitter) ceiling, ceiling]
        ceiling = min(8.0, 2.0 ** min(n, 64))
        d = j.next_delay()
        assert 0.5 * ceiling <= d <= ceiling
    assert len({round(Backoff(jitter=1.0, rng=random.Random(s)).next_delay(), 6) for s in range(20)}) > 15
    huge = Backoff(base_s=1.0, cap_s=30.0, jitter=0.0, failures=10_000)  # no overflow in long outages
    assert huge.next_delay() == 30.0


@pytest.mark.parametrize("kw, match", [({"base_s": 0}, "base_s"), ({"factor": 0.5}, "factor"),
                                       ({"cap_s": 0.1}, "cap_s"), ({"jitter": 1.5}, "jitter")])
def test_backoff_validation(kw, match):
    with pytest.raises(ValueError, match=match):
        Backoff(**kw)


def test_zip_is_what_numpy_writes(stack_file):
    # the stack format is a plain zip of .npy members: the agent reads it with numpy alone
    with zipfile.ZipFile(stack_file) as z:
        assert sorted(z.namelist()) == ["frames_u8.npy", "meta.npy", "phase.npy"]
