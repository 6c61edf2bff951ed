"""Convex solids (core/solids.py): one shadow volume per convex block gives what its faces give.

Detection is checked on small hand-made shells; the per-receiver volumes are checked against the
faces' own volumes (``build_occluders(solids=False)``) on the scenes where solids matter — the Cornell
box's open-bottom blocks, rooms full of closed interpenetrating boxes, subdivided boxes — for points
in free space, on the surfaces (with and without the one-sided limit), and next to the solids' planes.
"""

from __future__ import annotations

import numpy as np
import pytest
from scenes_for_tests import (
    Mesh,
    OrientedBox,
    box_face_quads,
    cornell_box,
    cornell_free_points,
    prism,
    random_box_room,
    random_free_points_in_room,
    random_rotation,
    random_unit_vectors,
)

from hemisphere_local_pass.core import Scene, form_factors, irradiance
from hemisphere_local_pass.core.culling import build_occluders
from hemisphere_local_pass.core.solids import solid_volumes

TOL = 1e-12


def _scene(mesh: Mesh) -> Scene:
    verts, polys = mesh.arrays()
    return Scene.from_polygons(verts, polys, mesh.radiance_array())


def _solids_of(mesh: Mesh):
    return build_occluders(_scene(mesh)).solids


def test_closed_box_is_one_solid():
    mesh = Mesh()
    for q in box_face_quads([0, 0, 0], [1, 2, 3], inward=False):
        mesh.add(q)
    sol = _solids_of(mesh)
    assert sol.n == 1 and not sol.hole[0]
    assert np.diff(sol.face_ptr).tolist() == [6]
    assert len(sol.edge_a) == 12


def test_open_bottom_prism_is_a_solid_with_a_hole():
    mesh = Mesh()
    for f in prism([[0, 0], [2, 0], [2.5, 1.5], [0.5, 2]], 1.0):
        mesh.add(f)
    sol = _solids_of(mesh)
    assert sol.n == 1 and sol.hole[0]
    np.testing.assert_allclose(sol.hole_out[0], [0, -1, 0], atol=1e-15)   # the prism stands on y = 0


def test_not_solids():
    # an L-shaped prism (a reflex edge), a box missing two faces (unshared edges in two planes) and
    # a box with a fin (an edge in three faces) are not convex solids
    mesh = Mesh()
    for f in prism([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], 1.0):
        mesh.add(f)
    assert _solids_of(mesh).n == 0
    mesh = Mesh()
    for q in box_face_quads([0, 0, 0], [1, 1, 1], inward=False)[:4]:
        mesh.add(q)
    sol = _solids_of(mesh)
    assert sol.n == 0
    mesh = Mesh()
    for q in box_face_quads([0, 0, 0], [1, 1, 1], inward=False):
        mesh.add(q)
    mesh.add([[1, 0, 0], [2, -1, 0], [2, -1, 1], [1, 0, 1]])   # a fin on the edge x = 1, y = 0
    assert _solids_of(mesh).n == 0
    # two boxes sharing a face are one solid (the 2 x 1 x 1 box; the shared face lies inside it)
    mesh = Mesh()
    for q in box_face_quads([0, 0, 0], [1, 1, 1], inward=False) + box_face_quads([1, 0, 0], [2, 1, 1], inward=False):
        mesh.add(q)
    sol = _solids_of(mesh)
    assert sol.n == 1 and np.diff(sol.face_ptr).tolist() == [6]


def test_volume_applies_only_from_outside():
    mesh = Mesh()
    for f in prism([[0, 0], [1, 0], [1, 1], [0, 1]], 1.0):
        mesh.add(f)
    occ = build_occluders(_scene(mesh))
    pts = np.array([[3.0, 0.5, 0.5],     # outside, beside it: applies
                    [0.5, 0.5, 0.5],     # inside
                    [0.5, -1.0, 0.5],    # below, looking into the open bottom
                    [3.0, 1.0, 0.5],     # in the plane of the top face
                    [3.0, 0.0, 0.5]])    # on the floor, in the plane of the hole (seen edge-on): applies
    nrm = np.tile([[-1.0, 0.0, 0.0]], (len(pts), 1))
    nrm[2] = [0.0, 1.0, 0.0]
    qp, qs, normal, offset = solid_volumes(occ.solids, pts, nrm, None)
    assert qp.tolist() == [0, 4]
    # beside it: the face facing P and the four silhouette edges of that face
    used = np.abs(normal[0]).sum(axis=1) > 0
    assert used.sum() == 5


def _compare(scene, pts, nrm, limit=None):
    with_s = build_occluders(scene)
    without = build_occluders(scene, solids=False)
    assert with_s.solids.n > 0
    kw = {} if limit is None else {"limit_directions": limit}
    f1 = form_factors(scene, pts, nrm, occluders=with_s, **kw)
    f0 = form_factors(scene, pts, nrm, occluders=without, **kw)
    assert np.abs(f1 - f0).max() <= TOL, np.abs(f1 - f0).max()
    h1 = irradiance(scene, pts, nrm, occluders=with_s, **kw)
    h0 = irradiance(scene, pts, nrm, occluders=without, **kw)
    assert np.abs(h1 - h0).max() <= TOL * max(1.0, np.abs(h0).max())
    return f1


def test_cornell_blocks_free_points(rng):
    mesh = cornell_box()
    pts = cornell_free_points(rng, 400)
    f = _compare(_scene(mesh), pts, random_unit_vectors(rng, len(pts)))
    assert np.abs(f.sum(axis=1) - 1).max() <= 1e-10


def test_box_room_free_points(rng):
    mesh, boxes = random_box_room(rng, 20)
    pts = random_free_points_in_room(rng, boxes, 200)
    _compare(_scene(mesh), pts, random_unit_vectors(rng, len(pts)))


@pytest.mark.parametrize("limit", [False, True], ids=["at_p", "one_sided_limit"])
def test_receivers_on_solid_faces_and_nearby(rng, limit):
    # points on the faces of rotated, subdivided boxes (edges, corners) and a hair off their planes
    mesh = Mesh()
    for q in box_face_quads([-20, -20, -20], [20, 20, 20], inward=True):
        mesh.add(q, (0.3, 0.4, 0.5))
    pts, nrm, lim = [], [], []
    for _ in range(4):
        box = OrientedBox(rng.uniform(-8, 8, size=3), random_rotation(rng), rng.uniform(1, 4, size=3))
        for f in box.faces():
            c = f.mean(axis=0)
            for corner in range(4):   # each face as four quads around its centre (a shared vertex)
                a, b, d = f[corner], 0.5 * (f[corner] + f[(corner + 1) % 4]), 0.5 * (f[corner] + f[corner - 1])
                mesh.add([a, b, c, d], tuple(rng.uniform(0, 1, size=3)))
            n = np.cross(f[1] - f[0], f[2] - f[0])
            n /= np.linalg.norm(n)
            for w in (rng.dirichlet(np.ones(4)), [0.5, 0.5, 0, 0], [1.0, 0, 0, 0]):
                p = np.asarray(w) @ f
                for off in (0.0, 1e-9, 1e-3):
                    pts.append(p + off * n)
                    nrm.append(n)
                    lim.append(c - p)
    pts, nrm, lim = np.array(pts), np.array(nrm), np.array(lim)
    _compare(_scene(mesh), pts, nrm, lim if limit else None)
