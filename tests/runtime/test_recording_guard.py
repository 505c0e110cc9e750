"""A Mitsuba scene freed while a kernel is recorded must not abort the process (holocore.runtime.recording).

Dr.Jit emits a shape's code twice under one name when the shape registry shrinks between two call sites of one
kernel (the collector freeing an old scene in a reference cycle mid-trace), and then aborts the process. The
render below frees an old scene's last reference into a fresh reference cycle in the middle of a wave path and
makes the collector run at the next allocation; with recording paused, the cycle is freed only after the trace.
Run in a child process: without the pause the parent would die with it.
"""

from __future__ import annotations

import gc
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from holocore.runtime.recording import recording_kernels

ROOT = Path(__file__).resolve().parents[2]

CHILD = textwrap.dedent("""
    import gc
    import numpy as np
    import holocore.trace.kernel as K
    from holocore.display.profiles import PAPER
    from holocore.pipeline import RenderOptions, render_loaded
    from tests.trace.scenes import camera, emitting_plane, scene

    old = [scene(plate=emitting_plane(-0.3))]  # an earlier job's scene, about to become garbage
    loaded = scene(sensor=camera(fov=8.0), plate=emitting_plane(-0.5, size=0.2))
    emission, seen = K._emission, []

    def emission_dropping_the_old_scene(*a, **k):
        if old and len(seen) == 1:  # between two steps of the recording: the old scene's last reference goes into
            # a cycle that the collector frees at the next allocation (unpaused, Dr.Jit then aborts: exit 134)
            cycle = [old.pop()]
            cycle.append(cycle)
            del cycle
            gc.set_threshold(1, 1, 1)
        seen.append(gc.isenabled())
        return emission(*a, **k)

    K._emission = emission_dropping_the_old_scene
    opt = PAPER.optics(resolution_hw=(24, 32), frames=2, z_inf_mm=4.0)
    res = render_loaded(loaded, opt, RenderOptions(preset="balanced", spp=16, wrp_planes=1), display=PAPER)
    gc.set_threshold(700, 10, 10)
    field = np.asarray(res.slm_field)
    assert seen and not any(seen), seen            # no automatic collection while kernels were recorded
    assert gc.isenabled()                          # and it is back on after the trace
    assert np.all(np.isfinite(field)) and np.abs(field).max() > 0
    assert not old and len(seen) >= 2, seen        # the old scene was dropped mid-recording
    print("render survived", len(seen))
""")


def test_a_scene_freed_by_the_collector_mid_trace_does_not_abort_the_render():
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    run = subprocess.run([sys.executable, "-c", CHILD], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=600)
    tail = (run.stdout + run.stderr)[-2000:]
    assert run.returncode == 0, tail
    assert "render survived" in run.stdout, tail


def test_collection_resumes_after_the_outermost_recording_and_only_if_it_was_on():
    assert gc.isenabled()
    with recording_kernels():
        with recording_kernels():
            assert not gc.isenabled()
        assert not gc.isenabled()  # the outer recording is still open
    assert gc.isenabled()
    gc.disable()
    try:
        with recording_kernels():
            pass
        assert not gc.isenabled()  # a caller that had paused it keeps it paused
    finally:
        gc.enable()


def test_an_exception_in_a_recording_turns_collection_back_on():
    @recording_kernels()
    def fails():
        assert not gc.isenabled()
        raise ValueError("bad scene")

    with pytest.raises(ValueError):
        fails()
    assert gc.isenabled()
