"""Speed of the exact local pass (issue 4): Cornell boxes of 175 and 9,468 polygons.

For >= 1,000 camera-visible surface points prints the time per point of the exact method
(``core.irradiance`` with the first-pass radiance on every polygon, and ``core.form_factors``), of the
unoccluded analytic sum over the same front-facing polygons (eq. 4 per polygon, no visibility,
vectorised: the floor no exact method can beat), their ratio, and max |ΣF − 1|.

    OMP_NUM_THREADS=1 python benchmarks/bench_local_pass.py [--points 1024] [--scenes small,large]
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
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench_local_pass.md"), help="markdown copy ('' for none)")
    args = ap.parse_args(argv)
    lines = [f"# Speed of the exact local pass\n\nMachine: {machine()}\n",
             f"Command: `OMP_NUM_THREADS=1 python benchmarks/bench_local_pass.py --points {args.points} "
             f"--scenes {args.scenes}`\n",
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
        _, t_floor = timed(floor_irradiance, scene, p, n)
        log(f"[{key}] floor {t_floor / m * 1e3:.3f} ms/pt")
        _, t_h = timed(irradiance, scene, p, n)
        log(f"[{key}] irradiance {t_h / m * 1e3:.3f} ms/pt")
        f, t_f = timed(form_factors, scene, p, n)
        dev = float(np.abs(f.sum(axis=1) - 1.0).max())
        lines.append(f"| {key} | {box.n_polygons} | {m} | {t_h / m * 1e3:.3f} | {t_f / m * 1e3:.3f} | "
                     f"{t_floor / m * 1e3:.3f} | {t_h / t_floor:.1f} | {dev:.2e} | {t_setup:.2f} |")
        print(lines[-1], flush=True)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
