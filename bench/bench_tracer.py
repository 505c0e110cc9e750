"""Tracer benchmarks: ratios measured in one run, written to bench/results/tracer.md (+ plots).

    .venv/bin/python bench/bench_tracer.py [--quick]

1. 24 frames vs 1 frame (path reuse)                         goal <= 1.15x
2. our WRP rays/s vs Mitsuba's own `path` integrator samples/s  goal >= 0.8x  (same scene, depth, machine)
3. two-stage (WRP) vs direct: rays for the same SLM-field PSNR goal >= 20x fewer
4. fast (ambient cache) vs full on a diffuse-dominant scene   goal >= 5x faster at <= 1 dB loss

Dr.Jit work is timed after dr.eval / dr.sync_thread, excluding the first (compiling) call.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared" / "scenes"
RESULTS = ROOT / "bench" / "results"


def _timed_interleaved(fns: dict, repeats=5) -> dict:
    """Best-of-``repeats`` seconds for each function, runs interleaved (A B C A B C ...) so that a slow spell of
    the machine costs every contender alike; each is warmed up (compiled) first."""
    import drjit as dr

    for fn in fns.values():
        fn()
    best = {k: math.inf for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            dr.sync_thread()
            t0 = time.perf_counter()
            fn()
            dr.sync_thread()
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


def _setup(scene_path, H, W, frames, f_mm=20.0, wavelengths=(640.0, 516.5, 455.4)):
    from holocore.display.optics import OpticsConfig
    from holocore.pipeline import RenderOptions, plan_scene
    from holocore.scene.load import load_scene

    loaded = load_scene(scene_path)
    optics = OpticsConfig(resolution_hw=(H, W), frames=frames, focal_length_mm=f_mm, wavelengths_nm=wavelengths)
    pl = plan_scene(loaded, optics, RenderOptions(preset="balanced"))
    return loaded, optics, pl


def bench_frames(scene_path, H, W, spp):
    """Whole trace (tracing + accumulation) for 1 and 24 frames, same rays."""
    from holocore.pipeline import frame_banks
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.trace.hologram_rays import RecordingGrid, TraceSettings, trace_field

    mi = mitsuba()
    fns = {}
    for F in (1, 24):
        loaded, optics, pl = _setup(scene_path, H, W, F)
        banks = frame_banks(optics, (H, W))
        integ = mi.load_dict({"type": "path", "max_depth": 6})
        z = pl.analysis.z_wrp_m

        def run(loaded=loaded, optics=optics, pl=pl, banks=banks, integ=integ, z=z, F=F):
            grid = RecordingGrid(wavelengths_m=optics.wavelengths_m, pitch_m=optics.pitch_m, shape_hw=(H, W),
                                 plane_z_m=z, z_wrp_m=z)
            return trace_field(loaded.scene, pl.hmap, grid, frames=F,
                               settings=TraceSettings(spp=spp, amp_spp=1, max_delta=pl.plan.max_delta),
                               integrator=integ, seed=0, bank_phasors=banks)

        fns[F] = run
    rows = _timed_interleaved(fns)
    return {"t1_s": rows[1], "t24_s": rows[24], "ratio": rows[24] / rows[1], "rays": H * W * spp}


def bench_vs_mitsuba(scene_path, H, W, spp, depth=6):
    import drjit as dr

    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.trace.hologram_rays import RecordingGrid, TraceSettings, trace_field

    mi = mitsuba()
    loaded, optics, pl = _setup(scene_path, H, W, 1)
    integ = mi.load_dict({"type": "path", "max_depth": depth})
    z = pl.analysis.z_wrp_m

    def ours():
        grid = RecordingGrid(wavelengths_m=optics.wavelengths_m, pitch_m=optics.pitch_m, shape_hw=(H, W),
                             plane_z_m=z, z_wrp_m=z)
        return trace_field(loaded.scene, pl.hmap, grid, frames=1,
                           settings=TraceSettings(spp=spp, amp_spp=1, max_delta=pl.plan.max_delta, max_depth=depth),
                           integrator=integ, seed=0)

    rays = H * W * spp
    scene = loaded.scene
    # Mitsuba renders the same view the hologram shows (its field of view: the SLM's width seen at f), so that
    # both trace the same content; the scene's own, wider camera view is timed too, for reference.
    fov_holo = math.degrees(2.0 * math.atan(W * optics.pitch_m / (2.0 * pl.hmap.focal_length_m)))
    to_world = mi.ScalarTransform4f(np.array(loaded.sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4))

    def render_fn(fov):
        sensor = mi.load_dict({"type": "perspective", "fov": fov, "fov_axis": "x", "to_world": to_world,
                               "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}},
                               "sampler": {"type": "independent", "sample_count": spp}})

        def theirs():
            img = mi.render(scene, sensor=sensor, integrator=integ, spp=spp)
            dr.eval(img)
            return img

        return theirs

    times = _timed_interleaved({"ours": ours, "same_view": render_fn(fov_holo),
                                "camera_view": render_fn(loaded.fov_x_deg)})
    t_ours = times["ours"]
    t_mi = times["same_view"]
    return {"ours_rays_per_s": rays / t_ours, "mitsuba_samples_per_s": rays / t_mi,
            "ratio": t_mi / t_ours, "ratio_camera_view": times["camera_view"] / t_ours,
            "mitsuba_camera_view_samples_per_s": rays / times["camera_view"], "fov_holo_deg": fov_holo,
            "fov_camera_deg": loaded.fov_x_deg, "depth": depth, "rays": rays}


def _view_img(field, meta, z_focus):
    from holocore.evaluate.preview import view_rgb

    return view_rgb(field, meta, focus_z_m=z_focus, pupil_diameter_m=4e-3)


def bench_wrp_vs_direct(scene_path, H, W, spps):
    """Monte Carlo noise of the SLM field, two-stage (WRP, then ASM) vs direct (rays from the SLM plane).

    Both estimators are unbiased estimates of the same field with the same random-phase bank, so the noise
    power of one estimate is var = a / N (N rays per pixel); two runs that differ only in their ray seeds give
    var = ||U1 - U2||^2 / 2. The field PSNR against the converged field is 10 log10(signal / var), and the rays
    either method needs for a given field PSNR are proportional to its constant a = N var / signal: the ratio
    a_direct / a_wrp is the "rays needed for the same PSNR" ratio, whatever the PSNR. The signal is the
    two-stage field at the highest spp (noise removed).
    """
    import torch

    from holocore.optics.propagation import asm
    from holocore.pipeline import frame_banks
    from holocore.runtime.mitsuba_env import mitsuba
    from holocore.trace.hologram_rays import RecordingGrid, TraceSettings, trace_field

    mi = mitsuba()
    loaded, optics, pl = _setup(scene_path, H, W, 4, wavelengths=(516.5,))
    banks = frame_banks(optics, (H, W))
    integ = mi.load_dict({"type": "path", "max_depth": 6})
    z = pl.analysis.z_wrp_m
    lam = optics.wavelengths_m[0]

    def slm_field(method, spp, seed):
        plane = z if method == "wrp" else 0.0
        grid = RecordingGrid(wavelengths_m=(lam,), pitch_m=optics.pitch_m, shape_hw=(H, W), plane_z_m=plane,
                             z_wrp_m=z)
        u = trace_field(loaded.scene, pl.hmap, grid, frames=4,
                        settings=TraceSettings(spp=spp, amp_spp=1, max_delta=pl.plan.max_delta),
                        integrator=integ, seed=seed, bank_phasors=banks)
        if method == "wrp":
            u = asm(torch.from_numpy(u[:, 0]), -z, lam, optics.pitch_m).numpy()[:, None]
        return u.astype(np.complex128)

    rows, signal = [], None
    for method in ("wrp", "direct"):
        for spp in sorted(spps, reverse=True):
            slm_field(method, spp, 1)  # warm-up (compile)
            t0 = time.perf_counter()
            u1 = slm_field(method, spp, 11)
            dt = time.perf_counter() - t0
            u2 = slm_field(method, spp, 12)
            var = float(np.sum(np.abs(u1 - u2) ** 2) / 2)  # noise power of one estimate
            if signal is None:  # the two-stage field at the highest spp: |mean|^2 minus the mean's own noise
                signal = float(np.sum(np.abs((u1 + u2) / 2) ** 2)) - var / 2
            rows.append({"method": method, "spp": spp, "rays": H * W * spp, "seconds": dt,
                         "field_psnr_db": 10 * math.log10(signal / var), "a": spp * var / signal})
    a = {m: float(np.median([r["a"] for r in rows if r["method"] == m])) for m in ("wrp", "direct")}
    ana = pl.analysis
    return {"rows": rows, "a_wrp": a["wrp"], "a_direct": a["direct"], "ratio": a["direct"] / a["wrp"],
            "z_wrp_mm": z * 1e3, "z_image_mm": 0.5e3 * (ana.z_near_holo_m + ana.z_far_holo_m)}


def bench_fast_vs_full(scene_path, H, W, ref_spp):
    from holocore.display.optics import OpticsConfig
    from holocore.evaluate.metrics import psnr
    from holocore.pipeline import RenderOptions, render_loaded
    from holocore.scene.load import load_scene

    loaded = load_scene(scene_path)
    optics = OpticsConfig(resolution_hw=(H, W), frames=4, focal_length_mm=20.0, wavelengths_nm=(640.0, 516.5, 455.4))
    ref = render_loaded(loaded, optics, RenderOptions(preset="reference", spp=ref_spp))
    ana = ref.meta["analysis"]
    z_focus = 0.5 * (ana["z_near_holo_m"] + ana["z_far_holo_m"])
    ref_img = _view_img(ref.slm_field, ref.meta, z_focus)
    out = {}
    for preset in ("fast", "balanced"):
        render_loaded(loaded, optics, RenderOptions(preset=preset))  # warm-up (compile)
        t0 = time.perf_counter()
        r = render_loaded(loaded, optics, RenderOptions(preset=preset))
        dt = time.perf_counter() - t0
        img = _view_img(r.slm_field, r.meta, z_focus)
        s = float((img * ref_img).sum() / max((img * img).sum(), 1e-300))
        out[preset] = {"seconds": dt, "psnr_db": psnr(s * img, ref_img, data_range=float(ref_img.max()))}
    out["speedup"] = out["balanced"]["seconds"] / out["fast"]["seconds"]
    out["shape"] = f"{H}x{W}"
    out["psnr_loss_db"] = out["balanced"]["psnr_db"] - out["fast"]["psnr_db"]
    return out


def _machine():
    import drjit
    import mitsuba
    import torch

    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"torch {torch.__version__}, mitsuba {mitsuba.__version__}, drjit {drjit.__version__}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smaller sizes (a few minutes)")
    ap.add_argument("--only", choices=["frames", "mitsuba", "direct", "fast"], action="append")
    ap.add_argument("--plot-only", action="store_true", help="redraw tracer.png from tracer.json, measure nothing")
    args = ap.parse_args()
    if args.plot_only:
        plot(json.loads((RESULTS / "tracer.json").read_text()))
        return
    if not SHARED.is_dir():
        sys.exit(f"shared scenes not found at {SHARED}: the benchmarks run on ../shared/scenes")
    from holocore.runtime.mitsuba_env import variant

    cbox = SHARED / "cbox-mirror-glass" / "cbox.xml"
    only = set(args.only or ["frames", "mitsuba", "direct", "fast"])
    n = 64 if args.quick else 128
    # --only reruns some benchmarks and keeps the others' latest figures (each with its own date and machine)
    old = json.loads((RESULTS / "tracer.json").read_text()) if args.only and (RESULTS / "tracer.json").is_file() else {}
    res: dict = {**old, "date": datetime.date.today().isoformat(), "machine": _machine(), "variant": variant()}
    if old:
        res["others_date"] = old.get("others_date") or old.get("date")
    stamp = {"date": res["date"], "machine": res["machine"], "load_average": round(os.getloadavg()[0], 2)}
    if "frames" in only:
        res["frames"] = {**bench_frames(cbox, n, n, spp=16), **stamp}
        print("24 vs 1 frames:", json.dumps(res["frames"]))
    if "mitsuba" in only:
        res["mitsuba"] = {**bench_vs_mitsuba(cbox, n, n, spp=16 if args.quick else 64), **stamp}
        print("vs mitsuba path:", json.dumps(res["mitsuba"]))
    if "direct" in only:
        m = 64 if args.quick else 128
        res["direct"] = {**bench_wrp_vs_direct(cbox, m, m, spps=[4, 16] if args.quick else [4, 16, 64]), **stamp}
        print("wrp vs direct:", json.dumps(res["direct"]))
    if "fast" in only:
        room = ROOT / "out" / "bench_scene"
        from holocore.scene.demo import write_demo_scene

        # 256^2 (quick: 128^2): large enough that tracing, not the fixed per-render steps, sets the time
        m = 128 if args.quick else 256
        res["fast"] = {**bench_fast_vs_full(write_demo_scene(room), m, m, ref_spp=128 if args.quick else 256), **stamp}
        print("fast vs full:", json.dumps(res["fast"]))
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "tracer.json").write_text(json.dumps(res, indent=2))
    write_markdown(res)
    plot(res)


def plot(res: dict) -> None:
    """tracer.png: field PSNR vs rays (two-stage vs direct) and the time of each run in the other benchmarks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ax = axes[0]
    if "direct" in res:
        for method, style in (("wrp", "o-"), ("direct", "s--")):
            pts = sorted((r["rays"], r["field_psnr_db"]) for r in res["direct"]["rows"] if r["method"] == method)
            ax.semilogx([p[0] for p in pts], [p[1] for p in pts], style,
                        label="two-stage (WRP + ASM)" if method == "wrp" else "direct (rays from the SLM)")
        ax.set_xlabel("rays")
        ax.set_ylabel("SLM-field PSNR (dB, signal / Monte Carlo noise)")
        ax.set_title(f"cbox: two-stage needs {res['direct']['ratio']:.3g}x fewer rays")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    ax = axes[1]
    bars = []
    if "frames" in res:
        bars += [("cbox: 1 frame", res["frames"]["t1_s"]), ("cbox: 24 frames", res["frames"]["t24_s"])]
    if "mitsuba" in res:
        m = res["mitsuba"]
        bars += [("cbox: ours, 1 frame", m["rays"] / m["ours_rays_per_s"]),
                 ("cbox: Mitsuba path", m["rays"] / m["mitsuba_samples_per_s"])]
    if "fast" in res:
        sh = res["fast"].get("shape", "")
        bars += [(f"demo {sh}: fast", res["fast"]["fast"]["seconds"]),
                 (f"demo {sh}: balanced", res["fast"]["balanced"]["seconds"])]
    if bars:
        ax.barh([b[0] for b in bars][::-1], [b[1] for b in bars][::-1], color="tab:blue")
        ax.set_xscale("log")
        ax.set_xlabel("seconds (log)")
        ax.set_title("time per run, " + res.get("date", ""))
        ax.grid(True, axis="x", which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(RESULTS / "tracer.png", dpi=110)
    plt.close(fig)


def write_markdown(res: dict) -> None:
    lines = ["# Tracer benchmarks\n", f"Machine: {res['machine']}; variant {res['variant']}; {res['date']}.",
             "Regenerate: `.venv/bin/python bench/bench_tracer.py`.\n", "| benchmark | measured | goal |",
             "|---|---|---|"]
    if "frames" in res:
        f = res["frames"]
        lines.append(f"| 24 frames vs 1 (cbox, same rays) | {f['ratio']:.3f}x ({f['t24_s']:.2f} s vs {f['t1_s']:.2f} s) | <= 1.15x |")
    if "mitsuba" in res:
        m = res["mitsuba"]
        lines.append(f"| WRP rays/s vs Mitsuba `path` samples/s (cbox, depth {m['depth']}, same view) | {m['ratio']:.2f}x "
                     f"({m['ours_rays_per_s']:.3g} vs {m['mitsuba_samples_per_s']:.3g}) | >= 0.8x |")
    if "direct" in res:
        d = res["direct"]
        lines.append(f"| two-stage vs direct: rays for the same SLM-field PSNR (cbox, z_wrp {d['z_wrp_mm']:.1f} mm) | "
                     f"{d['ratio']:.0f}x fewer | >= 20x fewer |")
    if "fast" in res:
        f = res["fast"]
        lines.append(f"| fast vs balanced (demo scene) | {f['speedup']:.2f}x faster, {f['psnr_loss_db']:+.2f} dB loss "
                     f"| >= 5x at <= 1 dB |")
    when = [f"{k} {res[k]['date']} (load average {res[k]['load_average']})" for k in ("frames", "mitsuba", "direct", "fast")
            if k in res and "date" in res[k]]
    if when:
        lines += ["", "Measured: " + "; ".join(when) + (f"; the other rows {res['others_date']}" if res.get(
            "others_date") else "") + "."]
    if "fast" in res:
        f = res["fast"]
        lines += ["", f"Fast vs balanced at {f['shape']}: " + ", ".join(
            f"{k} {f[k]['seconds']:.2f} s / {f[k]['psnr_db']:.2f} dB" for k in ("fast", "balanced"))
            + " (PSNR of the focused view against a reference-preset render)."]
    if "frames" in res and "mitsuba" in res:
        lines += ["", f"Rays per run: {res['frames']['rays']:,} (24 vs 1 frames), {res['mitsuba']['rays']:,} (vs "
                  "Mitsuba); each figure is the best of 5 warm runs, the contenders interleaved."]
    if "mitsuba" in res and "ratio_camera_view" in res["mitsuba"]:
        m = res["mitsuba"]
        lines += ["", f"Same view: Mitsuba renders, from the scene's sensor pose, the hologram's field of view "
                  f"({m['fov_holo_deg']:.2f} deg: the SLM's width seen at f), so both trace the same content. "
                  f"Against the scene's own {m['fov_camera_deg']:.1f} deg camera view, which holds cheaper content "
                  f"(mostly walls; the hologram's view is cbox's centre), the ratio is {m['ratio_camera_view']:.2f}x "
                  f"({m['mitsuba_camera_view_samples_per_s']:.3g} samples/s). A WRP ray is one wave path: ray "
                  "generation through T^-1, the coherent delta chain with float64 differentials, the incoherent "
                  "path from its image point, and its complex contribution, all in one Dr.Jit kernel "
                  "(`holocore/trace/kernel.py`)."]
    if "direct" in res:
        d = res["direct"]
        lines += ["", "## Two-stage vs direct: Monte Carlo noise of the SLM field", "",
                  "Both methods estimate the same SLM field (same random-phase bank); two runs that differ only in "
                  "their ray seeds give the noise power var of one estimate. Field PSNR = 10 log10(signal / var); "
                  "a = spp * var / signal is constant for an unbiased estimator, and the rays a method needs for "
                  "any given field PSNR are proportional to a, so the ratio is a_direct / a_wrp "
                  f"(medians: {d['a_direct']:.3g} / {d['a_wrp']:.3g}). Why so large: a direct ray's weight "
                  f"r / cos(theta) carries the {d['z_image_mm']:.1f} mm from the SLM to the image ("
                  f"{d['z_wrp_mm'] - d['z_image_mm']:.2f} mm from the WRP), "
                  "so its noise power per ray is (r_slm / r_wrp)^2 larger, and its cone also gathers the scene "
                  "outside the field of view, which the WRP's small sub-holograms never sample (paper Sec. 4.4).",
                  "",
                  "| method | spp | rays | seconds | field PSNR dB | a |", "|---|---|---|---|---|---|"]
        for r in d["rows"]:
            lines.append(f"| {r['method']} | {r['spp']} | {r['rays']:,} | {r['seconds']:.2f} | "
                         f"{r['field_psnr_db']:.2f} | {r['a']:.3g} |")
    (RESULTS / "tracer.md").write_text("\n".join(lines) + "\n")
    print((RESULTS / "tracer.md").read_text())


if __name__ == "__main__":
    main()
