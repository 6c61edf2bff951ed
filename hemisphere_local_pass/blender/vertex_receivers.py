"""Vertices mode's receivers: the meshes to evaluate, their vertices (POINT domain) or corners
(CORNER domain) in world space with normals and limit directions (the one-sided limit from inside
their faces), and the rho and E of each receiver's polygons.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import numpy as np

__all__ = ["receiver_materials", "receivers", "selected_meshes"]


def selected_meshes(scene, view_layer, names=None):
    """The receiving mesh objects: ``names`` (``--objects``) when given, else the selected meshes."""
    if names:
        obs = []
        for name in names:
            ob = scene.objects.get(name)
            if ob is None:
                raise ValueError(f"--objects: scene '{scene.name}' has no object '{name}'")
            if ob.type != "MESH":
                raise ValueError(f"--objects: object '{name}' is a {ob.type.lower()}, not a mesh")
            if ob not in obs:
                obs.append(ob)
        return obs
    obs = [ob for ob in scene.objects if ob.type == "MESH" and ob.select_get(view_layer=view_layer)]
    if not obs:
        raise ValueError("vertices mode needs at least one selected mesh object (or name them: --objects NAME ...)")
    return obs


def _newell(verts, loops, start, total) -> np.ndarray:
    """(P, 3) unit Newell normals of polygons (vectorised over corners)."""
    v = verts[loops]  # (L, 3)
    poly = np.repeat(np.arange(len(start)), total)
    nxt_idx = np.arange(len(loops)) + 1
    last = start + total - 1
    nxt_idx[last] = start  # wrap around each polygon
    cross = np.cross(v, v[nxt_idx])
    area = np.zeros((len(start), 3))
    np.add.at(area, poly, cross)
    norm = np.linalg.norm(area, axis=1, keepdims=True)
    return area / np.where(norm > 0, norm, 1.0)


def _tangent_towards(target, point, normal) -> np.ndarray:
    """Unit vectors from ``point`` towards ``target`` projected into the plane normal to ``normal``."""
    d = target - point
    d = d - np.einsum("ij,ij->i", d, normal)[:, None] * normal
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.where(n > 0, d / np.where(n > 0, n, 1.0), 0.0)


def receivers(ob, mesh, matrix):
    """Receiver points of one original mesh in world space.

    Returns ``(domain, points (n, 3), normals (n, 3), limits (n, 3), corner_poly (L,), elem_of_corner)``:
    CORNER domain (some face flat): one receiver per corner, the face normal for flat faces and the
    vertex normal for smooth ones, the limit direction towards the face centroid; POINT domain (all
    faces smooth): one receiver per vertex, its normal, the limit direction the normalised sum of
    the directions to the adjacent faces' centroids.
    """
    from .scene_export import mesh_arrays, polygon_of_corner

    arrays = mesh_arrays(mesh)
    m = np.asarray(matrix, dtype=np.float64).reshape(4, 4)
    lin = m[:3, :3]
    world = arrays.vertices @ lin.T + m[:3, 3]
    det = np.linalg.det(lin)
    face_n = _newell(world, arrays.loop_vertices, arrays.loop_start, arrays.loop_total)
    if det < 0:
        face_n = -face_n  # the exported scene reverses mirrored polygons: same front side
    vn = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    if len(mesh.vertices):
        mesh.vertices.foreach_get("normal", vn)
    vn = vn.reshape(-1, 3).astype(np.float64) @ np.linalg.inv(lin)  # inverse transpose, row vectors
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
    cpoly = polygon_of_corner(arrays)
    centroid = np.add.reduceat(world[arrays.loop_vertices], arrays.loop_start, axis=0) / arrays.loop_total[:, None]
    if arrays.n_polygons and arrays.use_smooth.all():
        n_v = len(world)
        lim = np.zeros((n_v, 3))
        corner_dir = _tangent_towards(centroid[cpoly], world[arrays.loop_vertices], vn[arrays.loop_vertices])
        np.add.at(lim, arrays.loop_vertices, corner_dir)
        first = np.full(n_v, -1, dtype=np.int64)
        first[arrays.loop_vertices[::-1]] = np.arange(len(arrays.loop_vertices))[::-1]
        norm = np.linalg.norm(lim, axis=1)
        weak = (norm < 1e-6) & (first >= 0)
        lim[weak] = corner_dir[first[weak]]  # symmetric neighbourhood: use the first face's direction
        norm = np.linalg.norm(lim, axis=1, keepdims=True)
        lim = np.where(norm > 0, lim / np.where(norm > 0, norm, 1.0), 0.0)
        return "POINT", world, vn, lim, arrays, cpoly
    smooth_c = arrays.use_smooth[cpoly]
    pts = world[arrays.loop_vertices]
    nrm = np.where(smooth_c[:, None], vn[arrays.loop_vertices], face_n[cpoly])
    lim = _tangent_towards(centroid[cpoly], pts, nrm)
    return "CORNER", pts, nrm, lim, arrays, cpoly


def receiver_materials(ob, mesh, arrays, rho_attr, emit_attr):
    """(P, 3) rho and E of the polygons of an original mesh (attributes, else material, else defaults)."""
    from .scene_export import _per_polygon, material_colours, read_attribute

    rho_vals = read_attribute(mesh, arrays, rho_attr, ob.name, allow_grey=True) if rho_attr else None
    emit_vals = read_attribute(mesh, arrays, emit_attr, ob.name, allow_grey=True) if emit_attr else None
    slots = [s.material for s in ob.material_slots] or [None]
    table = [material_colours(mat) for mat in slots]
    slot = np.clip(arrays.material_index, 0, len(table) - 1)
    rho = _per_polygon(arrays, *rho_vals) if rho_vals is not None else np.array([t[0] for t in table])[slot]
    emit = _per_polygon(arrays, *emit_vals) if emit_vals is not None else np.array([t[1] for t in table])[slot]
    return rho.reshape(-1, 3), emit.reshape(-1, 3)
