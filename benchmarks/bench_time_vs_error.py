"""Time against error, side by side in one run (issue 11 sec. 3): Cycles, the exact image, the adaptive image.

The 256² Cornell box (``benchmarks/bench_cycles.py``'s camera with its sub-pixel lens shift) at ~175,
~9,500 and ~170,000 polygons. For each scene, in one run on this machine:

* **exact**: ``core.adaptive_irradiance(..., tolerance=0)`` (every hit pixel exact, bit for bit the
  image of ``core.irradiance``), with ``workers`` = all cores when the core accepts it;
* **adaptive**: ``core.adaptive_irradiance`` at tolerances 1e-2, 1e-3, 1e-4 of the image's mean
  irradiance (absolute per channel, the core's own units), its samples from the error-bounded far field
  with ``--sample-share`` of the tolerance (default ``core.adaptive.SAMPLE_SHARE``, the Blender job's), the
  final samples (no interpolation uses them) with ``--final-share`` (default ``core.adaptive.FINAL_SHARE``);
* **Cycles**: ``bench_cycles.py``'s local-pass-equivalent recipe (one material per polygon, max bounces
  0, no denoising, 2 threads, Blender's default light sampling) at increasing spp, run in a ``bpy``
  Python (``--bpy``, default ``.venv/bpy-4.2/bin/python``) as a subprocess of this run.

Reported per row: wall time of the method (preparation — scene build, first pass, camera rays, BVH —
timed apart, once per scene), exact evaluations, RMS and max error of the radiance image
``E + ρH/π`` against the exact image (luminance, relative to its mean: Cycles' metric in
bench_cycles.py), the largest per-channel error of H relative to the mean H (the adaptive tolerance's
own metric), and Cycles' bias (mean error). Writes ``docs/bench_time_vs_error.md``/``.json`` and
``docs/bench_time_vs_error.png`` (log-log time against RMS and max error); the markdown keeps what follows
its hand-written marker line (``_common.KEEP_PREFIX``)::

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_time_vs_error.py [--scenes small,large,huge]
        [--size 256] [--spp 1,4,16,64,256,1024] [--rel 1e-2,1e-3,1e-4] [--sample-share 0.25]

The all-exact reference of a scene is cached (``HLP_CACHE``, ``exact_H_<scene>_<n>_<size>.npz``) with
the command and seconds that made it; ``--exact-time`` (default: scenes below 20,000 polygons) says
for which scenes the exact image is (re)timed in this run. Without a cached reference a scene's
errors cannot be measured: ``huge`` is then run for time and exact evaluations only, its errors shown
as estimated by the method itself.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CACHE, ROOT, log, luminance, machine, solved_radiance, with_kept_sections  # noqa: E402

from hemisphere_local_pass.core.adaptive import FINAL_SHARE, SAMPLE_SHARE  # noqa: E402
from hemisphere_local_pass.scenes import PAPER_SETTINGS, cornell_box  # noqa: E402

DOCS = ROOT / "docs"
SETTINGS = dict(PAPER_SETTINGS, huge={"subdivisions": 160})


def prepare(key, size):
    """Scene, camera-ray hits as images, reflectivity/emission per pixel; and the seconds it took."""
    import bench_cycles

    from hemisphere_local_pass.core.raycast import build_bvh, cast_rays

    t = time.perf_counter()
    box = cornell_box(**SETTINGS[key])
    lum = solved_radiance(key, box)
    scene = box.scene(radiance=lum)
    o, d = bench_cycles.shifted_camera_rays(box, size)
    hits = cast_rays(scene, o, d, bvh=build_bvh(scene))
    hit = hits.hit
    p = np.where(hit[:, None], hits.point, 0.0).reshape(size, size, 3)
    n = np.where(hit[:, None], scene.poly_normals[np.maximum(hits.polygon, 0)], 0.0).reshape(size, size, 3)
    g = hits.source.reshape(size, size)
    src = np.maximum(hits.source, 0)
    rho = np.where(hit[:, None], box.reflectivity[src], 0.0).reshape(size, size, 3)
    emit = np.where(hit[:, None], box.emission[src], 0.0).reshape(size, size, 3)
    return box, lum, scene, (p, n, g), rho, emit, time.perf_counter() - t


#: half-width (pixels) of the square around a pixel centre inside which a discontinuity of the radiance image
#: makes the pixel *straddling* (:func:`straddling`): twice the half-width of Cycles' 0.01-pixel pixel filter
STRADDLE_PX = 0.01


def straddling(box, scene, size, reach=STRADDLE_PX):
    """(size, size) bool: pixels whose radiance image ``E + ρ/π H`` may jump within ``reach`` pixels of the centre.

    Cycles' pixel (bench_cycles: Gaussian filter 0.01 pixel wide) averages over a footprint around the
    centre where the exact image takes the centre's value; where an edge between surfaces passes through
    that footprint (a different plane, emission or reflectivity behind it) the two differ by a finite amount
    that no number of samples removes: at 1024² one pixel centre lies 0.0012 pixel from the light's edge,
    21× the mean luminance apart, an RMS floor of 2 % over 10^6 pixels. Found by rays through the four
    corners ``(±reach, ±reach)`` around the (shifted) centre: any line within ``reach`` of the centre
    separates it from one of them. Cycles' errors are measured over the other pixels (the count is shown).
    """
    import bench_cycles

    from hemisphere_local_pass.core.adaptive import _input_planes
    from hemisphere_local_pass.core.raycast import build_bvh, cast_rays

    bvh = build_bvh(scene)
    planes = _input_planes(scene)

    def look(shift):
        o, d = bench_cycles.shifted_camera_rays(box, size, shift)
        src = cast_rays(scene, o, d, bvh=bvh).source
        s = np.maximum(src, 0)
        return src >= 0, planes[s], box.emission[s], box.reflectivity[s]

    hit0, pl0, e0, r0 = look(bench_cycles.SHIFT_PX)
    out = np.zeros(size * size, dtype=bool)
    for dx in (-reach, reach):
        for dy in (-reach, reach):
            hit, pl, e, r = look((bench_cycles.SHIFT_PX[0] + dx, bench_cycles.SHIFT_PX[1] + dy))
            out |= (hit != hit0) | (hit0 & ((pl != pl0) | (e != e0).any(axis=1) | (r != r0).any(axis=1)))
    return out.reshape(size, size)


def run_adaptive(scene, inputs, tol, workers, sample_share=0.0, final_share=None):
    from hemisphere_local_pass.core import adaptive_irradiance

    p, n, g = inputs
    t = time.perf_counter()
    h, st = adaptive_irradiance(scene, p, n, g, tolerance=tol, workers=workers, sample_share=sample_share,
                                final_share=final_share)
    return h, st, time.perf_counter() - t


def cycles_rows(bpy_python, key, size, spp, exact_radiance, max_seconds, materials, skip):
    """Render with Cycles in a bpy subprocess (this file's ``--cycles-worker`` mode); errors over the pixels
    not in ``skip (size, size)`` bool (:func:`straddling`).

    Returns ``(rows per spp, Blender version, seconds to build the bpy scene)``, or Nones if it failed.
    """
    with tempfile.TemporaryDirectory() as tmp:
        ref = Path(tmp) / "exact.npy"
        np.save(ref, np.where(skip[..., None], np.nan, exact_radiance))
        out = Path(tmp) / "rows.json"
        cmd = [bpy_python, __file__, "--cycles-worker", key, str(size), spp, str(ref), str(out), str(max_seconds),
               materials]
        r = subprocess.run(cmd, stdout=sys.stderr, stderr=sys.stderr, check=False, env=dict(os.environ))
        if r.returncode != 0:
            log(f"[{key}] Cycles worker failed with exit code {r.returncode}")
            return None, None, None
        data = json.loads(out.read_text())
        return data["rows"], data["blender"], data["build_seconds"]


def cycles_worker(key, size, spp, ref_path, out_path, max_seconds, materials):
    """Inside a bpy Python: build bench_cycles' scene, render at each spp, compare with the exact image."""
    import bench_cycles
    import bpy

    box = cornell_box(**SETTINGS[key])
    lum = solved_radiance(key, box)
    exact = np.load(ref_path)
    keep = ~np.isnan(exact).any(axis=2)          # the pixels that straddle no edge (NaN: skipped)
    y_exact = luminance(exact)[keep]
    mean = float(y_exact.mean())
    t = time.perf_counter()
    scene, mats = bench_cycles.build_blender_scene(box, lum, size, threads=2, materials=materials)
    build = time.perf_counter() - t
    log(f"[{key}] Cycles scene ({materials} materials) built in {build:.1f} s")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in (int(x) for x in spp.split(",")):
            img, sec = bench_cycles.render(scene, mats, s, "default", Path(tmp) / f"r_{s}.exr")
            d = luminance(img)[keep] - y_exact
            rows.append({"spp": s, "seconds": sec, "rms": float(np.sqrt(np.mean(d * d)) / mean),
                         "max": float(np.abs(d).max() / mean), "bias": float(d.mean() / mean),
                         "straddling_skipped": int((~keep).sum())})
            log(f"[{key}] Cycles {s} spp: {sec:.1f} s, RMS {rows[-1]['rms']:.2e}, bias {rows[-1]['bias']:+.1e}")
            if sec > max_seconds:
                break
    Path(out_path).write_text(json.dumps({"rows": rows, "blender": bpy.app.version_string, "build_seconds": build}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="small,large")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--rel", default="1e-2,1e-3,1e-4")
    ap.add_argument("--spp", default="1,4,16,64,256,1024")
    ap.add_argument("--max-seconds", type=float, default=120.0, help="stop Cycles once a render takes longer")
    ap.add_argument("--exact-time", default="", help="scenes whose exact image is timed in this run "
                    "(default: those below 20,000 polygons; others use the cached reference)")
    ap.add_argument("--bpy", default=str(ROOT / ".venv" / "bpy-4.2" / "bin" / "python"), help="'' for no Cycles")
    ap.add_argument("--cycles-buckets-above", type=int, default=20000,
                    help="above this many polygons Cycles gets bench_cycles' materials='buckets' recipe: one "
                         "material per polygon was not built in 10 minutes at 187,588 polygons (2026-12-06; "
                         "material copies cost time growing with the materials, and a mesh holds at most 32,767 "
                         "material slots)")
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    ap.add_argument("--serial-exact", action=argparse.BooleanOptionalAction, default=True,
                    help="also time the exact image on 1 worker where it is timed (the workers' speed-up)")
    ap.add_argument("--sample-share", type=float, default=SAMPLE_SHARE,
                    help="the adaptive samples' far-field share of the tolerance (core.adaptive.SAMPLE_SHARE, the "
                         "Blender job's; 0: exact samples)")
    ap.add_argument("--final-share", type=float, default=FINAL_SHARE,
                    help="the final samples' share of the tolerance (core.adaptive.FINAL_SHARE, the Blender job's; "
                         "core/adaptive.py step 6)")
    ap.add_argument("--out", default=str(DOCS / "bench_time_vs_error"))
    ap.add_argument("--replot", action="store_true", help="only redraw OUT.png from OUT.json (no run)")
    args = ap.parse_args(argv)
    if args.replot:
        plot(json.loads(Path(args.out + ".json").read_text()), args.out + ".png")
        return
    import bench_cycles

    command = ("OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_time_vs_error.py "
               f"--scenes {args.scenes} --size {args.size} --rel {args.rel} --spp {args.spp} "
               f"--sample-share {args.sample_share:g} --final-share {args.final_share:g}"
               + (f" --exact-time {args.exact_time}" if args.exact_time else "")
               + ("" if args.serial_exact else " --no-serial-exact")
               + ("" if args.max_seconds == 120.0 else f" --max-seconds {args.max_seconds:g}")
               + ("" if Path(args.out) == DOCS / "bench_time_vs_error" else f" --out {args.out}"))
    rels = [float(r) for r in args.rel.split(",")]
    report = {"machine": machine(), "command": command, "size": args.size, "workers": args.workers,
              "sample_share": args.sample_share, "final_share": args.final_share, "scenes": []}
    for key in args.scenes.split(","):
        box, lum, scene, inputs, rho, emit, t_prep = prepare(key, args.size)
        log(f"[{key}] {box.n_polygons} polygons: preparation {t_prep:.1f} s")
        entry = {"scene": key, "polygons": box.n_polygons, "preparation_seconds": t_prep, "rows": []}
        cache = CACHE / f"exact_H_{key}_{box.n_polygons}_{args.size}.npz"
        timed_exact = (key in args.exact_time.split(",")) if args.exact_time else box.n_polygons < 20000
        exact_h = None
        if timed_exact:
            exact_h, st, sec = run_adaptive(scene, inputs, 0.0, args.workers)
            entry["rows"].append({"method": "exact", "seconds": sec, "exact_points": st.exact_points})
            log(f"[{key}] exact image: {sec:.1f} s, {st.exact_points} points")
            if not cache.exists():
                np.savez(cache, H=exact_h, seconds=sec, command=command)
            if args.serial_exact and args.workers > 1:
                # the same image on one worker, right after: the speed-up of every core (issue 11: >= 1.8x on 2)
                serial_h, st1, sec1 = run_adaptive(scene, inputs, 0.0, 1)
                same = bool(np.array_equal(serial_h, exact_h))
                entry["rows"].append({"method": "exact, 1 worker", "seconds": sec1, "exact_points": st1.exact_points,
                                      "same_bits": same})
                entry["workers_speedup"] = sec1 / sec
                log(f"[{key}] exact image on 1 worker: {sec1:.1f} s ({sec1 / sec:.2f}x), same bits: {same}")
        elif cache.exists():
            z = np.load(cache)
            exact_h = z["H"]
            entry["rows"].append({"method": "exact (cached)", "seconds": float(z["seconds"]),
                                  "exact_points": int((inputs[2] >= 0).sum()), "cached": str(z["command"])})
        hit = inputs[2] >= 0
        mean_h = float(exact_h[hit].mean()) if exact_h is not None else None
        rad_exact = emit + rho / np.pi * exact_h if exact_h is not None else None
        y_exact = luminance(rad_exact) if rad_exact is not None else None
        for rel in rels:
            if mean_h is None:  # no reference: the tolerance from the mean of a loose adaptive image
                probe, _, _ = run_adaptive(scene, inputs, 0.05 * float(np.pi * np.abs(lum).mean()), args.workers)
                mean_h = float(probe[hit].mean())
                entry["mean_from_probe"] = True
            h, st, sec = run_adaptive(scene, inputs, rel * mean_h, args.workers, args.sample_share,
                                      args.final_share)
            row = {"method": f"adaptive {rel:g}", "rel": rel, "seconds": sec, "exact_points": st.exact_points,
                   "estimate": st.error_estimate / mean_h, "sample_bound": st.sample_bound / mean_h,
                   "final_points": st.final_points,
                   "forced_surface": st.forced_surface, "forced_shadow": st.forced_shadow, "rejected": st.rejected,
                   "accepted": st.accepted}
            if exact_h is not None:
                dy = luminance(emit + rho / np.pi * h) - y_exact
                row.update(rms=float(np.sqrt(np.mean(dy * dy)) / y_exact.mean()),
                           max=float(np.abs(dy).max() / y_exact.mean()),
                           h_max=float(np.abs(h - exact_h).max() / mean_h))
            entry["rows"].append(row)
            log(f"[{key}] adaptive {rel:g}: {sec:.1f} s, {st.exact_points} exact, {row}")
        if args.bpy and rad_exact is not None and Path(args.bpy).exists():
            materials = "buckets" if box.n_polygons > args.cycles_buckets_above else "polygon"
            skip = straddling(box, scene, args.size)
            log(f"[{key}] {int(skip.sum())} pixels straddle an edge within {STRADDLE_PX} pixel: not in Cycles' errors")
            rows, blender, build = cycles_rows(args.bpy, key, args.size, args.spp, rad_exact, args.max_seconds,
                                               materials, skip)
            if rows:
                entry["blender"] = blender
                entry["cycles_materials"] = materials
                entry["cycles_build_seconds"] = build
                for r in rows:
                    entry["rows"].append({"method": f"Cycles {r['spp']} spp", **r})
                errs, secs = [r["rms"] for r in rows], [r["seconds"] for r in rows]
                entry["cycles_1pct"] = bench_cycles.time_to(errs, secs, 0.01)
                entry["cycles_0.1pct"] = bench_cycles.time_to(errs, secs, 0.001)
        report["scenes"].append(entry)
        write(report, args.out)
    write(report, args.out)


def write(report, out):
    md = ["# Time against error: Cycles, the exact image and the adaptive image (one run)\n",
          f"Machine: {report['machine']}. Load average at the end of the run: {os.getloadavg()[0]:.1f} (1 min) "
          f"on {os.cpu_count()} cores (above ~{os.cpu_count()}, other jobs shared the machine and the seconds are "
          "inflated); rows of one scene were measured minutes apart in the same run.\n",
          f"Command: `{report['command']}`\n",
          "Errors: radiance image E + ρH/π against the exact image, luminance, relative to its mean (Cycles' "
          "metric); *H max* = largest per-channel |ΔH| over the mean H (the adaptive tolerance's metric). "
          "Seconds exclude preparation (scene, first pass from cache, camera rays, BVH), given per scene.\n",
          f"Adaptive samples: far field with {report.get('sample_share', 0.0):g} of the tolerance "
          f"(`sample_share`, core/adaptive.py step 5; 0: exact samples), the final samples with "
          f"{report.get('final_share', report.get('sample_share', 0.0)):g} (`final_share`, step 6); "
          "*exact evaluations* of an adaptive row count its samples.\n"]
    for e in report["scenes"]:
        md.append(f"## {e['polygons']} polygons (preparation {e['preparation_seconds']:.1f} s)\n")
        md.append("| method | seconds | exact evaluations | RMS error | max error | H max / mean H | "
                  "estimate / mean H | bias |")
        md.append("|---|---|---|---|---|---|---|---|")
        for r in e["rows"]:
            def f(k, fmt="{:.2e}", r=r):
                return fmt.format(r[k]) if r.get(k) is not None else "—"
            exact = "0 (reference)" if r["method"].startswith("exact") else f("rms")
            md.append(f"| {r['method']} | {r['seconds']:.1f} | {r.get('exact_points', '—')} | {exact} | "
                      f"{'0' if r['method'].startswith('exact') else f('max')} | {f('h_max')} | {f('estimate')} | "
                      f"{f('bias', '{:+.1e}')} |")
        if e.get("cycles_1pct") is not None or "blender" in e:
            c1 = e.get("cycles_1pct")
            recipes = {"polygon": "a material per polygon",
                       "buckets": "bench_cycles' bucketed materials: emitters one each, the rest one per "
                                  "reflectivity and radiance level, L / level from a face attribute"}
            recipe = recipes.get(e.get("cycles_materials", "polygon"))
            build = e.get("cycles_build_seconds")
            built = "" if build is None else f", bpy scene built in {build:.1f} s, not counted"
            skipped = next((r["straddling_skipped"] for r in e["rows"] if "straddling_skipped" in r), None)
            over = ("" if skipped is None else
                    f"; Cycles' errors over the pixels but {skipped} whose centre lies within {STRADDLE_PX} pixel "
                    "of an edge of the radiance image (`straddling`: Cycles' pixel filter averages across it)")
            md.append(f"\nCycles (Blender {e.get('blender', '?')}, {recipe}{built}; default light sampling, 2 threads"
                      f"{over}) reaches 1 % RMS in {'—' if c1 is None else f'{c1:.1f} s'} (log-log interpolation "
                      "between spp settings).")
            a3 = next((r for r in e["rows"] if r.get("rel") == 1e-3), None)
            if c1 is not None and a3 is not None:
                md.append(f"Adaptive at 1e-3 (max error {a3.get('max', float('nan')):.1e} of the mean): "
                          f"{a3['seconds']:.1f} s, {c1 / a3['seconds']:.2f}× Cycles' time to 1 % RMS.")
            ex = next((r for r in e["rows"] if r["method"] in ("exact", "exact (cached)")), None)
            if c1 is not None and ex is not None:
                md.append(f"Exact image: {ex['seconds']:.1f} s, {c1 / ex['seconds']:.2f}× Cycles' time to 1 % RMS.")
        one = next((r for r in e["rows"] if r["method"] == "exact, 1 worker"), None)
        if one is not None and e.get("workers_speedup") is not None:
            same = "the same" if one["same_bits"] else "NOT the same"
            md.append(f"Exact image on {report.get('workers', '?')} workers: {e['workers_speedup']:.2f}× faster than "
                      f"on 1 ({one['seconds']:.1f} s), {same} bits.")
        md.append("")
    Path(out + ".md").write_text(with_kept_sections("\n".join(md) + "\n", out + ".md"), encoding="utf-8")
    Path(out + ".json").write_text(json.dumps(report, indent=1), encoding="utf-8")
    try:
        plot(report, out + ".png")
    except ImportError:  # matplotlib is optional
        log("matplotlib missing: no plot")


def plot(report, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    scenes = report["scenes"]
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.5 * len(scenes), 4.5), squeeze=False)
    for ax, e in zip(axes[0], scenes, strict=True):
        cyc = [r for r in e["rows"] if r["method"].startswith("Cycles")]
        ada = [r for r in e["rows"] if r["method"].startswith("adaptive") and r.get("rms") is not None]
        if cyc:
            ax.loglog([r["seconds"] for r in cyc], [r["rms"] for r in cyc], "o-", label="Cycles RMS")
            ax.loglog([r["seconds"] for r in cyc], [r["max"] for r in cyc], "o:", label="Cycles max")
            for r in cyc:  # the spp: the first render also pays Cycles' one-off start, so times need not rise
                ax.annotate(r["method"].split()[1], (r["seconds"], r["rms"]), fontsize=7)
        if ada:
            ax.loglog([r["seconds"] for r in ada], [max(r["rms"], 1e-12) for r in ada], "s-", label="adaptive RMS")
            ax.loglog([r["seconds"] for r in ada], [max(r["max"], 1e-12) for r in ada], "s:", label="adaptive max")
            for r in ada:
                ax.annotate(f"{r['rel']:g}", (r["seconds"], max(r["max"], 1e-12)), fontsize=8)
        for r in e["rows"]:
            if r["method"].startswith("exact") and "1 worker" not in r["method"]:
                ax.axvline(r["seconds"], color="k", ls="--", label=f"exact ({r['seconds']:.0f} s)")
        ax.axhline(0.01, color="grey", lw=0.5)
        ax.set_title(f"{e['polygons']} polygons, {report.get('size', 256)}²")
        ax.set_xlabel("seconds (wall, preparation apart)")
        ax.set_ylabel("error / mean (luminance)")
        ax.legend(fontsize=7)
        # minor labels collide on an axis spanning a decade or more, and are the only ones on a shorter one
        lo, hi = ax.get_xlim()
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter() if hi > 10 * lo else
                                     matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if len(sys.argv) > 1 and sys.argv[1] == "--cycles-worker":
        cycles_worker(sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5], sys.argv[6], float(sys.argv[7]),
                      sys.argv[8])
    else:
        main()
