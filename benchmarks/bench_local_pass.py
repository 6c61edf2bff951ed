"""Speed of the exact local pass (issue 4): Cornell boxes of 175 and 9,468 polygons.

For >= 1,000 camera-visible surface points prints the time per point of the exact method
(``core.irradiance`` with the first-pass radiance on every polygon, and ``core.form_factors``), of the
unoccluded analytic sum over the same front-facing polygons (eq. 4 per polygon, no visibility,
vectorised: the floor no exact method can beat), their ratio, and max |ΣF − 1|.

Each method runs ``--repeat`` times, the three interleaved so that they share the machine's slow and
fast phases (a shared VM drifts by ±30 % over minutes); the table gives the fastest run and, in
brackets, the median, as ``timeit`` would.

    OMP_NUM_THREADS=1 python benchmarks/bench_local_pass.py [--points 1024] [--scenes small,large] [--repeat 5]
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import ROOT, case, log, machine, timed

from hemisphere_local_pass.baselines.analytic import unoccluded_form_factors
from hemisphere_local_pass.core import form_factors, irradiance


def floor_irradiance(scene, points, normals):
    """``Σ L_i F_i`` over the polygons facing each point, unoccluded (eq. 4): ``(m, 3)``."""
    return unoccluded_form_factors(scene, points, normals, front_only=True) @ scene.poly_radiance


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=1024)
    ap.add_argument("--scenes", default="small,large")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=5, help="runs of each method (min and median reported)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench_local_pass.md"), help="markdown copy ('' for none)")
    args = ap.parse_args(argv)
    lines = [f"# Speed of the exact local pass\n\nMachine: {machine()}\n",
             f"Command: `OMP_NUM_THREADS=1 python benchmarks/bench_local_pass.py --points {args.points} "
             f"--scenes {args.scenes} --repeat {args.repeat}`\n",
             f"Times: fastest of {args.repeat} interleaved runs (median in brackets), ms per point.\n",
             "| scene | polygons | points | exact irradiance ms/pt | exact form factors ms/pt | floor ms/pt "
             "| ratio (irradiance / floor) | max abs(ΣF − 1) | scene preparation s (once) |",
             "|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for key in args.scenes.split(","):
        box, scene, p, n, _ = case(key, args.points, args.seed)
        m = len(p)
        log(f"[{key}] {box.n_polygons} polygons, {m} points")
        # per-scene preparation (merged occluders, tiles, their edges), once per scene: timed apart
        _, t_setup = timed(irradiance, scene, p[:1], n[:1])
        log(f"[{key}] scene preparation {t_setup:.2f} s")
        runs = {"floor": [], "irradiance": [], "form factors": []}
        for r in range(args.repeat):
            _, t = timed(floor_irradiance, scene, p, n)
            runs["floor"].append(t)
            _, t = timed(irradiance, scene, p, n)
            runs["irradiance"].append(t)
            f, t = timed(form_factors, scene, p, n)
            runs["form factors"].append(t)
            log(f"[{key}] run {r + 1}: " + ", ".join(f"{k} {v[-1] / m * 1e3:.3f}" for k, v in runs.items()) + " ms/pt")
        best = {k: min(v) / m * 1e3 for k, v in runs.items()}
        cell = {k: f"{best[k]:.3f} ({float(np.median(v)) / m * 1e3:.3f})" for k, v in runs.items()}
        dev = float(np.abs(f.sum(axis=1) - 1.0).max())
        lines.append(f"| {key} | {box.n_polygons} | {m} | {cell['irradiance']} | {cell['form factors']} | "
                     f"{cell['floor']} | {best['irradiance'] / best['floor']:.1f} | {dev:.2e} | {t_setup:.2f} |")
        print(lines[-1], flush=True)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
