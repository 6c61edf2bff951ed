"""Cost of the exact point evaluation on float64 against float32-rounded Cornell-box coordinates.

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_float32_geometry.py [--subdivisions 35] [--points 4]

Blender stores vertex coordinates as float32; the numeric boxes are float64. Prints, for the same
polygons, the CPU time (``time.process_time``, one process, ``workers=1``) of ``core.form_factors`` at
light-polygon centroids after one call that prepares the scene (that call's time and the number of
merged occluders are shown too, and both times as ratios to the float64 scene) with the coordinates as
built, rounded to float32 everywhere, on the (rotated) blocks only, on the (axis-aligned) room only, and
with the blocks' quads split into triangles. A second table replaces the classic blocks by rectangular
ones (same cells, rotated about z) built the two ways a Blender scene holds a rotated object: the
rotation in the object's transform (float32 *local* coordinates, axis-aligned, turned into world space
in float64 by ``scene_export`` with the float32 ``matrix_world``) or applied to the mesh (float32 world
coordinates, like the classic blocks). docs/first-pass.md ("Why the sample solves the numeric box") has
the figures.
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

F32 = np.float32

#: rectangular blocks (width, depth, height; centre x, y; rotation about z in radians), about the classic
#: ones in the unit box
RECT_BLOCKS = [((0.30, 0.30, 0.30), (0.66, 0.30), -0.29), ((0.30, 0.30, 0.60), (0.33, 0.62), 0.28)]


def timed(vertices, polygons, emission, points):
    sc = Scene.from_polygons(vertices, polygons)
    q = patch_quadrature(sc, 1)
    idx = q.start[np.flatnonzero(np.asarray(emission).sum(axis=1) > 0)[:points]]
    t = time.process_time()
    form_factors(sc, q.points[idx[:1]], q.normals[idx[:1]], workers=1)  # preparation
    prep = time.process_time() - t
    t = time.process_time()
    f = form_factors(sc, q.points[idx], q.normals[idx], workers=1)
    return time.process_time() - t, prep, scene_occluders(sc).n, sc.n_input, float(np.abs(f.sum(axis=1) - 1).max())


def rect_block(size, cell):
    """A rectangular block without bottom, centred on the z axis, standing on z = 0, in cells of about
    ``cell``: ``(V, 3)`` float32 local vertices (carried in float64) and quads facing outward."""
    w, d, h = size
    xs = np.linspace(-w / 2, w / 2, max(1, round(w / cell)) + 1)
    ys = np.linspace(-d / 2, d / 2, max(1, round(d / cell)) + 1)
    zs = np.linspace(0.0, h, max(1, round(h / cell)) + 1)
    index, quads = {}, []

    def vid(x, y, z):
        return index.setdefault((F32(x), F32(y), F32(z)), len(index))

    def strip(a, b, fix, at, lo, hi, flip):  # quads of the plane coordinate `fix` = at, cells a x b
        for i in range(len(a) - 1):
            for j in range(len(b) - 1):
                c = [(a[i], b[j]), (a[i + 1], b[j]), (a[i + 1], b[j + 1]), (a[i], b[j + 1])]
                q = [vid(*np.insert(np.array(p), fix, at)) for p in (c[::-1] if flip else c)]
                quads.append(q)

    strip(xs, ys, 2, h, 0, 0, False)                    # top (+z)
    strip(xs, zs, 1, ys[0], 0, 0, False)                # -y side: (x, z) counter-clockwise about -y
    strip(xs, zs, 1, ys[-1], 0, 0, True)
    strip(ys, zs, 0, xs[0], 0, 0, True)
    strip(ys, zs, 0, xs[-1], 0, 0, False)
    return np.array(list(index), dtype=np.float64), quads


def rect_scene(box, mode, cell):
    """The room of ``box`` plus :data:`RECT_BLOCKS`: ``mode`` "float64" (world coordinates in float64),
    "transform" (float32 room; blocks in float32 local coordinates times a float32 matrix, in float64: a
    Blender object with its rotation in the transform) or "applied" (those world coordinates rounded to
    float32: the rotation applied to the mesh)."""
    names = np.array(box.names)
    room = [p for p, n in zip(box.polygons, names) if "block" not in n]
    emission = [e for e, n in zip(box.emission, names) if "block" not in n]
    verts = [box.vertices if mode == "float64" else box.vertices.astype(F32).astype(np.float64)]
    polys, off = list(room), len(box.vertices)
    for size, (cx, cy), angle in RECT_BLOCKS:
        local, quads = rect_block(size, cell)
        c, s = np.cos(angle), np.sin(angle)
        m = np.array([[c, -s, 0.0, cx], [s, c, 0.0, cy], [0.0, 0.0, 1.0, 0.0]])
        if mode != "float64":
            m = m.astype(F32).astype(np.float64)
        world = local @ m[:, :3].T + m[:, 3]
        if mode == "applied":
            world = world.astype(F32).astype(np.float64)
        verts.append(world)
        polys += [[i + off for i in q] for q in quads]
        emission += [np.zeros(3)] * len(quads)
        off += len(world)
    return np.concatenate(verts), polys, np.array(emission)


def table(title, cases, points):
    print(f"\n# {title}, {points} light-centroid points, workers=1, CPU seconds")
    print("| coordinates | polygons | occluders | preparation + 1 point (s) | points (s) | ratio to float64 "
          "(prep / points) | max abs(sum F - 1) |\n|---|---|---|---|---|---|---|")
    ref = None
    for label, v, polys, em in cases:
        secs, prep, n_o, n, err = timed(v, polys, em, points)
        ref = ref or (prep, secs)
        print(f"| {label} | {n} | {n_o} | {prep:.2f} | {secs:.3f} | {prep / ref[0]:.1f} / {secs / ref[1]:.1f} "
              f"| {err:.1e} |", flush=True)


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
    f32 = box.vertices.astype(F32).astype(np.float64)
    tri, tri_emission = [], []
    for i, p in enumerate(box.polygons):
        parts = [[p[0], p[1], p[2]], [p[0], p[2], p[3]]] if "block" in names[i] and len(p) == 4 else [list(p)]
        tri += parts
        tri_emission += [box.emission[i]] * len(parts)
    tri_emission = np.array(tri_emission)
    table(f"cornell_box({args.subdivisions}, block_detail=1.05)", [
        ("float64 (as built)", box.vertices, box.polygons, box.emission),
        ("float32 everywhere", f32, box.polygons, box.emission),
        ("float32 on the blocks only", np.where(in_block[:, None], f32, box.vertices), box.polygons, box.emission),
        ("float32 on the room only", np.where(in_block[:, None], box.vertices, f32), box.polygons, box.emission),
        ("blocks triangulated, float64", box.vertices, tri, tri_emission),
        ("blocks triangulated, float32", f32, tri, tri_emission)], args.points)
    cell = 1.0 / (args.subdivisions * 1.05)
    table(f"the same room with rectangular blocks (cells of 1/{args.subdivisions * 1.05:g})", [
        (label, *rect_scene(box, mode, cell)) for label, mode in [
            ("float64", "float64"), ("float32, rotation in the object transform", "transform"),
            ("float32, rotation applied to the mesh", "applied")]], args.points)


if __name__ == "__main__":
    main()
