"""project_point: the visible fragments at one receiver, as the inspector draws them.

Checks the contract: unit vectors on the upper hemisphere, fragments counter-clockwise seen from P,
per-fragment factors that sum to the per-polygon factors of ``form_factors``, the paper's dist(v),
and that the fragments tile the hemisphere of a closed scene without overlap (their factors sum to 1
and, independently, their spherical areas sum to 2π).
"""

from __future__ import annotations

import numpy as np
from scenes_for_tests import cornell_box, cornell_free_points, random_unit_vectors


def spherical_area(dirs: np.ndarray) -> float:
    """Area of a convex spherical polygon (unit vertices counter-clockwise seen from the centre)."""
    a = dirs[0]
    total = 0.0
    for b, c in zip(dirs[1:-1], dirs[2:]):
        # Van Oosterom & Strackee solid angle of the triangle (a, b, c)
        num = np.dot(a, np.cross(b, c))
        den = 1 + np.dot(a, b) + np.dot(b, c) + np.dot(c, a)
        total += 2 * np.arctan2(num, den)
    return total


def test_fragments_match_form_factors_and_tile_the_hemisphere(core, rng):
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys)
    points = cornell_free_points(rng, 12)
    normals = random_unit_vectors(rng, 12)
    F = core.form_factors(scene, points, normals)
    for p, n, row in zip(points, normals, F):
        proj = core.project_point(scene, p, n)
        assert len(proj.fragments) == len(proj.polygon) == len(proj.form_factor) == len(proj.distance)
        np.testing.assert_allclose(proj.polygon_form_factors, row, rtol=0, atol=1e-15)
        assert abs(proj.form_factor.sum() - 1.0) <= 1e-12
        area = 0.0
        for dirs, dist, ff, poly in zip(proj.fragments, proj.distance, proj.form_factor, proj.polygon):
            assert dirs.ndim == 2 and dirs.shape[1] == 3 and len(dirs) >= 3
            np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-14)
            assert (dirs @ n >= -1e-12).all(), "fragment below the horizon"
            assert ff >= 0
            # dist(v) is the distance from P to the fragment's vertex in the polygon's plane
            # (the classic Cornell data has non-planar walls, split into triangles: one piece's plane)
            pts3d = p + dirs * dist[:, None]
            pieces = scene.poly_source == poly
            dev = np.abs(pts3d @ scene.poly_normals[pieces].T - scene.poly_offsets[pieces]).max(axis=0)
            assert dev.min() <= 1e-9 * 555, "fragment vertices are not in their polygon's plane"
            a = spherical_area(dirs)
            assert a >= -1e-12, "fragment is not positively oriented about P"
            area += a
        # the fragments partition the whole sphere's upper half ... and nothing else
        assert abs(area - 2 * np.pi) <= 1e-9


def test_limit_direction_is_accepted(core):
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys)
    p = np.array([0.0, 0.0, 300.0])  # on the floor, at the foot of the left wall
    proj = core.project_point(scene, p, [0.0, 1.0, 0.0], limit_direction=[1.0, 0.0, 0.0])
    assert abs(proj.form_factor.sum() - 1.0) <= 1e-10
