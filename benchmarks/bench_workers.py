"""Every core (issue 10, parts 3 and 6): the exact local pass on 1 and on all workers, side by side.

For the Cornell boxes of 175 and 9,468 polygons and camera-visible points, prints per method the wall
time per point, the CPU time (this process + its workers) and the speedup of N workers over one process,
the runs of 1 and N workers interleaved ``--repeat`` times so that they share the machine's slow and fast
phases (fastest and median). Checks that every run gives the same bits. Also prints what a worker costs:
starting a pool, and shipping the prepared scene (pickle + unpickle of the scene with its caches) against
preparing it again in the worker (the pool ships it: see ``core.parallel``).

    python benchmarks/bench_workers.py [--points 1024] [--scenes small,large] [--repeat 3] [--workers N]
"""

from __future__ import annotations

import argparse
import copy
import os
import pickle
import time

import numpy as np
from _common import ROOT, case, log, machine

from hemisphere_local_pass.core import form_factors, irradiance
from hemisphere_local_pass.core.clear_tiles import tile_edges
from hemisphere_local_pass.core.culling import build_occluders
from hemisphere_local_pass.core.local_pass import _occluders, _tile_edges
from hemisphere_local_pass.core.parallel import WorkerPool, default_workers


def _cpu_of(pids) -> float:
    """User + system CPU seconds of live processes ``pids`` (Linux /proc)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0
    for pid in pids:
        with open(f"/proc/{pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        total += int(fields[11]) + int(fields[12])
    return total / tick


def _self_cpu() -> float:
    t = os.times()
    return t.user + t.system


def _load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=1024)
    ap.add_argument("--scenes", default="small,large")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workers", type=int, default=0, help="N (0: every core, os.sched_getaffinity)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench_workers.md"), help="markdown copy ('' for none)")
    args = ap.parse_args(argv)
    n = args.workers or default_workers()
    lines = [f"# The local pass on 1 and {n} workers\n\nMachine: {machine()}; load average at start {_load()}\n",
             f"Command: `python benchmarks/bench_workers.py --points {args.points} --scenes {args.scenes} "
             f"--repeat {args.repeat} --workers {args.workers}`\n"]

    t = time.perf_counter()
    pool = WorkerPool(n)
    pool.submit(abs, 1).result()
    start = time.perf_counter() - t
    lines.append(f"Starting a pool of {n} workers (Python + numpy + the core's imports, in parallel): "
                 f"{start:.2f} s wall, {_cpu_of(pool.pids):.2f} s CPU in all.\n")

    lines += ["| scene | polygons | method | 1 process ms/pt (median) | " + f"{n} workers ms/pt (median) | "
              "speedup (of medians) | CPU s, 1 | CPU s, N | same bits |",
              "|---|---|---|---|---|---|---|---|---|"]
    ship = []
    for key in args.scenes.split(","):
        _, scene, pts, nrm, _ = case(key, args.points)
        m = len(pts)
        # shipping the prepared scene vs preparing it again
        occ = _occluders(scene, None)
        if len(occ.tile_occluder):
            _tile_edges(scene, occ)
        t = time.perf_counter()
        blob = pickle.dumps((scene, occ), protocol=pickle.HIGHEST_PROTOCOL)
        dump = time.perf_counter() - t
        t = time.perf_counter()
        pickle.loads(blob)
        load = time.perf_counter() - t
        bare = copy.copy(scene)
        for attr in [a for a in vars(bare) if a.startswith("_") and a not in ("_n",)]:
            if attr in ("_occluders", "_tile_edges", "_hierarchy", "_radiance_tables", "_reps", "_wanted"):
                delattr(bare, attr)
        t = time.perf_counter()
        occ2 = build_occluders(bare)
        if len(occ2.tile_occluder):
            tile_edges(bare, occ2)
        prep = time.perf_counter() - t
        ship.append(f"| {key} | {scene.n_polygons} | {len(blob) / 2**20:.2f} MB | {dump * 1e3:.1f} | "
                    f"{load * 1e3:.1f} | {prep * 1e3:.1f} |")

        for name, fn in (("irradiance", irradiance), ("form_factors", form_factors)):
            runs = {1: [], n: []}
            cpu = {1: [], n: []}
            ref = None
            same = True
            fn(scene, pts[:8], nrm[:8], workers=1)  # warm caches
            for r in range(args.repeat):
                for w in (1, n) if r % 2 == 0 else (n, 1):
                    c0, p0 = _self_cpu(), _cpu_of(pool.pids)
                    t = time.perf_counter()
                    out = fn(scene, pts, nrm, workers=1) if w == 1 else fn(scene, pts, nrm, executor=pool)
                    runs[w].append(time.perf_counter() - t)
                    cpu[w].append(_self_cpu() - c0 + _cpu_of(pool.pids) - p0)
                    if ref is None:
                        ref = out
                    same &= bool(np.array_equal(ref, out))
                    log(f"{key} {name} workers={w}: {runs[w][-1]:.2f} s (load {_load()})")
            med = {w: float(np.median(v)) for w, v in runs.items()}
            best = {w: min(v) for w, v in runs.items()}
            lines.append(f"| {key} | {scene.n_polygons} | {name} | {best[1] / m * 1e3:.3f} ({med[1] / m * 1e3:.3f}) | "
                         f"{best[n] / m * 1e3:.3f} ({med[n] / m * 1e3:.3f}) | {med[1] / med[n]:.2f}× | "
                         f"{np.median(cpu[1]):.2f} | {np.median(cpu[n]):.2f} | {'yes' if same else 'NO'} |")
    pool.shutdown()
    lines += ["", f"{args.points} camera-visible points per scene; N = {n}; a kept pool (its start-up excluded; "
              "see above); the N-worker CPU column adds the workers' CPU to this process's.", "",
              "Shipping the prepared scene (what a worker receives once) against preparing it again:", "",
              "| scene | polygons | pickle size | pickle ms | unpickle ms | prepare again ms |",
              "|---|---|---|---|---|---|",
              *ship, "", f"Load average at the end {_load()}."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text)


if __name__ == "__main__":
    main()
