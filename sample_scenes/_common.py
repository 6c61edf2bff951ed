"""Shared pieces of the sample-scene scripts: meshes from arrays, materials, camera, world, solve, save.

Every sample is deterministic (no random numbers without a fixed seed) and built in the Blender that
runs the script (a .blend saved by a newer Blender crashes Debian's Blender 3.4 when opened).
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def import_package():
    try:
        import hemisphere_local_pass  # noqa: F401
    except ImportError:
        sys.path.insert(0, ROOT)


def material(name, rho, emit=(0.0, 0.0, 0.0)):
    """A Principled BSDF material: base colour = reflectivity ρ, emission colour × strength = E."""
    import bpy

    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    mat.diffuse_color = (float(rho[0]), float(rho[1]), float(rho[2]), 1.0)
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (float(rho[0]), float(rho[1]), float(rho[2]), 1.0)
    strength = float(max(emit))
    col = bsdf.inputs.get("Emission Color") or bsdf.inputs.get("Emission")
    if strength > 0:
        col.default_value = (emit[0] / strength, emit[1] / strength, emit[2] / strength, 1.0)
    bsdf.inputs["Emission Strength"].default_value = strength
    return mat


def mesh_object(name, verts, faces, mat=None, *, collection=None, location=(0.0, 0.0, 0.0)):
    """An object with a new mesh from ``verts (V, 3)`` and ``faces`` (index lists), linked to ``collection``."""
    import bpy

    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(map(float, v)) for v in verts], [], [list(map(int, f)) for f in faces])
    mesh.update()
    if mat is not None:
        mesh.materials.append(mat)
    ob = bpy.data.objects.new(name, mesh)
    ob.location = tuple(float(c) for c in location)
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def grid(origin, e1, e2, n1, n2):
    """An ``n1 × n2`` grid of quads spanning ``origin + [0, 1] e1 + [0, 1] e2``; normal ``e1 × e2``."""
    origin, e1, e2 = (np.asarray(a, dtype=np.float64) for a in (origin, e1, e2))
    u, v = np.meshgrid(np.arange(n1 + 1) / n1, np.arange(n2 + 1) / n2, indexing="ij")
    verts = origin + u[..., None] * e1 + v[..., None] * e2
    idx = np.arange((n1 + 1) * (n2 + 1)).reshape(n1 + 1, n2 + 1)
    faces = [[idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]] for i in range(n1) for j in range(n2)]
    return verts.reshape(-1, 3), faces


def box(lo, hi, *, inward=False, cells=1):
    """The six faces of the box [lo, hi] as one mesh's ``(verts, faces)``, each face ``cells × cells``."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    d = hi - lo
    x, y, z = np.diag(d)
    sides = [(lo, y, x), (lo + z, x, y), (lo, x, z), (lo + y, z, x), (lo, z, y), (lo + x, y, z)]  # outward
    verts, faces = [], []
    for o, a, b in sides:
        if inward:
            a, b = b, a
        v, f = grid(o, a, b, cells, cells)
        faces += [[i + sum(len(q) for q in verts) for i in face] for face in f]
        verts.append(v)
    return np.concatenate(verts), faces


def camera(location, look_at, *, lens=28.0, resolution=(64, 64), clip=(0.01, 100.0)):
    """The scene camera at ``location`` looking at ``look_at`` (z up)."""
    import bpy
    from mathutils import Vector

    scene = bpy.context.scene
    data = bpy.data.cameras.new("Camera")
    data.lens = lens
    data.clip_start, data.clip_end = clip
    cam = bpy.data.objects.new("Camera", data)
    cam.location = Vector(location)
    cam.rotation_euler = (Vector(look_at) - Vector(location)).to_track_quat("-Z", "Y").to_euler()
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.resolution_x, scene.render.resolution_y = int(resolution[0]), int(resolution[1])
    scene.render.resolution_percentage = 100
    return cam


def black_world():
    import bpy

    scene = bpy.context.scene
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.color = (0.0, 0.0, 0.0)
    if scene.world.node_tree is not None:
        for node in scene.world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)


def reset():
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    black_world()


def solve(prefix, *, tolerance=None, order=None, quiet=False):
    """The first pass, as the operator and the ``solve`` command run it; returns its report."""
    import_package()
    from hemisphere_local_pass.blender.first_pass import SolverProgressLines, solve_first_pass

    report = solve_first_pass(tolerance=tolerance, order=order,
                              progress=None if quiet else SolverProgressLines(interval=5.0))
    print(f"{prefix}: {report.summary()}", file=sys.stderr)
    return report


def parser(prog, description):
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument("output", nargs="?", help=".blend file to write (none: build and solve only)")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--tolerance", type=float, default=None, help="first pass: unshot / emitted power at the end")
    ap.add_argument("--order", type=int, choices=(1, 2), default=None, help="first pass quadrature order")
    return ap


def save(prefix, output):
    import bpy

    if not output:
        return None
    out = os.path.abspath(output)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=out, compress=True)
    print(f"{prefix}: wrote {out}")
    return out


def script_argv():
    return sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]


__all__ = ["black_world", "box", "camera", "grid", "import_package", "material", "mesh_object", "parser", "reset",
           "save", "script_argv", "solve", "math"]
