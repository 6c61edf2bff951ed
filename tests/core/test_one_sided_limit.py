"""The one-sided limit at receivers on the foot of a wall / in a room corner (``limit_directions``).

At a receiver P exactly on the bottom edge of a wall of a closed box (P in the wall's plane), the
exact integral at P has the wall contribute 0 and its plane hide nothing: sum F = 1/2 (1/4 in a
room corner). With ``limit_directions = u`` (a unit tangent vector pointing from P into the floor
face), the result must be lim_{d -> 0+} F(P + d u). Checked against d = 1e-4, 1e-6, 1e-8 times the
box size:

* F(P + d u) converges to the limit linearly in d: |e(d) - (d / d1) e(d1)| <= 1e-2 |(d / d1) e(d1)|
  + 1e-13 with e(d) = F(P + d u) - F_limit and d1 = 1e-4 (the d^2 term is ~1e-4 relative here);
* the two-point linear extrapolation from d = 1e-6, 1e-8 reproduces F_limit to 1e-12;
* sum F_limit = 1 to 1e-10 and sum F(P + d u) = 1 to 1e-10 (closed scene).
"""

from __future__ import annotations

import numpy as np
import pytest
from scenes_for_tests import (
    CORNELL_SHORT_BLOCK_FOOT,
    Mesh,
    box_face_quads,
    cornell_box,
    split_box,
    unit,
)

LO = np.array([2.0, -1.0, 0.5])
HI = np.array([4.5, 1.0, 3.5])
SIZE = float(np.max(HI - LO))
DELTAS = (1e-4, 1e-6, 1e-8)
UP = np.array([0.0, 0.0, 1.0])


def plain_box(lo=LO, hi=HI):
    m = Mesh()
    for q in box_face_quads(lo, hi, inward=True):
        m.add(q)
    return m


def check_limit(core, mesh, P, N, u, size, exact_sum):
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys)
    P, N, u = (np.asarray(x, dtype=np.float64) for x in (P, N, u))
    assert abs(np.dot(N, u)) < 1e-15 and abs(np.linalg.norm(u) - 1) < 1e-15

    exact = core.form_factors(scene, P[None], N[None])[0]
    assert np.all(np.isfinite(exact)) and exact.min() >= 0
    if exact_sum is not None:
        assert abs(exact.sum() - exact_sum) <= 1e-10, f"exact value at P: sum F = {exact.sum()!r}, want {exact_sum}"

    lim = core.form_factors(scene, P[None], N[None], limit_directions=u[None])[0]
    assert np.all(np.isfinite(lim)) and lim.min() >= 0
    assert abs(lim.sum() - 1.0) <= 1e-10, f"limit: sum F = {lim.sum()!r}"

    deltas = np.array(DELTAS) * size
    pts = P[None] + deltas[:, None] * u[None]
    Fd = core.form_factors(scene, pts, np.repeat(N[None], len(deltas), axis=0))
    for k, d in enumerate(deltas):
        assert abs(Fd[k].sum() - 1.0) <= 1e-10, f"P + {d:g} u: sum F = {Fd[k].sum()!r}"
    e = Fd - lim
    for k in (1, 2):
        pred = e[0] * deltas[k] / deltas[0]
        bad = np.abs(e[k] - pred) > 1e-2 * np.abs(pred) + 1e-13
        assert not bad.any(), (
            f"not linear convergence at d = {deltas[k]:g} for polygons {np.flatnonzero(bad).tolist()}: "
            f"F(P + d u) - F_limit = {e[k][bad].tolist()}, predicted {pred[bad].tolist()}; "
            f"limit {lim[bad].tolist()}"
        )
    extrap = Fd[2] - deltas[2] * (Fd[1] - Fd[2]) / (deltas[1] - deltas[2])
    err = np.abs(extrap - lim)
    assert err.max() <= 1e-12, f"limit vs extrapolation: max diff {err.max():.3e}: {lim.tolist()} vs {extrap.tolist()}"
    return exact, lim


def polys_in_plane(mesh, axis, value):
    verts, polys = mesh.arrays()
    return [i for i, p in enumerate(polys) if np.all(verts[p][:, axis] == value)]


@pytest.mark.parametrize("split", [False, True])
def test_foot_of_wall(core, rng, split):
    mesh = split_box(LO, HI, rng, inward=True) if split else plain_box()
    P = np.array([LO[0], LO[1] + 0.375 * (HI[1] - LO[1]), LO[2]])
    exact, lim = check_limit(core, mesh, P, UP, [1.0, 0.0, 0.0], SIZE, 0.5)
    wall = polys_in_plane(mesh, 0, LO[0])
    floor = polys_in_plane(mesh, 2, LO[2])
    assert np.all(exact[wall] == 0.0), "the wall through P must contribute 0 at P itself"
    assert np.all(exact[floor] == 0.0) and np.all(lim[floor] == 0.0)
    assert lim[wall].sum() > 0.49  # seen from just inside the floor, the wall fills almost half the hemisphere


def test_foot_of_wall_at_floor_vertices(core, rng):
    """P at a vertex shared by several floor pieces on the wall's foot (T-junctions included)."""
    mesh = split_box(LO, HI, rng, inward=True, cells=(3, 5))
    verts, _ = mesh.arrays()
    on_edge = verts[(verts[:, 0] == LO[0]) & (verts[:, 2] == LO[2]) & (verts[:, 1] > LO[1]) & (verts[:, 1] < HI[1])]
    assert len(on_edge)
    for P in on_edge[:3]:
        check_limit(core, mesh, P, UP, [1.0, 0.0, 0.0], SIZE, 0.5)


@pytest.mark.parametrize("split", [False, True])
def test_room_corner(core, rng, split):
    """Corners at the origin: there the limit depends on the direction of approach, and P + d u
    must be exactly on the ray (no rounding of a large coordinate by a tiny d)."""
    size = HI - LO
    for lo, P, N, u in (
        (np.zeros(3), np.zeros(3), UP, unit([1.0, 1.0, 0.0])),  # floor corner, diagonally
        (-size, np.zeros(3), -UP, unit([-1.0, -0.5, 0.0])),  # ceiling corner, looking down, skew
    ):
        mesh = split_box(lo, lo + size, rng, inward=True) if split else plain_box(lo, lo + size)
        check_limit(core, mesh, P, N, u, SIZE, 0.25)


def test_foot_of_cornell_block(core):
    """On the floor at the foot of a block's side, approached from outside the block.

    At P itself half of the hemisphere looks into the block, whose inside is closed by the backs
    of its own faces: with ``double_sided=True`` and unit radiance everywhere, H(P) = 1 exactly.
    (Whether ``form_factors`` reports back faces is not part of the contract, so the exact sum
    of F at P is not checked here.)
    """
    mesh = cornell_box()
    a, b = (np.array([x, 0.0, z]) for x, z in CORNELL_SHORT_BLOCK_FOOT[:2])
    P = a + 0.5 * (b - a)
    y_up = np.array([0.0, 1.0, 0.0])
    out = unit(np.cross(b - a, y_up))
    foot = np.array(CORNELL_SHORT_BLOCK_FOOT)
    centre = np.array([foot[:, 0].mean(), 0.0, foot[:, 1].mean()])
    if np.dot(out, P - centre) < 0:
        out = -out
    check_limit(core, mesh, P, y_up, out, 559.2, None)
    verts, polys = mesh.arrays()
    ones = np.ones((len(polys), 3))
    H = core.irradiance(core.Scene.from_polygons(verts, polys, ones, double_sided=True), P[None], y_up[None])
    np.testing.assert_allclose(H, np.pi, rtol=0, atol=1e-10)  # H = pi sum F L


def test_limit_directions_mixed_batch(core):
    """Zero rows mean the exact value at P; rows with a direction the limit; None == all zeros."""
    mesh = plain_box()
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys)
    P = np.array([[LO[0], 0.0, LO[2]], [LO[0], 0.0, LO[2]], [3.0, 0.0, 2.0], [LO[0], LO[1], LO[2]]])
    N = np.array([UP, UP, unit([0.3, -0.2, 1.0]), UP])
    U = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0], unit([1.0, 1.0, 0.0])])
    F = core.form_factors(scene, P, N, limit_directions=U)
    F0 = core.form_factors(scene, P, N)
    Fz = core.form_factors(scene, P, N, limit_directions=np.zeros((4, 3)))
    np.testing.assert_array_equal(F0, Fz)
    np.testing.assert_allclose(F[[0, 2]], F0[[0, 2]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(F.sum(axis=1), [0.5, 1.0, 1.0, 1.0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(F0.sum(axis=1), [0.5, 0.5, 1.0, 0.25], rtol=0, atol=1e-10)
    H = core.irradiance(core.Scene.from_polygons(verts, polys, np.ones((len(polys), 3))), P, N, limit_directions=U)
    np.testing.assert_allclose(H, np.pi * np.repeat(F.sum(axis=1)[:, None], 3, axis=1), rtol=0, atol=1e-10)


def test_limit_at_interior_point_is_the_value(core, rng):
    """Away from any discontinuity the limit is just the value at P."""
    mesh = split_box(LO, HI, rng, inward=True)
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys)
    m = 50
    P = LO + (HI - LO) * rng.uniform(0.05, 0.95, size=(m, 3))
    N = unit(rng.normal(size=(m, 3)))
    U = unit(np.cross(N, rng.normal(size=(m, 3))))
    F = core.form_factors(scene, P, N, limit_directions=U)
    F0 = core.form_factors(scene, P, N)
    np.testing.assert_allclose(F, F0, rtol=0, atol=1e-12)


def face_boundary_receivers(mesh):
    """Every vertex and edge midpoint of every planar polygon, with the polygon's normal and the
    limit direction pointing from the point towards the polygon's centroid (into the face)."""
    verts, polys = mesh.arrays()
    P, N, U = [], [], []
    for poly in polys:
        c = verts[poly]
        n = np.cross(c[1] - c[0], c[2] - c[0])
        n /= np.linalg.norm(n)
        if np.abs((c - c[0]) @ n).max() > 1e-12 * np.abs(c).max():
            continue  # non-planar (the Cornell box's red wall)
        centroid = c.mean(axis=0)
        for k in range(len(c)):
            for p in (c[k], 0.5 * (c[k] + c[(k + 1) % len(c)])):
                u = centroid - p
                u -= np.dot(u, n) * n
                P.append(p)
                N.append(n)
                U.append(u / np.linalg.norm(u))
    return np.array(P), np.array(N), np.array(U)


@pytest.mark.parametrize("scene", ["split_box", "cornell"])
def test_limit_at_every_vertex_and_edge_of_a_closed_scene(core, rng, scene):
    """What the Blender layer needs for vertex colours: at every corner and edge midpoint of every
    face (T-junctions, room corners, feet of walls and of blocks included), the limit from inside
    the face sums to 1; the exact value at the point never exceeds 1."""
    mesh = split_box(LO, HI, rng, inward=True) if scene == "split_box" else cornell_box()
    verts, polys = mesh.arrays()
    s = core.Scene.from_polygons(verts, polys)
    P, N, U = face_boundary_receivers(mesh)
    F = core.form_factors(s, P, N, limit_directions=U)
    assert np.all(np.isfinite(F)) and F.min() >= 0.0
    err = np.abs(F.sum(axis=1) - 1.0)
    bad = np.flatnonzero(err > 1e-10)
    assert not len(bad), (
        f"{len(bad)} of {len(P)} receivers: limit sum F != 1; e.g. P={P[bad[0]].tolist()} N={N[bad[0]].tolist()} "
        f"u={U[bad[0]].tolist()} sum={F[bad[0]].sum()!r}"
    )
    F0 = core.form_factors(s, P, N)
    assert np.all(np.isfinite(F0)) and F0.min() >= 0.0 and F0.sum(axis=1).max() <= 1.0 + 1e-10


def test_idle_limits_are_dropped_and_agree_with_the_limit_path(core, rng, monkeypatch):
    """``receivers.idle_limits_dropped``: a receiver that no polygon off its own plane touches needs no one-sided
    limit (the limit path costs ~10x per receiver; vertices mode hands every corner in with one). At every
    face corner and edge midpoint of a split box and of the Cornell box, the dropped receivers' values agree
    with the limit path's (forced for all) to 1e-12 of the largest H, the kept ones bit for bit; every
    receiver on another face's plane and inside its box (feet of walls and blocks, room corners) keeps its limit."""
    from hemisphere_local_pass.core import local_pass, receivers

    for mesh in (split_box(LO, HI, rng, inward=True), cornell_box()):
        verts, polys = mesh.arrays()
        s = core.Scene.from_polygons(verts, polys, rng.uniform(0.0, 1.0, (len(polys), 3)))
        P, N, U = face_boundary_receivers(mesh)
        u = receivers.prepare_receivers(P, N, U)[2]
        kept = receivers.idle_limits_dropped(s, P, unit(N), u).any(axis=1)
        H = core.irradiance(s, P, N, limit_directions=U)
        with monkeypatch.context() as mp:
            mp.setattr(local_pass, "idle_limits_dropped", lambda scene, p, n, u: u)
            H_limit = core.irradiance(s, P, N, limit_directions=U)
        assert 0 < kept.sum() < len(P), (kept.sum(), len(P))
        np.testing.assert_array_equal(H[kept], H_limit[kept])
        np.testing.assert_allclose(H[~kept], H_limit[~kept], rtol=0, atol=1e-12 * np.abs(H_limit).max())
        # a receiver on the plane of a polygon not coplanar with it, inside that polygon's box, keeps its limit
        sp, sn = s.poly_vertices, s.poly_normals
        on_plane = np.abs(np.einsum("pc,mc->mp", sn, P) - np.einsum("pc,pc->p", sn, sp[:, 0])[None]) <= 1e-9
        in_box = ((sp.min(axis=1)[None] - 1e-9 <= P[:, None]) & (P[:, None] <= sp.max(axis=1)[None] + 1e-9)).all(axis=2)
        not_coplanar = np.abs(unit(N) @ sn.T) < 1.0 - 1e-9
        assert kept[(on_plane & in_box & not_coplanar).any(axis=1)].all()
