"""The yardstick's table: from paper-report runs (bench/paper_report.py --stages equal) made with the display's
filter and without, per scene and method the viewer-faithful PSNR at 2, 4 and 6 mm pupils, the mean over 2-6 mm
for each seed of the scored planes and eye grid (and their spread), the brightness steps over the eye grid (the
largest max / min of any pupil), and the band share of each pupil; under each scene, which method leads at each
pupil.

    python bench/yardstick_table.py bench/results/yardstick/4f bench/results/yardstick/none > TABLE.md
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ORDER = ("ours", "fast", "direct", "layers", "light-field", "light-field-sgd", "focal-stack")


def rows(folder: Path) -> list[str]:
    out = []
    for path in sorted(folder.glob("equal_*.json")):
        eq = json.loads(path.read_text())
        viewer = (eq.get("viewer") or {}).get("methods") or {}
        planes = ", ".join(f"{f['name']} {f['z_m'] * 1e3:.3f}" for f in eq.get("focus", []))
        out.append(f"\n**{eq['scene']}** ({folder.name}; budget {eq['budget_s']:g} s a method, {eq['frames']} frames, "
                   f"{eq['shape_hw'][0]}x{eq['shape_hw'][1]} px; scored planes mm: {planes})\n")
        out.append("| method | 2 mm | 4 mm | 6 mm | mean 2-6 mm by seed | spread | brightness steps | "
                   "band share 2/4/6 mm |")
        out.append("|---|---|---|---|---|---|---|---|")
        best: dict[float, tuple[float, str]] = {}
        for name in sorted(viewer, key=lambda m: ORDER.index(m) if m in ORDER else len(ORDER)):
            d = viewer[name]
            by = {round(p["pupil_mm"], 3): p for p in d["pupils"]}
            cell = lambda mm: f"{by[mm]['mean_psnr_db']:.2f}" if mm in by else "-"  # noqa: E731
            band = "/".join(f"{by[mm].get('band_share', float('nan')):.2f}" for mm in (2.0, 4.0, 6.0) if mm in by)
            seeds = d.get("seeds") or {"0": d["mean_2_6_db"]}
            vals = [float(v) for v in seeds.values()]
            steps = max(float(p.get("brightness_max_over_min", float("nan"))) for p in d["pupils"])
            out.append(f"| {name} | {cell(2.0)} | {cell(4.0)} | {cell(6.0)} | "
                       f"{' / '.join(f'{v:.2f}' for v in vals)} | {max(vals) - min(vals):.2f} | {steps:.2f} | {band} |")
            for mm, p in by.items():
                if p["mean_psnr_db"] > best.get(mm, (-1e9, ""))[0]:
                    best[mm] = (float(p["mean_psnr_db"]), name)
        lead = "; ".join(f"{mm:g} mm: {n} ({v:.2f})" for mm, (v, n) in sorted(best.items()))
        out.append(f"\nLeads: {lead}.")
        for ours, label in (("ours", "The default mode (coded)"), ("ours (directional)", "Directional frames")):
            margins = []
            for mm in sorted(best):
                mine = _psnr(viewer.get(ours), mm)
                rivals = [(_psnr(d, mm), n) for n, d in viewer.items()
                          if not n.startswith(("ours", "fast", "direct"))]
                rivals = [(v, n) for v, n in rivals if v is not None]
                if mine is not None and rivals:
                    v, n = max(rivals)
                    margins.append(f"{mm:g} mm {mine - v:+.2f} ({n})")
            if margins:
                out.append(f"{label} against the best baseline, dB: {'; '.join(margins)}.")
    return out


def _psnr(d: dict | None, mm: float) -> float | None:
    for p in (d or {}).get("pupils", ()):
        if round(p["pupil_mm"], 3) == mm:
            return float(p["mean_psnr_db"])
    return None


def main(argv: list[str]) -> int:
    for folder in argv:
        print("\n".join(rows(Path(folder))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
