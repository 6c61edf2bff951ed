"""The adaptive pass's far-field samples (``adaptive_irradiance(..., sample_share=s)``, core/adaptive.py step 5)
against its exact samples, on two 64² crops of ``bench_time_vs_error.prepare``'s 256² Cornell box.

The crops (rows 96–160 × columns 96–160: the back wall and the blocks; rows 0–64 × columns 160–224: the
ceiling's light and a wall) keep a run of the 187,588-polygon box to minutes. For each share: wall seconds
(both crops, ``--workers``), samples per hit pixel, the largest measured error of H over the tolerance
(against the cached all-exact 256² image, ``bench_time_vs_error.py`` makes it), the largest estimate over the
tolerance and the largest (error − bound) of a sample over the tolerance (≤ 0: every sample within its
bound). This chose ``core.adaptive.SAMPLE_SHARE`` (docs/adaptive.md, "Far-field samples")::

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_sample_share.py [--scene huge]
        [--rel 1e-3] [--shares 0,0.05,0.1,0.2,0.3,0.05/0.9] [--workers 2]

A share ``s/f`` gives the final samples (core/adaptive.py step 6) ``final_share=f``. Without a cached all-exact
256² image the crops' exact values and the mean H (over every 4th pixel each way) are computed and cached.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CACHE, machine  # noqa: E402

CROPS = ((slice(96, 160), slice(96, 160)), (slice(0, 64), slice(160, 224)))


def reference(args, box, scene, p, n, g):
    """``(ref, mean)``: the all-exact H on the crops (``ref[ys, xs]``, an (256, 256, 3) array filled there) and
    the image's mean H over its hit pixels, from the cached all-exact 256² image if there is one, else computed
    here (the crops, and the mean over every 4th pixel each way) and cached."""
    from hemisphere_local_pass.core import irradiance

    full = CACHE / f"exact_H_{args.scene}_{box.n_polygons}_256.npz"
    if full.exists():
        ref = np.load(full)["H"]
        return ref, float(ref[g >= 0].mean())
    path = CACHE / f"exact_H_{args.scene}_{box.n_polygons}_256_crops.npz"
    if path.exists():
        data = np.load(path)
        return data["H"], float(data["mean"])
    ref = np.zeros(g.shape + (3,))
    grid = np.zeros(g.shape, dtype=bool)
    grid[::4, ::4] = True
    grid &= g >= 0
    mask = grid.copy()
    for ys, xs in CROPS:
        mask[ys, xs] = g[ys, xs] >= 0
    t = time.perf_counter()
    ref[mask] = irradiance(scene, p[mask], n[mask], workers=args.workers)
    mean = float(ref[grid].mean())
    print(f"[setup] exact reference on the crops and every 4th pixel: {mask.sum()} points, "
          f"{time.perf_counter() - t:.1f} s", file=sys.stderr)
    CACHE.mkdir(parents=True, exist_ok=True)
    np.savez(path, H=ref, mean=mean)
    return ref, mean


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="huge")
    ap.add_argument("--rel", type=float, default=1e-3)
    ap.add_argument("--shares", default="0,0.05,0.1,0.2,0.3",
                    help="comma-separated sample_share values, each optionally /final_share (e.g. 0.05/0.9)")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    import bench_time_vs_error

    from hemisphere_local_pass.core import adaptive_irradiance

    box, _, scene, (p, n, g), _, _, prep = bench_time_vs_error.prepare(args.scene, 256)
    ref, mean = reference(args, box, scene, p, n, g)
    tol = args.rel * mean
    print(f"{machine()}\n\n{box.n_polygons} polygons (preparation {prep:.1f} s), tolerance {args.rel:g} of the "
          f"mean H, {args.workers} workers\n")
    print("| share / final share | seconds | samples / hit pixels | final samples | max error / tol | estimate / tol "
          "| sample error − bound / tol |")
    print("|---|---|---|---|---|---|---|")
    for config in args.shares.split(","):
        share, _, final = config.partition("/")
        share = float(share)
        final = float(final) if final else None
        seconds, samples, finals, hits, err, est, over = 0.0, 0, 0, 0, 0.0, 0.0, -np.inf
        for ys, xs in CROPS:
            t = time.perf_counter()
            h, st = adaptive_irradiance(scene, p[ys, xs], n[ys, xs], g[ys, xs], tolerance=tol, workers=args.workers,
                                        sample_share=share, final_share=final)
            seconds += time.perf_counter() - t
            samples, finals, hits = samples + st.exact_points, finals + st.final_points, hits + st.hit_pixels
            e = np.abs(h - ref[ys, xs]).max(axis=2)
            err, est = max(err, float(e.max()) / tol), max(est, st.error_estimate / tol)
            if st.exact_mask.any():
                over = max(over, float((e - st.pixel_error)[st.exact_mask].max()) / tol)
        label = f"{share:g}" if final is None else f"{share:g} / {final:g}"
        print(f"| {label} | {seconds:.1f} | {100 * samples / hits:.1f} % | {100 * finals / hits:.1f} % | {err:.3f} "
              f"| {est:.3f} | {over:.1e} |", flush=True)


if __name__ == "__main__":
    main()
