"""Invariance of the visible form factors to <= 1e-9 (absolute; F is in [0, 1]).

Rigid motions, scaling by 1e-4 ... 1e4, translation by 1e6 (on coordinates quantised to 2^-30 so
that the translated scene is *exactly* the same geometry), polygon order, cyclic vertex order,
splitting a polygon into triangles (its pieces' F sum to the original's F), and batching (all
points at once vs one at a time).

Two scenes: a random occluded scene (overlapping and interpenetrating convex polygons above a few
receivers) and a room with 8 random interpenetrating boxes and random free receivers.
"""

from __future__ import annotations

import numpy as np
import pytest
from scenes_for_tests import (
    fan_triangles,
    random_box_room,
    random_free_points_in_room,
    random_occluded_scene,
    random_rotation,
    random_unit_vectors,
    receivers,
)

TOL = 1e-9


def occluded_scene(rng):
    mesh, verts, polys = random_occluded_scene(rng)
    pts, nrm = receivers(rng)
    return verts, polys, pts, nrm


def box_room_scene(rng):
    mesh, boxes = random_box_room(rng, 8)
    verts, polys = mesh.arrays()
    pts = random_free_points_in_room(rng, boxes, 60)
    return verts, polys, pts, random_unit_vectors(rng, len(pts))


SCENES = {"occluded": occluded_scene, "box_room": box_room_scene}


def ff(core, verts, polys, pts, nrm):
    return core.form_factors(core.Scene.from_polygons(verts, polys), pts, nrm)


def assert_close(got, want, what):
    assert got.shape == want.shape
    err = np.abs(got - want)
    i = np.unravel_index(np.argmax(err), err.shape)
    assert err[i] <= TOL, f"{what}: max |dF| = {err[i]:.3e} at (point, polygon) {i}: {got[i]!r} vs {want[i]!r}"


@pytest.fixture(params=list(SCENES))
def case(request, rng):
    return SCENES[request.param](rng)


def test_rigid_motion(core, case, rng):
    verts, polys, pts, nrm = case
    F = ff(core, verts, polys, pts, nrm)
    for _ in range(3):
        R = random_rotation(rng)
        t = rng.normal(size=3) * 10
        F2 = ff(core, verts @ R.T + t, polys, pts @ R.T + t, nrm @ R.T)
        assert_close(F2, F, "rigid motion")
    # a mirror image reverses every polygon's orientation: mirror and reverse the vertex order
    M = np.diag([1.0, -1.0, 1.0])
    F3 = ff(core, verts @ M, [p[::-1] for p in polys], pts @ M, nrm @ M)
    assert_close(F3, F, "reflection")


@pytest.mark.parametrize("scale", [1e-4, 1e-2, 0.37, 3.7, 1e2, 1e4])
def test_scaling(core, case, scale):
    verts, polys, pts, nrm = case
    F = ff(core, verts, polys, pts, nrm)
    assert_close(ff(core, verts * scale, polys, pts * scale, nrm), F, f"scaling by {scale:g}")


def quantise(x, bits=30):
    return np.round(np.asarray(x) * 2.0**bits) / 2.0**bits


@pytest.mark.parametrize("offset", [(1e6, 0.0, 0.0), (-1e6, 1e6, 1e6), (0.0, -1e6, 0.0)])
def test_translation_far_from_origin(core, case, offset):
    verts, polys, pts, nrm = case
    verts, pts = quantise(verts), quantise(pts)
    t = np.asarray(offset)
    assert np.array_equal((verts + t) - t, verts) and np.array_equal((pts + t) - t, pts)  # exact
    F = ff(core, verts, polys, pts, nrm)
    assert_close(ff(core, verts + t, polys, pts + t, nrm), F, f"translation by {offset}")


def test_polygon_order(core, case, rng):
    verts, polys, pts, nrm = case
    F = ff(core, verts, polys, pts, nrm)
    for _ in range(3):
        perm = rng.permutation(len(polys))
        F2 = ff(core, verts, [polys[j] for j in perm], pts, nrm)
        assert_close(F2, F[:, perm], "polygon order")


def test_vertex_order_and_numbering(core, case, rng):
    verts, polys, pts, nrm = case
    F = ff(core, verts, polys, pts, nrm)
    rolled = [list(np.roll(p, int(rng.integers(len(p))))) for p in polys]
    assert_close(ff(core, verts, rolled, pts, nrm), F, "cyclic vertex order")
    # renumbering the vertices (a permutation of the vertex array) changes nothing either
    perm = rng.permutation(len(verts))
    inv = np.argsort(perm)
    renum = [[int(inv[i]) for i in p] for p in polys]
    assert_close(ff(core, verts[perm], renum, pts, nrm), F, "vertex numbering")


def test_splitting_into_triangles(core, case, rng):
    verts, polys, pts, nrm = case
    F = ff(core, verts, polys, pts, nrm)
    n = len(polys)
    split = [i for i in range(n) if len(polys[i]) > 3 and rng.random() < 0.6]
    new_polys = [p for i, p in enumerate(polys) if i not in split]
    keep = [i for i in range(n) if i not in split]
    owners = []
    new_verts = verts.copy()
    for i in split:
        if rng.random() < 0.5:
            pieces = fan_triangles(list(np.roll(polys[i], int(rng.integers(len(polys[i]))))))
        else:  # a fan around an interior point (the vertex centroid)
            c = len(new_verts)
            new_verts = np.vstack([new_verts, verts[polys[i]].mean(axis=0)])
            p = polys[i]
            pieces = [[c, p[k], p[(k + 1) % len(p)]] for k in range(len(p))]
        new_polys += pieces
        owners.append((i, len(pieces)))
    assert split, "nothing was split"
    F2 = ff(core, new_verts, new_polys, pts, nrm)
    assert_close(F2[:, :len(keep)], F[:, keep], "unsplit polygons after splitting others")
    col = len(keep)
    for i, k in owners:
        assert_close(F2[:, col:col + k].sum(axis=1), F[:, i], f"sum over the pieces of polygon {i}")
        col += k


def test_batching(core, case):
    verts, polys, pts, nrm = case
    scene = core.Scene.from_polygons(verts, polys)
    F = core.form_factors(scene, pts, nrm)
    single = np.vstack([core.form_factors(scene, pts[i:i + 1], nrm[i:i + 1]) for i in range(len(pts))])
    assert_close(single, F, "one point at a time vs all at once")
    rev = core.form_factors(scene, pts[::-1].copy(), nrm[::-1].copy())[::-1]
    assert_close(rev, F, "reversed point order")


def test_irradiance_rigid_motion(core, rng):
    verts, polys, pts, nrm = box_room_scene(rng)
    L = rng.uniform(0, 2, size=(len(polys), 3))
    H = core.irradiance(core.Scene.from_polygons(verts, polys, L), pts, nrm)
    R = random_rotation(rng)
    t = rng.normal(size=3) * 100
    H2 = core.irradiance(core.Scene.from_polygons(verts @ R.T + t, polys, L), pts @ R.T + t, nrm @ R.T)
    assert np.abs(H2 - H).max() <= TOL * np.abs(L).max()
