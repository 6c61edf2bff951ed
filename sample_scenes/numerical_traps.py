"""A scene of numerical traps, far from the origin; solved, with a camera.

    blender -b --python sample_scenes/numerical_traps.py -- out.blend [--cells 4] [--resolution 64]
    python sample_scenes/numerical_traps.py out.blend ...     # a venv with the bpy module

Everything stands at ``OFFSET`` = (20000, -15000, 300) m (float32 vertices there are only known to about
2 mm; the objects keep small local coordinates and their matrix carries the offset), in a closed
4 × 4 × 3 m room lit by a ceiling panel:

* **touching faces**: a crate resting exactly on the floor, a second crate touching the first face to face;
* **coplanar faces**: a poster lying exactly in the back wall's plane (overlapping it), a copy of one
  wall cell on top of itself, and a mat 1 µm above the floor;
* **slivers**: a fan of 40 triangles 2 m long and 0.2 mm wide on the left wall;
* **tiny and huge polygons together**: a 10 × 10 grid of 1 mm tiles on the crate, and a 2 km × 2 km
  ground quad 1 cm below the room's floor (hidden from the inside, but in every form-factor computation).
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import _common as c  # noqa: E402

OFFSET = (20000.0, -15000.0, 300.0)
W = D = 4.0
H = 3.0


def build(cells: int = 4, *, resolution: int = 64, tolerance=None, order=None, quiet=False, solve=True):
    import bpy

    c.reset()
    white = c.material("white", (0.7, 0.7, 0.7))
    red = c.material("red", (0.7, 0.15, 0.1))
    blue = c.material("blue", (0.1, 0.2, 0.6))
    lamp = c.material("lamp", (0.8, 0.8, 0.8), (15.0, 14.0, 12.0))
    off = OFFSET
    c.mesh_object("Room", *c.box((0, 0, 0), (W, D, H), inward=True, cells=cells), white, location=off)
    c.mesh_object("Lamp", [(1.5, 1.5, H - 0.01), (1.5, 2.5, H - 0.01), (2.5, 2.5, H - 0.01), (2.5, 1.5, H - 0.01)],
                  [[0, 1, 2, 3]], lamp, location=off)
    # touching: on the floor, and face to face
    c.mesh_object("Crate", *c.box((0.8, 0.8, 0.0), (1.6, 1.6, 0.8)), red, location=off)
    c.mesh_object("Crate2", *c.box((1.6, 1.0, 0.0), (2.1, 1.5, 0.5)), blue, location=off)
    # coplanar: a poster in the back wall's plane, a duplicate wall cell, a mat 1 µm above the floor
    c.mesh_object("Poster", [(2.6, D, 1.0), (1.4, D, 1.0), (1.4, D, 2.2), (2.6, D, 2.2)], [[0, 1, 2, 3]], blue,
                  location=off)  # faces -y, into the room, exactly in the wall plane
    s = W / cells
    c.mesh_object("DuplicateCell", [(0, 0, 0), (0, s, 0), (s, s, 0), (s, 0, 0)], [[0, 1, 2, 3]], white,
                  location=(off[0] + W - s, off[1] + D - s, off[2] + H))  # a ceiling cell twice, facing down
    c.mesh_object("Mat", [(2.4, 2.4, 1e-6), (3.6, 2.4, 1e-6), (3.6, 3.6, 1e-6), (2.4, 3.6, 1e-6)], [[0, 1, 2, 3]],
                  red, location=off)
    # slivers: a fan on the left wall (x = 0, facing +x)
    verts = [(0.0, 0.5, 0.2)]
    faces = []
    for k in range(41):
        verts.append((0.0, 0.5 + 2e-4 * k, 2.2))
    for k in range(40):
        faces.append([0, k + 2, k + 1])  # facing +x, into the room
    c.mesh_object("Slivers", verts, faces, white, location=off)
    # tiny tiles on the crate's top, a huge ground under the room
    tiles_v, tiles_f = [], []
    for i in range(10):
        for j in range(10):
            x, y = 1.0 + 2e-3 * i, 1.0 + 2e-3 * j
            b = len(tiles_v)
            tiles_v += [(x, y, 0.8 + 1e-4), (x + 1e-3, y, 0.8 + 1e-4), (x + 1e-3, y + 1e-3, 0.8 + 1e-4),
                        (x, y + 1e-3, 0.8 + 1e-4)]
            tiles_f.append([b, b + 1, b + 2, b + 3])
    c.mesh_object("TinyTiles", tiles_v, tiles_f, blue, location=off)
    g = 1000.0
    c.mesh_object("Ground", [(-g, -g, -0.01), (g, -g, -0.01), (g, g, -0.01), (-g, g, -0.01)], [[0, 1, 2, 3]], white,
                  location=off)
    cam = (off[0] + 3.6, off[1] + 0.4, off[2] + 1.7)
    c.camera(cam, (off[0] + 1.0, off[1] + 3.0, off[2] + 0.8), lens=18.0, resolution=(resolution, resolution),
             clip=(0.01, 50.0))
    bpy.context.view_layer.update()
    report = c.solve("numerical_traps", tolerance=1e-2 if tolerance is None else tolerance, order=order,
                     quiet=quiet) if solve else None
    return bpy.context.scene, report


def main(argv):
    ap = c.parser("numerical_traps.py", "Build the numerical-traps sample .blend")
    ap.add_argument("--cells", type=int, default=4, help="cells per room face side")
    args = ap.parse_args(argv)
    build(args.cells, resolution=args.resolution, tolerance=args.tolerance, order=args.order)
    c.save("numerical_traps", args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main(c.script_argv()))
