"""Focal sweeps of scenes before and after the scene scale their plan suggests (docs/scene_scale.md).

For each scene: `holo plan --json` says how many depths of field its light spans and which scale would bring its
near content to 0.5 m; the scene is rendered at scale 1 and at that scale (the paper's display at half its rows and
columns, 8 frames, the fast preset), and `holo view --sweep` writes each focal sweep as a contact sheet. The focus lines of both plans
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
RENDER = ["--resolution", "540x960", "--frames", "8", "--preset", "fast"]


def _run(*args: str) -> str:
    done = subprocess.run([*HOLO, *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"holo {' '.join(args[:2])} failed: {done.stderr.strip().splitlines()[-1:]}")
    return done.stdout


def _focus(scene: str, scale: float) -> dict:
    plan = json.loads(_run("plan", scene, *RENDER, "--scene-scale", str(scale), "--json"))
    return plan["focus"]


def _sweep(scene: str, scale: float, out: Path, name: str, work: Path) -> Path:
    """The focal sweep's farthest and nearest views side by side, half size, 256 colours (the sheet of five views
    `holo view --sweep 5` writes is 3 x 2 tiles, each with a caption strip above it)."""
    from PIL import Image

    result = work / f"{name}-{scale:g}.npz"
    _run("render", scene, "--out", str(result), *RENDER, "--scene-scale", str(scale))
    sheet = work / f"{name}-scale-{scale:g}-sheet.png"
    _run("view", str(result), "--sweep", "5", "--out", str(sheet))
    im = Image.open(sheet).convert("RGB")
    tw, th = im.size[0] // 3, im.size[1] // 2
    far, near = im.crop((0, 0, tw, th)), im.crop((tw, th, 2 * tw, 2 * th))
    pair = Image.new("RGB", (2 * tw + 8, th))
    pair.paste(far, (0, 0))
    pair.paste(near, (tw + 8, 0))
    pair = pair.resize((pair.size[0] // 2, pair.size[1] // 2), Image.LANCZOS)
    path = out / f"{name}-scale-{scale:g}.png"
    pair.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(path, optimize=True)
    return path


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
