"""What loading scenes without Mitsuba's mesh merging costs (holocore.scene.load._MERGE_SHAPES): load time and
a render of each scene, merged and per shape, alternately. Results: bench/results/shape_merging.md.

    .venv/bin/python bench/bench_shape_merging.py cli 5        # `holo render` in a fresh process per run
    .venv/bin/python bench/bench_shape_merging.py inproc 7     # one process, loaded once, rendered repeatedly

Scenes: the bundles in ../shared/scenes and holocore.scene.paper's scenes (written to a temporary folder).
Each run prints one JSON line; the summary at the end gives min and median per scene and setting.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "scenes"
RENDER = ["--resolution", "270x480", "--frames", "1", "--preset", "fast", "--spp", "32"]


def scenes(folder: Path) -> dict[str, str]:
    from holocore.scene.paper import PAPER_SCENES, write_paper_scene

    out = {"veach-bidir": str(SHARED / "veach-bidir"), "cbox-mirror-glass": str(SHARED / "cbox-mirror-glass"),
           "veach-mis": str(SHARED / "veach-mis" / "integrator_direct_both.xml")}
    out = {k: v for k, v in out.items() if Path(v).exists()}
    for n in PAPER_SCENES:
        out[f"paper-{n}"] = str(write_paper_scene(n, folder / n))
    return out


def as_holo(merge: str, args: list[str]) -> int:
    """`holo ARGS` with the merging set (the flag is the loader's module constant)."""
    import holocore.scene.load as load
    from holo.app import main

    load._MERGE_SHAPES = merge == "1"
    sys.argv = ["holo", *args]
    return main()


def cli(reps: int, folder: Path) -> list[dict]:
    rows = []
    for name, path in scenes(folder).items():
        for r in range(reps):
            for merge in ("1", "0") if r % 2 == 0 else ("0", "1"):
                out = folder / "o.npz"
                cmd = [sys.executable, __file__, "as-holo", merge, "render", path, "--out", str(out), *RENDER]
                t = time.perf_counter()
                p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
                row = {"scene": name, "merge": merge == "1", "wall": round(time.perf_counter() - t, 3),
                       "rc": p.returncode, "load_avg": round(os.getloadavg()[0], 2)}
                if p.returncode == 0:
                    import numpy as np

                    with np.load(out, allow_pickle=True) as z:
                        row["t"] = json.loads(str(z["meta"]))["timings"]
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def inproc(reps: int, folder: Path) -> list[dict]:
    import holocore.scene.load as load
    from holocore.display.optics import OpticsConfig
    from holocore.pipeline import RenderOptions, render_loaded

    optics, opts, rows = OpticsConfig(resolution_hw=(270, 480), frames=1), RenderOptions(preset="fast", spp=32), []
    for name, path in scenes(folder).items():
        loaded = {}
        for merge in (True, False):
            load._MERGE_SHAPES = merge
            for _ in range(3):
                t = time.perf_counter()
                loaded[merge] = load.load_scene(path)
                rows.append({"scene": name, "merge": merge, "load_s": time.perf_counter() - t,
                             "shapes": len(loaded[merge].scene.shapes())})
        for r in range(reps):
            for merge in (True, False) if r % 2 == 0 else (False, True):
                t = time.perf_counter()
                res = render_loaded(loaded[merge], optics, opts)
                rows.append({"scene": name, "merge": merge, "wall": time.perf_counter() - t,
                             "t": res.meta["timings"], "load_avg": round(os.getloadavg()[0], 2)})
                print(json.dumps(rows[-1]), flush=True)
    return rows


def summary(rows: list[dict]) -> None:
    for name in dict.fromkeys(r["scene"] for r in rows):
        for merge in (True, False):
            g = [r for r in rows if r["scene"] == name and r["merge"] == merge]
            cols = {"load_s": [r["load_s"] for r in g if "load_s" in r], "wall": [r["wall"] for r in g if "t" in r],
                    "trace_s": [r["t"]["trace_s"] for r in g if "t" in r],
                    "total_s": [r["t"]["total_s"] for r in g if "t" in r]}
            print(name, "merged" if merge else "per shape", " ".join(
                f"{k} {min(v):.3f}/{statistics.median(v):.3f}" for k, v in cols.items() if v), flush=True)


if __name__ == "__main__":
    if sys.argv[1] == "as-holo":
        sys.exit(as_holo(sys.argv[2], sys.argv[3:]))
    with tempfile.TemporaryDirectory() as tmp:
        summary((cli if sys.argv[1] == "cli" else inproc)(int(sys.argv[2]), Path(tmp)))
