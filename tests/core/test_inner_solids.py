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
