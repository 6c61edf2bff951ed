"""The error-bounded far field (core/far_field.py): irradiance with a tolerance.

Every case compares ``irradiance(..., tolerance=t, return_stats=True)`` with the exact call on the same
receivers: the measured error ``|H_t − H_exact|`` must not exceed the returned bound, per receiver and
channel, and the bound must not exceed the tolerance (plus its stated rounding allowance,
:data:`~hemisphere_local_pass.core.far_field.ROUNDING` of the sums). The scenes are built to break
the bound: a chequerboard of contrasting radiance (nothing may be skipped), a low-contrast
chequerboard and a radiance ramp (edges are skipped, the error is real), a bright small patch among
dim polygons, receivers close to a subdivided wall, grazing normals, one-sided limits, double-sided
emitters and a subdivided plane hidden behind a wall. ``tolerance = 0`` is the exact path, bit for bit.
The linear proxies of whole nodes (varying radiance) are checked node by node against the exact sums
over their members (a curved falloff, a steep ramp, a hard shadow edge, a tiny chequerboard), and end to
end on a box whose radiance differs on every polygon.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hemisphere_local_pass.core import Scene, irradiance, radiance
from hemisphere_local_pass.core.far_field import ROUNDING, FarFieldStats
from hemisphere_local_pass.scenes import cornell_box

BOX = cornell_box(12)


def _receivers(rng, m, offset=1e-6):
    """Receivers on random polygons of the box, just off their front side, facing along the normal."""
    pick = rng.choice(BOX.n_polygons, size=m)
    u, v = rng.uniform(0.05, 0.95, size=(2, m))
    quads = BOX.vertices[np.array([BOX.polygons[i] for i in pick])]
    pts = (1 - u)[:, None] * ((1 - v)[:, None] * quads[:, 0] + v[:, None] * quads[:, 1]) \
        + u[:, None] * ((1 - v)[:, None] * quads[:, 3] + v[:, None] * quads[:, 2])
    nrm = BOX.normals()[pick]
    return pts + offset * nrm, nrm


def _chequer(contrast, base=1.0):
    """Radiance alternating ``base ± contrast`` polygon by polygon (neighbours differ), light kept bright."""
    parity = (np.arange(BOX.n_polygons) % 2) * 2 - 1
    rad = base + contrast * parity[:, None] * np.array([1.0, 0.5, 0.25])
    return rad + BOX.emission


def _spiked(rad):
    """``rad`` with one polygon of every part 0.5 brighter: no face is nearly uniform (no proxies)."""
    rad = rad.copy()
    for nm in set(BOX.names):
        rad[BOX.names.index(nm)] += 0.5
    return rad


def _check(scene, pts, nrm, rel_tol=1e-4, limit=None, expect_skips=None, expect_error=None):
    exact = irradiance(scene, pts, nrm, limit_directions=limit, workers=1)
    tol = rel_tol * exact.mean(axis=0)
    h, st = irradiance(scene, pts, nrm, limit_directions=limit, workers=1, tolerance=tol, return_stats=True)
    assert isinstance(st, FarFieldStats)
    err = np.abs(h - exact)
    assert (err <= st.error_bound).all(), (err - st.error_bound).max()
    # the skipped part stays within the tolerance; the rest is the stated rounding allowance
    assert (st.error_bound <= tol * (1 + 1e-12) + 1e-9 * (1.0 + np.abs(exact))).all()
    if expect_skips is True:
        assert st.edges_skipped.sum() > 0
    elif expect_skips is False:
        assert st.edges_skipped.sum() == 0
    if expect_error:
        assert err.max() > 1e3 * np.finfo(float).eps * np.abs(exact).max()  # a real error, not rounding
    return h, exact, st


def test_tolerance_zero_is_the_exact_path_bit_for_bit():
    rng = np.random.default_rng(1)
    scene = BOX.scene(radiance=rng.uniform(0.0, 2.0, size=(BOX.n_polygons, 3)))
    pts, nrm = _receivers(rng, 200)
    ref = irradiance(scene, pts, nrm, workers=1)
    for tol in (0.0, [0.0, 0.0, 0.0], np.zeros(3)):
        h = irradiance(scene, pts, nrm, workers=1, tolerance=tol)
        assert h.tobytes() == ref.tobytes()
    h, st = irradiance(scene, pts, nrm, workers=1, tolerance=0.0, return_stats=True)
    assert h.tobytes() == ref.tobytes()
    assert (st.error_bound == 0).all() and st.max_error_bound == 0.0


def test_constant_walls_are_summed_as_nodes_exactly_to_rounding():
    """The bench scene's kind: constant radiance per wall. Clear nodes above the tiles are summed whole
    (their interior edges weigh exactly zero), nothing needs skipping, and H agrees to rounding."""
    rad = BOX.emission + 0.1 * BOX.reflectivity * (BOX.emission.sum(axis=1) == 0)[:, None]
    scene = BOX.scene(radiance=rad)
    pts, nrm = _receivers(np.random.default_rng(2), 256)
    h, exact, st = _check(scene, pts, nrm, expect_skips=False)
    assert st.clear_nodes.sum() > 0
    np.testing.assert_allclose(h, exact, rtol=1e-12, atol=1e-15)


def test_contrasting_chequerboard_skips_nothing():
    scene = BOX.scene(radiance=_chequer(0.9))
    pts, nrm = _receivers(np.random.default_rng(3), 128)
    _check(scene, pts, nrm, expect_skips=False)


@pytest.mark.parametrize("contrast", [1e-6, 1e-8])
def test_low_contrast_chequerboard_skips_edges_within_the_bound(contrast):
    """A spike on every face keeps the faces apart (no proxies): the weak edges are left out."""
    scene = BOX.scene(radiance=_spiked(_chequer(contrast)))
    pts, nrm = _receivers(np.random.default_rng(4), 128)
    _check(scene, pts, nrm, rel_tol=1e-5 if contrast == 1e-6 else 1e-7, expect_skips=True, expect_error=True)


@pytest.mark.parametrize("contrast", [1e-6, 1e-8])
def test_low_contrast_chequerboard_faces_become_proxies_within_the_bound(contrast):
    """Without spikes every face is nearly uniform: one polygon of mid-range radiance each."""
    scene = BOX.scene(radiance=_chequer(contrast))
    pts, nrm = _receivers(np.random.default_rng(4), 128)
    _, exact, st = _check(scene, pts, nrm, rel_tol=1e-5 if contrast == 1e-6 else 1e-7, expect_error=True)
    assert (st.error_bound[exact > 0] > 0).all()       # (receivers on the floor inside a block see nothing)


def test_radiance_ramp_within_the_bound():
    c = np.array([np.mean([BOX.vertices[i] for i in p], axis=0) for p in BOX.polygons])
    rad = 1.0 + 1e-6 * (c @ np.array([1.0, 2.0, 3.0]))[:, None] * np.array([1.0, -1.0, 0.5])
    pts, nrm = _receivers(np.random.default_rng(5), 128)
    _check(BOX.scene(radiance=rad), pts, nrm, rel_tol=1e-6, expect_error=True)
    _check(BOX.scene(radiance=_spiked(rad)), pts, nrm, rel_tol=1e-6, expect_skips=True, expect_error=True)


def test_bright_small_patch_among_dim_polygons():
    rng = np.random.default_rng(6)
    rad = np.full((BOX.n_polygons, 3), 1e-3) * (1 + 1e-7 * rng.uniform(size=(BOX.n_polygons, 1)))
    walls = [i for i, nm in enumerate(BOX.names) if nm == "back wall"]
    rad[walls[len(walls) // 2]] = 1e4
    scene = BOX.scene(radiance=rad)
    pts, nrm = _receivers(rng, 128)
    h, exact, st = _check(scene, pts, nrm)
    # the patch dominates H: its edges are never skipped, so the error stays far below the patch's share
    assert (np.abs(h - exact) <= 1e-4 * exact.mean(axis=0)).all()


def test_receivers_close_to_a_subdivided_wall_and_grazing():
    rng = np.random.default_rng(7)
    scene = BOX.scene(radiance=_spiked(_chequer(1e-6)))
    m = 96
    # close to the back wall (y = 1), facing it, and on the floor with nearly horizontal normals
    close = np.column_stack([rng.uniform(0.05, 0.95, m), 1.0 - 10.0 ** rng.uniform(-6, -2, m),
                             rng.uniform(0.05, 0.95, m)])
    n_close = np.tile([0.0, 1.0, 0.0], (m, 1))
    floor = np.column_stack([rng.uniform(0.05, 0.95, m), rng.uniform(0.05, 0.6, m), np.full(m, 1e-7)])
    tilt = 10.0 ** rng.uniform(-9, -2, m)
    ang = rng.uniform(0, 2 * np.pi, m)
    n_graze = np.column_stack([np.cos(ang), np.sin(ang), tilt])
    n_graze /= np.linalg.norm(n_graze, axis=1, keepdims=True)
    _check(scene, np.vstack([close, floor]), np.vstack([n_close, n_graze]), rel_tol=1e-5)


def test_one_sided_limits_double_sided_and_hidden_geometry():
    rng = np.random.default_rng(8)
    rad = _chequer(1e-7)
    # a subdivided plane behind the back wall (hidden from every receiver), radiance 1
    s = np.linspace(0.0, 1.0, 21)
    u, v = np.meshgrid(s, s, indexing="ij")
    pv = np.column_stack([u.ravel(), np.full(u.size, 1.05), v.ravel()])
    i, j = np.meshgrid(np.arange(20), np.arange(20), indexing="ij")
    a = (i * 21 + j).ravel()
    quads = np.stack([a, a + 1, a + 22, a + 21], axis=1) + len(BOX.vertices)
    verts = np.vstack([BOX.vertices, pv])
    polys = list(BOX.polygons) + [list(q) for q in quads]
    rad = np.vstack([rad, np.ones((len(quads), 3))])
    pts, nrm = _receivers(rng, 128, offset=0.0)
    limit = np.zeros_like(pts)
    limit[::3] = np.cross(nrm[::3], rng.normal(size=(len(nrm[::3]), 3)))
    limit[::3] /= np.linalg.norm(limit[::3], axis=1, keepdims=True)
    for double in (False, True):
        scene = Scene.from_polygons(verts, polys, rad, double_sided=double)
        _check(scene, pts, nrm, rel_tol=1e-6, limit=limit)


def test_radiance_returns_the_bound_on_l_and_bad_tolerances_are_refused():
    rng = np.random.default_rng(9)
    scene = BOX.scene(radiance=_chequer(1e-6))
    pts, nrm = _receivers(rng, 64)
    tol = 1e-5
    h, sth = irradiance(scene, pts, nrm, workers=1, tolerance=tol, return_stats=True)
    ell, stl = radiance(scene, pts, nrm, 0.5, 0.1, workers=1, tolerance=tol, return_stats=True)
    np.testing.assert_array_equal(ell, 0.1 + 0.5 / np.pi * h)
    np.testing.assert_array_equal(stl.error_bound, 0.5 / np.pi * sth.error_bound)
    exact = radiance(scene, pts, nrm, 0.5, 0.1, workers=1)
    assert (np.abs(ell - exact) <= stl.error_bound).all()
    for bad in (-1e-3, np.nan, [1e-3, 1e-3], [[1e-3] * 3]):
        with pytest.raises(ValueError, match="tolerance"):
            irradiance(scene, pts, nrm, workers=1, tolerance=bad)


def test_the_rounding_allowance_is_small():
    assert ROUNDING < 1e-9


def test_bit_identical_on_workers():
    """With a tolerance the chunks are still the job's: 1 and 2 workers give the same bits and bounds."""
    rng = np.random.default_rng(10)
    scene = BOX.scene(radiance=_spiked(_chequer(1e-6)))
    pts, nrm = _receivers(rng, 160)
    tol = 1e-5
    h1, s1 = irradiance(scene, pts, nrm, workers=1, budget=2**15, tolerance=tol, return_stats=True)
    h2, s2 = irradiance(scene, pts, nrm, workers=2, budget=2**15, tolerance=tol, return_stats=True)
    assert h1.tobytes() == h2.tobytes()
    assert s1.error_bound.tobytes() == s2.error_bound.tobytes()
    assert s1.edges_skipped.sum() > 0


# --- linear proxies of whole nodes (smoothly varying radiance) ---------------------------------------


def _grid_scene(nx, field, size=1.0):
    """An ``nx × nx`` grid of quads on z = 0 (facing +z) of side ``size``; radiance ``field(x, y) (n, 3)`` at
    the quads' centres."""
    s = np.linspace(0.0, size, nx + 1)
    u, v = np.meshgrid(s, s, indexing="ij")
    verts = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    i, j = np.meshgrid(np.arange(nx), np.arange(nx), indexing="ij")
    a = (i * (nx + 1) + j).ravel()
    quads = np.stack([a, a + nx + 1, a + nx + 2, a + 1], axis=1)
    c = verts[quads].mean(axis=1)
    return Scene.from_polygons(verts, quads.tolist(), field(c[:, 0], c[:, 1]))


_FIELDS = {
    # a smooth radiosity-like falloff, curved: the fit's residual ε is the curvature
    "falloff": lambda x, y: np.column_stack([1.0 / (0.3 + (x - 0.3) ** 2 + (y - 0.6) ** 2)] * 3) * [1.0, 0.6, 0.3],
    # a steep linear ramp sampled per quad: the staircase (sawtooth) against the fit is all there is
    "ramp": lambda x, y: np.column_stack([0.2 + 5.0 * x + 3.0 * y] * 3) * [1.0, 0.5, 2.0],
    # a hard shadow edge across smooth light
    "shadow": lambda x, y: np.column_stack([np.where(x + 0.3 * y < 0.55, 0.1, 1.0 + x * y)] * 3),
    # bright single quads at corners of nodes (the plane's corner, the middle) on smooth light: the residual
    # term weighs each member's |ε| by its own moment about the node's centroid, largest at a corner
    "spots": lambda x, y: np.column_stack([1.0 + 0.3 * x + 40.0 * ((np.abs(x - 0.5 + 1 / 128) < 1e-9)
                                                                  & (np.abs(y - 0.5 + 1 / 128) < 1e-9))
                                           + 40.0 * ((x > 1 - 1 / 64) & (y > 1 - 1 / 64))] * 3),
    # a smooth field with a tiny chequerboard on it
    "chequer": lambda x, y: np.column_stack(
        [1.0 + 0.5 * x * x + 1e-3 * ((np.floor(x * 64) + np.floor(y * 64)) % 2)] * 3),
}


def _member_sums(scene, occ, h, ff, ep, en):
    """(E, 3) the exact ``π Σ_i L_i F_i`` over the members of node ``en`` seen from receiver ``ep``, from
    the exact form factors ``ff (m, n)``."""
    exact = np.zeros((len(ep), 3))
    for k, (p, v) in enumerate(zip(ep, en)):
        tiles = h.perm[h.first_tile[v]:h.last_tile[v]]
        mem = np.concatenate([occ.tile_members[occ.tile_ptr[t]:occ.tile_ptr[t + 1]] for t in tiles])
        exact[k] = np.pi * (ff[p, mem][:, None] * scene.poly_radiance[mem]).sum(axis=0)
    return exact


@pytest.mark.parametrize("field", sorted(_FIELDS))
def test_linear_proxy_bound_holds_node_by_node(field):
    """Every (receiver, node) pair's proxy against the exact sum over the node's members (form factors of
    the unoccluded plane): ``|proxy − exact| <= bound`` of :func:`far_field.linear_node_test`, for
    receivers from 0.01 to 3 above the plane, tilted, and nodes from one tile to the whole plane — also
    where the bound is far above the tolerance (the bound must hold, not only fit)."""
    from hemisphere_local_pass.core import form_factors
    from hemisphere_local_pass.core.chunk import prepare_scene, scene_hierarchy, scene_node_edges
    from hemisphere_local_pass.core.far_field import linear_node_irradiance, linear_node_test

    scene = _grid_scene(64, _FIELDS[field])
    occ = prepare_scene(scene)
    h, ne = scene_hierarchy(scene, occ), scene_node_edges(scene, occ)
    fit = ne.fit
    assert fit.ok[h.n_tiles:].sum() >= 4 and fit.ok[:h.n_tiles].all()
    rng = np.random.default_rng(7)
    m = 24
    pts = np.column_stack([rng.uniform(-0.5, 1.5, m), rng.uniform(-0.5, 1.5, m), 10.0 ** rng.uniform(-2, 0.5, m)])
    nrm = np.column_stack([rng.normal(0, 0.4, (m, 2)), -np.ones(m)])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    ff = form_factors(scene, pts, nrm, workers=1)                          # (m, n), exact, nothing occludes
    nodes = np.flatnonzero(fit.ok)
    ep, en = np.repeat(np.arange(m), len(nodes)), np.tile(nodes, m)
    _, bound = linear_node_test(fit, h, pts, nrm, ep, en, np.full(3, 1.0))
    use = np.isfinite(bound).all(axis=1)
    ep, en, bound = ep[use], en[use], bound[use]
    # wholly above every receiver's horizon (the clear test's condition): the box's corners
    hmin = np.einsum("pki,pi->pk", h.corners[en] - pts[ep][:, None, :], nrm[ep]).min(axis=1)
    keep = hmin > 0
    ep, en, bound = ep[keep], en[keep], bound[keep]
    assert len(ep) > 500
    proxy, rnd = linear_node_irradiance(fit, ep, en, pts, nrm)
    exact = _member_sums(scene, occ, h, ff, ep, en)
    err = np.abs(proxy - exact)
    allow = bound + rnd + 1e-13 * np.abs(exact)                            # exact's own rounding
    assert (err <= allow).all(), (err / allow).max()
    # not vacuous: many pairs have a bound far below their value, and the error is real there
    tight = bound.max(axis=1) < 1e-3 * np.abs(exact).max(axis=1)
    assert tight.sum() > 50
    assert err[tight].max() > 1e-14 * np.abs(exact).max()


@pytest.mark.parametrize("field", ["falloff", "ramp"])
def test_linear_prefilter_rejects_only_what_the_test_rejects(field):
    """:func:`far_field.linear_may_fit` (the cheap necessary condition that spares the full test) is False
    only where :func:`far_field.linear_node_test` fails, at tolerances from 1e-6 to 10 (one channel 0), for
    receivers near and far, tilted; and it rejects most pairs at the small tolerances (not vacuous)."""
    from hemisphere_local_pass.core.chunk import prepare_scene, scene_hierarchy, scene_node_edges
    from hemisphere_local_pass.core.far_field import linear_may_fit, linear_node_test

    scene = _grid_scene(32, _FIELDS[field])
    occ = prepare_scene(scene)
    h, fit = scene_hierarchy(scene, occ), scene_node_edges(scene, occ).fit
    rng = np.random.default_rng(11)
    m = 40
    pts = np.column_stack([rng.uniform(-0.5, 1.5, m), rng.uniform(-0.5, 1.5, m), 10.0 ** rng.uniform(-2, 1, m)])
    nrm = np.column_stack([rng.normal(0, 0.4, (m, 2)), -np.ones(m)])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nodes = np.flatnonzero(fit.ok)
    ep, en = np.repeat(np.arange(m), len(nodes)), np.tile(nodes, m)
    passed = 0
    for tol in ([1e-6] * 3, [1e-3] * 3, [1e-1, 1e-2, 1e-1], [10.0] * 3, [1.0, 0.0, 1.0]):
        tol = np.array(tol)
        fits = linear_node_test(fit, h, pts, nrm, ep, en, tol)[0]
        may = linear_may_fit(fit, h, pts, ep, en, tol)
        assert not (fits & ~may).any()
        passed += fits.sum()
        if tol.max() <= 1e-3:
            assert may.mean() < 0.5
    assert passed > 100


def _wall_receivers(box, seed, n, inside=0, depth=0.0):
    """Receivers at the centroids of ``n`` random polygons of ``box``, 1e-6 off them along their normals,
    and the first ``inside`` of them again ``depth`` further in: (points (n + inside, 3), normals)."""
    pick = np.random.default_rng(seed).choice(box.n_polygons, size=n)
    c = np.array([box.vertices[box.polygons[i]].mean(axis=0) for i in pick])
    nrm = box.normals()[pick]
    pts = np.concatenate([c + 1e-6 * nrm, c[:inside] + depth * nrm[:inside]])
    return pts, np.concatenate([nrm, nrm[:inside]])


def smooth_box(sub):
    """``cornell_box(sub)`` with a smooth radiance, different on every polygon (benchmarks' kind); also the
    adaptive pass's far-field samples' scene (test_adaptive.py)."""
    box = cornell_box(sub)
    c = np.array([box.vertices[p].mean(axis=0) for p in box.polygons])
    d2 = ((c - [0.5, 0.5, 1.0]) ** 2).sum(axis=1)
    rad = box.emission + box.reflectivity * (0.2 + 0.3 * c[:, 2:3] + 0.4 / (0.4 + d2[:, None]))
    shadow = (c[:, 2] < 1e-9) & (np.abs(c[:, 0] - 0.35) < 0.12) & (np.abs(c[:, 1] - 0.3) < 0.15)
    rad[shadow] *= 0.3                                                      # a shadow on the floor
    return box, box.scene(radiance=rad)


@pytest.mark.parametrize("rel_tol", [1e-4, 1e-2])
def test_smooth_radiance_box_takes_linear_proxies_within_the_bound(rel_tol):
    """A closed box with smoothly varying radiance (no face nearly uniform, few equal neighbours): the
    clear nodes go as linear proxies; error <= bound <= tolerance; receivers on the walls (1e-6 off them,
    next to the nodes they see) and 0.2 inside."""
    box, scene = smooth_box(40)
    pts, nrm = _wall_receivers(box, 3, 60, inside=20, depth=0.2)
    h, exact, st = _check(scene, pts, nrm, rel_tol=rel_tol)
    assert st.linear_proxies.sum() > 100


def test_float32_convex_cores_are_no_proxies():
    """Rounded to float32 the rotated blocks' faces get convex cores (the hull of their interior cells,
    which may exceed the cells' union by rounding slivers of the ring cells): such a face occludes exactly
    but is no exact tiling, so it must not become a uniform proxy (its slivers would emit twice, outside the
    bound); the faces that do tile exactly still do, and the bound holds."""
    from hemisphere_local_pass.core.culling import build_occluders
    from hemisphere_local_pass.core.far_field import proxy_scene

    box = cornell_box(15, block_detail=1.05)               # block faces of 5 x 5 cells: 3 x 3 inside
    rad = np.zeros((box.n_polygons, 3))
    names = np.array(box.names)
    for k, part in enumerate(dict.fromkeys(box.names)):     # one radiance per part: every face is uniform
        rad[names == part] = 0.1 + 0.05 * k
    rad += box.emission
    sc = Scene.from_polygons(box.vertices.astype(np.float32).astype(np.float64), box.polygons, rad)
    occ = build_occluders(sc)
    assert occ.hull_cores.any()
    sp, half = proxy_scene(sc, occ, np.full(3, 1.0))
    assert half is not None and sp.n_polygons < sc.n_polygons        # the exact tilings became proxies
    loose = proxy_scene(sc, dataclasses.replace(occ, hull_cores=None), np.full(3, 1.0))[0]
    assert loose.n_polygons < sp.n_polygons                         # ... and the cores would have
    rng = np.random.default_rng(8)
    pick = rng.choice(sc.n_polygons, 96)
    pts = sc.poly_centers[pick] + 1e-6 * sc.poly_normals[pick]
    _check(sc, pts, sc.poly_normals[pick], rel_tol=1e-3)



def test_proxy_scenes_of_two_tolerances_are_both_kept():
    """The adaptive pass alternates two tolerances (its samples' and its final samples'): the proxy scenes of
    both stay cached (the same objects, so they are prepared and shipped to workers once), at most
    ``PROXY_KEEP`` of them."""
    from hemisphere_local_pass.core.culling import build_occluders
    from hemisphere_local_pass.core.far_field import PROXY_KEEP, proxy_scene

    box = cornell_box(6)
    names = np.array(box.names)
    rng = np.random.default_rng(3)
    rad = box.emission.copy()
    for k, part in enumerate(dict.fromkeys(box.names)):      # part k varies by 10^-k within its faces
        m = names == part
        rad[m] += 0.3 + 10.0 ** -k * rng.uniform(0.0, 1.0, (m.sum(), 1))
    sc = Scene.from_polygons(box.vertices, box.polygons, rad)
    occ = build_occluders(sc)
    tols = [np.full(3, t) for t in (1e-4, 1e-3, 1e-2)]
    first = [proxy_scene(sc, occ, t)[0] for t in tols]
    assert len({sp.n_polygons for sp in first}) == 3            # three different sets of proxies
    assert PROXY_KEEP == 2 and len(sc._proxy) == 2
    assert proxy_scene(sc, occ, tols[2])[0] is first[2] and proxy_scene(sc, occ, tols[1])[0] is first[1]
    for _ in range(2):                                          # alternating: no rebuild
        assert proxy_scene(sc, occ, tols[2])[0] is first[2] and proxy_scene(sc, occ, tols[1])[0] is first[1]
    assert proxy_scene(sc, occ, tols[0])[0] is not first[0]     # the oldest was dropped


def test_plain_tiles_take_the_exact_paths_sums_within_the_bound(monkeypatch):
    """Clear tiles that skip no edge go through the exact path's own tile sums (:func:`far_field._tile_sums`,
    cheaper per edge) unless their welded list is much shorter: with and without that path (``PLAIN_RATIO``
    0) error <= bound <= tolerance and the two agree within their bounds; a smooth radiance takes it for
    most clear tiles."""
    from hemisphere_local_pass.core import far_field

    calls = []
    real = far_field._tile_sums

    def spy(te, point, *a):
        calls.append(len(point))
        return real(te, point, *a)

    monkeypatch.setattr(far_field, "_tile_sums", spy)
    box, scene = smooth_box(16)
    pts, nrm = _wall_receivers(box, 5, 40)
    h1, exact, st1 = _check(scene, pts, nrm, rel_tol=1e-4)
    n_plain = sum(calls)
    assert n_plain > 10 * len(pts)
    monkeypatch.setattr(far_field, "PLAIN_RATIO", 0.0)
    calls.clear()
    h0, _, st0 = _check(scene, pts, nrm, rel_tol=1e-4)
    assert sum(calls) == 0
    assert (np.abs(h1 - h0) <= st0.error_bound + st1.error_bound).all()


def _hard_smooth_box(kind):
    """The smooth box of :func:`smooth_box` made hard for the budgeted proxies: a bright patch among dim
    polygons, a steep gradient, a low-contrast chequerboard on the back wall."""
    box, scene = smooth_box(40)
    c = np.array([box.vertices[p].mean(axis=0) for p in box.polygons])
    rad = scene.poly_radiance.copy()
    if kind == "patch":
        rad[np.argmin(((c - [0.5, 0.999, 0.5]) ** 2).sum(axis=1))] += 50.0
    elif kind == "steep":
        rad *= 1.0 + 40.0 * np.clip(c[:, 0] - 0.45, 0.0, 0.1)[:, None]
    else:
        back = c[:, 1] > 1 - 1e-9
        rad[back] *= 1.0 + 0.05 * ((np.arange(len(c)) % 2) * 2 - 1)[back, None]
    return box, box.scene(radiance=rad)


@pytest.mark.parametrize("kind", ["patch", "steep", "chequer"])
def test_credit_proxies_stay_within_the_bound(kind, monkeypatch):
    """Nodes taken on their receiver's credit (:class:`far_field.ProxyCredit`) spend the budget of other
    nodes: error <= bound <= tolerance per receiver and channel, on scenes built to break it, receivers on
    the walls (1e-6 off, next to the nodes) and inside; the credit takes more nodes whole than the shares
    alone."""
    from hemisphere_local_pass.core import far_field

    box, scene = _hard_smooth_box(kind)
    pts, nrm = _wall_receivers(box, 5, 40, inside=15, depth=0.3)
    for rel_tol in (1e-4, 1e-2):
        _, _, st = _check(scene, pts, nrm, rel_tol=rel_tol)
        assert st.linear_proxies.sum() > 0
    monkeypatch.setattr(far_field, "PROXY_CREDIT", False)
    _, _, st0 = _check(scene, pts, nrm, rel_tol=1e-2)
    assert st.clear_nodes.sum() > st0.clear_nodes.sum()      # the credit was used (not vacuous)


def _cancelling_rows(rng, n):
    """Quads (n, 4, 3) relative to P that make eq. 4's terms cancel: small and far (1e-6 .. 1e-2 of their
    distance, up to 1e3), seen near edge on or with an edge pointing at P, plus a few wide ones (edges over
    90°, which must stay on the exact path)."""
    dist = 10.0 ** rng.uniform(-1, 3, n)
    size = dist * 10.0 ** rng.uniform(-6, -2, n)
    d = rng.normal(size=(n, 3))
    d[:, 2] = np.abs(d[:, 2]) + 1e-3
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = d * dist[:, None]
    s1 = rng.normal(size=(n, 3))
    pointing = rng.random(n) < 0.3
    s1[pointing] = d[pointing]                    # one edge pair along the line of sight
    s1 /= np.linalg.norm(s1, axis=1, keepdims=True)
    s2 = np.cross(s1, rng.normal(size=(n, 3)))
    s2 /= np.linalg.norm(s2, axis=1, keepdims=True)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * 0.5
    q = c[:, None, :] + size[:, None, None] * (corners[None, :, :1] * s1[:, None] + corners[None, :, 1:] * s2[:, None])
    wide = rng.random(n) < 0.1                    # a big polygon right over P: edges over 90°
    q[wide] = np.array([[-5.0, -5.0, 0.1], [5.0, -5.0, 0.1], [5.0, 5.0, 0.1], [-5.0, 5.0, 0.1]]) \
        + rng.normal(scale=1e-3, size=(int(wide.sum()), 4, 3))
    return q, wide


def test_float64_eq4_rows_kept_by_the_tolerance_are_within_their_bound():
    """With a tolerance, eq. 4's cancelling rows stay in float64 (``contour_integral_bounded``): each is
    within its returned bound of the exact path's extended-precision value, the others are equal to it
    bit for bit, and the bound is a rounding-level one (<= 1e-10 of the row's Σ|terms| / 2π)."""
    from hemisphere_local_pass.core.form_factor import contour_integral, contour_integral_bounded

    if np.finfo(np.longdouble).eps >= np.finfo(np.float64).eps:
        pytest.skip("no extended precision on this platform: the two paths are the same")
    rng = np.random.default_rng(7)
    q, wide = _cancelling_rows(rng, 20000)
    normal = np.broadcast_to([0.0, 0.0, 1.0], (len(q), 3))
    ff_exact = contour_integral(q, normal)
    ff, bound = contour_integral_bounded(q, normal)
    kept = bound > 0
    assert kept.sum() > 10000                     # most rows cancel, and are kept
    assert not kept[wide].any()
    assert np.array_equal(ff[~kept], ff_exact[~kept])
    err = np.abs(ff - ff_exact)
    assert (err <= bound).all(), float((err / np.where(bound > 0, bound, 1)).max())
    # the rows' scale: Σ|t_e| / 2π with |t_e| <= γ_e <= |e| / min(|a|, |b|)
    edge = np.linalg.norm(np.roll(q, -1, axis=1) - q, axis=2)
    near = np.minimum(np.linalg.norm(q, axis=2), np.linalg.norm(np.roll(q, -1, axis=1), axis=2))
    scale = (edge / near).sum(axis=1) / (2 * np.pi)
    assert (bound[kept] <= 1e-10 * np.maximum(scale[kept], 1e-300) + 1e-13).all()


def test_third_factor_bounds_the_kernels_third_derivative():
    """:func:`far_field._third_factor` bounds ``|u|⁶ |D³_v (N·u)|u|^-4|`` for unit v in a plane at distance δ
    from P (checked by a fourth-order central difference at random points, normals and planes, grazing to
    head on), and is tight within a factor of a few at grazing (not vacuous)."""
    from hemisphere_local_pass.core.far_field import _third_factor

    rng = np.random.default_rng(5)
    n = 4000
    u = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-1, 1, (n, 1))
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    plane = rng.normal(size=(n, 3))
    plane /= np.linalg.norm(plane, axis=1, keepdims=True)
    v = np.cross(plane, rng.normal(size=(n, 3)))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    r = np.linalg.norm(u, axis=1)
    delta = np.abs(np.einsum("ij,ij->i", plane, u))

    def f(t):
        x = u + t[:, None] * v
        return np.einsum("ij,ij->i", nrm, x) / np.einsum("ij,ij->i", x, x) ** 2

    hs = 1e-2 * r
    d3 = (f(2 * hs) - 2 * f(hs) + 2 * f(-hs) - f(-2 * hs)) / (2 * hs**3)
    # the difference's own error is O(h²) of the fifth derivative: 1 % of the scale at h = r / 100
    measured = np.abs(d3) * r**6
    bound = _third_factor(delta, r)
    assert (measured <= bound * 1.01).all(), (measured / bound).max()
    assert (measured / bound).max() > 0.3


def test_residual_term_makes_the_proxy_closer():
    """The proxy's residual term ``π ½ ∇²k(c) : E2`` brings it closer to the exact sum over the members:
    on a smooth falloff (whose linear fit leaves a curved residual) the median error of the proxies falls
    at least 3× against the same proxies without it, and a ramp (no residual) is unchanged."""
    from hemisphere_local_pass.core import form_factors
    from hemisphere_local_pass.core.chunk import prepare_scene, scene_hierarchy, scene_node_edges
    from hemisphere_local_pass.core.far_field import linear_node_irradiance

    for field, most in (("falloff", 1 / 3), ("ramp", 1.0 + 1e-9)):
        scene = _grid_scene(32, _FIELDS[field])
        occ = prepare_scene(scene)
        h, fit = scene_hierarchy(scene, occ), scene_node_edges(scene, occ).fit
        rng = np.random.default_rng(3)
        m = 12
        pts = np.column_stack([rng.uniform(-0.5, 1.5, m), rng.uniform(-0.5, 1.5, m), 10.0 ** rng.uniform(-1, 0.5, m)])
        nrm = np.tile([0.0, 0.0, -1.0], (m, 1))
        ff = form_factors(scene, pts, nrm, workers=1)
        nodes = np.flatnonzero(fit.ok)
        ep, en = np.repeat(np.arange(m), len(nodes)), np.tile(nodes, m)
        hmin = np.einsum("pki,pi->pk", h.corners[en] - pts[ep][:, None, :], nrm[ep]).min(axis=1)
        ep, en = ep[hmin > 0], en[hmin > 0]
        with_term = linear_node_irradiance(fit, ep, en, pts, nrm)[0]
        saved = fit.eps2.copy()
        fit.eps2[:] = 0.0
        fit._rect_cache = None
        without = linear_node_irradiance(fit, ep, en, pts, nrm)[0]
        fit.eps2[:] = saved
        fit._rect_cache = None
        exact = _member_sums(scene, occ, h, ff, ep, en)
        e1, e0 = np.abs(with_term - exact).max(axis=1), np.abs(without - exact).max(axis=1)
        real = e0 > 1e-11 * np.abs(exact).max()
        assert real.sum() > 50
        assert np.median(e1[real] / e0[real]) <= most, (field, np.median(e1[real] / e0[real]))
