"""Does ``workers`` parallelise the adaptive pass? 1 against 2 workers, side by side in one process.

``core.adaptive_irradiance`` makes several core calls (two per quadtree level until 2026-12-06, one per
round of spot checks since). Each configuration runs on the same cached camera-ray hits of a benchmark Cornell box
(``bench_time_vs_error.prepare``), in turn, ``--repeat`` times (the best time is kept; the machine is
shared, so the load average is printed):

* ``1 worker``: every exact evaluation in this process;
* ``2 workers, a pool per call``: the behaviour before branch cv11 (each core call started its own
  pool of worker processes and shipped the scene to it; calls of fewer than
  ``parallel.MIN_POOL_CHUNKS`` chunks ran here);
* ``2 workers, one pool``: the current pass (one pool for all its calls, ``parallel.job_pool``);
* the control: ``core.irradiance`` at the same exact pixels in one call, on 1 and on 2 workers (how
  much the machine's load leaves to gain from a second process at all).

It also prints the sizes of the core calls (exact points per call). The images are checked bit for
bit against each other. CPU time (this process and its reaped worker processes) is printed too: the
wall times swing with the load of a shared machine, the CPU a configuration spends far less.

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_workers.py --scene large --size 128 --rel 1e-2
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import log  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="large")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--rel", type=float, default=1e-2, help="tolerance relative to the image's mean H")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args(argv)

    from bench_adaptive_oracle import reference

    import hemisphere_local_pass.core.adaptive as ad

    scene, p, n, g, H = reference(args.scene, args.size)
    tol = args.rel * float(H[g >= 0].mean())
    calls = []
    core = ad.irradiance

    def counting(scene_, pts, nrm, **kw):
        calls.append(len(pts))
        return core(scene_, pts, nrm, **kw)

    def per_call_pools(workers=None):  # the pass before cv11: no pool of its own
        return None, False

    configs = [("1 worker", 1, False), ("2 workers, a pool per call", 2, True), ("2 workers, one pool", 2, False)]
    best = {name: np.inf for name, *_ in configs}
    cpu = {}

    def cpu_now():  # this process and its reaped children (every pool is shut down and reaped by then)
        t = os.times()
        return t.user + t.system + t.children_user + t.children_system
    images = {}
    ad.irradiance = counting
    saved_pool = ad.job_pool
    try:
        # warm-up: the scene's caches (occluders, hierarchy) are built once, outside the timings
        core(scene, p[g >= 0][:64], n[g >= 0][:64], workers=1)
        for rep in range(args.repeat):
            for name, workers, old in configs:
                ad.job_pool = per_call_pools if old else saved_pool
                calls.clear()
                c0, t = cpu_now(), time.perf_counter()
                img, st = ad.adaptive_irradiance(scene, p, n, g, tolerance=tol, workers=workers)
                sec = time.perf_counter() - t
                cpu[name] = min(cpu.get(name, np.inf), cpu_now() - c0)
                best[name] = min(best[name], sec)
                images[name] = img
                log(f"[{rep}] {name}: {sec:.2f} s, {st.exact_points} exact, {len(calls)} core calls")
            mask = st.exact_mask
            for workers in (1, 2):
                name = f"core.irradiance, the same pixels in one call, {workers} worker{'s' * (workers > 1)}"
                c0, t = cpu_now(), time.perf_counter()
                core(scene, p[mask], n[mask], workers=workers)
                sec = time.perf_counter() - t
                cpu[name] = min(cpu.get(name, np.inf), cpu_now() - c0)
                best[name] = min(best.get(name, np.inf), sec)
                log(f"[{rep}] {name}: {sec:.2f} s")
    finally:
        ad.irradiance = core
        ad.job_pool = saved_pool
    ref = images["1 worker"]
    same = all(np.array_equal(ref, im) for im in images.values())
    sizes = np.array(calls)
    print(f"{args.scene} box ({scene.n_input} polygons), {args.size}², tolerance {args.rel:g} of the mean; "
          f"{st.exact_points} exact evaluations ({st.exact_fraction:.1%}), load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"core calls: {len(sizes)}, points per call: min {sizes.min()}, median {int(np.median(sizes))}, "
          f"max {sizes.max()}; images bit-identical: {same}\n")
    print("| configuration | best wall time (s) | speed-up over 1 worker (same kind) | least CPU time, "
          "parent + workers (s) |")
    print("|---|---|---|---|")
    for name in best:
        base = best["1 worker"] if name in dict((c[0], 0) for c in configs) else best[
            "core.irradiance, the same pixels in one call, 1 worker"]
        print(f"| {name} | {best[name]:.2f} | {base / best[name]:.2f} | {cpu[name]:.2f} |")


if __name__ == "__main__":
    main()
