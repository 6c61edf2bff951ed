"""A receiver's exact irradiance does not depend on the other receivers of its chunk: the camera hits of
a Cornell box image evaluated in image order and shuffled must agree bit for bit.

Found with this check (2026-12-07, before 9685126): 10 of the 65,536 pixels of the 9,468-polygon 256²
image moved by 1 ulp when shuffled; after it, none. Too slow for the tests at that size (~4 min on 2
cores); tests/core/test_receiver_independence.py holds the two-receiver case it was bisected to.

    OMP_NUM_THREADS=1 python benchmarks/check_shuffled_image.py [--scene large] [--size 256] [--seed 1]

Exits 1 when a pixel differs.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_time_vs_error  # noqa: E402

from hemisphere_local_pass.core import irradiance  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="large")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args(argv)
    box, _, scene, (p, n, g), *_ = bench_time_vs_error.prepare(args.scene, args.size)
    hit = g.reshape(-1) >= 0
    P, N = p.reshape(-1, 3)[hit], n.reshape(-1, 3)[hit]
    perm = np.random.default_rng(args.seed).permutation(len(P))
    t = time.perf_counter()
    ordered = irradiance(scene, P, N, workers=args.workers)
    shuffled = np.empty_like(ordered)
    shuffled[perm] = irradiance(scene, P[perm], N[perm], workers=args.workers)
    differ = np.flatnonzero((ordered.view(np.uint64) != shuffled.view(np.uint64)).any(axis=1))
    rel = np.abs(ordered - shuffled).max() / max(np.abs(ordered).max(), 1e-300)
    print(f"{box.n_polygons} polygons, {len(P)} hit pixels of {args.size}²: {len(differ)} differ "
          f"(max relative {rel:.2e}), {time.perf_counter() - t:.1f} s")
    return 1 if len(differ) else 0


if __name__ == "__main__":
    sys.exit(main())
