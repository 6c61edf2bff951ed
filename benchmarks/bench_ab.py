"""The exact core of an earlier commit against this checkout's, side by side in one process (issue 10).

The earlier commit's ``hemisphere_local_pass`` is extracted (``git archive``) into a temporary folder and
imported as ``hlp_base`` (its absolute imports renamed), so both cores run on the same camera-visible
points of the same Cornell boxes (``_common.case``), interleaved run by run: they share the machine's
slow and fast phases, and the ratios are what travels. Times are CPU seconds of this process
(``time.process_time``: on a shared machine, wall time also counts the other processes' turns).

Prints per scene: the fastest and median ms per point of each core, the median of the per-run ratios,
and max |ΔH| (``bitwise`` when the results are equal bit for bit). ``--profile``: cProfile cumulative
seconds of the per-point stages, fastest of two profiled runs of each core.

    OMP_NUM_THREADS=1 python benchmarks/bench_ab.py --base dcab52e [--scenes small,large] [--repeat 5]
        [--points 1024] [--form-factors] [--profile] [--image 128]

``--image N`` also runs both cores once on the camera hits of an N × N image (``bench_time_vs_error.prepare``,
preparation included in the times) and compares them.
"""

from __future__ import annotations

import argparse
import cProfile
import importlib
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import ROOT, case, log, machine, solved_radiance

STAGES = ("irradiance", "shadow_volumes", "coverage", "visit_tiles", "_enclosed", "clear_pairs", "clear_irradiance",
          "hemisphere_candidates", "occluder_pairs", "visible_terms", "contour_by_width", "_test_pairs",
          "split_convex")


def import_base(commit: str, tmp: Path):
    """``commit``'s package as ``hlp_base`` (a renamed copy in ``tmp``): ``(core, scenes)`` modules."""
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", commit, "hemisphere_local_pass"], check=True,
                         capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tmp)], input=tar, check=True)
    (tmp / "hemisphere_local_pass").rename(tmp / "hlp_base")
    for f in (tmp / "hlp_base").rglob("*.py"):
        f.write_text(f.read_text(encoding="utf-8").replace("hemisphere_local_pass", "hlp_base"), encoding="utf-8")
    sys.path.insert(0, str(tmp))
    return importlib.import_module("hlp_base.core"), importlib.import_module("hlp_base.scenes")


def stage_profile(fn, package: str, *args, **kwargs) -> tuple[dict, int]:
    """cProfile cumulative seconds of :data:`STAGES` (functions of ``package``) in one call ``fn(*args, **kwargs)``;
    with the number of function calls."""
    pr = cProfile.Profile()
    pr.enable()
    fn(*args, **kwargs)
    pr.disable()
    cum, calls = {}, 0
    for (path, _, name), (_, nc, _, ct, _) in pstats.Stats(pr).stats.items():
        calls += nc
        if name in STAGES and f"/{package}/" in path:
            cum[name] = cum.get(name, 0.0) + ct
    return cum, calls


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the earlier commit (any git revision)")
    ap.add_argument("--scenes", default="small,large")
    ap.add_argument("--points", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--form-factors", action="store_true", help="also time form_factors")
    ap.add_argument("--profile", action="store_true", help="cProfile the stages of irradiance")
    ap.add_argument("--image", type=int, default=0,
                    help="also compare irradiance once at the camera hits of an N x N image (bench_time_vs_error)")
    args = ap.parse_args(argv)
    import hemisphere_local_pass.core as new
    from hemisphere_local_pass.scenes import PAPER_SETTINGS

    with tempfile.TemporaryDirectory() as tmp:
        old, old_scenes = import_base(args.base, Path(tmp))
        print(f"Machine: {machine()}\n\nbase {args.base} (hlp_base) against this checkout, "
              f"{args.repeat} interleaved runs, CPU ms per point\n")
        print("| scene | polygons | points | call | base ms/pt | this ms/pt | ratio (median of runs) | max abs(ΔH) |")
        print("|---|---|---|---|---|---|---|---|")
        profiles = []
        for key in args.scenes.split(","):
            box, scene, p, n, _ = case(key, args.points)
            o_scene = old_scenes.cornell_box(**PAPER_SETTINGS[key]).scene(radiance=solved_radiance(key, box))
            old.irradiance(o_scene, p[:1], n[:1], workers=1)     # both scenes prepared before timing
            new.irradiance(scene, p[:1], n[:1], workers=1)
            calls = ["irradiance"] + (["form_factors"] if args.form_factors else [])
            m = len(p)
            for name in calls:
                t_old, t_new = [], []
                for r in range(args.repeat):
                    t = time.process_time()
                    h_old = getattr(old, name)(o_scene, p, n, workers=1)
                    t_old.append(time.process_time() - t)
                    t = time.process_time()
                    h_new = getattr(new, name)(scene, p, n, workers=1)
                    t_new.append(time.process_time() - t)
                    log(f"[{key} {name}] run {r + 1}: {t_old[-1] / m * 1e3:.3f} / {t_new[-1] / m * 1e3:.3f} ms/pt")
                d = float(np.abs(h_old - h_new).max())
                same = "bitwise" if np.array_equal(h_old, h_new) else f"{d:.2e}"
                ratio = float(np.median(np.array(t_old) / np.array(t_new)))
                cells = [f"{min(t) / m * 1e3:.3f} ({np.median(t) / m * 1e3:.3f})" for t in (t_old, t_new)]
                print(f"| {key} | {scene.n_polygons} | {m} | {name} | {cells[0]} | {cells[1]} | {ratio:.2f} | {same} |",
                      flush=True)
            if args.profile:
                best = {}
                for label, mod, s, pkg in (("base", old, o_scene, "hlp_base"), ("this", new, scene,
                                                                                   "hemisphere_local_pass")) * 2:
                    cum, n_calls = stage_profile(mod.irradiance, pkg, s, p, n, workers=1)
                    if label not in best or cum.get("irradiance", 0.0) < best[label][0].get("irradiance", 0.0):
                        best[label] = (cum, n_calls)
                profiles.append((key, best))
        if args.image:
            import bench_time_vs_error

            print(f"\n| scene | {args.image}² image: hit pixels | base s | this s | max abs(ΔH) |")
            print("|---|---|---|---|---|")
            for key in args.scenes.split(","):
                box, lum, scene, (p, n, g), *_ = bench_time_vs_error.prepare(key, args.image)
                hit = g.reshape(-1) >= 0
                p, n = p.reshape(-1, 3)[hit], n.reshape(-1, 3)[hit]
                o_scene = old_scenes.cornell_box(**bench_time_vs_error.SETTINGS[key]).scene(radiance=lum)
                t = time.process_time()
                h_old = old.irradiance(o_scene, p, n, workers=1)
                t_old = time.process_time() - t
                t = time.process_time()
                h_new = new.irradiance(scene, p, n, workers=1)
                t_new = time.process_time() - t
                same = "bitwise" if np.array_equal(h_old, h_new) else f"{float(np.abs(h_old - h_new).max()):.2e}"
                print(f"| {key} | {len(p)} | {t_old:.1f} | {t_new:.1f} | {same} |", flush=True)
        for key, best in profiles:
            print(f"\n| stage ({key}, cProfile cumulative s, {args.points} points) | base | this | ratio |")
            print("|---|---|---|---|")
            for st in STAGES:
                a, b = best["base"][0].get(st, 0.0), best["this"][0].get(st, 0.0)
                print(f"| {st} | {a:.3f} | {b:.3f} | {a / b if b else float('nan'):.2f} |")
            print(f"| function calls | {best['base'][1]} | {best['this'][1]} | |")


if __name__ == "__main__":
    main()
