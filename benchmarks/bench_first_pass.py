"""First pass (progressive refinement) on the Cornell boxes: time, shots, energy balance, peak memory.

    .venv/core/bin/python benchmarks/bench_first_pass.py [--scenes small,large,huge] [--tolerance 1e-3]
        [--order 2] [--clusters N] [--profile]
    .venv/core/bin/python benchmarks/bench_first_pass.py --accuracy 12 --clusters 30,100,300

``huge`` is the 106,312-polygon box of ``sample_scenes/cornell_box_100k.py``; ``--clusters N`` runs the
clustered solver (reflected light from about N clusters); ``--profile`` prints the top functions of a
cProfile of the run. ``--accuracy S`` compares, on ``cornell_box(S)``, the flat centroid rule and the
clustered solver for every N of ``--clusters`` against a reference (flat, order 2, tolerance 1e-4):
area-weighted mean / 95th percentile / max of the per-polygon relative difference (RGB summed), point
evaluations, and the solver's own estimate.

Prints per scene: polygons, shots, steps, point evaluations, the unshot fraction reached, the energy
balance, the quadrature error estimate, wall time, and the process's peak RSS (``ru_maxrss``) next to what
the dense n × n float32 matrix of the old solver would take. Progress lines (with ETA) go to stderr.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from hemisphere_local_pass.first_pass import make_solver, solve_radiosity  # noqa: E402
from hemisphere_local_pass.scenes import PAPER_SETTINGS, cornell_box  # noqa: E402


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kB


class _Every:
    """Progress line on stderr at most every ``seconds``."""

    def __init__(self, seconds):
        self.seconds, self.last = seconds, 0.0

    def __call__(self, p):
        now = time.perf_counter()
        if now - self.last >= self.seconds:
            self.last = now
            print(p.message(), file=sys.stderr, flush=True)


SETTINGS = dict(PAPER_SETTINGS, huge={"subdivisions": 120, "block_detail": 1.05})


def accuracy(subdivisions: int, clusters: list[int], tolerance: float):
    box = cornell_box(subdivisions)
    scene = box.scene()
    t0 = time.perf_counter()
    ref = solve_radiosity(scene, box.reflectivity, box.emission, tolerance=1e-4, order=2)
    print(f"# cornell_box({subdivisions}): {scene.n_input} polygons; reference (flat, order 2, 1e-4): "
          f"{ref.point_evaluations} point evaluations, {time.perf_counter() - t0:.1f} s")
    lit = ref.radiance.sum(axis=1) > 1e-9

    def row(name, r, secs):
        d = np.abs(r.radiance - ref.radiance).sum(axis=1)[lit] / ref.radiance.sum(axis=1)[lit]
        est = f"{r.cluster_error:.3f}" if np.isfinite(r.cluster_error) else "-"
        mean = np.average(d, weights=ref.areas[lit])
        print(f"| {name} | {r.clusters or '-'} | {mean:.3f} | {np.percentile(d, 95):.3f} | {d.max():.3f} "
              f"| {r.point_evaluations} | {secs:.1f} s | {est} |", flush=True)

    print(f"| solver (tolerance {tolerance:g}) | clusters | mean rel. diff | p95 | max | point evaluations | time "
          "| cluster estimate |\n|---|---|---|---|---|---|---|---|")
    t0 = time.perf_counter()
    row("flat, centroid rule", solve_radiosity(scene, box.reflectivity, box.emission, tolerance=tolerance, order=1),
        time.perf_counter() - t0)
    for k in clusters:
        t0 = time.perf_counter()
        r = solve_radiosity(scene, box.reflectivity, box.emission, tolerance=tolerance, order=2, clusters=k)
        row(f"clusters={k}", r, time.perf_counter() - t0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="small,large")
    ap.add_argument("--tolerance", type=float, default=1e-3)
    ap.add_argument("--order", type=int, default=2)
    ap.add_argument("--no-estimate", action="store_true", help="skip the 1-point error estimate")
    ap.add_argument("--clusters", default="", help="N (or N1,N2,... with --accuracy): the clustered solver")
    ap.add_argument("--profile", action="store_true", help="cProfile the run, print the top 12 functions")
    ap.add_argument("--max-shots", type=int, default=None, help="stop after this many shots (profiling)")
    ap.add_argument("--accuracy", type=int, default=0, metavar="S",
                    help="compare against a reference on cornell_box(S)")
    args = ap.parse_args(argv)
    clusters = [int(k) for k in args.clusters.split(",") if k]
    if args.accuracy:
        accuracy(args.accuracy, clusters, args.tolerance)
        return
    print(f"# first pass, tolerance {args.tolerance:g}, order {args.order}; peak RSS before: {peak_rss_mb():.0f} MB")
    for key in args.scenes.split(","):
        t0 = time.perf_counter()
        box = cornell_box(**SETTINGS[key])
        scene = box.scene()
        t1 = time.perf_counter()
        solver = make_solver(scene, box.reflectivity, box.emission, tolerance=args.tolerance, order=args.order,
                             estimate_error=not args.no_estimate, clusters=clusters[0] if clusters else None,
                             max_shots=args.max_shots)
        if args.profile:
            import cProfile
            import pstats

            prof = cProfile.Profile()
            r = prof.runcall(solver.run, progress=_Every(10.0))
        else:
            r = solver.run(progress=_Every(10.0))
        wall = time.perf_counter() - t1
        print(f"# {key}: scene built in {t1 - t0:.1f} s; {r.summary()}")
        n = box.n_polygons
        print(f"{key}: {n} polygons, {r.shots} shots / {r.steps} steps, {r.point_evaluations} point evaluations, "
              f"unshot {r.unshot_fraction:.2e}, balance error {r.balance_error:.1e}, back faces "
              f"{r.back_face_power.sum() / r.emitted_power.sum():.4f}, quadrature error est. {r.quadrature_error:.1e}; "
              f"{wall:.1f} s ({1e3 * wall / max(r.point_evaluations, 1):.2f} ms per point evaluation); "
              f"peak RSS {peak_rss_mb():.0f} MB (a dense float32 F would be {4 * n * n / 2**20:.0f} MB)")
        sys.stdout.flush()
        if args.profile:
            pstats.Stats(prof, stream=sys.stdout).sort_stats("cumulative").print_stats(12)


if __name__ == "__main__":
    main()
