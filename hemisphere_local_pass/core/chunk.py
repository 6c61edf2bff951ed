"""One chunk of receivers through the exact pipeline, and the per-scene preparation it needs.

For all receivers of a chunk together (every stage vectorised over receivers):

1. shadow volumes of the merged faces and convex solids (:func:`.visibility.shadow_volumes`);
2. level 1: merged faces (clusters) inside another volume are hidden (:func:`.visibility.coverage`);
3. level 1.5: the tile hierarchy, front to back, with coverage culling (:func:`.hierarchy.visit_tiles`):
   only the tiles above the horizon that no nearer occluder covers survive;
4. clear tiles: surviving tiles nothing cuts are summed over their edges (:mod:`.clear_tiles`);
5. the other surviving tiles by quarters (:func:`.hierarchy.refine_cut_tiles`: a quarter inside one of
   its tile's cutting volumes is dropped, a volume that misses a quarter leaves its list); the members of
   the quarters left become candidates, clipped to the hemisphere (:func:`.projection.hemisphere_candidates`);
6. level 2: the volumes that can hide part of each candidate, nearest first
   (:func:`.visibility.occluder_pairs`); then the exact visible fragments or signed terms, and eq. 4.

Memory: when a chunk's surviving tiles hold more candidate polygons than ``budget / K``, its receivers
are halved (recursively) for stages 5–6 only, so a chunk's candidate arrays stay below ``budget × 3 × 8``
bytes however many receivers it has and whatever the scene size; stages 1–4 run once per chunk (each
receiver's result is its own, so the halves' fragments are those of the whole); everything else per chunk
is over (receiver, merged face) and over the tiles that survive.
"""

from __future__ import annotations

import copy

import numpy as np

from . import far_field as far_field_module
from .clear_tiles import TileEdges, clear_pairs, tile_edges
from .culling import Occluders, build_occluders
from .far_field import NodeEdges, ProxyCredit, clear_node_test, node_edges
from .form_factor import contour_integral, contour_integral_bounded
from .hierarchy import SubTiles, TileHierarchy, build_hierarchy, build_subtiles, refine_cut_tiles, visit_tiles
from .parallel import Cancelled
from .projection import hemisphere_candidates
from .rowops import take_rows
from .scene import Scene
from .tolerances import COORD_EPS
from .visibility import Fragments, coverage, occluder_pairs, shadow_volumes, subtract_shadow_volumes, visible_terms

__all__ = ["Cancelled", "PREPARATION_STAGES", "prepare_scene", "visible", "visible_fragments_with_ff"]

DEFAULT_BUDGET = 2**19

#: the candidate stage of :func:`visible` runs on groups of receivers whose surviving tiles hold at most
#: ``budget / (K + 1)`` members, or up to :data:`GROUP_CAP` times that while a group has at most
#: :data:`MIN_GROUP_POINTS` receivers: in a large scene each receiver brings thousands of members, and groups of
#: a few receivers would pay the candidate stage's per-call overhead (hundreds of numpy calls) many times over
#: (190,774 polygons: 16 receivers a group; ~11 % of the call; smaller scenes are split as before)
MIN_GROUP_POINTS = 64
GROUP_CAP = 4

#: the phases of :func:`prepare_scene`, in order (``progress(done, len(PREPARATION_STAGES))`` after each)
PREPARATION_STAGES = ("merged faces", "depth tables", "tiles", "solids", "tile edges", "hierarchy")


def prepare_scene(scene: Scene, *, occluders: Occluders | None = None, progress=None, cancel=None) -> Occluders:
    """Everything the local pass precomputes per scene, cached on the scene; returns its occluders.

    Merged occluders with their depth tables, tiles and convex solids (:func:`.culling.build_occluders`),
    the tiles' welded edges (:func:`.clear_tiles.tile_edges`) and the tile hierarchy
    (:func:`.hierarchy.build_hierarchy`) — O(n log n) time and O(n) memory in the number of polygons n
    when the scene's polygons merge into few faces (the depth tables are polygons × merged faces); from
    :data:`.culling.PER_PAIR_DEPTH_FROM` merged faces on there are no tables (:mod:`.depth_pairs`:
    memory O(n) besides polygons × convex solids, time ~O(n^1.5) for a curved mesh).

    Args:
        occluders: prebuilt occluders to use instead of the scene's own.
        progress: ``progress(done, total)`` after each of the :data:`PREPARATION_STAGES` (total 6),
            stages already cached included; cancel: checked before each stage, True raises
            :class:`Cancelled`.
    """
    total = len(PREPARATION_STAGES)
    done = [0]

    def step(name):
        done[0] += 1
        if progress is not None:
            progress(done[0], total)
        if cancel is not None and done[0] < total and cancel():
            raise Cancelled(f"cancelled while preparing the scene (after {name})")

    if cancel is not None and cancel():
        raise Cancelled("cancelled before preparing the scene")
    if occluders is not None:
        occ = occluders
        for name in PREPARATION_STAGES[:4]:
            step(name)
    else:
        occ = getattr(scene, "_occluders", None)
        if occ is None:
            occ = build_occluders(scene, step=step)
            scene._occluders = occ
        else:
            for name in PREPARATION_STAGES[:4]:
                step(name)
    scene_tile_edges(scene, occ)
    step("tile edges")
    scene_hierarchy(scene, occ)
    step("hierarchy")
    return occ


def scene_occluders(scene: Scene, occluders: Occluders | None = None) -> Occluders:
    """``occluders`` or the scene's own (built once and cached on the scene)."""
    if occluders is not None:
        return occluders
    occ = getattr(scene, "_occluders", None)
    if occ is None:
        occ = build_occluders(scene)
        scene._occluders = occ
    return occ


def scene_tile_edges(scene: Scene, occ: Occluders) -> TileEdges:
    cached = getattr(scene, "_tile_edges", None)
    if cached is None or cached[0] is not occ:
        cached = (occ, tile_edges(scene, occ))
        scene._tile_edges = cached
    return cached[1]


def scene_node_edges(scene: Scene, occ: Occluders) -> NodeEdges:
    """The welded edges of every hierarchy node (:func:`.far_field.node_edges`), cached on the scene."""
    cached = getattr(scene, "_node_edges", None)
    if cached is None or cached[0] is not occ:
        cached = (occ, node_edges(scene, occ, scene_hierarchy(scene, occ), scene_tile_edges(scene, occ)))
        scene._node_edges = cached
    return cached[1]


def scene_hierarchy(scene: Scene, occ: Occluders) -> TileHierarchy:
    cached = getattr(scene, "_hierarchy", None)
    if cached is None or cached[0] is not occ:
        cached = (occ, build_hierarchy(occ, scene.poly_radii))
        scene._hierarchy = cached
    return cached[1]


def scene_subtiles(scene: Scene, occ: Occluders) -> SubTiles:
    """The quarters of the scene's tiles (:func:`.hierarchy.build_subtiles`), cached on the scene."""
    cached = getattr(scene, "_subtiles", None)
    if cached is None or cached[0] is not occ:
        cached = (occ, build_subtiles(occ, scene.poly_vertices, scene.poly_centers))
        scene._subtiles = cached
    return cached[1]


def visible_fragments_with_ff(scene: Scene, points, normals, limit=None, *, occluders=None, include=None):
    """Visible fragments of every polygon for receivers ``points, normals (m, 3)`` and their form factors.

    Returns ``(fragments, ff)`` with ``ff (F,)`` the form factor of each fragment (eq. 4, >= 0).
    """
    frags, ff, _ = visible(scene, points, normals, limit, scene_occluders(scene, occluders), include,
                           use_clear=False)
    return frags, ff


def _row(include):
    """The one row of an ``include`` broadcast along the receivers (or given as one row), else None."""
    if include is None:
        return None
    inc = np.asarray(include)
    if inc.ndim == 1:
        return inc
    if inc.shape[0] == 1 or inc.strides[0] == 0:
        return inc[0]
    return None


def _representatives(scene: Scene):
    """``(n,)`` bool: the polygons that represent their group of identical copies, or None when every
    polygon does (cached on the scene: an O(n) pass per chunk is what hidden geometry must not cost)."""
    cached = getattr(scene, "_reps", False)
    if cached is False:
        reps = scene.dup_rep == np.arange(scene.n_polygons)
        cached = None if reps.all() else reps
        scene._reps = cached
    return cached


def _wanted_tiles(scene: Scene, occ: Occluders, row: np.ndarray) -> np.ndarray:
    """``(T,)`` bool: tiles with a member in ``row (n,)`` (the polygons to project), cached for the row."""
    cached = getattr(scene, "_wanted", None)
    if cached is not None and cached[0] is occ and (cached[1] is row or np.array_equal(cached[1], row)):
        return cached[2]
    wanted = np.logical_or.reduceat(row[occ.tile_members], occ.tile_ptr[:-1]) if len(occ.tile_members) \
        else np.zeros(0, dtype=bool)
    scene._wanted = (occ, row.copy(), wanted)
    return wanted


def visible(scene: Scene, points, normals, limit, occ: Occluders, include, *, use_clear: bool,
            budget: int = DEFAULT_BUDGET, signed: bool | None = None, far_field: bool = False,
            far_tolerance=None):
    """The visibility stage: ``(fragments, ff, clear)``; with ``use_clear`` (callers that only sum over
    fragments) the clear tiles (see :mod:`.clear_tiles`) are left out of the fragments and returned as
    ``clear = (pairs, tile_edges)``, and the visible parts come as signed terms (see
    :func:`.visibility.visible_terms`): ``ff`` is then negative for the terms to subtract, and the
    fragments carry no vertices (``verts`` None), only their ids; ``signed=False`` keeps the clear tiles
    apart but subtracts the rest into real fragments (the gradients need their edges).

    ``include``: None, or bool (m, n) / (1, n) pairs to project (others only occlude).

    ``far_field`` (with ``use_clear``, constant radiance; only for a tolerance > 0): whole hierarchy nodes
    that are clear are not expanded (:mod:`.far_field`) and come as ``clear = (pairs, tile_edges, nodes)``
    with ``nodes = (point, node, side)``; without it ``clear`` has two items and nothing changes.
    ``far_tolerance`` (3,): the far field's tolerance, for the nodes taken whole by their linear proxy
    (:func:`.far_field.clear_node_test`; None: only nodes with a welded list). With ``far_tolerance`` the
    signed terms' eq. 4 sums that cancel may stay in float64 (:func:`.form_factor.contour_integral_bounded`):
    ``fragments.ff_bound (F,)`` bounds each ``ff``'s distance from the exact path's."""
    signed = use_clear if signed is None else signed
    # with a tolerance the fragments' cancelling sums may stay in float64, their rounding bounded
    bounded = signed and far_tolerance is not None
    reps = _representatives(scene)
    row = _row(include)
    if reps is not None:  # identical copies are projected once (see Scene._find_duplicates)
        if include is None or row is not None:
            row = reps if row is None else row & reps
            include = row[None, :]
        else:
            include = include & reps[None, :]
    sv, table = shadow_volumes(occ, points, normals, limit)
    cov = coverage(sv, table, occ, points)
    wanted = None if row is None else _wanted_tiles(scene, occ, row)
    h = scene_hierarchy(scene, occ)
    clear_test = None
    far_field = far_field and use_clear and not scene.linear and len(occ.tile_occluder) > 0
    if far_field:
        ne = scene_node_edges(scene, occ)
        free = None if limit is None else ~limit.any(axis=1)
        use_credit = far_tolerance is not None and far_field_module.PROXY_CREDIT
        credit = ProxyCredit(len(points), free) if use_credit else None

        def clear_test(ep, en):
            ok, side = clear_node_test(ne, h, points, normals, ep, en, far_tolerance, credit)
            return (ok if free is None else ok & free[ep]), side

    tiles = visit_tiles(h, occ, sv, table, cov, points, normals, wanted, clear_test)
    cov.tiles = tiles
    clear = None
    keep = np.ones(len(tiles.point), dtype=bool)
    if use_clear and len(occ.tile_occluder):
        te = scene_tile_edges(scene, occ)
        pairs = clear_pairs(te, occ, cov, sv, table, points, normals, limit)
        keep[pairs.pair] = False
        clear = (pairs, te) if not far_field else (pairs, te, tiles.nodes)
    tiles = tiles.take(keep) if not keep.all() else tiles
    k = scene.poly_vertices.shape[1] + 1
    per_point = np.bincount(tiles.point, weights=np.diff(occ.tile_ptr)[tiles.tile], minlength=len(points))
    parts = []
    for s, e in _receiver_groups(np.concatenate([[0], np.cumsum(per_point)]), 0, len(points), budget // k):
        # the candidate stage per group of receivers (memory bound); everything before it was done once
        lo, hi = np.searchsorted(tiles.point, (s, e))
        cov.tiles = tiles if (lo, hi) == (0, len(tiles.point)) else tiles.take(np.arange(lo, hi))
        parts.append(_fragments(scene, points, normals, limit, include, occ, sv, table, cov, signed, bounded))
    cov.tiles = tiles
    if len(parts) == 1:
        frags, ff = parts[0]
    elif signed:
        frags = Fragments(None, None, *(np.concatenate([getattr(f, a) for f, _ in parts])
                                        for a in ("counts", "point", "poly", "side", "owner")))
        ff = np.concatenate([f for _, f in parts])
        if bounded:
            frags.ff_bound = np.concatenate([f.ff_bound for f, _ in parts])
    else:
        frags, ff = Fragments.concat([f for f, _ in parts]), np.concatenate([f for _, f in parts])
    if reps is not None:
        # credit each fragment to the copy that faces the receiver (then the lowest index)
        rep = frags.poly
        opp = scene.dup_opp[rep]
        use_opp = (frags.side > 0) & (opp >= 0)
        frags.poly = np.where(use_opp, opp, scene.dup_same[rep])
        frags.side = np.where(use_opp, -frags.side, frags.side)
    return frags, ff, clear


def _receiver_groups(cum, s: int, e: int, limit: int) -> list[tuple[int, int]]:
    """Receiver ranges ``[s, e)`` halved (recursively) until each holds at most ``limit`` candidate
    polygons (``cum``: cumulative candidates per receiver, (m+1,)), or at most :data:`GROUP_CAP` × ``limit``
    with at most :data:`MIN_GROUP_POINTS` receivers, or one receiver."""
    held = cum[e] - cum[s]
    if held <= limit or e - s <= 1 or (e - s <= MIN_GROUP_POINTS and held <= GROUP_CAP * limit):
        return [(s, e)]
    h = s + (e - s) // 2
    return _receiver_groups(cum, s, h, limit) + _receiver_groups(cum, h, e, limit)


def _fragments(scene, points, normals, limit, include, occ, sv, table, cov, signed, bounded=False):
    """The candidate stage of :func:`visible` for the tile pairs ``cov.tiles``: ``(fragments, ff)``; with
    ``bounded`` (signed terms only) the fragments carry ``ff_bound`` (see :func:`visible`)."""
    tiles = cov.tiles
    members = (occ.tile_ptr, occ.tile_members)
    if sv.inf is None:
        # the cut tiles by quarters: hidden quarters and the volumes that miss a quarter cost nothing below.
        # Also when no tile of the chunk is cut: a receiver's candidates then come in sub-tile order whatever
        # the other receivers of its chunk, and so does the order of its sums (a chunk with one cut tile
        # elsewhere moved the last bit of 10 of 65,536 pixels at 9,468 polygons, 2026-12-07)
        st = scene_subtiles(scene, occ)
        cov = copy.copy(cov)
        cov.tiles = tiles = refine_cut_tiles(st, tiles, sv, points)
        members = (st.ptr, st.members)
    cand = hemisphere_candidates(scene, points, normals, limit, include, members, tiles)
    ptr, ids, planes, hidden = occluder_pairs(cand, sv, table, cov, occ, scene, points)
    allc = Fragments(cand.verts, cand.inf, cand.counts, cand.point, cand.poly, cand.side, np.arange(len(hidden)))
    flat = None if cand.flat is None else (cand.flat, scene.poly_normals)
    if signed:
        # signed terms, integrated set by set; the sums need only their ids (verts None)
        terms = visible_terms(allc, ptr, ids, sv, planes, ~hidden, flat)
        res = [contour_by_width(t, normals, points, flat, bounded=True) if bounded
               else (contour_by_width(t, normals, points, flat), None) for t, _ in terms]
        # (max(·, 0) moves no value farther from the exact path's than its bound)
        ff = np.concatenate([sign * np.maximum(t.side * f, 0.0) for (t, sign), (f, _) in zip(terms, res)]
                            or [np.zeros(0)])
        frags = Fragments(None, None, *(np.concatenate([getattr(t, a) for t, _ in terms] or [np.zeros(0, dtype=int)])
                                        for a in ("counts", "point", "poly", "side", "owner")))
        if bounded:
            frags.ff_bound = np.concatenate([b for _, b in res] or [np.zeros(0)])
    else:
        frags = subtract_shadow_volumes(allc.take(~hidden), ptr, ids, sv, planes, flat)
        # a fragment's exact factor is >= 0; rounding can leave -1e-17 on a sliver
        ff = np.maximum(frags.side * contour_by_width(frags, normals, points, flat), 0.0)
    return frags, ff


def contour_by_width(frags: Fragments, normals, points, flat=None, bounded: bool = False):
    """Eq. 4 for every fragment, the many small ones (<= 4 vertices) without their padding slots.

    ``flat``: None or, in a one-sided limit, ``(candidate flags (C,), plane normals (n, 3))`` as for
    :func:`.visibility.subtract_shadow_volumes`: fragments of candidates lying in a plane through P take
    that plane as the great circle of their edges (see :func:`.form_factor.contour_integral`).
    ``bounded`` (a tolerance's callers): ``(F (F,), bound (F,))`` from
    :func:`.form_factor.contour_integral_bounded`, ``bound`` on ``|F − F_exact path|``."""
    integral = contour_integral_bounded if bounded else contour_integral
    width = frags.verts.shape[1]
    small = frags.counts <= 4
    noise = None if frags.inf is None else COORD_EPS * np.abs(points).max(axis=1)[frags.point]
    planes = None
    if frags.inf is not None and flat is not None:
        on = flat[0][frags.owner]
        if on.any():
            planes = np.where(on[:, None], take_rows(flat[1], frags.poly), 0.0)
    if width <= 4 or small.all() or not small.any():
        return integral(frags.verts, take_rows(normals, frags.point), frags.inf, noise, planes)
    out = np.empty(len(frags.counts))
    bound = np.zeros(len(frags.counts))
    for sel, w in ((np.flatnonzero(small), 4), (np.flatnonzero(~small), width)):
        res = integral(take_rows(frags.verts[:, :w], sel), take_rows(normals, frags.point[sel]),
                       None if frags.inf is None else take_rows(frags.inf[:, :w], sel),
                       None if noise is None else noise[sel],
                       None if planes is None else take_rows(planes, sel))
        if bounded:
            out[sel], bound[sel] = res
        else:
            out[sel] = res
    return (out, bound) if bounded else out
