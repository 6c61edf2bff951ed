"""``Scene.from_arrays(loop_triangles=...)``: polygons the core would split are split into the mesh's
own triangles (Blender's ``Mesh.loop_triangles``), so the surface and the linearly interpolated
radiance are the renderer's; polygons kept whole stay whole (issue 14.14)."""

from __future__ import annotations

import numpy as np
import pytest

HEX = np.array([(np.cos(a), np.sin(a), 0.0) for a in np.arange(6) * np.pi / 3])
#: Blender's loop triangles of a hexagon (corner indices)
HEX_TRIS = np.array([(5, 0, 1), (1, 2, 3), (3, 4, 5), (1, 3, 5)])
#: an L-shaped (concave) hexagon in z = 0, counter-clockwise, and a triangulation other than ear clipping's
L_SHAPE = np.array([(0, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1, 0), (1, 2, 0), (0, 2, 0)], dtype=float)
L_TRIS = np.array([(0, 1, 2), (0, 2, 3), (0, 3, 5), (3, 4, 5)])


def arrays(verts, n):
    return verts, np.arange(n), np.array([0]), np.array([n])


def tri_set(scene):
    return {tuple(sorted(map(tuple, np.round(t[:3], 12)))) for t in scene.poly_vertices}


def test_linear_radiance_uses_the_given_triangles(core):
    corner = np.array([0.0, 1.0, 0.0, 5.0, 0.0, 1.0])  # not affine over the hexagon
    sc = core.Scene.from_arrays(*arrays(HEX, 6), corner_radiance=corner,
                                loop_triangles=HEX_TRIS, loop_triangle_polygons=np.zeros(4, int))
    assert sc.n_polygons == 4 and set(sc.poly_source) == {0}
    assert tri_set(sc) == {tuple(sorted(map(tuple, np.round(HEX[t], 12)))) for t in HEX_TRIS}
    np.testing.assert_array_equal(sc.corner_radiance[..., 0], corner[HEX_TRIS])
    np.testing.assert_allclose(sc.poly_normals, [(0, 0, 1)] * 4, atol=1e-15)  # wound like the polygon
    fan = core.Scene.from_arrays(*arrays(HEX, 6), corner_radiance=corner)  # the core's own fan differs ...
    assert tri_set(fan) != tri_set(sc)
    # ... and so does what a point above the hexagon receives (the radiance between the corners differs)
    p, n = np.array([[0.0, 0.0, 0.3]]), np.array([[0.0, 0.0, -1.0]])
    h_own, h_fan = core.irradiance(sc, p, n), core.irradiance(fan, p, n)
    assert abs(h_own[0, 0] - h_fan[0, 0]) > 0.1 * h_own[0, 0]


def test_constant_concave_polygon_uses_the_given_triangles_convex_stays_whole(core):
    verts = np.concatenate([L_SHAPE, HEX + (5.0, 0.0, 0.0)])
    loops = np.arange(12)
    tris = np.concatenate([L_TRIS, HEX_TRIS + 6])
    sc = core.Scene.from_arrays(verts, loops, [0, 6], [6, 6], np.array([[1.0] * 3, [2.0] * 3]),
                                loop_triangles=tris, loop_triangle_polygons=[0] * 4 + [1] * 4)
    assert list(sc.poly_source) == [0, 0, 0, 0, 1] and sc.poly_counts[-1] == 6  # the convex hexagon stays whole
    assert tri_set(sc) >= {tuple(sorted(map(tuple, L_SHAPE[t]))) for t in L_TRIS}
    without = core.Scene.from_arrays(verts, loops, [0, 6], [6, 6], np.array([[1.0] * 3, [2.0] * 3]))
    p, n = np.array([[0.7, 0.6, 1.0], [5.2, 0.1, 0.4]]), np.array([[0.0, 0.0, -1.0]] * 2)
    # the same surface: the same form factors (a partition of the same polygon)
    np.testing.assert_allclose(core.form_factors(sc, p, n), core.form_factors(without, p, n), rtol=1e-12, atol=1e-15)


def test_degenerate_triangles_left_out_polygon_kept(core):
    # a square with a collinear extra corner: Blender makes a zero-area triangle of it
    verts = np.array([(0, 0, 0), (1, 0, 0), (2, 0, 0), (2, 2, 0), (0, 2, 0)], dtype=float)
    tris = np.array([(0, 1, 2), (0, 2, 3), (0, 3, 4)])  # the first has zero area
    corner = np.arange(5.0)
    sc = core.Scene.from_arrays(*arrays(verts, 5), corner_radiance=corner, loop_triangles=tris,
                                loop_triangle_polygons=[0, 0, 0])
    assert sc.n_polygons == 2 and not sc.dropped


def test_loop_triangle_errors_name_the_polygon(core):
    with pytest.raises(ValueError, match="polygon 0 .*corners of another polygon"):
        core.Scene.from_arrays(np.concatenate([HEX, HEX + 3]), np.arange(12), [0, 6], [6, 6],
                               corner_radiance=np.zeros(12), loop_triangles=[(5, 0, 6)],
                               loop_triangle_polygons=[0], polygon_names=["Hex.polygon 0", "Hex.polygon 1"])
    with pytest.raises(ValueError, match="2 entries for 1 triangles"):
        core.Scene.from_arrays(*arrays(HEX, 6), loop_triangles=[(0, 1, 2)], loop_triangle_polygons=[0, 0])
