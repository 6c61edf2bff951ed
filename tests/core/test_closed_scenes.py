"""Closed scenes: every point inside sees sum_i F_i = 1 to 1e-10, for any normal direction.

(a) a box whose faces are split into quads, triangle pairs and fans (with T-junctions where the
faces meet), (b) the Cornell box with its two blocks and the light (front closed), (c) a room with
50 randomly rotated, overlapping and interpenetrating boxes. Points are uniformly random in the
free space (never inside a block or box), normals uniformly random on the whole sphere: polygons
are opaque from both sides, so even a receiver facing the back of a box sees a closed world.
All points of a scene go through the vectorised API in one call.
"""

from __future__ import annotations

import numpy as np
import pytest
from scenes_for_tests import (
    CORNELL_SHORT_BLOCK_FOOT,
    CORNELL_SHORT_HEIGHT,
    CORNELL_TALL_BLOCK_FOOT,
    CORNELL_TALL_HEIGHT,
    _inside_convex_prism,
    cornell_box,
    cornell_free_points,
    monte_carlo_form_factors,
    random_box_room,
    random_free_points_in_room,
    random_unit_vectors,
    signed_volume,
    split_box,
)

TOL = 1e-10
# random receivers per scene in the slow test: 10,000 where the runtime allows; the 324-polygon box
# room costs ~20 ms per point on one core (Nov 2026), so it gets 3,000 (23,000 in total, ~1.5 min)
N_POINTS = {"split_box": 10_000, "cornell": 10_000, "box_room": 3000}

BOX_LO = np.array([-1.5, 2.0, 0.25])
BOX_HI = np.array([1.5, 4.5, 2.25])


def split_box_case(rng, m):
    mesh = split_box(BOX_LO, BOX_HI, rng, inward=True)
    pts = BOX_LO + (BOX_HI - BOX_LO) * rng.uniform(1e-6, 1 - 1e-6, size=(m, 3))
    return mesh, pts


def cornell_case(rng, m):
    return cornell_box(), cornell_free_points(rng, m)


def box_room_case(rng, m):
    mesh, boxes = random_box_room(rng, 50)
    return mesh, random_free_points_in_room(rng, boxes, m)


CASES = {"split_box": split_box_case, "cornell": cornell_case, "box_room": box_room_case}


# --------------------------------------------------------------------------------------------
# the scene builders on their own


def test_machinery_split_box_is_closed_and_inward(rng):
    mesh = split_box(BOX_LO, BOX_HI, rng, inward=True)
    verts, polys = mesh.arrays()
    assert any(len(p) == 3 for p in polys) and any(len(p) == 4 for p in polys)
    assert signed_volume(verts, polys) == pytest.approx(-np.prod(BOX_HI - BOX_LO), rel=1e-14)


def test_machinery_box_room_volume(rng):
    mesh, boxes = random_box_room(rng, 50)
    verts, polys = mesh.arrays()
    assert len(polys) == 24 + 300
    want = -1000.0 + sum(8 * np.prod(b.half) for b in boxes)
    assert signed_volume(verts, polys) == pytest.approx(want, rel=1e-12)
    # the boxes really overlap each other
    centres = np.array([b.centre for b in boxes])
    pts = random_free_points_in_room(rng, boxes, 100)
    for b in boxes:
        assert not b.contains(pts).any()
    inside = [b.contains(centres) for b in boxes]
    assert sum(int(x.sum()) - 1 for x in inside) > 0, "no box contains another's centre"


@pytest.mark.parametrize("case", CASES)
def test_machinery_rays_never_escape(case, rng):
    """Monte Carlo rays from free points in every direction always hit something: the scene is closed."""
    mesh, pts = CASES[case](rng, 6)
    verts, polys = mesh.arrays()
    for p, n in zip(pts, random_unit_vectors(rng, len(pts)), strict=True):
        for sign in (1.0, -1.0):
            F = monte_carlo_form_factors(rng, verts, polys, p, sign * n, 4000)
            assert abs(F.sum() - 1.0) < 1e-12  # a single escaping ray would give 1/4000


# --------------------------------------------------------------------------------------------
# the implementation


def check_closed(core, mesh, pts, nrm):
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys, mesh.radiance_array())
    F = core.form_factors(scene, pts, nrm)
    assert F.shape == (len(pts), len(polys))
    assert F.dtype == np.float64
    assert np.all(np.isfinite(F))
    assert F.min() >= 0.0, f"negative form factor {F.min():.3e}"
    err = np.abs(F.sum(axis=1) - 1.0)
    worst = int(np.argmax(err))
    assert err[worst] <= TOL, (
        f"max |sum F - 1| = {err[worst]:.3e} over {len(pts)} points ({np.sum(err > TOL)} above {TOL:g}); "
        f"worst: point={pts[worst].tolist()!r} normal={nrm[worst].tolist()!r} sum={F[worst].sum()!r}"
    )
    return err


@pytest.mark.parametrize("case", CASES)
def test_closed_scene_quick(core, case, rng):
    mesh, pts = CASES[case](rng, 100)
    check_closed(core, mesh, pts, random_unit_vectors(rng, len(pts)))


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES)
def test_closed_scene_many_points(core, case, rng):
    mesh, pts = CASES[case](rng, N_POINTS[case])
    check_closed(core, mesh, pts, random_unit_vectors(rng, len(pts)))


@pytest.mark.parametrize("case", CASES)
def test_closed_scene_receivers_on_faces(core, case, rng):
    """Receivers on the scene's (planar) faces with the face's front normal: the local pass's case.

    The face's own plane contains the receiver (it contributes 0); every other direction of the
    hemisphere ends on the front of some polygon, so sum F = 1. Receivers from which the back of a
    polygon is visible (on the floor under a Cornell block, on a wall inside a box poking through
    it, on a box face inside another box) are left out: whether ``form_factors`` reports back
    faces is not part of the contract.
    """
    if case == "box_room":
        mesh, boxes = random_box_room(rng, 50)
    else:
        mesh = CASES[case](rng, 1)[0]
    verts, polys = mesh.arrays()
    pts, nrm = [], []
    for poly in polys:
        c = verts[poly]
        n = np.cross(c[1] - c[0], c[2] - c[0])
        n /= np.linalg.norm(n)
        if np.abs((c - c[0]) @ n).max() > 1e-12 * np.abs(c).max():
            continue  # the Cornell box's non-planar red wall: its triangulation is the implementation's choice
        k = 2 if case == "box_room" else 8  # the box room costs ~20x more per point
        w = rng.dirichlet(np.ones(len(c)), size=k)
        pts.append(w @ c)
        nrm.append(np.repeat(n[None], k, axis=0))
    pts, nrm = np.concatenate(pts), np.concatenate(nrm)
    if case == "cornell":
        keep = np.ones(len(pts), dtype=bool)
        blocks = ((CORNELL_SHORT_BLOCK_FOOT, CORNELL_SHORT_HEIGHT), (CORNELL_TALL_BLOCK_FOOT, CORNELL_TALL_HEIGHT))
        for foot, h in blocks:
            mid = pts.copy()
            mid[:, 1] = 0.5 * h  # test the footprint only; the height separately (floor points count)
            keep &= ~(_inside_convex_prism(mid, foot, h, -1e-6) & (pts[:, 1] < h - 1e-6))
    elif case == "box_room":
        keep = np.all((pts >= 0.0) & (pts <= 10.0), axis=1)  # box faces poking out of the room
        for b in boxes:
            keep &= ~b.contains(pts, margin=-1e-9)
    else:
        keep = np.ones(len(pts), dtype=bool)
    assert keep.sum() > 0.5 * len(pts)
    check_closed(core, mesh, pts[keep], nrm[keep])
