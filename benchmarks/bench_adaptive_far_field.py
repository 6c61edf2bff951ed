"""How much cheaper the adaptive pass's samples would be with the core's error-bounded far field (issue 11: the
next step measured, not built): ``core.irradiance`` exact and with ``tolerance=`` on the same camera-ray hits,
interleaved in one process, one worker.

The samples are ``--points`` random hit pixels of ``bench_time_vs_error.prepare``'s 256² Cornell box (the
pixels the adaptive pass evaluates are hit pixels). For each ``--rel`` (tolerance relative to the image's mean
H; half of the adaptive tolerance is what the far field could be given) it prints ms per point exact and with
the far field (the first far-field call, which builds the proxy scene, is not timed), the speed-up, the largest
measured error over the mean H (against the cached all-exact image when there is one, else the exact call)
and the largest returned bound::

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_far_field.py [--scene huge]
        [--rel 5e-4,5e-3] [--points 256]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CACHE, log, machine  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="huge")
    ap.add_argument("--rel", default="5e-4,5e-3")
    ap.add_argument("--points", type=int, default=256)
    ap.add_argument("--size", type=int, default=256)
    args = ap.parse_args(argv)
    import bench_time_vs_error

    from hemisphere_local_pass.core import irradiance

    box, _, scene, (p, n, g), _, _, _ = bench_time_vs_error.prepare(args.scene, args.size)
    hit = np.flatnonzero(g.reshape(-1) >= 0)
    idx = np.random.default_rng(0).choice(hit, min(args.points, len(hit)), replace=False)
    pts, nrm = p.reshape(-1, 3)[idx], n.reshape(-1, 3)[idx]
    cache = CACHE / f"exact_H_{args.scene}_{box.n_polygons}_{args.size}.npz"
    ref = np.load(cache)["H"].reshape(-1, 3) if cache.exists() else None
    exact = irradiance(scene, pts, nrm, workers=1)
    mean_h = float(ref[hit].mean()) if ref is not None else float(exact.mean())
    if ref is not None:
        log(f"exact samples equal the cached image's: {np.array_equal(exact, ref[idx])}")
        exact = ref[idx]
    print(f"{machine()}\n{box.n_polygons} polygons, {len(idx)} hit pixels of the {args.size}² box, one worker")
    print("| far-field tolerance / mean H | exact ms/pt | far field ms/pt | speed-up | max error / mean H | "
          "max bound / mean H |")
    print("|---|---|---|---|---|---|")
    for rel in (float(r) for r in args.rel.split(",")):
        tol = rel * mean_h
        irradiance(scene, pts[:8], nrm[:8], tolerance=tol, workers=1)  # builds the proxy scene: not timed
        t = time.perf_counter()
        irradiance(scene, pts, nrm, workers=1)
        te = time.perf_counter() - t
        t = time.perf_counter()
        h, st = irradiance(scene, pts, nrm, tolerance=tol, workers=1, return_stats=True)
        tf = time.perf_counter() - t
        print(f"| {rel:g} | {te / len(idx) * 1e3:.2f} | {tf / len(idx) * 1e3:.2f} | {te / tf:.2f}× | "
              f"{np.abs(h - exact).max() / mean_h:.2e} | {st.error_bound.max() / mean_h:.2e} |", flush=True)


if __name__ == "__main__":
    main()
