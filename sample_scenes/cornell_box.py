"""Build the sample Cornell box as a Blender scene (and optionally save it as a .blend file).

Run as a script::

    blender -b --python sample_scenes/cornell_box.py -- out.blend [--subdivisions 4] [--resolution 64]
        [--domain FACE|POINT]
    python sample_scenes/cornell_box.py out.blend ...        # in a venv with the bpy module

or import it (bpy module): ``build(subdivisions=4, resolution=64)`` builds into the current scene.

The box comes from ``hemisphere_local_pass.scenes.cornell_box`` (closed; the classic camera stands
outside, in front of the front wall, and its near clip plane lies just inside that wall). One mesh
object per part (floor, ceiling, light, walls, blocks), each with a Principled BSDF material (base
colour = reflectivity rho, emission colour x strength = E for the light) and a ``radiosity``
FLOAT_COLOR attribute: the first pass's radiance per polygon, solved in this Blender session by
``hemisphere_local_pass.blender.first_pass`` (FACE domain, exactly what the operator and the ``solve``
command write), or with ``domain="POINT"`` the mean of the adjacent polygons' values at each vertex
(linearly varying radiance).

Build the scene in the Blender that will render it: a .blend saved by a newer Blender (e.g. the bpy 4.2
module) crashes Debian's Blender 3.4 when opened (Blender's forward-compatibility limit), so
``blender -b --python sample_scenes/cornell_box.py -- out.blend`` with that Blender, not a copy.
"""

from __future__ import annotations

import math
import os
import sys

import numpy as np

_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _import_package():
    try:
        import hemisphere_local_pass  # noqa: F401
    except ImportError:
        sys.path.insert(0, _ROOT)


def first_pass(scene=None, *, tolerance=None, order=None, quiet=False, clusters=None):
    """Solve the first pass in this Blender session (``hemisphere_local_pass.blender.first_pass``): writes
    the FACE-domain ``radiosity`` attribute on every mesh; returns the report (progress on stderr)."""
    _import_package()
    from hemisphere_local_pass.blender.first_pass import SolverProgressLines, solve_first_pass

    report = solve_first_pass(scene, tolerance=tolerance, order=order, clusters=clusters,
                              progress=None if quiet else SolverProgressLines(interval=5.0))
    import resource

    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: kB
    print(f"cornell_box: {report.summary()}; job {report.seconds:.1f} s, peak RSS so far {rss:.0f} MB",
          file=sys.stderr)
    return report


def _material(bpy, name, rho, emit):
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):  # 5.0+: always node-based, the flag is deprecated
        mat.use_nodes = True
    mat.diffuse_color = (float(rho[0]), float(rho[1]), float(rho[2]), 1.0)
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (float(rho[0]), float(rho[1]), float(rho[2]), 1.0)
    strength = float(max(emit)) if max(emit) > 0 else 0.0
    col = bsdf.inputs.get("Emission Color") or bsdf.inputs.get("Emission")
    if strength > 0:
        col.default_value = (emit[0] / strength, emit[1] / strength, emit[2] / strength, 1.0)
        bsdf.inputs["Emission Strength"].default_value = strength
    else:
        bsdf.inputs["Emission Strength"].default_value = 0.0
    return mat


def build(subdivisions: int = 4, *, resolution: int = 64, domain: str = "FACE", reset: bool = True,
          radiosity=None, size: float = 1.0, block_detail: float = 1.0, tolerance=None, quiet: bool = False,
          solve: bool = True, order=None, clusters=None):
    """Build the Cornell box into the current Blender session; returns ``(scene, box, radiosity)``.

    Args:
        subdivisions: grid intervals per room edge (4 -> 172 polygons).
        resolution: square image size in pixels.
        domain: "FACE" (constant radiosity per polygon) or "POINT" (per-vertex means, linear).
        reset: start from an empty factory scene.
        radiosity: (n, 3) per-polygon values to store instead of the first pass's solution.
        block_detail: the blocks' cell size relative to the room's (``scenes.cornell_box``).
        tolerance: the first pass's stopping tolerance (default: ``first_pass.DEFAULT_TOLERANCE``).
        solve: run the first pass when ``radiosity`` is not given (False: geometry, materials and camera
            only, no attribute; the returned values are then None).
        order, clusters: the first pass's quadrature order and shooting clusters (``solve_first_pass``).
    """
    import bpy

    _import_package()
    from hemisphere_local_pass.scenes.cornell_box import cornell_box

    if domain not in ("FACE", "POINT"):
        raise ValueError(f"domain must be FACE or POINT, got {domain!r}")
    if reset:
        bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    box = cornell_box(subdivisions, size=size, block_detail=block_detail)
    values = None if radiosity is None else np.asarray(radiosity, dtype=np.float64)
    loops, start, total = box.loops()
    names = np.array(box.names)
    for part in dict.fromkeys(box.names):  # one object per part, in order of appearance
        sel = np.flatnonzero(names == part)
        corner_idx = np.concatenate([np.arange(start[i], start[i] + total[i]) for i in sel])
        used, local = np.unique(loops[corner_idx], return_inverse=True)
        verts = box.vertices[used]
        polys, c = [], 0
        for i in sel:
            polys.append(local[c:c + total[i]].tolist())
            c += total[i]
        mesh = bpy.data.meshes.new(part)
        mesh.from_pydata(verts.tolist(), [], polys)
        mesh.update()
        ob = bpy.data.objects.new(part.title().replace(" ", ""), mesh)
        mesh.materials.append(_material(bpy, part, box.reflectivity[sel[0]], box.emission[sel[0]]))
        scene.collection.objects.link(ob)
        if values is None:
            continue  # solved below, by the first pass
        val = values[sel]
        if domain == "FACE":
            attr = mesh.attributes.new("radiosity", "FLOAT_COLOR", "FACE")
            data = val
        elif domain == "POINT":
            attr = mesh.attributes.new("radiosity", "FLOAT_COLOR", "POINT")
            acc = np.zeros((len(used), 3))
            cnt = np.zeros(len(used))
            lv = np.concatenate([np.array(p) for p in polys])
            np.add.at(acc, lv, np.repeat(val, [len(p) for p in polys], axis=0))
            np.add.at(cnt, lv, 1.0)
            data = acc / cnt[:, None]
        else:
            raise ValueError(f"domain must be FACE or POINT, got {domain!r}")
        rgba = np.concatenate([data, np.ones((len(data), 1))], axis=1).astype(np.float32)
        attr.data.foreach_set("color", rgba.reshape(-1))
    cam_data = bpy.data.cameras.new("Camera")
    cam_data.sensor_fit = "AUTO"
    cam_data.angle = float(box.camera["fov"])
    # the classic camera stands outside the closed box, in front of the front wall (the plane y = 0):
    # the near clip plane just inside that wall lets it look through it, in our rays and in Cycles
    outside = max(0.0, -float(box.camera["location"][1]))
    cam_data.clip_start = outside + 1e-5 * size if outside > 0 else 1e-4 * size
    cam_data.clip_end = 100.0 * size
    cam = bpy.data.objects.new("Camera", cam_data)
    cam.location = tuple(float(v) for v in box.camera["location"])
    cam.rotation_euler = (math.pi / 2, 0.0, 0.0)  # local -Z (view) -> +Y, local +Y (up) -> +Z
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.resolution_x = scene.render.resolution_y = int(resolution)
    scene.render.resolution_percentage = 100
    if hasattr(scene, "world") and scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.color = (0.0, 0.0, 0.0)  # black world (a closed box: nothing sees it anyway)
    if scene.world.node_tree is not None:
        for node in scene.world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    bpy.context.view_layer.update()
    if values is None and solve:
        first_pass(scene, tolerance=tolerance, order=order, quiet=quiet, clusters=clusters)
        values = np.zeros((box.n_polygons, 3))
        for part in dict.fromkeys(box.names):  # the solution in the box's polygon order
            mesh = bpy.data.objects[part.title().replace(" ", "")].data
            got = np.empty(4 * len(mesh.polygons), dtype=np.float32)
            mesh.attributes["radiosity"].data.foreach_get("color", got)
            values[names == part] = got.reshape(-1, 4)[:, :3]
        if domain == "POINT":
            _face_to_point(bpy, scene)
    return scene, box, values


def _face_to_point(bpy, scene):
    """Replace every mesh's FACE ``radiosity`` by its POINT version: the mean of the adjacent faces' values."""
    for ob in scene.collection.objects:
        if ob.type != "MESH":
            continue
        mesh = ob.data
        n = len(mesh.polygons)
        face = np.empty(4 * n, dtype=np.float32)
        mesh.attributes["radiosity"].data.foreach_get("color", face)
        face = face.reshape(n, 4)[:, :3].astype(np.float64)
        loops = np.empty(len(mesh.loops), dtype=np.int32)
        mesh.loops.foreach_get("vertex_index", loops)
        total = np.empty(n, dtype=np.int32)
        mesh.polygons.foreach_get("loop_total", total)
        acc = np.zeros((len(mesh.vertices), 3))
        cnt = np.zeros(len(mesh.vertices))
        np.add.at(acc, loops, np.repeat(face, total, axis=0))
        np.add.at(cnt, loops, 1.0)
        mesh.attributes.remove(mesh.attributes["radiosity"])
        attr = mesh.attributes.new("radiosity", "FLOAT_COLOR", "POINT")
        rgba = np.concatenate([acc / np.maximum(cnt, 1)[:, None], np.ones((len(cnt), 1))], axis=1)
        attr.data.foreach_set("color", rgba.astype(np.float32).reshape(-1))


def main(argv):
    import argparse

    import bpy

    parser = argparse.ArgumentParser(prog="cornell_box.py", description="Build the sample Cornell box .blend")
    parser.add_argument("output", help=".blend file to write")
    parser.add_argument("--subdivisions", type=int, default=4)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--domain", choices=("FACE", "POINT"), default="FACE")
    parser.add_argument("--block-detail", type=float, default=1.0, help="blocks' cell size relative to the room's")
    parser.add_argument("--tolerance", type=float, default=None, help="first pass: unshot / emitted power at the end")
    args = parser.parse_args(argv)
    build(args.subdivisions, resolution=args.resolution, domain=args.domain, block_detail=args.block_detail,
          tolerance=args.tolerance)
    out = os.path.abspath(args.output)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=out)
    print(f"cornell_box: wrote {out}")
    return 0


if __name__ == "__main__":
    _argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    sys.exit(main(_argv))
