"""Cost of the exact point evaluation on float64 against float32-rounded Cornell-box coordinates.

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_float32_geometry.py [--subdivisions 35] [--points 4]

Blender stores vertex coordinates as float32; the numeric boxes are float64. Prints, for the same
polygons, the time of ``core.form_factors`` at light-polygon centroids (one process, ``workers=1``, after
one call that prepares the scene; that call's time and the number of merged occluders are shown too) with
the coordinates as built, rounded to float32 everywhere, on the
(rotated) blocks only, on the (axis-aligned) room only, and with the blocks' quads split into triangles.
docs/first-pass.md ("Why the sample solves the numeric box") has the figures.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from hemisphere_local_pass.core import Scene, form_factors  # noqa: E402
from hemisphere_local_pass.core.chunk import scene_occluders  # noqa: E402
from hemisphere_local_pass.first_pass import patch_quadrature  # noqa: E402
from hemisphere_local_pass.scenes import cornell_box  # noqa: E402


def timed(vertices, polygons, emission, points):
    sc = Scene.from_polygons(vertices, polygons)
    q = patch_quadrature(sc, 1)
    idx = q.start[np.flatnonzero(emission.sum(axis=1) > 0)[:points]]
    t = time.perf_counter()
    form_factors(sc, q.points[idx[:1]], q.normals[idx[:1]], workers=1)  # preparation
    prep = time.perf_counter() - t
    t = time.perf_counter()
    f = form_factors(sc, q.points[idx], q.normals[idx], workers=1)
    return time.perf_counter() - t, prep, scene_occluders(sc).n, sc.n_input, float(np.abs(f.sum(axis=1) - 1).max())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subdivisions", type=int, default=35)
    ap.add_argument("--points", type=int, default=4)
    args = ap.parse_args(argv)
    box = cornell_box(args.subdivisions, block_detail=1.05)
    names = np.array(box.names)
    in_block = np.zeros(len(box.vertices), dtype=bool)
    for i, p in enumerate(box.polygons):
        if "block" in names[i]:
            in_block[p] = True
    f32 = box.vertices.astype(np.float32).astype(np.float64)
    tri, tri_emission = [], []
    for i, p in enumerate(box.polygons):
        parts = [[p[0], p[1], p[2]], [p[0], p[2], p[3]]] if "block" in names[i] and len(p) == 4 else [list(p)]
        tri += parts
        tri_emission += [box.emission[i]] * len(parts)
    tri_emission = np.array(tri_emission)
    cases = [("float64 (as built)", box.vertices, box.polygons, box.emission),
             ("float32 everywhere", f32, box.polygons, box.emission),
             ("float32 on the blocks only", np.where(in_block[:, None], f32, box.vertices), box.polygons, box.emission),
             ("float32 on the room only", np.where(in_block[:, None], box.vertices, f32), box.polygons, box.emission),
             ("blocks triangulated, float64", box.vertices, tri, tri_emission),
             ("blocks triangulated, float32", f32, tri, tri_emission)]
    print(f"# cornell_box({args.subdivisions}, block_detail=1.05), {args.points} light-centroid points, workers=1")
    print("| coordinates | polygons | occluders | preparation + 1 point (s) | points (s) | max abs(sum F - 1) |\n"
          "|---|---|---|---|---|---|")
    for label, v, polys, em in cases:
        secs, prep, n_o, n, err = timed(v, polys, em, args.points)
        print(f"| {label} | {n} | {n_o} | {prep:.2f} | {secs:.2f} | {err:.1e} |", flush=True)


if __name__ == "__main__":
    main()
