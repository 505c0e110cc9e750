"""Focal sweeps of scenes before and after the scene scale their plan suggests (docs/scene_scale.md).

For each scene: `holo plan --json` says how many depths of field its light spans and which scale would bring its
near content to 0.5 m; the scene is rendered at scale 1 and at that scale (the whole camera view, fit_camera_fov,
a small preview), and `holo view --sweep` writes each focal sweep as a contact sheet. The focus lines of both plans
go to the markdown table this prints.

    .venv/bin/python scripts/scene_scale_pictures.py SCENE [SCENE ...] --out docs/pictures/scene_scale
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

HOLO = [sys.executable, "-m", "holo"]
RENDER = ["--resolution", "270x480", "--fit-camera-fov", "--frames", "2", "--preset", "fast"]


def _run(*args: str) -> str:
    done = subprocess.run([*HOLO, *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"holo {' '.join(args[:2])} failed: {done.stderr.strip().splitlines()[-1:]}")
    return done.stdout


def _focus(scene: str, scale: float) -> dict:
    plan = json.loads(_run("plan", scene, *RENDER, "--scene-scale", str(scale), "--json"))
    return plan["focus"]


def _sweep(scene: str, scale: float, out: Path, name: str, work: Path) -> Path:
    result = work / f"{name}-{scale:g}.npz"
    _run("render", scene, "--out", str(result), *RENDER, "--scene-scale", str(scale))
    sheet = out / f"{name}-scale-{scale:g}.png"
    _run("view", str(result), "--sweep", "5", "--out", str(sheet))
    return sheet


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", help="scene folders or XML files")
    ap.add_argument("--out", type=Path, required=True, help="folder for the contact sheets")
    ap.add_argument("--work", type=Path, default=Path("/tmp/scene_scale_work"), help="folder for the renders")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    args.work.mkdir(parents=True, exist_ok=True)
    print("| scene | scale | depths of field (4 mm pupil) | near content | focal sweep |")
    print("|---|---|---|---|---|")
    for scene in args.scenes:
        name = Path(scene).stem if Path(scene).suffix == ".xml" else Path(scene).name
        before = _focus(scene, 1.0)
        scales = [1.0] + ([before["suggested_scene_scale"]] if before["suggested_scene_scale"] else [])
        for s in scales:
            focus = before if s == 1.0 else _focus(scene, s)
            sheet = _sweep(scene, s, args.out, name, args.work)
            near = f"{focus['near_m']:.3g} m" if focus["near_m"] else "–"
            print(f"| {name} | {s:g} | {focus['depths_of_field']:.2g} | {near} | ![{name} at {s:g}]({sheet.name}) |",
                  flush=True)


if __name__ == "__main__":
    main()
