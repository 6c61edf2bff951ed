"""The spatial hierarchy (issue 10, sec. 3.4): hidden, coplanar and back-facing geometry costs nothing,
and nothing about the answer changes.

* Hidden planes outside a closed box (below the floor, behind a wall) give the box's own form factors
  and irradiance to 1e-13, and no tile of theirs survives the traversal for any receiver.
* Culling decisions of the hierarchy are exact: with every node decision switched off (only the tiles'
  own tests) the results are the same to 1e-13, on a box with a window onto a plane behind it.
* A plane a receiver lies in costs nothing: none of its tiles survives.
* Cut tiles by quarters: the same factors and irradiance to 1e-13, fewer candidates.
* The tree's boxes and spheres contain their children's; every tile is reached once.
* Merged faces (the vectorised merge): grids merge into one convex face, L-shapes, rings and
  T-junctions do not; scene preparation reports progress and can be cancelled.
"""

from __future__ import annotations

import numpy as np
import pytest

from hemisphere_local_pass.core import Cancelled, Scene, chunk, form_factors, hierarchy, irradiance, prepare_scene
from hemisphere_local_pass.core.chunk import PREPARATION_STAGES, scene_hierarchy, scene_occluders
from hemisphere_local_pass.core.raycast import build_bvh, cast_rays
from hemisphere_local_pass.core.visibility import coverage, shadow_volumes
from hemisphere_local_pass.scenes import camera_rays, cornell_box


def grid(nx, origin, du, dv):
    s = np.linspace(0.0, 1.0, nx + 1)
    u, v = np.meshgrid(s, s, indexing="ij")
    verts = np.asarray(origin) + u.reshape(-1, 1) * np.asarray(du) + v.reshape(-1, 1) * np.asarray(dv)
    i, j = np.meshgrid(np.arange(nx), np.arange(nx), indexing="ij")
    a = (i * (nx + 1) + j).ravel()
    return verts, np.stack([a, a + nx + 1, a + nx + 2, a + 1], axis=1)


def box_with(*planes, drop=()):
    """The 175-polygon box (radiance: emission + 0.1 reflectivity) plus ``planes`` (radiance 0.5), minus
    the box polygons ``drop``: ``(scene, box scene, box)``."""
    box = cornell_box(5)
    quads = np.array(box.polygons)
    rad = box.emission + 0.1 * box.reflectivity
    keep = np.setdiff1d(np.arange(len(quads)), drop)
    verts, polys, radiance = [box.vertices], [quads[keep]], [rad[keep]]
    base = len(box.vertices)
    for pv, pq in planes:
        verts.append(pv)
        polys.append(pq + base)
        radiance.append(np.full((len(pq), 3), 0.5))
        base += len(pv)
    scene = Scene.from_polygons(np.concatenate(verts), np.concatenate(polys).tolist(), np.concatenate(radiance))
    bare = Scene.from_polygons(box.vertices, quads[keep].tolist(), rad[keep])
    return scene, bare, box


def receivers(box, scene, m=24, seed=1):
    o, d = camera_rays(box, int(np.ceil(np.sqrt(m))) + 1)
    d = d + np.random.default_rng(seed).uniform(-0.02, 0.02, d.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    h = cast_rays(scene, o, d, bvh=build_bvh(scene))
    keep = np.flatnonzero(h.hit)[:m]
    return h.point[keep], scene.poly_normals[h.polygon[keep]]


def surviving_tiles(scene, p, n):
    """(receiver, tile) pairs that survive the hierarchy, as (points, occluder of each tile)."""
    occ = scene_occluders(scene)
    sv, table = shadow_volumes(occ, p, n)
    cov = coverage(sv, table, occ, p)
    tiles = hierarchy.visit_tiles(scene_hierarchy(scene, occ), occ, sv, table, cov, p, n)
    return tiles, occ


BELOW = grid(60, (-0.5, -0.5, -0.1), (2.0, 0.0, 0.0), (0.0, 2.0, 0.0))       # facing up, outside the box
BEHIND = grid(40, (-0.25, 1.05, -0.25), (0.0, 0.0, 1.5), (1.5, 0.0, 0.0))    # facing the box


def test_hidden_planes_change_nothing_and_cost_nothing():
    scene, bare, box = box_with(BELOW, BEHIND)
    p, n = receivers(box, bare)
    f_bare, f = form_factors(bare, p, n), form_factors(scene, p, n)
    assert np.abs(f[:, :175] - f_bare).max() <= 1e-13
    assert np.abs(f[:, 175:]).max() == 0.0
    np.testing.assert_allclose(f.sum(axis=1), 1.0, atol=1e-10)
    h_bare, h = irradiance(bare, p, n), irradiance(scene, p, n)
    assert np.abs(h - h_bare).max() <= 1e-13 * np.abs(h_bare).max()
    tiles, occ = surviving_tiles(scene, p, n)
    plane_faces = np.unique(occ.members[175:])
    assert not np.isin(occ.tile_occluder[tiles.tile], plane_faces).any()
    assert tiles.visited < 60 * len(p)      # a few nodes per receiver, not the planes' 325 tiles


@pytest.mark.parametrize("closed", [False, True])
def test_node_decisions_change_nothing(monkeypatch, closed):
    """The hierarchy's own decisions (covered, outside, enclosed) against none at all: the same factors."""
    box = cornell_box(5)
    back = [i for i, nm in enumerate(box.names) if nm == "back wall"]
    drop = () if closed else back[7:10]            # a window in the back wall: the plane behind shows
    scene, _, box = box_with(BEHIND, BELOW, drop=drop)
    p, n = receivers(box, scene, m=32, seed=3)
    f = form_factors(scene, p, n)
    h = irradiance(scene, p, n)
    monkeypatch.setattr(hierarchy, "NODE_MARGIN", np.inf)
    monkeypatch.setattr(hierarchy, "_enclosures", lambda sol, points, normals: (
        np.zeros(len(points) + 1, dtype=np.int64),) + (np.zeros((0, 3)),) * 2 + (np.zeros(0),) * 2
        + (np.zeros((0, 3)), np.zeros(0)))
    fresh = Scene(scene.poly_vertices, scene.poly_counts, scene.poly_source, scene.poly_radiance, scene.n_input)
    f0 = form_factors(fresh, p, n)
    h0 = irradiance(fresh, p, n)
    assert np.abs(f - f0).max() <= 1e-13
    assert np.abs(h - h0).max() <= 1e-13 * np.abs(h0).max()
    if not closed:
        assert f[:, 175 - len(drop):175 - len(drop) + 1600].sum() > 1e-3     # the plane is seen


def test_plane_through_the_receivers_costs_nothing():
    """A big subdivided plane the receivers lie in (a ground plane under the box): seen edge-on, none of
    its tiles survives, and the box's factors are unchanged."""
    ground = grid(64, (-4.0, -4.0, -0.5), (8.0, 0.0, 0.0), (0.0, 8.0, 0.0))
    scene, bare, box = box_with(ground)
    rng = np.random.default_rng(5)
    xy = rng.uniform(-3.5, -1.5, (16, 2))
    p = np.column_stack([xy, np.full(16, -0.5)])
    n = np.tile([0.0, 0.0, 1.0], (16, 1))
    tiles, occ = surviving_tiles(scene, p, n)
    assert not np.isin(occ.tile_occluder[tiles.tile], np.unique(occ.members[175:])).any()
    f_bare, f = form_factors(bare, p, n), form_factors(scene, p, n)
    assert np.abs(f[:, :175] - f_bare).max() <= 1e-13
    assert np.abs(f[:, 175:]).max() == 0.0


def test_tree_contains_its_children():
    scene, _, _ = box_with(BELOW)
    occ = scene_occluders(scene)
    h = scene_hierarchy(scene, occ)
    n_t = h.n_tiles
    assert np.array_equal(np.sort(h.perm), np.arange(n_t))
    parent = np.repeat(np.arange(len(h.radii)), np.diff(h.child_ptr))
    c = h.child
    lo, hi = h.corners.min(axis=1), h.corners.max(axis=1)
    assert (lo[c] >= lo[parent]).all() and (hi[c] <= hi[parent]).all()
    reach = np.linalg.norm(h.centers[c] - h.centers[parent], axis=1) + h.radii[c]
    assert (reach <= h.radii[parent]).all()
    assert (h.min_radius[c] >= h.min_radius[parent]).all()
    # every tile is reached exactly once from its face's root
    seen = np.zeros(n_t, dtype=int)
    for face, root in enumerate(h.root):
        stack = [root]
        while stack:
            node = stack.pop()
            if node < n_t:
                assert occ.tile_occluder[node] == face
                seen[node] += 1
            stack.extend(h.child[h.child_ptr[node]:h.child_ptr[node + 1]])
    assert (seen == 1).all()


def _occluder_count(verts, quads):
    return scene_occluders(Scene.from_polygons(verts, [list(q) for q in quads])).n


def test_merged_faces():
    v, q = grid(6, (0, 0, 0), (1, 0, 0), (0, 1, 0))
    assert _occluder_count(v, q) == 1                                  # a grid: one convex face
    cells = q.reshape(6, 6, 4)
    l_shape = np.concatenate([cells[:3, :3].reshape(-1, 4), cells[3:, :3].reshape(-1, 4),
                              cells[:3, 3:].reshape(-1, 4)])
    assert _occluder_count(v, l_shape) == len(l_shape)                # not convex: every quad on its own
    ring = cells[[0, 0, 0, 1, 1, 2, 2, 2], [0, 1, 2, 0, 2, 0, 1, 2]]
    assert _occluder_count(v, ring) == 8                               # a hole
    two = np.concatenate([cells[:2, :2].reshape(-1, 4), cells[4:, 4:].reshape(-1, 4)])
    assert _occluder_count(v, two) == 2                                # disjoint: two faces
    tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    occ = scene_occluders(Scene.from_polygons(v, tris.tolist()))
    assert occ.n == 1 and occ.counts[0] == 4                           # collinear points dropped
    # a T-junction: one big cell next to two small ones (the big one's edge is split on the other side):
    # the big cell shares no whole edge and stays alone, the two small ones merge into one rectangle
    vt = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 0.5, 0], [2, 1, 0], [1, 0.5, 0]],
                  dtype=float)
    qt = [[0, 1, 2, 3], [1, 4, 5, 7], [7, 5, 6, 2]]
    assert _occluder_count(vt, qt) == 2


def test_prepare_scene_progress_and_cancel():
    scene, _, _ = box_with(BELOW)
    calls = []
    prepare_scene(scene, progress=lambda d, t: calls.append((d, t)))
    total = len(PREPARATION_STAGES)
    assert calls == [(i, total) for i in range(1, total + 1)]
    fresh = Scene(scene.poly_vertices, scene.poly_counts, scene.poly_source, scene.poly_radiance, scene.n_input)
    seen = []
    with pytest.raises(Cancelled):
        prepare_scene(fresh, progress=lambda d, t: seen.append(d), cancel=lambda: len(seen) >= 2)
    assert seen == [1, 2]
    assert getattr(fresh, "_occluders", None) is None                   # nothing half-built is kept
    assert chunk.Cancelled is Cancelled


def test_chunks_split_to_the_budget():
    """A chunk whose surviving tiles hold more candidates than the budget has its candidate stage run in
    groups of receivers (memory bound): the same fragments, receiver by receiver."""
    box = cornell_box(5)
    scene = box.scene(radiance=box.emission + 0.1 * box.reflectivity)
    p, n = receivers(box, scene, m=20, seed=7)
    occ = scene_occluders(scene)
    calls = []
    real = chunk._receiver_groups

    def spy(*a, **k):
        groups = real(*a, **k)
        calls.append(len(groups))
        return groups

    for use_clear in (True, False):
        whole = chunk.visible(scene, p, n, None, occ, None, use_clear=use_clear)
        chunk._receiver_groups = spy
        try:
            split = chunk.visible(scene, p, n, None, occ, None, use_clear=use_clear, budget=2000)
        finally:
            chunk._receiver_groups = real
        assert calls and calls[-1] > 1
        for (frags, ff, _), ref in ((split, whole), (whole, whole)):
            per_point = np.bincount(frags.point, weights=ff, minlength=len(p))
            np.testing.assert_allclose(per_point, np.bincount(ref[0].point, weights=ref[1], minlength=len(p)),
                                       rtol=0, atol=1e-15)
        if use_clear:
            assert np.array_equal(np.sort(split[2][0].point), np.sort(whole[2][0].point))


def test_receiver_groups_bound_their_members():
    """The candidate stage's groups partition the receivers; each holds at most the budget's members, or at
    most GROUP_CAP times that with at most MIN_GROUP_POINTS receivers (a large scene's receivers are not run a
    few at a time), or is one receiver; groups of a small scene are those of the plain budget."""
    rng = np.random.default_rng(3)
    for per in (rng.integers(0, 40, 500), rng.integers(0, 4000, 300), np.full(200, 10), np.array([10**6, 5, 5])):
        cum = np.concatenate([[0], np.cumsum(per)])
        limit = 2000
        groups = chunk._receiver_groups(cum, 0, len(per), limit)
        assert [g[0] for g in groups] == [0] + [g[1] for g in groups[:-1]] and groups[-1][1] == len(per)
        for s, e in groups:
            held = cum[e] - cum[s]
            assert held <= limit or e - s == 1 or (e - s <= chunk.MIN_GROUP_POINTS and held <= chunk.GROUP_CAP * limit)
    # 300 receivers of ~2,000 members each: groups of a few receivers with the plain budget, here tens
    cum = np.concatenate([[0], np.cumsum(np.full(300, 2000))])
    groups = chunk._receiver_groups(cum, 0, 300, 20000)
    assert min(e - s for s, e in groups) >= 37 and max(cum[e] - cum[s] for s, e in groups) <= 4 * 20000
    # receivers of few members: the plain budget decides (no group above it)
    cum = np.concatenate([[0], np.cumsum(np.full(10000, 10))])
    assert all(cum[e] - cum[s] <= 20000 for s, e in chunk._receiver_groups(cum, 0, 10000, 20000))


def test_float32_rounded_faces_get_convex_cores(monkeypatch):
    """Rounded to float32, the cells of a rotated block's top have no straight outline and do not merge;
    they get a convex core (the hull of the interior cells, in the tiling's kernel) plus their ring of
    outline cells: fewer occluders, the same form factors (to 1e-13) as with every cell on its own, and
    ΣF = 1 in the closed box."""
    from hemisphere_local_pass.core import culling

    box = cornell_box(15, block_detail=1.05)                 # block tops of 5 x 5 cells: 3 x 3 inside
    sc = Scene.from_polygons(box.vertices.astype(np.float32).astype(np.float64), box.polygons)
    occ = culling.build_occluders(sc)
    monkeypatch.setattr(culling, "_convex_cores", lambda scene, reps, root, rejected, m, c, p:
                        (m, c, p, np.full(scene.n_polygons, -1)))
    plain = culling.build_occluders(sc)
    names = np.array(box.names)[sc.poly_source]
    top = [i for i in range(sc.n_polygons) if "block" in names[i] and sc.poly_normals[i, 2] > 0.999]
    assert occ.n == plain.n - 2 * (9 - 1) and len(np.unique(occ.members[top])) < len(top)
    rng = np.random.default_rng(3)
    blocks = np.flatnonzero(np.char.find(names.astype(str), "block") >= 0)
    sel = np.concatenate([rng.choice(top, 2), rng.choice(blocks, 2), rng.choice(sc.n_polygons, 3)])
    p, n = sc.poly_centers[sel], sc.poly_normals[sel]
    f = form_factors(sc, p, n, workers=1, occluders=occ)
    ref = form_factors(sc, p, n, workers=1, occluders=plain)
    assert np.abs(f - ref).max() <= 1e-13
    assert np.abs(f.sum(axis=1) - 1).max() <= 1e-12


def test_subtiles_partition_every_tile_and_their_boxes_hold_their_members():
    box = cornell_box(20)
    scene = box.scene(radiance=box.emission + 0.5 * box.reflectivity)
    occ = prepare_scene(scene)
    st = chunk.scene_subtiles(scene, occ)
    n_t = len(occ.tile_ptr) - 1
    assert st.tile_ptr[-1] == len(st.mid) > n_t                 # some tiles are split
    for t in range(n_t):
        own = np.sort(occ.tile_members[occ.tile_ptr[t]:occ.tile_ptr[t + 1]])
        subs = range(st.tile_ptr[t], st.tile_ptr[t + 1])
        assert 1 <= len(subs) <= 4
        got = np.concatenate([st.members[st.ptr[s]:st.ptr[s + 1]] for s in subs])
        assert np.array_equal(np.sort(got), own)
        for s in subs:
            v = scene.poly_vertices[st.members[st.ptr[s]:st.ptr[s + 1]]].reshape(-1, 3)
            assert (np.abs(v - st.mid[s]) <= st.half[s] * (1 + 1e-15) + 1e-15).all()


@pytest.mark.parametrize("tolerance", [0.0, 1e-4])
def test_cut_tiles_by_quarters_change_nothing_and_drop_hidden_quarters(monkeypatch, tolerance):
    """The quarters' decisions (hidden quarter, volume that misses a quarter) against the tiles' lists as
    they are: the same factors and irradiance to 1e-13, and fewer candidates."""
    box = cornell_box(20)
    scene = box.scene(radiance=box.emission + 0.5 * box.reflectivity)
    p, n = receivers(box, scene, m=32, seed=5)
    counted = []
    real_hc = chunk.hemisphere_candidates

    def counting(*args):
        cand = real_hc(*args)
        counted.append(len(cand.point))
        return cand

    monkeypatch.setattr(chunk, "hemisphere_candidates", counting)
    tol = tolerance * irradiance(scene, p, n).mean(axis=0)
    f = form_factors(scene, p, n)
    counted.clear()
    h = irradiance(scene, p, n, tolerance=tol)
    quarters = sum(counted)
    monkeypatch.setattr(chunk, "refine_cut_tiles", lambda st, tiles, sv, points: tiles)
    monkeypatch.setattr(chunk, "scene_subtiles", lambda scene, occ: hierarchy.SubTiles(
        None, occ.tile_ptr, occ.tile_members, None, None))
    f0 = form_factors(scene, p, n)
    counted.clear()
    h0 = irradiance(scene, p, n, tolerance=tol)
    assert np.abs(f - f0).max() <= 1e-13
    assert np.abs(h - h0).max() <= 1e-13 * np.abs(h0).max()
    assert quarters < sum(counted)          # (measured: 15,532 → 12,382 candidates exact, 640 → 590 at 1e-4)
