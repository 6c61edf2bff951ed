"""Closed-form configuration factors (Howell's catalogue) and exact occluded cases, <= 1e-13 relative.

Also irradiance H = pi sum L_i F_i (eq. 1 with radiance L; the paper's eq. 3 reads L as radiosity)
and radiance L = E + rho/pi H (eq. 5) on these cases, and one-sided emission: back faces do not
emit unless ``double_sided=True``, but always occlude.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scenes_for_tests import (
    Mesh,
    box_face_quads,
    howell_parallel_corner,
    howell_perpendicular_condition,
    howell_perpendicular_corner,
    lambert_unoccluded,
    random_unit_vectors,
)

REL = 1e-13

F_PARALLEL_111 = 0.138531605994893
F_PERPENDICULAR_111 = 0.055734197002554
F_CUBE_CEILING = 0.239456470460774
F_CUBE_WALL = 0.190135882384807
F_OCCLUDED_EMITTER = 0.179592352845580
F_OCCLUDED_OCCLUDER = 0.138531605994893

UP = np.array([[0.0, 0.0, 1.0]])
ORIGIN = np.zeros((1, 3))


def rect_xy(x0, x1, y0, y1, z, facing_down=True):
    q = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], dtype=np.float64)  # normal +z
    return q[::-1] if facing_down else q


def scene_of(core, polys, radiance=None, **kw):
    mesh = Mesh()
    for i, p in enumerate(polys):
        mesh.add(p, radiance[i] if radiance is not None else (0.0, 0.0, 0.0))
    verts, idx = mesh.arrays()
    rad = mesh.radiance_array() if radiance is not None else None
    return core.Scene.from_polygons(verts, idx, rad, **kw)


def assert_rel(got, want, rel=REL, what=""):
    got = np.asarray(got, dtype=np.float64)
    want = np.asarray(want, dtype=np.float64)
    err = np.abs(got - want) / np.abs(want)
    assert np.all(err <= rel), (
        f"{what}relative error {err.max():.3e} > {rel:g}: got {got.tolist()!r}, want {want.tolist()!r}"
    )


# --------------------------------------------------------------------------------------------
# the test machinery on its own: the Howell formulas and the Lambert reference agree


def test_machinery_howell_constants():
    assert_rel(howell_parallel_corner(1.0, 1.0, 1.0), F_PARALLEL_111, 1e-14)
    assert_rel(howell_perpendicular_corner(1.0, 1.0, 1.0), F_PERPENDICULAR_111, 1e-14)
    assert_rel(4 * howell_parallel_corner(0.5, 0.5, 1.0), F_CUBE_CEILING, 1e-14)
    assert_rel(2 * howell_perpendicular_corner(1.0, 0.5, 0.5), F_CUBE_WALL, 1e-14)
    assert_rel(3 * howell_parallel_corner(1.0, 1.0, 2.0), F_OCCLUDED_EMITTER, 1e-14)
    assert abs(F_CUBE_CEILING + 4 * F_CUBE_WALL - 1.0) < 1e-14


def test_machinery_lambert_matches_howell(rng):
    for a, b, c in rng.uniform(0.05, 20.0, size=(50, 3)):
        assert_rel(lambert_unoccluded(ORIGIN[0], UP[0], rect_xy(0, a, 0, b, c)), howell_parallel_corner(a, b, c),
                   1e-12)
        wall = np.array([[0, c, 0], [b, c, 0], [b, c, a], [0, c, a]], dtype=np.float64)
        assert_rel(lambert_unoccluded(ORIGIN[0], UP[0], wall), howell_perpendicular_corner(a, b, c), 1e-12)


# --------------------------------------------------------------------------------------------
# the implementation against the catalogue


def test_parallel_rectangle_unit(core):
    scene = scene_of(core, [rect_xy(0, 1, 0, 1, 1)])
    F = core.form_factors(scene, ORIGIN, UP)
    assert F.shape == (1, 1) and F.dtype == np.float64
    assert_rel(F[0, 0], F_PARALLEL_111)


def test_perpendicular_rectangle_unit(core):
    wall = np.array([[0, 1, 0], [1, 1, 0], [1, 1, 1], [0, 1, 1]], dtype=np.float64)
    wall = wall[::-1] if np.cross(wall[1] - wall[0], wall[2] - wall[0])[1] > 0 else wall  # face -y (towards P)
    scene = scene_of(core, [wall])
    F = core.form_factors(scene, ORIGIN, UP)
    assert_rel(F[0, 0], F_PERPENDICULAR_111)


def test_parallel_rectangle_general(core, rng):
    abc = np.concatenate([rng.uniform(0.05, 20.0, size=(40, 3)), 10.0 ** rng.uniform(-3, 3, size=(20, 3))])
    for a, b, c in abc:
        scene = scene_of(core, [rect_xy(0, a, 0, b, c)])
        # receivers below three of its corners: each sees it with its normal through a corner
        pts = np.array([[0.0, 0.0, 0.0], [a, 0.0, 0.0], [a, b, 0.0]])
        F = core.form_factors(scene, pts, np.repeat(UP, 3, axis=0))
        assert_rel(F[:, 0], np.full(3, howell_parallel_corner(a, b, c)), what=f"a, b, c = {a!r}, {b!r}, {c!r}: ")


# small factors, where eq. 4's terms cancel (F ~ 5e-5 from terms of order 0.1): found by a wider
# random sweep, kept as fixed regression cases
PERPENDICULAR_HARD = [
    (0.6167255839896155, 111.17049352949188, 29.449840715179953),
    (0.003068834904926294, 3.295894455392158, 0.1238326676900369),
    (0.0025340424828313142, 0.04307686167867261, 0.05133516663716901),
    (0.9800132594736924, 15.2121574688642, 18.758741806205215),
]


def test_perpendicular_rectangle_general(core, rng):
    abc = np.concatenate([rng.uniform(0.05, 20.0, size=(40, 3)), 10.0 ** rng.uniform(-3, 3, size=(20, 3)),
                          PERPENDICULAR_HARD])
    for a, b, c in abc:
        if howell_perpendicular_condition(a, b, c) > 1e-15:
            continue  # the reference itself is not accurate enough (no extended precision here)
        wall = np.array([[0, c, 0], [0, c, a], [b, c, a], [b, c, 0]], dtype=np.float64)  # faces -y
        scene = scene_of(core, [wall])
        F = core.form_factors(scene, np.array([[0.0, 0.0, 0.0], [b, 0.0, 0.0]]), np.repeat(UP, 2, axis=0))
        assert_rel(F[:, 0], np.full(2, howell_perpendicular_corner(a, b, c)), what=f"a, b, c = {a!r}, {b!r}, {c!r}: ")


def test_unit_cube_floor_centre(core):
    quads = box_face_quads([0, 0, 0], [1, 1, 1], inward=True)
    scene = scene_of(core, quads)
    F = core.form_factors(scene, np.array([[0.5, 0.5, 0.0]]), UP)[0]
    centroids = np.array([q.mean(axis=0) for q in quads])
    floor = np.argmin(centroids[:, 2])
    ceiling = np.argmax(centroids[:, 2])
    walls = [i for i in range(6) if i not in (floor, ceiling)]
    assert F[floor] == 0.0
    assert_rel(F[ceiling], F_CUBE_CEILING)
    assert_rel(F[walls], np.full(4, F_CUBE_WALL))
    assert abs(F.sum() - 1.0) <= 1e-13


def occluded_case(core, *, occluder_faces_p=True, emitter_faces_p=True, double_sided=False,
                  radiance=((1.0, 2.0, 3.0), (0.25, 0.5, 0.125))):
    emitter = rect_xy(-1, 1, -1, 1, 2.0, facing_down=emitter_faces_p)
    occluder = rect_xy(0, 1, 0, 1, 1.0, facing_down=occluder_faces_p)
    return scene_of(core, [emitter, occluder], radiance=radiance, double_sided=double_sided)


def test_occluded_square(core):
    scene = occluded_case(core)
    F = core.form_factors(scene, ORIGIN, UP)[0]
    assert_rel(F[0], F_OCCLUDED_EMITTER)
    assert_rel(F[1], F_OCCLUDED_OCCLUDER)


def test_occluded_square_symmetric_receivers(core):
    """The same occlusion seen from receivers at the occluder's other foot points (mirror images)."""
    emitter = rect_xy(-1, 1, -1, 1, 2.0)
    occluders = [rect_xy(-1, 0, 0, 1, 1.0), rect_xy(-1, 0, -1, 0, 1.0), rect_xy(0, 1, -1, 0, 1.0)]
    for occ in occluders:
        scene = scene_of(core, [occ, emitter])
        F = core.form_factors(scene, ORIGIN, UP)[0]
        assert_rel(F, [F_OCCLUDED_OCCLUDER, F_OCCLUDED_EMITTER])


def test_occluded_square_irradiance_and_radiance(core):
    L = np.array([[1.0, 2.0, 3.0], [0.25, 0.5, 0.125]])
    scene = occluded_case(core, radiance=L)
    H = core.irradiance(scene, ORIGIN, UP)
    assert H.shape == (1, 3) and H.dtype == np.float64
    # H is the irradiance of eq. 1 with radiance L: pi sum L_i F_i
    want = math.pi * (L[0] * F_OCCLUDED_EMITTER + L[1] * F_OCCLUDED_OCCLUDER)
    assert_rel(H[0], want)
    rho = np.array([[0.5, 0.25, 0.75]])
    E = np.array([[0.125, 0.0, 2.0]])
    Lo = core.radiance(scene, ORIGIN, UP, rho, emission=E)
    assert Lo.shape == (1, 3)
    assert_rel(Lo[0], E[0] + rho[0] / math.pi * want)
    Lo0 = core.radiance(scene, ORIGIN, UP, rho)  # emission defaults to 0
    assert_rel(Lo0[0], rho[0] / math.pi * want)


def test_back_facing_occluder_occludes_but_does_not_emit(core):
    L = np.array([[1.0, 2.0, 3.0], [0.25, 0.5, 0.125]])
    scene = occluded_case(core, occluder_faces_p=False, radiance=L)
    H = core.irradiance(scene, ORIGIN, UP)[0]
    assert_rel(H, math.pi * L[0] * F_OCCLUDED_EMITTER)  # the emitter is still hidden behind the occluder's back
    F = core.form_factors(scene, ORIGIN, UP)[0]
    assert_rel(F[0], F_OCCLUDED_EMITTER)
    scene2 = occluded_case(core, occluder_faces_p=False, radiance=L, double_sided=True)
    H2 = core.irradiance(scene2, ORIGIN, UP)[0]
    assert_rel(H2, math.pi * (L[0] * F_OCCLUDED_EMITTER + L[1] * F_OCCLUDED_OCCLUDER))


def test_back_facing_emitter_does_not_emit_unless_double_sided(core):
    L = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    scene = occluded_case(core, emitter_faces_p=False, radiance=L)
    H = core.irradiance(scene, ORIGIN, UP)[0]
    np.testing.assert_array_equal(H, np.zeros(3))
    scene2 = occluded_case(core, emitter_faces_p=False, radiance=L, double_sided=True)
    H2 = core.irradiance(scene2, ORIGIN, UP)[0]
    assert_rel(H2, math.pi * L[0] * F_OCCLUDED_EMITTER)


def test_irradiance_in_unit_cube(core, rng):
    """H = pi sum_i L_i F_i with per-face RGB radiance, at the floor centre and at random points."""
    quads = box_face_quads([0, 0, 0], [1, 1, 1], inward=True)
    L = rng.uniform(0.0, 5.0, size=(6, 3))
    scene = scene_of(core, quads, radiance=L)
    centroids = np.array([q.mean(axis=0) for q in quads])
    ceiling = np.argmax(centroids[:, 2])
    floor = np.argmin(centroids[:, 2])
    walls = [i for i in range(6) if i not in (floor, ceiling)]
    H = core.irradiance(scene, np.array([[0.5, 0.5, 0.0]]), UP)[0]
    assert_rel(H, math.pi * (L[ceiling] * F_CUBE_CEILING + L[walls].sum(axis=0) * F_CUBE_WALL))
    pts = rng.uniform(0.05, 0.95, size=(200, 3))
    nrm = random_unit_vectors(rng, 200)
    F = core.form_factors(scene, pts, nrm)
    H = core.irradiance(scene, pts, nrm)
    np.testing.assert_allclose(H, math.pi * (F @ L), rtol=1e-13, atol=1e-13 * np.abs(L).max())


def test_project_point_consistent_with_form_factors(core):
    scene = occluded_case(core)
    proj = core.project_point(scene, ORIGIN[0], UP[0])
    pff = np.asarray(proj.polygon_form_factors)
    assert pff.shape == (2,)
    assert_rel(pff, [F_OCCLUDED_EMITTER, F_OCCLUDED_OCCLUDER])
    assert len(proj.fragments) == len(proj.polygon) == len(proj.form_factor)
    per_poly = np.zeros(2)
    for frag, pid, ff in zip(proj.fragments, proj.polygon, proj.form_factor, strict=True):
        frag = np.asarray(frag)
        assert frag.ndim == 2 and frag.shape[1] == 3 and frag.shape[0] >= 3
        np.testing.assert_allclose(np.linalg.norm(frag, axis=1), 1.0, rtol=0, atol=1e-14)
        assert np.all(frag[:, 2] >= -1e-14), "fragment below the receiver's horizon"
        assert ff >= 0
        per_poly[int(pid)] += ff
    assert_rel(per_poly, [F_OCCLUDED_EMITTER, F_OCCLUDED_OCCLUDER], 1e-12)
    # the direction towards the centre of the hidden quadrant of the emitter lies in the occluder's
    # fragment(s) only (point-in-polygon after central projection onto the plane z = 1)
    d = np.array([0.25, 0.25])
    inside = []
    for frag, pid in zip(proj.fragments, proj.polygon, strict=True):
        frag = np.asarray(frag)
        xy = frag[:, :2] / frag[:, 2:3]
        if point_in_polygon_2d(d, xy):
            inside.append(int(pid))
    assert inside == [1]


def point_in_polygon_2d(q, xy) -> bool:
    """Crossing-number test (works for non-convex polygons)."""
    inside = False
    k = len(xy)
    for i in range(k):
        (x0, y0), (x1, y1) = xy[i], xy[(i + 1) % k]
        if (y0 > q[1]) != (y1 > q[1]):
            x = x0 + (q[1] - y0) * (x1 - x0) / (y1 - y0)
            if x > q[0]:
                inside = not inside
    return inside


@pytest.mark.parametrize("scale", [1e-4, 1.0, 1e4])
def test_occluded_square_scaled(core, scale):
    emitter = rect_xy(-1, 1, -1, 1, 2.0) * scale
    occluder = rect_xy(0, 1, 0, 1, 1.0) * scale
    scene = scene_of(core, [emitter, occluder])
    F = core.form_factors(scene, ORIGIN, UP)[0]
    assert_rel(F, [F_OCCLUDED_EMITTER, F_OCCLUDED_OCCLUDER])
