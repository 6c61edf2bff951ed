"""Irradiance gradients (core.gradient): closed forms against independent checks.

* central finite differences of the exact :func:`irradiance`, Richardson-extrapolated, with a step per
  point; points where two such estimates with different steps disagree are next to a visibility event
  (the derivative jumps there) and are left out, and the test requires most points to remain;
* invariance under rigid motions (the gradient rotates with the scene);
* zero where H is constant (inside a closed box of one uniform radiance, with a block inside);
* an unoccluded polygon against the derivative of Lambert's formula (eq. 4) by the chain rule, written
  out here independently of the Reynolds-transport form the module uses.
"""

from __future__ import annotations

import numpy as np
import pytest
from scenes_for_tests import (
    cornell_box,
    cornell_free_points,
    random_box_room,
    random_free_points_in_room,
    random_occluded_scene,
    random_rotation,
    random_unit_vectors,
    receivers,
    split_box,
    unit,
)

REL = 1e-7


def _fd(core, scene, p, n, h, what="P"):
    """Richardson-extrapolated central differences ``(m, 3, 3)`` of irradiance, step ``h (m,)``.

    what="P": ∂H/∂P_k; what="N": ∂H/∂φ_k for a rotation of N about world axis k (compare with
    ``dH_dN · (e_k × N)``)."""
    out = np.zeros((len(p), 3, 3))
    for k in range(3):
        ek = np.eye(3)[k]

        def moved(t, ek=ek):
            if what == "P":
                return core.irradiance(scene, p + t[:, None] * ek, n)
            axis = np.broadcast_to(ek, n.shape)
            c, s = np.cos(t)[:, None], np.sin(t)[:, None]
            rot = n * c + np.cross(axis, n) * s + axis * (n @ ek)[:, None] * (1 - c)
            return core.irradiance(scene, p, rot)

        def central(t, moved=moved):
            return (moved(t) - moved(-t)) / (2 * t[:, None])

        out[:, :, k] = (4 * central(h / 2) - central(h)) / 3
    return out


def _step(scene, p, rel=1e-3):
    """Step per point: ``rel`` times a lower bound of the distance from P to the nearest polygon (the
    length scale on which H varies there), so that the Richardson error ``O(h⁴)`` stays ~1e-12."""
    d = np.linalg.norm(p[:, None] - scene.poly_centers[None], axis=2) - scene.poly_radii[None]
    size = np.ptp(scene.poly_centers, axis=0).max()
    return rel * np.maximum(d.min(axis=1), 1e-2 * size)


def _check_fd(core, scene, p, n, h=None, min_kept=0.7, what="P"):
    if h is None:
        h = _step(scene, p) if what == "P" else np.full(len(p), 1e-3)
    g = core.irradiance_gradient(scene, p, n, normal_gradient=True)
    if what == "P":
        got = g[0]
    else:  # a rotation about e_k moves N by e_k × N
        got = np.einsum("mcj,mkj->mck", g[1], np.cross(np.eye(3)[None], n[:, None, :]))
    f1 = _fd(core, scene, p, n, h, what)
    f2 = _fd(core, scene, p, n, 0.5 * h, what)
    scale = np.abs(f1).max(axis=(1, 2)) + 1e-300
    smooth = np.abs(f1 - f2).max(axis=(1, 2)) <= 1e-8 * scale
    assert smooth.mean() >= min_kept, f"only {smooth.sum()} of {len(p)} points away from visibility events"
    err = np.abs(got - f2).max(axis=(1, 2)) / scale
    bad = np.flatnonzero(smooth & (err > REL))
    assert not len(bad), f"points {p[bad]} normals {n[bad]}: relative error {err[bad]}"
    return err[smooth]


@pytest.mark.parametrize("seed", range(4))
def test_random_occluded_scenes_match_finite_differences(core, seed):
    rng = np.random.default_rng(1000 + seed)
    for _ in range(2):
        mesh, verts, polys = random_occluded_scene(rng)
        scene = core.Scene.from_polygons(verts, polys, rng.uniform(0.2, 2.0, size=(len(polys), 3)))
        p, n = receivers(rng)
        _check_fd(core, scene, p, n, min_kept=0.6)


@pytest.mark.parametrize("seed", range(2))
def test_linear_radiance_matches_finite_differences(core, seed):
    """Per-corner radiance: the interior term (the hit point moves with P) and the edge terms with
    radiance varying along the arcs."""
    rng = np.random.default_rng(2000 + seed)
    for what in ("P", "N"):
        mesh, verts, polys = random_occluded_scene(rng)
        corners = rng.uniform(0.2, 2.0, size=(sum(len(q) for q in polys), 3))
        scene = core.Scene.from_polygons(verts, polys, corner_radiance=corners)
        p, n = receivers(rng)
        _check_fd(core, scene, p, n, min_kept=0.6, what=what)


def test_cornell_box_matches_finite_differences(core, rng):
    """Merged walls, convex solids (the blocks' silhouettes), the light's shadow edges."""
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys, mesh.radiance_array())
    p = cornell_free_points(rng, 24)
    n = random_unit_vectors(rng, 24)
    _check_fd(core, scene, p, n)
    _check_fd(core, scene, p[:8], n[:8], what="N")     # the clear tiles' share of the normal gradient too


def test_box_room_matches_finite_differences(core, rng):
    """Interpenetrating rotated boxes in a room: solids, depth edges, shadow edges cut at corners."""
    mesh, boxes = random_box_room(rng, n_boxes=12)
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys, mesh.radiance_array())
    p = random_free_points_in_room(rng, boxes, 16)
    n = random_unit_vectors(rng, 16)
    _check_fd(core, scene, p, n)


def test_normal_gradient_matches_finite_differences(core):
    rng = np.random.default_rng(7)
    mesh, verts, polys = random_occluded_scene(rng)
    scene = core.Scene.from_polygons(verts, polys, rng.uniform(0.2, 2.0, size=(len(polys), 3)))
    p, n = receivers(rng)
    _check_fd(core, scene, p, n, what="N")
    gn = core.irradiance_normal_gradient(scene, p, n)
    assert np.abs(np.einsum("mck,mk->mc", gn, n)).max() <= 1e-15 * np.abs(gn).max()   # tangential


def test_rigid_motion_rotates_the_gradient(core, rng):
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    rad = mesh.radiance_array()
    p = cornell_free_points(rng, 20)
    n = random_unit_vectors(rng, 20)
    rot = random_rotation(rng)
    shift = np.array([123.0, -45.0, 6.5])
    a = core.Scene.from_polygons(verts, polys, rad)
    b = core.Scene.from_polygons(verts @ rot.T + shift, polys, rad)
    ga, na = core.irradiance_gradient(a, p, n, normal_gradient=True)
    gb, nb = core.irradiance_gradient(b, p @ rot.T + shift, n @ rot.T, normal_gradient=True)
    scale = np.abs(ga).max(axis=(1, 2))[:, None, None]
    np.testing.assert_allclose(gb / scale, ga @ rot.T / scale, rtol=0, atol=1e-12)
    scale = np.abs(na).max(axis=(1, 2))[:, None, None]
    np.testing.assert_allclose(nb / scale, na @ rot.T / scale, rtol=0, atol=1e-12)


def test_zero_gradient_where_irradiance_is_constant(core, rng):
    """A closed room (walls split into grids with T-junctions) and a block, all of one radiance: every
    point inside sees H = π L whatever its position or normal, so both gradients vanish."""
    room = split_box([0.0, 0.0, 0.0], [4.0, 4.0, 4.0], rng, inward=True)
    block = split_box([1.0, 0.5, 1.5], [2.0, 2.5, 2.25], rng, inward=False)
    room.extend(block)
    verts, polys = room.arrays()
    L = np.array([0.7, 1.3, 2.0])
    scene = core.Scene.from_polygons(verts, polys, np.tile(L, (len(polys), 1)))
    p = rng.uniform(0.1, 3.9, size=(60, 3))
    p = p[~np.all((p > [0.99, 0.49, 1.49]) & (p < [2.01, 2.51, 2.26]), axis=1)]
    n = random_unit_vectors(rng, len(p))
    h = core.irradiance(scene, p, n)
    np.testing.assert_allclose(h, np.pi * np.broadcast_to(L, h.shape), rtol=1e-12)
    gp, gn = core.irradiance_gradient(scene, p, n, normal_gradient=True)
    # the scale of the terms that cancel: π L / (distance to the nearest wall)
    dist = np.minimum(p, 4.0 - p).min(axis=1)
    assert (np.abs(gp).max(axis=(1, 2)) / (np.pi * L.max() / dist)).max() <= 1e-13
    assert np.abs(gn).max() <= 1e-13 * np.pi * L.max()


def _lambert_gradient(p, n, coords):
    """∂F/∂P (3,) of an unoccluded polygon wholly above the horizon: the chain rule through eq. 4,
    F = 1/(2π) Σ N·c γ/s with c = a×b, s = |c|, γ = atan2(s, a·b), a = A − P, b = B − P (da = db = −dP)."""
    a = coords - p
    b = np.roll(a, -1, axis=0)
    total = np.zeros(3)
    value = 0.0
    for ai, bi in zip(a, b):
        c = np.cross(ai, bi)
        s = np.linalg.norm(c)
        d = ai @ bi
        gamma = np.arctan2(s, d)
        # derivatives w.r.t. P (rows: the 3 components of dP)
        dc = np.stack([np.cross(e, ai - bi) for e in np.eye(3)])         # dc/dP_k = e_k × (a − b)
        ds = dc @ (c / s)
        dd = -(ai + bi)
        dgamma = (d * ds - s * dd) / (s * s + d * d)
        nc = n @ c
        value += nc * gamma / s
        total += (dc @ n) * gamma / s + nc * (dgamma / s - gamma * ds / (s * s))
    return np.sign(value) * total / (2 * np.pi)      # the sign of the vertex order about P


def test_unoccluded_polygon_matches_lambert_derivative(core, rng):
    for _ in range(10):
        k = int(rng.integers(3, 7))
        ang = np.sort(rng.uniform(0, 2 * np.pi, k))
        ang += np.linspace(0, 0, k)
        local = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(k)]) * rng.uniform(0.3, 1.5)
        coords = local @ random_rotation(rng).T + rng.uniform(-0.5, 0.5, 3) + [0, 0, 3.0]
        n = unit(np.array([0.0, 0.0, 1.0]) + 0.2 * rng.standard_normal(3))
        p = rng.uniform(-0.3, 0.3, 3)
        if ((coords - p) @ n).min() <= 0.05:
            continue
        nrm = np.cross(coords[1] - coords[0], coords[2] - coords[0])
        if nrm @ (p - coords[0]) < 0:
            coords = coords[::-1]          # show the front to P
        L = np.array([1.0, 2.0, 0.5])
        scene = core.Scene.from_polygons(coords, [list(range(k))], [L])
        g = core.irradiance_gradient(scene, p[None], n[None])[0]
        want = np.pi * L[:, None] * _lambert_gradient(p, n, coords)[None, :]
        np.testing.assert_allclose(g, want, rtol=0, atol=1e-12 * np.abs(want).max())


def test_linear_with_equal_corners_is_the_constant_gradient(core, rng):
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    rad = mesh.radiance_array()
    constant = core.Scene.from_polygons(verts, polys, rad)
    linear = core.Scene.from_polygons(verts, polys, corner_radiance=np.repeat(rad, [len(q) for q in polys], axis=0))
    p = cornell_free_points(rng, 12)
    n = random_unit_vectors(rng, 12)
    gc, nc = core.irradiance_gradient(constant, p, n, normal_gradient=True)
    gl, nl = core.irradiance_gradient(linear, p, n, normal_gradient=True)
    scale = np.abs(gc).max(axis=(1, 2))[:, None, None]
    np.testing.assert_allclose(gl / scale, gc / scale, rtol=0, atol=1e-11)
    scale = np.abs(nc).max(axis=(1, 2))[:, None, None]
    np.testing.assert_allclose(nl / scale, nc / scale, rtol=0, atol=1e-11)


def test_shapes_empty_and_bad_input(core):
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys, mesh.radiance_array())
    g = core.irradiance_gradient(scene, np.zeros((0, 3)), np.zeros((0, 3)))
    assert g.shape == (0, 3, 3)
    g, gn = core.irradiance_gradient(scene, [[200.0, 300.0, 250.0]], [[0.0, 1.0, 0.0]], normal_gradient=True)
    assert g.shape == gn.shape == (1, 3, 3)
    with pytest.raises(ValueError, match="points must have shape"):
        core.irradiance_gradient(scene, np.zeros((2, 2)), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="zero normal"):
        core.irradiance_gradient(scene, [[200.0, 300.0, 250.0]], [[0.0, 0.0, 0.0]])


def test_double_sided_matches_finite_differences(core):
    """Both sides emit: fragments seen from behind run the other way round (σ = +1)."""
    rng = np.random.default_rng(11)
    mesh, verts, polys = random_occluded_scene(rng)
    polys = [q[::-1] if i % 2 else q for i, q in enumerate(polys)]   # half of them show their back
    scene = core.Scene.from_polygons(verts, polys, rng.uniform(0.2, 2.0, size=(len(polys), 3)), double_sided=True)
    p, n = receivers(rng)
    _check_fd(core, scene, p, n, min_kept=0.6)


def test_batches_agree_with_single_points(core, rng):
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys, mesh.radiance_array())
    p = cornell_free_points(rng, 300)                  # more than one chunk
    n = random_unit_vectors(rng, 300)
    calls = []
    g, gn = core.irradiance_gradient(scene, p, n, normal_gradient=True, progress=lambda d, t: calls.append((d, t)))
    assert calls[-1] == (300, 300) and len(calls) >= 2
    for i in (0, 150, 299):
        gi, gni = core.irradiance_gradient(scene, p[i:i + 1], n[i:i + 1], normal_gradient=True)
        np.testing.assert_allclose(gi[0], g[i], rtol=0, atol=1e-14 * np.abs(g[i]).max())
        np.testing.assert_allclose(gni[0], gn[i], rtol=0, atol=1e-14 * np.abs(gn[i]).max())
    with pytest.raises(core.Cancelled):
        core.irradiance_gradient(scene, p, n, cancel=lambda: True)


def test_surface_points_and_one_sided_limits(core, rng):
    """Receivers on the walls (as an image's pixels are): the tangential gradient matches differences
    along the surface, the limit from inside the face is accepted, and nothing is NaN."""
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys, mesh.radiance_array())
    m = 12
    p = cornell_free_points(rng, m)
    p[:, 1] = 0.0                                   # on the floor (the blocks have no bottom: not under them)
    p = p[np.abs(core.irradiance(scene, p, np.tile([0.0, 1.0, 0.0], (m, 1)))).max(axis=1) > 0]
    m = len(p)
    n = np.tile([0.0, 1.0, 0.0], (m, 1))
    u = np.tile([1.0, 0.0, 0.0], (m, 1))
    g = core.irradiance_gradient(scene, p, n)
    gl = core.irradiance_gradient(scene, p, n, limit_directions=u)
    assert np.isfinite(g).all() and np.isfinite(gl).all()
    np.testing.assert_allclose(gl, g, rtol=0, atol=1e-12 * np.abs(g).max())     # interior points: the same
    h = 1e-3
    for k in (0, 2):                                                             # along the floor
        ek = np.eye(3)[k]

        def central(t, ek=ek):
            return (core.irradiance(scene, p + t * ek, n) - core.irradiance(scene, p - t * ek, n)) / (2 * t)

        fd = (4 * central(h / 2) - central(h)) / 3
        fd2 = (4 * central(h / 4) - central(h / 2)) / 3
        smooth = np.abs(fd - fd2).max(axis=1) <= 1e-8 * np.abs(fd).max(axis=1)
        assert smooth.mean() >= 0.7
        err = np.abs(g[:, :, k] - fd2).max(axis=1) / np.abs(g).max(axis=(1, 2))
        assert (err[smooth] <= REL).all(), err


def test_no_emitters_gives_zero(core):
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys)
    g, gn = core.irradiance_gradient(scene, [[200.0, 300.0, 250.0]], [[0.0, 1.0, 0.0]], normal_gradient=True)
    assert not g.any() and not gn.any()


def test_wall_foot_one_sided_and_corner(core):
    """At the foot of a wall (in the one-sided limit from the floor) the gradient is the one-sided one:
    differences along the foot line and forward differences into the room agree. In a room corner an edge
    of a visible fragment passes through P: there is no gradient, and NaN says so."""
    mesh = cornell_box()
    verts, polys = mesh.arrays()
    scene = core.Scene.from_polygons(verts, polys, mesh.radiance_array())
    p = np.array([[0.0, 0.0, 300.0]])                       # the green wall (x = 0) meets the floor
    n = np.array([[0.0, 1.0, 0.0]])
    u = np.array([[1.0, 0.0, 0.0]])
    g = core.irradiance_gradient(scene, p, n, limit_directions=u)[0]
    h0 = core.irradiance(scene, p, n, limit_directions=u)

    def along(t):
        ez = np.array([0.0, 0.0, t])
        return (core.irradiance(scene, p + ez, n, limit_directions=u)
                - core.irradiance(scene, p - ez, n, limit_directions=u)) / (2 * t)

    def into(t):
        return (core.irradiance(scene, p + [t, 0.0, 0.0], n) - h0) / t

    scale = np.abs(g).max()
    np.testing.assert_allclose(((4 * along(0.5) - along(1.0)) / 3)[0], g[:, 2], rtol=0, atol=REL * scale)
    forward = (8 * into(0.25) - 6 * into(0.5) + into(1.0)) / 3                  # O(t³) one-sided
    np.testing.assert_allclose(forward[0], g[:, 0], rtol=0, atol=1e-6 * scale)
    corner = core.irradiance_gradient(scene, [[0.0, 0.0, 0.0]], n, limit_directions=[[1.0, 0.0, 1.0]])
    assert np.isnan(corner).all()


def test_uniform_scaling_scales_the_position_gradient(core, rng):
    """H is scale-free (a scene scaled by s about any point, receivers with it): ∂H/∂P scales by 1/s,
    ∂H/∂N not at all; also far from the origin."""
    mesh, verts, polys = random_occluded_scene(rng)
    rad = rng.uniform(0.2, 2.0, size=(len(polys), 3))
    p, n = receivers(rng)
    ga, na = core.irradiance_gradient(core.Scene.from_polygons(verts, polys, rad), p, n, normal_gradient=True)
    for s, shift in ((1e3, np.zeros(3)), (0.01, np.array([2e4, -1e4, 5e3]))):
        b = core.Scene.from_polygons(verts * s + shift, polys, rad)
        gb, nb = core.irradiance_gradient(b, p * s + shift, n, normal_gradient=True)
        # far out, rounding the scaled inputs (ulp of 2e4 against a 0.03 scene) changes H by ~2e-9 already
        tol = 1e-13 if not shift.any() else 1e-8
        scale = np.abs(ga).max(axis=(1, 2))[:, None, None]
        np.testing.assert_allclose(gb * s / scale, ga / scale, rtol=0, atol=tol)
        scale = np.abs(na).max(axis=(1, 2))[:, None, None]
        np.testing.assert_allclose(nb / scale, na / scale, rtol=0, atol=tol)
