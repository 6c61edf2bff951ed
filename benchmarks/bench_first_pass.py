"""First pass (progressive refinement) on the Cornell boxes: time, shots, energy balance, peak memory.

    .venv/core/bin/python benchmarks/bench_first_pass.py [--scenes small,large] [--tolerance 1e-3]

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

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from hemisphere_local_pass.first_pass import ProgressiveSolver  # noqa: E402
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="small,large")
    ap.add_argument("--tolerance", type=float, default=1e-3)
    ap.add_argument("--order", type=int, default=2)
    ap.add_argument("--no-estimate", action="store_true", help="skip the 1-point error estimate")
    args = ap.parse_args(argv)
    print(f"# first pass, tolerance {args.tolerance:g}, order {args.order}; peak RSS before: {peak_rss_mb():.0f} MB")
    for key in args.scenes.split(","):
        box = cornell_box(**PAPER_SETTINGS[key])
        scene = box.scene()
        t0 = time.perf_counter()
        solver = ProgressiveSolver(scene, box.reflectivity, box.emission, tolerance=args.tolerance,
                                   order=args.order, estimate_error=not args.no_estimate)
        r = solver.run(progress=_Every(10.0))
        wall = time.perf_counter() - t0
        n = box.n_polygons
        print(f"{key}: {n} polygons, {r.shots} shots / {r.steps} steps, {r.point_evaluations} point evaluations, "
              f"unshot {r.unshot_fraction:.2e}, balance error {r.balance_error:.1e}, back faces "
              f"{r.back_face_power.sum() / r.emitted_power.sum():.4f}, quadrature error est. {r.quadrature_error:.1e}; "
              f"{wall:.1f} s ({1e3 * wall / max(r.point_evaluations, 1):.2f} ms per point evaluation); "
              f"peak RSS {peak_rss_mb():.0f} MB (a dense float32 F would be {4 * n * n / 2**20:.0f} MB)")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
