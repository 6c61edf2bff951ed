"""The clear-tile fast path (core/clear_tiles.py) gives what the general per-fragment path gives.

The fast path sums eq. 4 over the unique edges of tiles that nothing cuts; the general path clips,
subtracts shadow volumes and sums per fragment. Both are run on the same receivers of a subdivided
Cornell box (where most of what a receiver sees is clear tiles) and must agree to rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

from hemisphere_local_pass.core import form_factors, irradiance
from hemisphere_local_pass.core import local_pass as lp
from hemisphere_local_pass.core.clear_tiles import tile_edges
from hemisphere_local_pass.scenes import cornell_box


@pytest.fixture(scope="module", params=[1e-6, 0.0], ids=["off_surface", "on_surface"])
def case(request):
    rng = np.random.default_rng(7)
    box = cornell_box(20)
    radiance = rng.uniform(0.0, 2.0, size=(box.n_polygons, 3))
    scene = box.scene(radiance=radiance)
    # receivers on random polygons (on them, or just off their front side), facing along the normal:
    # on the surface, the tiles of the walls rising from it touch the horizon and still take the
    # fast path
    pick = rng.choice(box.n_polygons, size=300)
    u, v = rng.uniform(0.05, 0.95, size=(2, len(pick)))
    quads = box.vertices[np.array([box.polygons[i] for i in pick])]                # (m, 4, 3)
    pts = (1 - u)[:, None] * ((1 - v)[:, None] * quads[:, 0] + v[:, None] * quads[:, 1]) \
        + u[:, None] * ((1 - v)[:, None] * quads[:, 3] + v[:, None] * quads[:, 2])
    nrm = box.normals()[pick]
    return scene, pts + request.param * nrm, nrm


def general_path(scene, pts, nrm):
    """Per-polygon form factors and Σ L F with the fast path switched off."""
    occ = lp._occluders(scene, None)
    frags, ff, clear = lp._visible(scene, pts, nrm, None, occ, None, use_clear=False)
    assert clear is None
    f = np.zeros((len(pts), scene.n_input))
    np.add.at(f, (frags.point, scene.poly_source[frags.poly]), ff)
    lit = frags.side < 0
    h = np.zeros((len(pts), 3))
    np.add.at(h, frags.point, np.where(lit[:, None], ff[:, None] * scene.poly_radiance[frags.poly], 0.0))
    return np.minimum(f, 1.0), np.pi * h


def test_fast_path_is_taken(case):
    scene, pts, nrm = case
    occ = lp._occluders(scene, None)
    _, _, (pairs, te) = lp._visible(scene, pts, nrm, None, occ, None, use_clear=True)
    members = np.diff(occ.tile_ptr)[pairs.tile].sum()
    assert members > 0.5 * len(pts) * scene.n_polygons / 3       # most of what the receivers see
    # shared edges are stored once: fewer unique edges than (member, edge) incidences
    assert len(te.edge_a) < 0.7 * len(te.inc_edge)


def test_fast_path_equals_general_path(case):
    scene, pts, nrm = case
    f_gen, h_gen = general_path(scene, pts, nrm)
    f = form_factors(scene, pts, nrm)
    h = irradiance(scene, pts, nrm)
    assert np.abs(f - f_gen).max() <= 1e-14
    assert np.abs(f.sum(axis=1) - 1.0).max() <= 1e-10
    assert np.abs(h - h_gen).max() <= 1e-13 * np.abs(h_gen).max()


def test_tile_edges_weld_and_orient():
    """Every member's incidences close its contour; a shared edge is run in opposite directions."""
    box = cornell_box(8)
    scene = box.scene()
    occ = lp._occluders(scene, None)
    te = tile_edges(scene, occ)
    for t in range(len(occ.tile_occluder)):
        inc = slice(te.inc_ptr[t], te.inc_ptr[t + 1])
        e = te.inc_edge[inc] + te.edge_ptr[t]
        # every unique edge's signed use sums to 0 (interior) or ±1 (tile boundary)
        use = np.bincount(e - te.edge_ptr[t], weights=te.inc_sign[inc])
        assert set(np.unique(use)).issubset({-1.0, 0.0, 1.0})
        for poly in np.unique(te.inc_poly[inc]):
            mine = te.inc_poly[inc] == poly
            a = np.where(te.inc_sign[inc][mine] > 0, te.edge_a[e[mine]], te.edge_b[e[mine]])
            b = np.where(te.inc_sign[inc][mine] > 0, te.edge_b[e[mine]], te.edge_a[e[mine]])
            assert sorted(a.tolist()) == sorted(b.tolist())                  # a closed loop
            k = scene.poly_counts[poly]
            assert np.allclose(np.sort(te.vertices[a], axis=0), np.sort(scene.poly_vertices[poly, :k], axis=0))


@pytest.mark.parametrize("d", [1e-4, 1e-6, 1e-8])
def test_edges_passing_close_to_the_receiver(d):
    """A receiver on the ceiling ``d`` from a corner: the walls' top edges pass within ~d of it, their
    end points at very different distances. a · b must come from b itself (regression: a + (b − a)
    lost b's small coordinates, and ΣF went to 1 − 1e-9 at d = 1e-8)."""
    from scenes_for_tests import Mesh, box_face_quads

    mesh = Mesh()
    for q in box_face_quads(np.array([-2.5, -2.0, -3.0]), np.zeros(3), inward=True):
        mesh.add(q)
    verts, polys = mesh.arrays()
    from hemisphere_local_pass.core import Scene

    scene = Scene.from_polygons(verts, polys)
    u = np.array([-1.0, -0.5, 0.0]) / np.sqrt(1.25)
    p, n = (3.0 * d * u)[None], np.array([[0.0, 0.0, -1.0]])
    f = form_factors(scene, p, n)
    f_gen, _ = general_path(scene, p, n)
    assert np.abs(f - f_gen).max() <= 1e-15
    assert abs(f.sum() - 1.0) <= 1e-14


def test_fast_path_in_a_one_sided_limit():
    """Receivers that keep a one-sided limit (face corners that another face touches: the feet of the walls and
    blocks, room corners) take the fast path for the tiles it is certain for, and agree with the general path
    (every tile per fragment, in the limit) to rounding: ``u`` lies in the tangent plane, the decisions have
    margins, and a tile P is clearly off is continuous at P."""
    from hemisphere_local_pass.core.receivers import idle_limits_dropped, prepare_receivers

    rng = np.random.default_rng(11)
    box = cornell_box(20)
    scene = box.scene(radiance=rng.uniform(0.0, 2.0, size=(box.n_polygons, 3)))
    quads = box.vertices[np.array(box.polygons)]                                   # (n, 4, 3)
    nrm = box.normals()
    pts = quads.reshape(-1, 3)
    n4 = np.repeat(nrm, 4, axis=0)
    lim = np.repeat(quads.mean(axis=1), 4, axis=0) - pts
    lim -= np.einsum("ij,ij->i", lim, n4)[:, None] * n4
    lim /= np.linalg.norm(lim, axis=1, keepdims=True)
    p, n, u = prepare_receivers(pts, n4, lim)
    kept = np.flatnonzero(idle_limits_dropped(scene, p, n, u).any(axis=1))
    pick = rng.choice(kept, 120, replace=False)
    P, N, U = p[pick], n[pick], u[pick]
    occ = lp._occluders(scene, None)
    _, _, (pairs, _) = lp._visible(scene, P, N, U, occ, None, use_clear=True)
    assert len(np.unique(pairs.point)) == len(P)  # every receiver has clear tiles
    frags, ff, clear = lp._visible(scene, P, N, U, occ, None, use_clear=False)
    assert clear is None
    f_gen = np.zeros((len(P), scene.n_input))
    np.add.at(f_gen, (frags.point, scene.poly_source[frags.poly]), ff)
    f = form_factors(scene, P, N, limit_directions=U)
    assert np.abs(f - np.minimum(f_gen, 1.0)).max() <= 1e-14
    assert np.abs(f.sum(axis=1) - 1.0).max() <= 1e-10
