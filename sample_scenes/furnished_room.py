"""A furnished room: interpenetrating and instanced geometry, an n-gon window, modifiers; solved, with a camera.

    blender -b --python sample_scenes/furnished_room.py -- out.blend [--detail 1] [--resolution 64]
    python sample_scenes/furnished_room.py out.blend ...      # a venv with the bpy module

A closed 5 × 4 × 2.7 m room (2 × ``--detail`` cells per face side) lit by a 13-vertex arched window
(one n-gon, emitting sky light, 1 mm in front of its wall) and a ceiling panel. Furniture:

* a table: a plane with a **Solidify** modifier as the top, four legs that pass through it
  (**interpenetrating**);
* a chair (seat and back interpenetrating) in the collection "Chair", placed once and **instanced** three
  more times by collection-instance empties (one mirrored by a negative scale);
* a bookshelf: a board with an **Array** modifier (five shelves) between two side panels made by a
  **Mirror** modifier;
* a cushion on the sofa with a **Subdivision Surface** modifier; the sofa's back **Bevel**-ed.

Then the first pass (``hemisphere_local_pass.blender.first_pass``) writes the FACE ``radiosity``
attribute; instanced meshes hold the mean over their placements (the report says so).
"""

from __future__ import annotations

import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import _common as c  # noqa: E402

W, D, H = 5.0, 4.0, 2.7
WHITE, WOOD, FABRIC, FLOOR = (0.75, 0.75, 0.72), (0.45, 0.28, 0.15), (0.25, 0.35, 0.6), (0.55, 0.5, 0.45)


def window_ngon(centre_x, bottom, width, height, arch_points=9):
    """A window outline in the plane y = D − 1 mm (facing −y, into the room): 12 vertices, arched top."""
    y = D - 1e-3
    r = width / 2
    pts = [(centre_x + r, y, bottom), (centre_x - r, y, bottom)]
    pts.append((centre_x - r, y, bottom + height - r))
    for k in range(1, arch_points + 1):  # the arch, from left to right
        t = math.pi - math.pi * k / (arch_points + 1)
        pts.append((centre_x + r * math.cos(t), y, bottom + height - r + r * math.sin(t)))
    pts.append((centre_x + r, y, bottom + height - r))
    return pts[::-1]  # counter-clockwise seen from inside: the normal points into the room (-y)


def build(detail: int = 1, *, resolution: int = 64, tolerance=None, order=None, quiet=False, solve=True):
    import bpy

    c.reset()
    scene = bpy.context.scene
    white, wood, fabric, floor = (c.material(n, rho) for n, rho in
                                  (("white", WHITE), ("wood", WOOD), ("fabric", FABRIC), ("floor", FLOOR)))
    cells = max(1, 2 * detail)
    room = c.box((0, 0, 0), (W, D, H), inward=True, cells=cells)
    ob_room = c.mesh_object("Room", *room, white)
    ob_room.data.materials.append(floor)
    # the floor cells (normal +z) get the floor material
    for poly in ob_room.data.polygons:
        if poly.normal.z > 0.5:
            poly.material_index = 1
    sky = c.material("sky", (0.0, 0.0, 0.0), (2.5, 3.0, 3.6))
    win = window_ngon(2.5, 0.9, 1.2, 1.5)
    c.mesh_object("Window", win, [list(range(len(win)))], sky)
    lamp = c.material("lamp", (0.8, 0.8, 0.8), (12.0, 11.0, 9.0))
    c.mesh_object("CeilingLamp", [(2.2, 1.8, H - 0.02), (2.2, 2.4, H - 0.02), (2.8, 2.4, H - 0.02),
                                  (2.8, 1.8, H - 0.02)], [[0, 1, 2, 3]], lamp)   # faces down
    # table: a solidified top and legs through it
    top = c.mesh_object("TableTop", [(-0.7, -0.45, 0), (0.7, -0.45, 0), (0.7, 0.45, 0), (-0.7, 0.45, 0)],
                        [[0, 1, 2, 3]], wood, location=(2.5, 1.6, 0.75))
    top.modifiers.new("Solidify", "SOLIDIFY").thickness = 0.04
    for k, (x, y) in enumerate([(-0.6, -0.35), (0.6, -0.35), (0.6, 0.35), (-0.6, 0.35)]):
        c.mesh_object(f"Leg{k}", *c.box((x - 0.03, y - 0.03, 0), (x + 0.03, y + 0.03, 0.78)), wood,
                      location=(2.5, 1.6, 0))
    # a chair in its own collection, placed once and instanced three times
    chair = bpy.data.collections.new("Chair")
    scene.collection.children.link(chair)
    c.mesh_object("Seat", *c.box((-0.22, -0.22, 0.42), (0.22, 0.22, 0.47)), fabric, collection=chair)
    c.mesh_object("Back", *c.box((-0.22, 0.17, 0.3), (0.22, 0.22, 0.95)), wood, collection=chair)  # through the seat
    for k, (x, y, rot, mirror) in enumerate([(2.5, 0.7, 0.0, 1), (1.5, 1.6, math.pi / 2, 1),
                                             (3.5, 1.6, -math.pi / 2, -1)]):
        empty = bpy.data.objects.new(f"ChairInstance{k}", None)
        empty.instance_type = "COLLECTION"
        empty.instance_collection = chair
        empty.location = (x, y, 0.0)
        empty.rotation_euler = (0.0, 0.0, rot)
        empty.scale = (mirror, 1.0, 1.0)
        scene.collection.objects.link(empty)
    chair.instance_offset = (0.0, 0.0, 0.0)
    for ob in chair.objects:  # the collection's own chair stands at the table's far side, facing it
        ob.location = (2.5, 2.5, 0.0)
        ob.rotation_euler = (0.0, 0.0, math.pi)
    # bookshelf: an arrayed board, mirrored side panels
    board = c.mesh_object("Shelf", *c.box((-0.4, -0.15, 0.0), (0.4, 0.15, 0.02)), wood, location=(0.6, 3.75, 0.1))
    arr = board.modifiers.new("Array", "ARRAY")
    arr.count = 5
    arr.use_relative_offset, arr.use_constant_offset = False, True
    arr.constant_offset_displace = (0.0, 0.0, 0.4)
    side = c.mesh_object("ShelfSide", *c.box((0.4, -0.15, 0.0), (0.42, 0.15, 1.9)), wood, location=(0.6, 3.75, 0.0))
    mir = side.modifiers.new("Mirror", "MIRROR")
    mir.use_axis[0] = True
    # sofa with a bevelled back and a subdivided cushion (resting on the seat: touching faces)
    c.mesh_object("Sofa", *c.box((-0.9, -0.4, 0.0), (0.9, 0.4, 0.4)), fabric, location=(2.5, 0.25 + 0.4, 0.0))
    back = c.mesh_object("SofaBack", *c.box((-0.9, -0.1, 0.0), (0.9, 0.1, 0.85)), fabric, location=(2.5, 0.15, 0.0))
    bev = back.modifiers.new("Bevel", "BEVEL")
    bev.width, bev.segments = 0.03, 2
    cushion = c.mesh_object("Cushion", *c.box((-0.25, -0.25, 0.0), (0.25, 0.25, 0.12)), fabric,
                            location=(2.0, 0.7, 0.4))
    cushion.modifiers.new("Subdivision", "SUBSURF").levels = max(1, min(detail, 2))
    c.camera((4.6, 0.35, 1.6), (1.8, 3.0, 0.9), lens=20.0, resolution=(resolution, resolution))
    bpy.context.view_layer.update()
    # defaults: 2 % unshot, centroid rule: every exact point evaluation costs ~0.2 s in this cluttered room
    # (the core's shadow-volume subtraction, ~200 splits per point; docs/first-pass.md)
    report = c.solve("furnished_room", tolerance=2e-2 if tolerance is None else tolerance,
                     order=1 if order is None else order, quiet=quiet) if solve else None
    return scene, report


def main(argv):
    ap = c.parser("furnished_room.py", "Build the furnished-room sample .blend")
    ap.add_argument("--detail", type=int, default=1, help="room cells per face side / 2")
    args = ap.parse_args(argv)
    build(args.detail, resolution=args.resolution, tolerance=args.tolerance, order=args.order)
    c.save("furnished_room", args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main(c.script_argv()))
