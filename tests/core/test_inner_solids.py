"""Convex polytopes inside float32-rounded blocks (:mod:`hemisphere_local_pass.core.inner_solids`): an
extra shadow volume that changes no result, used only at receivers outside the block."""

from __future__ import annotations

import numpy as np

from hemisphere_local_pass.core import Scene, culling, form_factors
from hemisphere_local_pass.core.solids import no_solids, solid_volumes
from hemisphere_local_pass.scenes import cornell_box


def _float32_box(subdivisions=15):
    box = cornell_box(subdivisions, block_detail=1.05)
    return box, Scene.from_polygons(box.vertices.astype(np.float32).astype(np.float64), box.polygons)


def _receivers(box, sc):
    """Cells of every kind: light, block tops and sides, floor under and beside the blocks, walls."""
    names = np.array(box.names)[sc.poly_source]
    c = sc.poly_centers
    block = np.char.find(names.astype(str), "block") >= 0
    top = np.flatnonzero(block & (sc.poly_normals[:, 2] > 0.999))
    side = np.flatnonzero(block & (np.abs(sc.poly_normals[:, 2]) < 1e-3))
    floor = np.flatnonzero(names == "floor")
    under = floor[np.hypot(c[floor, 0] - 0.66, c[floor, 1] - 0.30) < 0.05]          # inside the short block
    beside = floor[np.hypot(c[floor, 0] - 0.66, c[floor, 1] - 0.30) > 0.25]
    rng = np.random.default_rng(5)
    return np.concatenate([np.flatnonzero(names == "light")[:2], rng.choice(top, 3), rng.choice(side, 3),
                           under[:2], rng.choice(beside, 2), rng.choice(np.flatnonzero(~block), 3)]), under[:2]


def test_float32_blocks_get_inner_polytopes_that_change_no_form_factor(monkeypatch):
    """Both rounded blocks get a polytope (6 faces: 4 sides, top, base) strictly inside them; the form
    factors equal those without it and those of every cell occluding on its own to rounding, and ΣF = 1
    at every receiver of the closed box (under a block too: the closed cavity)."""
    box, sc = _float32_box()
    occ = culling.build_occluders(sc)
    sol = occ.solids
    virtual = np.flatnonzero(sol.is_virtual())
    assert len(virtual) == 2 and (np.diff(sol.face_ptr)[virtual] == 6).all()
    sel, under = _receivers(box, sc)
    p, n = sc.poly_centers[sel], sc.poly_normals[sel]
    f = form_factors(sc, p, n, workers=1, occluders=occ)
    monkeypatch.setattr(culling, "inner_solids", lambda *a, **k: no_solids())
    without = form_factors(sc, p, n, workers=1, occluders=culling.build_occluders(sc))
    monkeypatch.setattr(culling, "_convex_cores", lambda scene, reps, root, rejected, m, c, pts:
                        (m, c, pts, np.full(scene.n_polygons, -1)))
    cells = form_factors(sc, p, n, workers=1, occluders=culling.build_occluders(sc))
    assert np.abs(f - without).max() <= 1e-15
    assert np.abs(f - cells).max() <= 1e-15
    assert np.abs(f.sum(axis=1) - 1).max() <= 1e-12
    # under the block the receiver sees the block's inside only; on its faces no polytope applies either
    names = np.array(box.names)[sc.poly_source]
    assert f[np.isin(sel, under)][:, np.char.find(names.astype(str), "block") < 0].sum() <= 1e-15
    qp, qs = solid_volumes(sol, p, n, None)[:2]
    short = virtual[np.argmin(np.hypot(sol.centers[virtual, 0] - 0.66, sol.centers[virtual, 1] - 0.30))]
    used = np.zeros(len(sel), dtype=bool)
    used[qp[qs == short]] = True
    on_short = names[sel] == "short block"
    assert on_short.any() and not used[np.isin(sel, under) | on_short].any() and used[:2].all()


def test_open_or_float64_surfaces_get_none(monkeypatch):
    """A block with a side cell missing is no closed surface: no polytope; float64 blocks are convex
    solids already (and merge: too few occluders to try)."""
    box, sc = _float32_box()
    names = np.array(box.names)
    drop = next(i for i, nm in enumerate(names) if nm == "short block"
                and abs(box.normals()[i, 2]) < 1e-3)
    keep = [p for i, p in enumerate(box.polygons) if i != drop]
    open_sc = Scene.from_polygons(box.vertices.astype(np.float32).astype(np.float64), keep)
    assert culling.build_occluders(open_sc).solids.is_virtual().sum() == 1          # the tall block only
    exact = culling.build_occluders(Scene.from_polygons(box.vertices, box.polygons)).solids
    assert not exact.is_virtual().any() and exact.n == 3


def _prism(cells, n_z=3, height=0.5):
    """A closed-but-bottomless block: the unit-grid ``cells [(i, j)]`` as its top (z = height, cell side
    0.1), outward side columns of ``n_z`` cells on the top's outline: ``(vertices (V, 3), quads)``."""
    index, quads = {}, []

    def vid(x, y, z):
        return index.setdefault((0.1 * x, 0.1 * y, z), len(index))

    top = [[(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)] for i, j in cells]
    edges = {(a, b) for c in top for a, b in zip(c, c[1:] + c[:1])}
    zs = np.linspace(0.0, height, n_z + 1)
    for c in top:
        quads.append([vid(*p, height) for p in c])
    for a, b in edges:
        if (b, a) not in edges:                                   # outline edge, counter-clockwise
            for z0, z1 in zip(zs[:-1], zs[1:]):
                quads.append([vid(*a, z0), vid(*b, z0), vid(*b, z1), vid(*a, z1)])
    return np.array(list(index), dtype=np.float64), quads


def _check_unchanged(verts, quads, receivers, monkeypatch, n_virtual):
    sc = Scene.from_polygons(verts, quads)
    occ = culling.build_occluders(sc)
    assert occ.solids.is_virtual().sum() == n_virtual
    p, n = receivers
    f = form_factors(sc, p, n, workers=1, occluders=occ)
    with monkeypatch.context() as m:
        m.setattr(culling, "inner_solids", lambda *a, **k: no_solids())
        ref = form_factors(sc, p, n, workers=1, occluders=culling.build_occluders(sc))
    assert np.abs(f - ref).max() <= 1e-15
    qp, qs = solid_volumes(occ.solids, p, n, None)[:2]
    used = np.zeros(len(p), dtype=bool)
    used[qp[occ.solids.is_virtual()[qs]]] = True
    return f, used


def test_an_l_shaped_block_gets_a_polytope_in_its_kernel(monkeypatch):
    """Not convex at all (an L of 3 x 3 cells less a corner, float64): the faces' planes bound its kernel,
    which lies inside it; the polytope there changes no form factor, seen from above, beside it and
    from inside the L's notch (where it is not used: not outside the hull)."""
    cells = [(i, j) for i in range(6) for j in range(6) if i < 3 or j < 3]
    verts, quads = _prism(cells)
    floor = [len(verts) + k for k in range(4)]
    verts = np.vstack([verts, [(-1, -1, 0), (2, -1, 0), (2, 2, 0), (-1, 2, 0)]])
    p = np.array([(0.3, 0.3, 1.5), (0.9, 1.2, 0.8), (-0.4, 0.2, 0.01), (0.45, 0.45, 0.2)])
    n = np.array([(0, 0, -1), (-0.6, -0.6, -0.5), (1, 0, 0), (-0.7, -0.7, 0.0)], dtype=float)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    f, used = _check_unchanged(verts, quads + [floor], (p, n), monkeypatch, 1)
    assert (f[:, :-1].sum(axis=1) > 0.01).all()                      # each receiver sees the block
    assert used[:3].all() and not used[3]


def test_random_rotated_float32_blocks(monkeypatch):
    """Blocks of 4 x 4 cells turned about z by random angles and rounded to float32; receivers around."""
    rng = np.random.default_rng(11)
    verts, quads = [], []
    for k in range(3):
        v, q = _prism([(i, j) for i in range(4) for j in range(4)], n_z=2, height=0.3 + 0.2 * rng.random())
        a = rng.uniform(0, np.pi)
        rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        v = (v - (0.2, 0.2, 0)) @ rot.T + (1.2 * k, 0.3 * k, 0)
        quads += [[i + sum(len(x) for x in verts) for i in qq] for qq in q]
        verts.append(v.astype(np.float32).astype(np.float64))
    verts = np.concatenate(verts)
    p = np.column_stack([rng.uniform(-0.5, 3.0, 12), rng.uniform(-1.0, 1.5, 12), rng.uniform(0.05, 1.5, 12)])
    n = rng.normal(size=(12, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert _check_unchanged(verts, quads, (p, n), monkeypatch, 3)[1].sum() >= 6
