"""A big convex solid seen from outside (issue 10: per-point memory bounded).

A closed UV sphere of 2,048 faces (exact poles: a closed convex solid, see :mod:`.solids`) with a
receiver outside it: the solid's volume has one plane per face facing P plus one per silhouette edge
(~870 here), while a face volume has 5. Stored apart (:class:`.visibility.ShadowVolumes` ``wide_*``),
the face volumes keep their own width; padded to the solid's, they took ~130 MB per receiver at
2,048 faces and 1.8 GB at 8,192 (O(n_o²)). Checked here: the volumes' layout, a traced peak bound for
one receiver (measured 22 MB; with the padded layout 137 MB), and the irradiance equal bit for bit to the
same receiver's with the face volumes padded as before (one wide volume placed in the narrow arrays);
and in a room of boxes, whose volumes are padded by default, the same bits with them stored apart.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
from scenes_for_tests import random_box_room, random_free_points_in_room, random_unit_vectors

from hemisphere_local_pass.core import Scene, irradiance, visibility
from hemisphere_local_pass.core.chunk import prepare_scene
from hemisphere_local_pass.scenes import uv_sphere


def _ball():
    v, p = uv_sphere(64, 32)
    v = np.asarray(v, dtype=np.float64).copy()
    v[np.abs(v) < 1e-12] = 0.0                  # sin(pi) != 0: the south pole's copies made one point
    return Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))


def _receiver():
    d = np.array([[0.3, 0.5, 0.8]])
    d /= np.linalg.norm(d)
    return 3.0 * d, -d


def _padded(sv):
    """``sv`` with its wide volumes put into the narrow arrays (the layout before ``wide_*``)."""
    w = np.flatnonzero(sv.wide_row >= 0)
    nrm, off = sv.rows(np.arange(len(sv.point)))
    inf = None if sv.offset_inf is None else np.zeros(off.shape)
    return visibility.ShadowVolumes(sv.point, sv.occluder, sv.side, sv.verts, sv.inf, sv.counts, nrm, off, inf,
                                    sv.near, sv.n_base, sv.n_face, sv.occludes, sv.covered), w


def test_ball_from_outside_memory_and_bits(monkeypatch):
    sc = _ball()
    occ = prepare_scene(sc)
    assert occ.solids is not None and occ.solids.n == 1
    p, n = _receiver()
    sv, _ = visibility.shadow_volumes(occ, p, n)
    assert sv.wide_row is not None and sv.normal.shape[1] == 5
    assert sv.wide_normal.shape[1] > 500 and (sv.wide_row >= 0).sum() == 1
    irradiance(sc, p, n, workers=1)             # warm caches outside the trace
    tracemalloc.start()
    try:
        h = irradiance(sc, p, n, workers=1)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 40e6, peak / 1e6
    orig = visibility.shadow_volumes

    def padded(*a, **k):
        sv, table = orig(*a, **k)
        out, w = _padded(sv)
        assert len(w) and out.normal.shape[1] == sv.n_planes
        return out, table

    monkeypatch.setattr("hemisphere_local_pass.core.chunk.shadow_volumes", padded)
    h_padded = irradiance(sc, p, n, workers=1)
    assert np.array_equal(h, h_padded)


def test_boxes_apart_equal_padded(monkeypatch):
    """A room of 30 boxes (their volumes: 9 planes, padded by default) with the volumes stored apart
    gives the padded layout's irradiance bit for bit (free receivers, random normals)."""
    rng = np.random.default_rng(3)
    mesh, boxes = random_box_room(rng, 30)
    p = random_free_points_in_room(rng, boxes, 40)
    n = random_unit_vectors(rng, len(p))
    sc = Scene.from_polygons(np.array(mesh.vertices), mesh.polygons, np.array(mesh.radiance))
    h_padded = irradiance(sc, p, n, workers=1)
    monkeypatch.setattr(visibility, "WIDE_FACTOR", 1)
    sv, _ = visibility.shadow_volumes(prepare_scene(sc), p, n)
    assert sv.wide_row is not None and (sv.wide_row >= 0).sum() > 100
    assert np.array_equal(irradiance(sc, p, n, workers=1), h_padded)


def test_plane_tree_same_pairs_and_planes_as_dense(monkeypatch):
    """The wide volume's pair tests through its bounding tree (:class:`.visibility._PlaneTree`) give the
    pairs and near planes of the dense test over every plane, call by call, with fewer planes computed,
    and H bit for bit."""
    sc = _ball()
    p, n = _receiver()
    monkeypatch.setattr(visibility, "WIDE_TREE_MIN", 0)          # the ball's 700-odd planes through the tree
    grouped, calls, seen = visibility._near_planes_grouped, [], {}

    def checked(keep, body, q, c, r, sv, n_j):
        a = grouped(keep, body, q, c, r, sv, n_j)
        monkeypatch.setattr(visibility, "WIDE_GROUPS", False)
        b = visibility._near_planes(keep, body, q, c, r, sv, n_j)
        monkeypatch.setattr(visibility, "WIDE_GROUPS", True)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
        seen["dense"] = seen.get("dense", 0) + len(keep) * sv.wide_normal.shape[1]
        calls.append(len(a[0]))
        return a

    near = visibility._PlaneTree.leaves_near

    def counted(tree, r, rel, margin):
        pi, leaf = near(tree, r, rel, margin)
        seen["computed"] = seen.get("computed", 0) + len(pi) * tree.LEAF
        return pi, leaf

    monkeypatch.setattr(visibility._PlaneTree, "leaves_near", counted)
    monkeypatch.setattr(visibility, "_near_planes_grouped", checked)
    h = irradiance(sc, p, n, workers=1)
    assert calls and sum(calls) > 100
    assert seen["computed"] < 0.5 * seen["dense"], seen
    monkeypatch.setattr(visibility, "WIDE_GROUPS", False)
    assert np.array_equal(h, irradiance(sc, p, n, workers=1))
