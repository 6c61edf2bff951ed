"""The adaptive pass on vertex receivers (issue 11: "vertices use it where it pays"): time and measured error.

The receivers are what the Blender job's vertices mode makes of the Cornell box's mesh in the CORNER domain
(flat faces): one per face corner, the face's normal, the one-sided limit towards the face's centroid. For
each scene the all-exact values (``core.irradiance``, every receiver) and the adaptive ones
(``core.adaptive_vertex_irradiance`` at tolerances relative to the mean H) are timed side by side in one
run, with the same workers; the adaptive results' max error over receivers and channels is measured against
the exact ones. The row "far field" is the job's path before the adaptive pass: every receiver from the core's
error-bounded far field with the whole tolerance. (The exact row already profits from the core's own skips:
idle one-sided limits dropped, repeated receivers evaluated once — ``core.receivers``, ``core.local_pass``.)

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_vertices.py [--scenes large,huge]
        [--rel 1e-2,1e-3] [--workers 2] [--sample-share 0.1 --final-share 0.9] [--parts floor,...]
        [--out docs/bench_adaptive_vertices]

``huge`` is the 187,588-polygon box (160 subdivisions per wall); the 175-polygon box has 6 lattice lines a
side, below ``MIN_SIDE``: nothing to interpolate there.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time

import numpy as np
from _common import ROOT, log, machine, solved_radiance

from hemisphere_local_pass.core import irradiance
from hemisphere_local_pass.core.adaptive import FINAL_SHARE, SAMPLE_SHARE
from hemisphere_local_pass.core.adaptive_vertices import adaptive_vertex_irradiance, lattices
from hemisphere_local_pass.core.local_pass import _distinct_receivers
from hemisphere_local_pass.core.receivers import idle_limits_dropped, prepare_receivers
from hemisphere_local_pass.scenes import PAPER_SETTINGS, cornell_box

SETTINGS = dict(PAPER_SETTINGS, huge={"subdivisions": 160}, medium={"subdivisions": 16})


def corner_receivers(box, scene, parts=None):
    """CORNER-domain receivers of ``box``: ``(points, normals, limits, polygons)``, one per face corner (of the
    polygons named in ``parts`` only, e.g. ``("floor",)``; None: all)."""
    loops = [(i, v) for i, poly in enumerate(box.polygons) for v in poly if parts is None or box.names[i] in parts]
    poly = np.array([i for i, _ in loops], dtype=np.int64)
    pts = box.vertices[[v for _, v in loops]]
    nrm = box.normals()[poly]
    cen = box.centroids()[poly]
    d = cen - pts
    d -= np.einsum("ij,ij->i", d, nrm)[:, None] * nrm
    lim = d / np.linalg.norm(d, axis=1, keepdims=True)
    return pts, nrm, lim, poly


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="large")
    ap.add_argument("--rel", default="1e-2,1e-3,1e-4")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--sample-share", type=float, default=SAMPLE_SHARE, help="as the Blender job (core.adaptive)")
    ap.add_argument("--final-share", type=float, default=FINAL_SHARE)
    ap.add_argument("--parts", default="", help="receivers on these parts only (e.g. 'floor,back wall'); all if empty")
    ap.add_argument("--out", default="", help="write <out>.md and <out>.json")
    args = ap.parse_args(argv)
    rels = [float(r) for r in args.rel.split(",")]
    cmd = ("OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_vertices.py "
           + shlex.join(argv if argv is not None else sys.argv[1:]))
    lines = [f"# The adaptive pass on vertex receivers\n\nMachine: {machine()}\n", f"Command: `{cmd}`\n",
             "| scene | receivers | on lattices | method | time s | core evaluations | max error / tol | "
             "mean error / tol | largest estimate / tol |", "|---|---|---|---|---|---|---|---|---|"]
    rows = []
    for key in args.scenes.split(","):
        box = cornell_box(**SETTINGS[key])
        lum = solved_radiance(key, box)  # cached; gathered from the small box's solution (benchmarks/_common.py)
        scene = box.scene(radiance=lum)
        p, n, lim, g = corner_receivers(box, scene, args.parts.split(",") if args.parts else None)
        m = len(p)
        irradiance(scene, p[:8], n[:8], limit_directions=lim[:8], workers=1)  # scene preparation, once
        t = time.perf_counter()
        lats = lattices(scene, p, n, g)
        t_lat = time.perf_counter() - t
        on = sum(len(la.receivers) for la in lats)
        u = idle_limits_dropped(scene, p, n, prepare_receivers(p, n, lim)[2])
        reps = _distinct_receivers(p, n, u)[0]
        distinct = m if reps is None else len(reps)
        keep = 0 if u is None else int(u.any(axis=1).sum())
        log(f"[{key}] {box.n_polygons} polygons, {m} receivers ({distinct} distinct for the core, {keep} with a "
            f"one-sided limit), {len(lats)} lattices holding {on} ({t_lat:.2f} s)")
        lines.insert(2, f"{key}: {m} receivers, {distinct} distinct for the core (a vertex's corners on one plane are "
                        f"one receiver once their idle limits are dropped), {keep} keep a one-sided limit.\n")
        t = time.perf_counter()
        exact = irradiance(scene, p, n, limit_directions=lim, workers=args.workers)
        t_exact = time.perf_counter() - t
        log(f"[{key}] exact {t_exact:.1f} s")
        mean = float(exact.mean())
        row = f"| {key} ({box.n_polygons}{', ' + args.parts if args.parts else ''}) | {m} | {on} ({on / m:.0%}) |"
        lines.append(f"{row} exact | {t_exact:.1f} | {distinct} distinct ({distinct / m:.1%}) | 0 | 0 | 0 |")
        rows.append(dict(scene=key, polygons=box.n_polygons, receivers=m, on_lattices=on, method="exact",
                         seconds=t_exact, exact_points=distinct))
        for rel in rels:
            tol = rel * mean
            # the job's path before the adaptive pass: every receiver from the far field with the whole tolerance
            t = time.perf_counter()
            H, far = irradiance(scene, p, n, limit_directions=lim, tolerance=tol, workers=args.workers,
                                return_stats=True)
            dt = time.perf_counter() - t
            e = np.abs(H - exact).max(axis=1)
            log(f"[{key}] far field {rel:g}: {dt:.1f} s, max error {e.max() / tol:.3f} tol")
            lines.append(f"{row} far field {rel:g} | {dt:.1f} ({t_exact / dt:.2f}× faster) | {distinct} distinct | "
                         f"{e.max() / tol:.3f} | {e.mean() / tol:.4f} | {far.error_bound.max() / tol:.3f} |")
            rows.append(dict(scene=key, polygons=box.n_polygons, receivers=m, on_lattices=on,
                             method=f"far field {rel:g}",
                             rel=rel, tolerance=tol, seconds=dt, exact_points=m,
                             max_error_over_tol=float(e.max() / tol), mean_error_over_tol=float(e.mean() / tol),
                             estimate_over_tol=float(far.error_bound.max() / tol)))
            t = time.perf_counter()
            H, st = adaptive_vertex_irradiance(scene, p, n, g, limit_directions=lim, tolerance=tol,
                                               workers=args.workers, sample_share=args.sample_share,
                                               final_share=args.final_share)
            dt = time.perf_counter() - t
            e = np.abs(H - exact).max(axis=1)
            log(f"[{key}] {rel:g}: {dt:.1f} s, {st.exact_points} core evaluations ({st.exact_fraction:.1%}), max "
                f"error {e.max() / tol:.3f} tol, estimate {st.error_estimate / tol:.3f} tol, {st.on_segment} on "
                "segments")
            lines.append(f"{row} adaptive {rel:g} | {dt:.1f} ({t_exact / dt:.2f}× faster) | {st.exact_points} "
                         f"({st.exact_fraction:.1%}) | {e.max() / tol:.3f} | {e.mean() / tol:.4f} | "
                         f"{st.error_estimate / tol:.3f} |")
            rows.append(dict(scene=key, polygons=box.n_polygons, receivers=m, on_lattices=on,
                             method=f"adaptive {rel:g}",
                             rel=rel, tolerance=tol, seconds=dt, exact_points=st.exact_points,
                             max_error_over_tol=float(e.max() / tol), mean_error_over_tol=float(e.mean() / tol),
                             estimate_over_tol=float(st.error_estimate / tol), on_segment=st.on_segment))
    print("\n".join(lines))
    if args.out:
        out = ROOT / args.out
        out.with_suffix(".md").write_text("\n".join(lines) + "\n")
        out.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
