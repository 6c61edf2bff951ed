"""The depth relations per pair (:mod:`.depth_pairs`) are the tables of :func:`.culling.build_occluders`.

Scenes of many merged faces get no (polygon × merged face) tables (``culling.PER_PAIR_DEPTH_FROM``);
here the threshold is set to 0 so that small scenes can be compared both ways:

* every entry of ``beyond_*``, ``front_*``, ``occ_beyond_*``, ``occ_reach_*`` (faces and solids' columns)
  equals :meth:`.DepthPairs.can_hide`'s answer, the coplanar lists are equal, and
  :class:`.BeyondLists` holds exactly the ``occ_beyond_*`` pairs of every (face, side) it keeps;
* form factors are bit-identical on the Cornell box (merged walls, blocks as solids), a split box,
  a random box room, random overlapping polygons with coplanar duplicates, and the UV sphere from
  inside, from outside, and with a box and a free quad inside;
* :func:`.depth_pairs.ball_pairs` finds every meeting pair of balls once (random sizes over 6 decades);
* the convexity search of large solids (:func:`.solids._outward`) finds the loop's solids (a dented sphere too);
* the face tree (:func:`.depth_pairs._median_order`) splits every node at its median; its leaves stay
  compact on a UV sphere at every n;
* the prepared occluders are O(n): < 1 KB a face (> 8 KB with the tables at 2,048 faces).
"""

from __future__ import annotations

import numpy as np
import pytest
from scenes_for_tests import cornell_box, random_box_room, random_occluded_scene, split_box

from hemisphere_local_pass.core import Scene, culling, depth_pairs, form_factors
from hemisphere_local_pass.core.depth_pairs import ball_pairs
from hemisphere_local_pass.core.rowops import unpack_rows
from hemisphere_local_pass.scenes import uv_sphere


def _sphere(outside=False, extra=False, closed=False):
    v, p = uv_sphere(16, 8)
    if closed:                                  # exact poles: one point each, the sphere is a convex solid
        v = np.asarray(v, dtype=np.float64).copy()
        v[np.abs(v) < 1e-12] = 0.0
    if not outside:
        p = [f[::-1] for f in p]
    if extra:
        from test_unmerged import _with_occluders
        v, p = _with_occluders(v, p)
    return v, p


def _scenes(rng):
    out = {}
    m = cornell_box()
    out["cornell"] = m.arrays()
    m = split_box(np.array([-1.5, 2.0, 0.25]), np.array([1.5, 4.5, 2.25]), rng, inward=True)
    out["split_box"] = m.arrays()
    m, _ = random_box_room(rng, 8)
    out["box_room"] = m.arrays()
    _, v, p = random_occluded_scene(rng)
    p = p + [list(p[0]), list(p[1])[::-1]]                     # a duplicate and a reversed copy
    out["random+duplicates"] = (v, p)
    out["sphere_in"] = _sphere()
    out["sphere_out"] = _sphere(outside=True)
    out["sphere+box+quad"] = _sphere(extra=True)
    out["ball_in"] = _sphere(closed=True)
    out["ball_out"] = _sphere(outside=True, closed=True)
    out["ball+box+quad"] = _sphere(extra=True, closed=True)
    return out


def _both(monkeypatch, v, p):
    scenes = []
    for threshold in (None, 0):
        monkeypatch.setattr(culling, "PER_PAIR_DEPTH_FROM", threshold)
        sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
        sc._occluders = culling.build_occluders(sc)
        scenes.append(sc)
    return scenes


@pytest.mark.parametrize("name", ["cornell", "split_box", "box_room", "random+duplicates", "sphere_in",
                                  "sphere_out", "sphere+box+quad", "ball_in", "ball_out", "ball+box+quad"])
def test_per_pair_equals_tables(monkeypatch, rng, name):
    v, p = _scenes(rng)[name]
    if name.startswith("ball"):                 # the solids' columns through the tree search (every solid)
        monkeypatch.setattr(depth_pairs, "SUPPORT_TREE_FROM", 0)
    dense, lazy = _both(monkeypatch, v, p)
    t, d = dense._occluders, lazy._occluders
    assert t.depth is None and d.depth is not None and d.beyond_pos is None
    n, n_o, n_vol = dense.n_polygons, t.n, t.n_vol
    assert np.array_equal(t.members, d.members) and np.array_equal(t.coplanar_ptr, d.coplanar_ptr)
    assert np.array_equal(t.coplanar_occ, d.coplanar_occ) and np.array_equal(t.first_source, d.first_source)
    # every (polygon, volume) and (face, volume) pair, both sides of both planes
    for polys, rows, tabs in ((True, n, (t.beyond_pos, t.beyond_neg, t.front_pos, t.front_neg)),
                              (False, n_o, (t.occ_beyond_pos, t.occ_beyond_neg, t.occ_reach_pos, t.occ_reach_neg))):
        b, o = (x.ravel() for x in np.meshgrid(np.arange(rows), np.arange(n_vol), indexing="ij"))
        full = [unpack_rows(x, np.arange(rows), n_vol).ravel() for x in tabs]
        for bp in (True, False):
            for fp in (True, False):
                want = (full[0] if bp else full[1]) & (full[2] if fp else full[3])
                got = d.depth.can_hide(polys, b, o, np.full(len(b), bp), np.full(len(b), fp))
                assert np.array_equal(got, want), (polys, bp, fp, np.flatnonzero(got != want)[:5])
    # the lists: exactly the occ_beyond pairs (k != o) of every (face, side) they keep
    lists = d.depth.lists
    for side, tab in ((0, t.occ_beyond_pos), (1, t.occ_beyond_neg)):
        col = unpack_rows(tab, np.arange(n_o), n_vol)[:, :n_o]
        for o in np.flatnonzero(~lists.open[side]):
            want = np.flatnonzero(col[:, o] & (np.arange(n_o) != o))
            assert np.array_equal(lists.faces[lists.ptr[side, o]:lists.ptr[side, o + 1]], want)
    # and the form factors
    d_pts = np.random.default_rng(5).normal(size=(12, 3))
    d_pts /= np.linalg.norm(d_pts, axis=1, keepdims=True)
    lo, hi = np.asarray(v).min(axis=0), np.asarray(v).max(axis=0)
    if name.startswith(("sphere", "ball")):
        pts, nrm = (3.0 if name.endswith("_out") else 0.9) * d_pts, -d_pts
    else:
        pts = lo + (hi - lo) * np.random.default_rng(6).uniform(0.05, 0.95, size=(12, 3))
        nrm = d_pts
    assert np.array_equal(form_factors(lazy, pts, nrm, workers=1), form_factors(dense, pts, nrm, workers=1))


@pytest.mark.parametrize("name", ["cornell", "box_room", "ball_in", "ball_out", "ball+box+quad"])
def test_solid_columns_tree_equals_dense(monkeypatch, rng, name):
    """The tree search of the support vertex and the near faces gives the dense search's columns."""
    v, p = _scenes(rng)[name]
    monkeypatch.setattr(culling, "PER_PAIR_DEPTH_FROM", 0)
    got = []
    for tree_from in (None, 0):
        monkeypatch.setattr(depth_pairs, "SUPPORT_TREE_FROM", tree_from)
        sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
        d = culling.build_occluders(sc).depth
        got.append((d.solid_front_pos, d.solid_front_neg, d.solid_reach_pos, d.solid_reach_neg))
    assert got[0][0].shape[1] > 0
    for a, b in zip(*got):
        assert np.array_equal(a, b)


def test_ball_pairs_finds_every_meeting_pair_once():
    rng = np.random.default_rng(3)
    for big in (0.5, 1e9):
        for _ in range(10):
            na, nb = rng.integers(1, 300, 2)
            ga, gb = rng.integers(0, 4, na), rng.integers(0, 4, nb)
            ca, cb = rng.normal(size=(na, 3)) * 3, rng.normal(size=(nb, 3)) * 3
            ra, rb = np.exp(rng.normal(size=na) * 3) * 0.1, np.exp(rng.normal(size=nb) * 3) * 0.1
            i, j = ball_pairs(ga, ca, ra, gb, cb, rb, big)
            key = i * nb + j
            assert len(np.unique(key)) == len(key)
            dist = np.linalg.norm(ca[:, None] - cb[None], axis=2)
            truth = (dist <= ra[:, None] + rb[None]) & (ga[:, None] == gb[None])
            assert set(np.flatnonzero(truth.ravel())) <= set(key.tolist())
            assert (ga[i] == gb[j]).all()
            near = dist[i, j] <= (ra[i] + rb[j]) * (1 + 2e-9)
            assert (near | (ra[i] >= big) | (rb[j] >= big)).all()


@pytest.mark.parametrize("name", ["cornell", "split_box", "box_room", "sphere_in", "sphere_out", "sphere+box+quad"])
def test_convexity_search_equals_loop(monkeypatch, rng, name):
    """:func:`.solids._outward`'s tree search gives the loop's solids (every field equal)."""
    from hemisphere_local_pass.core import solids

    v, p = _scenes(rng)[name]
    sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
    occ = culling.build_occluders(sc)
    args = (occ.vertices, occ.counts, occ.normals, occ.tilt, occ.noise)
    found = []
    for start in (10**9, 0):
        monkeypatch.setattr(solids, "OUTWARD_SEARCH_FROM", start)
        found.append(solids.build_solids(*args))
    a, b = found
    assert a.n == b.n
    for f in a.__dataclass_fields__:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def _nbytes(x, seen):
    if id(x) in seen:
        return 0
    seen.add(id(x))
    if isinstance(x, np.ndarray):
        return x.nbytes
    if isinstance(x, (list, tuple)):
        return sum(_nbytes(v, seen) for v in x)
    return sum(_nbytes(v, seen) for v in vars(x).values()) if hasattr(x, "__dict__") else 0


def test_per_pair_occluders_are_linear_in_the_faces(monkeypatch):
    """The prepared occluders of a 2,048-face sphere: < 1 KB a face per pair (measured 722 B at 4,608
    and 18,432 faces alike), > 8 KB a face with the tables (n_o bits × 8 tables, the n_o² lists)."""
    v, p = uv_sphere(64, 32)
    p = [f[::-1] for f in p]
    per_face = []
    for threshold in (0, None):
        monkeypatch.setattr(culling, "PER_PAIR_DEPTH_FROM", threshold)
        sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
        per_face.append(_nbytes(culling.build_occluders(sc), set()) / sc.n_polygons)
    assert per_face[0] < 1024 < 8192 < per_face[1], per_face


def test_median_order_splits_every_node(rng):
    """:func:`.depth_pairs._median_order` is a permutation in which every node's range (aligned, of
    ``width / 2**L`` slots, the last one short) splits at its middle between the lower and the upper
    half of its members along the longest extent of their centres."""
    from hemisphere_local_pass.core.depth_pairs import LEAF, _median_order

    for n in (1, 5, 37, 1000):
        pts = rng.normal(size=(n, 3)) * np.array([3.0, 1.0, 0.2])
        n_leaf = max(1, -(-n // LEAF))
        width = (1 << int(np.ceil(np.log2(n_leaf)))) * LEAF if n_leaf > 1 else LEAF
        order = _median_order(pts, width)
        assert np.array_equal(np.sort(order), np.arange(n))
        size = width
        while size > LEAF:
            for a in range(0, n, size):
                c = pts[order[a:a + size]]
                ax = np.argmax(c.max(axis=0) - c.min(axis=0))
                left, right = c[: size // 2, ax], c[size // 2:, ax]
                assert not len(right) or left.max() <= right.min()
            size //= 2


def test_tree_leaves_are_compact_on_a_sphere():
    """The leaves (4 faces) of :func:`.depth_pairs._tree` over a UV sphere stay within a few face sizes at
    every n (measured max |h| / largest face radius: 2.7, 2.9, 3.1 at 512, 2,048, 8,192 faces; the Morton
    ranges before: 4.4, 7.1, 16.3), which keeps the nodes its searches test per face O(log n)."""
    from hemisphere_local_pass.core.depth_pairs import Bodies, _tree

    for nu in (32, 64, 128):
        v, p = uv_sphere(nu, nu // 2)
        v = np.asarray(v, dtype=float)
        verts = np.array([[v[f[min(j, len(f) - 1)]] for j in range(4)] for f in p])
        nrm = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
        nrm /= np.linalg.norm(nrm, axis=1)[:, None]
        faces = Bodies(verts, np.array([len(f) for f in p]), nrm, np.zeros(len(p)))
        levels, _ = _tree(faces)
        assert levels[-1][0][12].max() < 3.5 * faces.radii.max(), nu


def test_convexity_search_of_a_dented_sphere_equals_loop(monkeypatch):
    """A sphere with one vertex pushed in is no solid, by the loop and by the search (which returns as
    soon as a face fails)."""
    from hemisphere_local_pass.core import solids

    v, p = uv_sphere(16, 8)
    v = np.array(v, dtype=float)
    v[20] *= 0.8
    sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
    occ = culling.build_occluders(sc)
    args = (occ.vertices, occ.counts, occ.normals, occ.tilt, occ.noise)
    found = []
    for start in (10**9, 0):
        monkeypatch.setattr(solids, "OUTWARD_SEARCH_FROM", start)
        found.append(solids.build_solids(*args))
    a, b = found
    assert a.n == b.n
    for f in a.__dataclass_fields__:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
