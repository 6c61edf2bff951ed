"""What the adaptive pass costs beyond its exact evaluations: an earlier commit's pass, this checkout's, and
one core call over the same pixels, side by side in one process, on every core.

Each scene (``bench_time_vs_error.prepare``: the 256² Cornell box's camera-ray hits) and tolerance runs, in
turn and ``--repeat`` times (fastest kept): the ``--base`` commit's ``adaptive_irradiance`` (its package
extracted as ``hlp_base``, ``bench_ab.import_base``), this checkout's, and ``core.irradiance`` over exactly
the pixels this checkout's pass evaluated, in one call (the floor: the same exact evaluations with no
quadtree, no shadow test and no waiting between calls). Wall seconds (the overhead is idle workers, which
CPU time would not show); each configuration starts its own pool of ``--workers`` processes, as a job does.

Prints per row: seconds of each, *pass / one call* for both passes, *this / base*, whether the two
passes gave the same image, exact pixels and counts (bit for bit), and the largest relative difference
between this pass's samples and the one call's values (the core's last bit may depend on how a call's
points fall into chunks)::

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_overhead.py --base 24c74ab
        [--scenes small,large] [--size 256] [--rel 1e-2,1e-3] [--repeat 2] [--workers 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import log, machine  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the earlier commit whose pass is compared")
    ap.add_argument("--scenes", default="small,large")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--rel", default="1e-2,1e-3", help="tolerances relative to the image's mean H")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    args = ap.parse_args(argv)

    import bench_ab
    import bench_time_vs_error as tve

    from hemisphere_local_pass.core import adaptive_irradiance, irradiance

    print(f"Machine: {machine()}")
    print("Command: `OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_overhead.py "
          f"--base {args.base} --scenes {args.scenes} --size {args.size} --rel {args.rel} --repeat {args.repeat} "
          f"--workers {args.workers}`\n")
    print("| polygons | tol / mean H | exact | base s | this s | one call s | base / one call | this / one call "
          "| this / base | same image | samples vs one call |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        base_core, base_scenes = bench_ab.import_base(args.base, Path(tmp))
        for key in args.scenes.split(","):
            box, lum, scene, (p, n, g), _, _, _ = tve.prepare(key, args.size)
            base_scene = base_scenes.cornell_box(**tve.SETTINGS[key]).scene(radiance=lum)
            hit = g >= 0
            # the tolerance's mean from a coarse grid of exact values (as the Blender job estimates it)
            mean = float(irradiance(scene, p[::16, ::16][hit[::16, ::16]], n[::16, ::16][hit[::16, ::16]]).mean())
            for rel in (float(r) for r in args.rel.split(",")):
                tol = rel * mean
                best = {"base": np.inf, "this": np.inf, "one": np.inf}
                for _ in range(args.repeat):
                    t = time.perf_counter()
                    hb, sb = base_core.adaptive_irradiance(base_scene, p, n, g, tolerance=tol, workers=args.workers)
                    best["base"] = min(best["base"], time.perf_counter() - t)
                    t = time.perf_counter()
                    ht, st = adaptive_irradiance(scene, p, n, g, tolerance=tol, workers=args.workers)
                    best["this"] = min(best["this"], time.perf_counter() - t)
                    yy, xx = np.nonzero(st.exact_mask)
                    t = time.perf_counter()
                    one = irradiance(scene, p[yy, xx], n[yy, xx], workers=args.workers)
                    best["one"] = min(best["one"], time.perf_counter() - t)
                    # the core's results may move by an ulp with the composition of a call's chunks (9,468
                    # polygons: 24 of 65,536 points): the largest relative difference is printed
                    drift = float((np.abs(one - ht[yy, xx]).max(axis=1) / np.abs(one).max(axis=1).clip(1e-300)).max())
                counts = ("exact_points", "forced_surface", "forced_shadow", "rejected", "accepted")
                same = (np.array_equal(hb, ht) and np.array_equal(sb.exact_mask, st.exact_mask)
                        and all(getattr(sb, c) == getattr(st, c) for c in counts))
                log(f"[{key}] {rel:g}: {best}")
                print(f"| {box.n_polygons:,} | {rel:g} | {st.exact_fraction:.1%} | {best['base']:.2f} | "
                      f"{best['this']:.2f} | {best['one']:.2f} | {best['base'] / best['one']:.3f} | "
                      f"{best['this'] / best['one']:.3f} | {best['this'] / best['base']:.3f} | "
                      f"{'bit for bit' if same else 'DIFFERENT'} | {'bit for bit' if drift == 0 else f'{drift:.1e}'} |",
                      flush=True)
    print(f"\nLoad average at the end: {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} cores")


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    main()
