"""Scene input: errors name the offending polygon/vertex; degenerate polygons are dropped and
counted; concave n-gons give the same F as their triangulation; non-planar quads are triangulated.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from scenes_for_tests import Mesh, unit

TOL = 1e-9  # the bound for "splitting a polygon into triangles"


def grid_scene(n_polys=10):
    """n_polys small quads above the origin, facing down; 4 vertices each."""
    m = Mesh()
    for i in range(n_polys):
        x = -2.0 + 0.45 * i
        m.add(np.array([[x, -0.2, 1.0 + 0.1 * i], [x, 0.2, 1.0 + 0.1 * i], [x + 0.4, 0.2, 1.0 + 0.1 * i],
                        [x + 0.4, -0.2, 1.0 + 0.1 * i]]))
    return m.arrays()


def names(msg, *numbers):
    return all(re.search(rf"(?<![\d.]){n}(?![\d.])", msg) for n in numbers)


def ff(core, verts, polys, pts, nrm, **kw):
    return core.form_factors(core.Scene.from_polygons(verts, polys, **kw), pts, nrm)


RECEIVERS = np.array([[0.0, 0.0, 0.0], [0.3, 0.4, 0.0], [1.1, 0.9, 0.2], [-0.5, 1.7, 0.1], [0.6, 0.6, 0.5]])
NORMALS = unit(np.array([[0, 0, 1], [0.2, -0.1, 1], [-0.3, 0.2, 1], [0.1, 0.4, 1], [0.0, 0.0, 1]], dtype=float))


# --------------------------------------------------------------------------------------------
# errors


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_vertex_names_it(core, bad):
    verts, polys = grid_scene()
    verts[29, 1] = bad  # a vertex of polygon 7
    assert 29 in polys[7]
    with pytest.raises(ValueError) as exc:
        core.Scene.from_polygons(verts, polys)
    assert names(str(exc.value), 29) or names(str(exc.value), 7), str(exc.value)


@pytest.mark.parametrize("shape", [(40, 2), (40,), (40, 3, 1), (40, 4)])
def test_wrong_vertex_shape(core, shape):
    _, polys = grid_scene()
    with pytest.raises(ValueError):
        core.Scene.from_polygons(np.zeros(shape), polys)


@pytest.mark.parametrize("index", [40, 1000, -1])
def test_out_of_range_index_names_polygon(core, index):
    verts, polys = grid_scene()
    polys[6] = [polys[6][0], polys[6][1], index, polys[6][3]]
    with pytest.raises(ValueError) as exc:
        core.Scene.from_polygons(verts, polys)
    assert names(str(exc.value), 6), str(exc.value)


def test_from_arrays_errors_name_polygon(core):
    verts, polys = grid_scene()
    loops = np.concatenate([np.asarray(p) for p in polys])
    total = np.array([len(p) for p in polys])
    start = np.concatenate([[0], np.cumsum(total)[:-1]])
    pnames = [f"obj.{i:03d}" for i in range(len(polys))]
    s = core.Scene.from_arrays(verts, loops, start, total, polygon_names=pnames)
    assert s.n_input == len(polys)
    bad = loops.copy()
    bad[start[8] + 2] = 999
    with pytest.raises(ValueError) as exc:
        core.Scene.from_arrays(verts, bad, start, total, polygon_names=pnames)
    assert "obj.008" in str(exc.value) or names(str(exc.value), 8), str(exc.value)
    with pytest.raises(ValueError):
        core.Scene.from_arrays(verts, loops, start, total[:-1])
    over = total.copy()
    over[-1] += 3  # runs past the end of loop_vertices
    with pytest.raises(ValueError) as exc:
        core.Scene.from_arrays(verts, loops, start, over, polygon_names=pnames)
    assert "obj.009" in str(exc.value) or names(str(exc.value), 9), str(exc.value)


def test_radiance_errors(core):
    verts, polys = grid_scene()
    with pytest.raises(ValueError):
        core.Scene.from_polygons(verts, polys, np.ones((len(polys) - 1, 3)))
    with pytest.raises(ValueError):
        core.Scene.from_polygons(verts, polys, np.ones((len(polys), 2)))
    rad = np.ones((len(polys), 3))
    rad[4, 2] = np.nan
    with pytest.raises(ValueError) as exc:
        core.Scene.from_polygons(verts, polys, rad)
    assert names(str(exc.value), 4), str(exc.value)


def test_receiver_shape_errors(core):
    verts, polys = grid_scene()
    scene = core.Scene.from_polygons(verts, polys)
    P = np.zeros((3, 3))
    N = np.tile([0.0, 0.0, 1.0], (3, 1))
    with pytest.raises(ValueError):
        core.form_factors(scene, P[:, :2], N)
    with pytest.raises(ValueError):
        core.form_factors(scene, P, N[:2])
    with pytest.raises(ValueError):
        core.form_factors(scene, P, N, limit_directions=np.zeros((2, 3)))
    with pytest.raises(ValueError):
        core.irradiance(scene, P, N[:, :2])
    bad = P.copy()
    bad[1, 0] = np.nan
    with pytest.raises(ValueError):
        core.form_factors(scene, bad, N)


# --------------------------------------------------------------------------------------------
# degenerate polygons


def test_degenerate_polygons_dropped_and_counted(core):
    verts, polys = grid_scene(4)
    extra = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 2.0], [2.0, 0.0, 2.0], [3.0, 0.0, 2.0], [0.0, 1.0, 2.0]])
    v0 = len(verts)
    verts = np.vstack([verts, extra])
    valid_polys = list(polys)
    degenerate = {
        4: [v0, v0 + 1, v0 + 2],  # collinear: zero area
        5: [v0, v0, v0 + 4],  # a repeated vertex: two distinct vertices
        6: [v0, v0 + 1],  # fewer than three vertices
        7: [v0, v0 + 1, v0 + 2, v0 + 3],  # four collinear vertices
        8: [v0 + 4, v0 + 4, v0 + 4],  # one point
    }
    all_polys = valid_polys + [degenerate[k] for k in sorted(degenerate)]
    all_polys.append([v0, v0 + 1, v0 + 1, v0 + 4])  # 9: a repeated corner, but a fine triangle
    scene = core.Scene.from_polygons(verts, all_polys)
    assert set(scene.dropped) == set(degenerate), scene.dropped
    assert scene.n_input == len(all_polys)
    for k, reason in scene.dropped.items():
        assert isinstance(reason, str) and reason, (k, reason)
    F = core.form_factors(scene, RECEIVERS, NORMALS)
    assert F.shape == (len(RECEIVERS), len(all_polys))
    assert np.all(F[:, sorted(degenerate)] == 0.0)
    ref = ff(core, verts, valid_polys + [[v0, v0 + 1, v0 + 4]], RECEIVERS, NORMALS)
    np.testing.assert_allclose(F[:, list(range(4)) + [9]], ref, rtol=0, atol=1e-15)
    assert F[:, 9].max() > 0


# --------------------------------------------------------------------------------------------
# concave and non-planar polygons


def planar(coords2d, z):
    c = np.asarray(coords2d, dtype=np.float64)
    return np.column_stack([c, np.full(len(c), z)])


# reversed so that it faces down: index j is the corner (0,2), (1,2), (1,1) [reflex], (2,1), (2,0), (0,0)
L_SHAPE = planar([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], 1.5)[::-1]
L_PIECES = [[0, 1, 2], [0, 2, 5], [2, 3, 4], [2, 4, 5]]


def star(n=5, r_out=1.3, r_in=0.5, z=1.2, centre=(0.4, 0.3)):
    ang = np.pi / 2 + np.arange(2 * n) * np.pi / n
    r = np.where(np.arange(2 * n) % 2 == 0, r_out, r_in)
    pts = np.column_stack([centre[0] + r * np.cos(ang), centre[1] + r * np.sin(ang)])
    return planar(pts, z)[::-1]  # counter-clockwise seen from below: faces down


def star_pieces(n=5):
    """Manual triangulation of star(): indices into the reversed array (outer tips at odd... )."""
    k = 2 * n
    # in the reversed array, index j corresponds to original index k - 1 - j
    orig = lambda i: k - 1 - (i % k)  # noqa: E731
    inner = [orig(i) for i in range(1, k, 2)]
    pieces = [[inner[0], inner[i], inner[i + 1]] for i in range(1, n - 1)]  # inner pentagon
    for i in range(0, k, 2):  # tips: inner before, tip, inner after
        pieces.append([orig(i - 1), orig(i), orig(i + 1)])
    return pieces


def oriented_like(coords, piece, ref_normal):
    c = coords[piece]
    n = np.cross(c[1] - c[0], c[2] - c[0])
    return piece if np.dot(n, ref_normal) > 0 else piece[::-1]


def check_same_as_pieces(core, shape, pieces, occluder=None):
    ref_n = np.cross(shape[1] - shape[0], shape[2] - shape[0])
    verts = shape.copy()
    polys_whole = [list(range(len(shape)))]
    polys_split = [oriented_like(shape, list(p), ref_n) for p in pieces]
    if occluder is not None:
        base = len(verts)
        verts = np.vstack([verts, occluder])
        polys_whole.append(list(range(base, base + len(occluder))))
        polys_split.append(list(range(base, base + len(occluder))))
    Fw = ff(core, verts, polys_whole, RECEIVERS, NORMALS)
    Fs = ff(core, verts, polys_split, RECEIVERS, NORMALS)
    np.testing.assert_allclose(Fw[:, 0], Fs[:, :len(pieces)].sum(axis=1), rtol=0, atol=TOL)
    if occluder is not None:
        np.testing.assert_allclose(Fw[:, 1], Fs[:, -1], rtol=0, atol=TOL)
    assert Fw[:, 0].max() > 0.01


def inside_2d(q, xy):
    """Crossing-number point-in-polygon test for many points q (n, 2)."""
    inside = np.zeros(len(q), dtype=bool)
    for i in range(len(xy)):
        (x0, y0), (x1, y1) = xy[i], xy[(i + 1) % len(xy)]
        cross = (y0 > q[:, 1]) != (y1 > q[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            x = x0 + (q[:, 1] - y0) * (x1 - x0) / (y1 - y0)
        inside ^= cross & (x > q[:, 0])
    return inside


@pytest.mark.parametrize("which", ["L", "star"])
def test_machinery_pieces_tile_the_shape(which, rng):
    shape, pieces = (L_SHAPE, L_PIECES) if which == "L" else (star(), star_pieces())
    xy = shape[:, :2]
    q = xy.min(axis=0) + (xy.max(axis=0) - xy.min(axis=0)) * rng.random((20000, 2))
    cover = sum(inside_2d(q, xy[p]).astype(int) for p in pieces)
    assert np.array_equal(cover, inside_2d(q, xy).astype(int))


def test_concave_l_shape(core):
    check_same_as_pieces(core, L_SHAPE, L_PIECES)


def test_concave_l_shape_as_occluder_and_emitter(core):
    emitter = planar([[-1, -1], [-1, 3], [3, 3], [3, -1]], 2.5)  # facing down
    check_same_as_pieces(core, L_SHAPE, L_PIECES, occluder=emitter)
    # a triangle hiding part of the L from the receivers
    tri = planar([[0.3, 0.2], [1.4, 0.2], [1.4, 1.3]], 1.8)[::-1]
    check_same_as_pieces(core, L_SHAPE + [0, 0, 1.5], L_PIECES, occluder=tri)


def test_concave_star(core):
    check_same_as_pieces(core, star(), star_pieces())
    check_same_as_pieces(core, star(), star_pieces(), occluder=planar([[-1, -1], [2, -1], [2, 2], [-1, 2]], 2.0))


def test_non_planar_quad_is_triangulated(core):
    """A non-planar quad equals one of its two triangulations (the documented rule picks which).

    Unoccluded and seen from the front, both triangulations give the same F (it depends only on
    the boundary); a plate cutting through the fold makes them differ, so the check has teeth.
    """
    quad = np.array([[0.0, 0.0, 1.0], [1.2, 0.0, 1.0], [1.2, 1.0, 2.0], [0.0, 1.0, 1.0]])[::-1]  # faces down
    plate = np.array([[0.2, 0.1, 1.45], [0.2, 0.9, 1.45], [1.1, 0.9, 1.45], [1.1, 0.1, 1.45]])  # faces down
    verts = np.vstack([quad, plate])
    R = np.array([[0.6, 0.5, 0.0], [0.3, 0.3, 0.2], [1.0, 0.7, 0.5]])
    N = unit(np.array([[0, 0, 1], [0.2, 0.1, 1], [-0.2, -0.3, 1]]))
    for tri in ([0, 1, 2], [0, 2, 3], [0, 1, 3], [1, 2, 3], [4, 5, 6]):  # every piece seen from its front
        c = verts[tri]
        assert np.all((R - c[0]) @ np.cross(c[1] - c[0], c[2] - c[0]) > 0.1)
    Fq = ff(core, verts, [[0, 1, 2, 3], [4, 5, 6, 7]], R, N)
    Fa = ff(core, verts, [[0, 1, 2], [0, 2, 3], [4, 5, 6, 7]], R, N)
    Fb = ff(core, verts, [[0, 1, 3], [1, 2, 3], [4, 5, 6, 7]], R, N)
    Fa = np.column_stack([Fa[:, :2].sum(axis=1), Fa[:, 2]])
    Fb = np.column_stack([Fb[:, :2].sum(axis=1), Fb[:, 2]])
    assert np.abs(Fa - Fb).min() > 1e-3  # the two triangulations really differ
    ok_a = np.abs(Fq - Fa).max() <= TOL
    ok_b = np.abs(Fq - Fb).max() <= TOL
    assert ok_a or ok_b, f"non-planar quad F {Fq.tolist()} is neither triangulation: {Fa.tolist()} / {Fb.tolist()}"
