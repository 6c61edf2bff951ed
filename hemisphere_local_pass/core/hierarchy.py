"""The spatial hierarchy of sec. 3.4: tiles grouped into a tree per merged face, visited front to back.

"Assume that all polygons are stored in a space hierarchy. Traversing the hierarchy front to back and
projecting the polygons stored in each voxel is equivalent to a depth sort of the polygons. If the
region of the hemisphere corresponding to the projected silhouette of a voxel is already 'covered' by
polygons, the voxel needs no further consideration." (sec. 3.4)

Structure (built once per scene, O(T log T) for T tiles): the leaves are the *tiles* of
:mod:`.culling` (~16 member polygons of one merged face each, the paper's voxels). Per merged face its
tiles are ordered along a Morton curve of their centres and grouped four by four, level by level, up
to one root per face; every node stores its bounding box (8 corners) and a bounding sphere that
contains its children's spheres. Leaves have the tile's index as node id; internal nodes follow.

Traversal (per chunk of receivers, vectorised over (receiver, node) pairs, breadth first): a pair
starts at the root of every merged face whose cluster is not already hidden (level 1 of
:func:`.visibility.coverage`: the face lies wholly inside another occluder's shadow volume). Nearer
occluders are the ones that can cover a node: each pair carries the list of shadow volumes that cut
its face (the face's *cutting volumes*, level 1's output — volumes whose occluder is on P's side of
the face, so in front of it), and at each node

* the node is dropped when its bounding sphere is below the receiver's horizon (the tiles' own test
  then drops every tile in it);
* the node is dropped when its box lies inside one of those volumes (*covered*: every point of the
  node, hence every member polygon, is hidden);
* a volume is dropped from the node's list when the box lies outside one of its planes (it cannot
  cut any tile below);
* (irradiance) the node is dropped when none of its tiles has a member that is projected at all
  (polygons with zero radiance are only occluders there).

Node decisions use a margin of several times the plane tolerance of the exact tests, so that they are
*implied* by the decisions the tiles' own test (:func:`.visibility._test_pairs` on the tile's box)
would make: a tile box lies in its node's box, its corners' plane distances are convex combinations
of the node corners', and its tolerance is smaller. At a leaf the tile takes exactly the test of
level 1.5 against the volumes left in its list, so the tiles that survive, and the volumes listed for
each, are the ones the dense per-tile test gives — only the work is output-sensitive: a hidden plane
of 90,000 quads is culled at a handful of nodes per receiver instead of 5,600 tiles.

Below the leaves (:class:`SubTiles`, :func:`refine_cut_tiles`): a tile that a shadow edge crosses has
members hidden, cut and clear; its quarters take the node tests against the tile's list, so the members
of a hidden quarter are no candidates and a quarter's members are not tested against the volumes that
miss it (measured on the 190,774-polygon box, 64 receivers exact, first group of receivers: 11,125 of
14,681 (receiver, quarter) pairs left, 24 % hidden).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .csr import expand
from .culling import grid_cells, member_boxes
from .rowops import take_rows
from .tolerances import COORD_EPS, PLANE_EPS
from .visibility import _cone, _test_pairs

__all__ = ["SubTiles", "TileHierarchy", "TilePairs", "build_hierarchy", "build_subtiles", "refine_cut_tiles",
           "visit_tiles"]

#: children per internal node
FANOUT = 4
#: node decisions need the corners beyond a plane by this many times the exact tests' tolerance
NODE_MARGIN = 4.0


@dataclass
class TileHierarchy:
    """Tree over the tiles of each merged face (see the module doc); ``N`` nodes, leaves ``0..T-1``.

    Attributes:
        corners: (N, 8, 3) bounding boxes; centers (N, 3), radii (N,): bounding spheres containing the
            children's spheres (leaves: the tile's sphere).
        child_ptr (N+1,), child (N - n_roots,): CSR lists of the children of every node (empty for
            leaves); first_tile, last_tile (N,): the node's tiles are ``perm[first:last]``.
        perm: (T,) tiles in tree order; root: (n_o,) root node of every merged face (-1: no tiles);
        tiled: (n_o,) faces whose tiles are tested on their own (more than one tile and member:
            level 1.5; a face's only tile would repeat level 1).
        mid, half: (N, 3) centre and half extent of every box (for exact min / max of a plane over it).
        min_radius: (N,) smallest bounding radius of a member polygon below the node.
        face: (N,) the merged face (occluder) every node belongs to.
    """

    corners: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    child_ptr: np.ndarray
    child: np.ndarray
    first_tile: np.ndarray
    last_tile: np.ndarray
    perm: np.ndarray
    root: np.ndarray
    tiled: np.ndarray
    min_radius: np.ndarray | None = None
    face: np.ndarray | None = None
    mid: np.ndarray | None = None
    half: np.ndarray | None = None

    def __post_init__(self):
        lo, hi = self.corners.min(axis=1), self.corners.max(axis=1)
        self.mid, self.half = 0.5 * (lo + hi), 0.5 * (hi - lo)

    @property
    def n_tiles(self) -> int:
        return len(self.perm)


def _morton(q: np.ndarray) -> np.ndarray:
    """Morton codes of ``q (T, 3)`` int64 in [0, 1024): 30-bit interleaving."""
    code = np.zeros(len(q), dtype=np.int64)
    for bit in range(10):
        for ax in range(3):
            code |= ((q[:, ax] >> bit) & 1) << (3 * bit + ax)
    return code


def build_hierarchy(occ, poly_radii: np.ndarray) -> TileHierarchy:
    """The tree of :class:`TileHierarchy` over ``occ``'s tiles (an :class:`~.culling.Occluders`);
    ``poly_radii (n,)``: the bounding radii of the scene's polygons."""
    n_t, n_o = len(occ.tile_occluder), occ.n
    face = occ.tile_occluder
    # Morton order of the tile centres within each face's box
    lo = np.full((n_o, 3), np.inf)
    hi = np.full((n_o, 3), -np.inf)
    np.minimum.at(lo, face, occ.tile_centers)
    np.maximum.at(hi, face, occ.tile_centers)
    ext = np.where(hi > lo, hi - lo, 1.0)
    q = np.clip(((occ.tile_centers - lo[face]) / ext[face] * 1023.0).astype(np.int64), 0, 1023) if n_t \
        else np.zeros((0, 3), dtype=np.int64)
    perm = np.lexsort((_morton(q), face)) if n_t else np.zeros(0, dtype=np.int64)
    corners = [occ.tile_corners]
    centers = [occ.tile_centers]
    radii = [occ.tile_radii]
    first = [np.empty(n_t, dtype=np.int64)]
    first[0][perm] = np.arange(n_t)
    last = [first[0] + 1]
    rmin = [np.minimum.reduceat(poly_radii[occ.tile_members], occ.tile_ptr[:-1]) if n_t else np.zeros(0)]
    node_face = [face]
    children: list[np.ndarray] = []
    parents_of: list[np.ndarray] = []
    items, item_face = perm, face[perm]                   # the current level, in tree order
    root = np.full(n_o, -1, dtype=np.int64)
    n_nodes = n_t
    while len(items):
        starts = np.flatnonzero(np.r_[True, item_face[1:] != item_face[:-1]])
        size = np.diff(np.append(starts, len(items)))
        done = size == 1
        root[item_face[starts[done]]] = items[starts[done]]
        keep = ~np.repeat(done, size)
        items, item_face = items[keep], item_face[keep]
        if not len(items):
            break
        starts = np.flatnonzero(np.r_[True, item_face[1:] != item_face[:-1]])
        size = np.diff(np.append(starts, len(items)))
        rank = np.arange(len(items)) - np.repeat(starts, size)
        group = np.repeat(np.cumsum((size + FANOUT - 1) // FANOUT) - (size + FANOUT - 1) // FANOUT, size) \
            + rank // FANOUT
        g_start = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
        n_new = len(g_start)
        cat_c = np.concatenate(corners)
        cat_s, cat_r = np.concatenate(centers), np.concatenate(radii)
        box_lo = np.minimum.reduceat(cat_c[items].min(axis=1), g_start, axis=0)
        box_hi = np.maximum.reduceat(cat_c[items].max(axis=1), g_start, axis=0)
        bits = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=bool)
        c = np.where(bits[None], box_hi[:, None, :], box_lo[:, None, :])
        mid = 0.5 * (box_lo + box_hi)
        par = n_nodes + group                                            # parent node of every item
        reach = np.linalg.norm(cat_s[items] - mid[group], axis=1) + cat_r[items]
        r = np.zeros(n_new)
        np.maximum.at(r, group, reach)
        corners.append(c)
        centers.append(mid)
        radii.append(r * (1.0 + 1e-12))                                  # contains the children despite rounding
        cat_f, cat_l = np.concatenate(first), np.concatenate(last)
        first.append(np.minimum.reduceat(cat_f[items], g_start))
        last.append(np.maximum.reduceat(cat_l[items], g_start))
        rmin.append(np.minimum.reduceat(np.concatenate(rmin)[items], g_start))
        children.append(items)
        parents_of.append(par)
        items, item_face = n_nodes + np.arange(n_new), item_face[g_start]
        node_face.append(item_face)
        n_nodes += n_new
    n_children = np.zeros(n_nodes + 1, dtype=np.int64)
    child = np.concatenate(children) if children else np.zeros(0, dtype=np.int64)
    parent = np.concatenate(parents_of) if parents_of else np.zeros(0, dtype=np.int64)
    np.add.at(n_children, parent + 1, 1)
    order = np.argsort(parent, kind="stable")
    tiled = (np.bincount(occ.members, minlength=n_o) > 1) & (np.bincount(face, minlength=n_o) > 1)
    return TileHierarchy(np.concatenate(corners), np.concatenate(centers), np.concatenate(radii),
                         np.cumsum(n_children), child[order], np.concatenate(first), np.concatenate(last), perm,
                         root, tiled, np.concatenate(rmin), np.concatenate(node_face))


@dataclass
class TilePairs:
    """(receiver, tile) pairs above the horizon and not known to be hidden, sorted by (receiver, tile).

    Attributes: point (P,), tile (P,); tested (P,) bool: the tile was tested against its face's
    cutting volumes (level 1.5); ptr (P+1,), q: CSR lists of the shadow-volume instances that cut
    each tested tile (nearest-first order is set later, per polygon); untested pairs' lists are empty
    (their polygons use their face's list). ``visited`` counts the (receiver, node) pairs looked at.
    """

    point: np.ndarray
    tile: np.ndarray
    tested: np.ndarray
    ptr: np.ndarray
    q: np.ndarray
    visited: int = 0
    nodes: tuple | None = None

    def take(self, sel) -> TilePairs:
        sel = np.flatnonzero(sel) if np.asarray(sel).dtype == bool else np.asarray(sel)
        b, q = expand(sel, self.ptr, self.q)
        ptr = np.zeros(len(sel) + 1, dtype=np.int64)
        np.add.at(ptr, b + 1, 1)
        return TilePairs(self.point[sel], self.tile[sel], self.tested[sel], np.cumsum(ptr), q, self.visited,
                         self.nodes)


@dataclass
class SubTiles:
    """The quarters of every tile (``S`` sub-tiles): a 2 × 2 grid over the tile's two longest extents, by
    member centre; tiles of fewer than :data:`SUBTILE_FROM` members are their own one sub-tile.

    Attributes:
        tile_ptr: (T+1,) each tile's sub-tiles ``tile_ptr[t]:tile_ptr[t+1]``; ptr: (S+1,), members: (n,)
            CSR lists of every sub-tile's polygons (a tile's sub-tiles list exactly its members); mid, half:
            (S, 3) the centre and half extents of each sub-tile's axis-aligned box over its members'
            vertices (as :class:`TileHierarchy`'s, for :func:`_node_tests`).
    """

    tile_ptr: np.ndarray
    ptr: np.ndarray
    members: np.ndarray
    mid: np.ndarray
    half: np.ndarray


#: tiles with at least this many members are split into quarters (:class:`SubTiles`)
SUBTILE_FROM = 8


def build_subtiles(occ, poly_vertices: np.ndarray, poly_centers: np.ndarray) -> SubTiles:
    """The :class:`SubTiles` of ``occ``'s tiles (``poly_vertices (n, K, 3)``, padding repeating a vertex;
    ``poly_centers (n, 3)``): the tiles' own grid rule (:func:`.culling.grid_cells`) with 2 × 2 cells."""
    size = np.diff(occ.tile_ptr)
    order, start, tile = grid_cells(poly_centers[occ.tile_members], occ.tile_ptr[:-1],
                                    np.where(size >= SUBTILE_FROM, 2, 1))
    members = occ.tile_members[order]
    lo, hi = member_boxes(poly_vertices[members], start)
    tile_ptr = np.zeros(len(size) + 1, dtype=np.int64)
    np.add.at(tile_ptr, tile + 1, 1)
    return SubTiles(np.cumsum(tile_ptr), np.append(start, len(members)).astype(np.int64), members,
                    0.5 * (lo + hi), 0.5 * (hi - lo))


def refine_cut_tiles(st: SubTiles, tiles: TilePairs, sv, points) -> TilePairs:
    """``tiles`` (the pairs whose members become candidates) as (receiver, sub-tile) pairs, ``tile`` then
    a sub-tile of ``st``: a sub-tile that lies inside one of its tile's cutting volumes is dropped (every
    member is hidden), and a volume is dropped from a sub-tile's list when the sub-tile's box lies outside
    one of its planes (no member can be cut by it) — both with :func:`_node_tests`' margin, so that they
    are implied by the tests each member would take (its vertices lie in the box, its tolerance is
    smaller): the candidates' fragments are the same, fewer polygons and pairs cost them. Without a
    one-sided limit only (``sv.inf`` None)."""
    b, sub = expand(tiles.tile, st.tile_ptr, np.arange(len(st.mid)))
    eb, eq = expand(b, tiles.ptr, tiles.q)                   # (sub pair, volume) entries, the tile's lists
    keep = np.ones(len(b), dtype=bool)
    keep_e = np.ones(len(eb), dtype=bool)
    # only tiles split in several sub-tiles gain anything (a whole tile was tested already)
    pe = b[eb]
    test = np.flatnonzero(np.diff(st.tile_ptr)[tiles.tile[pe]] > 1)
    if len(test):
        covered, outside = _node_tests(st, sub[eb[test]], tiles.point[pe[test]], eq[test], sv, points)
        keep[eb[test[covered]]] = False
        keep_e[test[outside]] = False
    keep_e &= keep[eb]
    new = np.full(len(b), -1, dtype=np.int64)
    new[keep] = np.arange(int(keep.sum()))
    ptr = np.zeros(int(keep.sum()) + 1, dtype=np.int64)
    np.add.at(ptr, new[eb[keep_e]] + 1, 1)
    return TilePairs(tiles.point[b[keep]], sub[keep], tiles.tested[b[keep]], np.cumsum(ptr), eq[keep_e],
                     tiles.visited, tiles.nodes)


def _box_range(h: TileHierarchy, node, point, normal, offset, points):
    """Smallest and largest ``normal . x - offset`` over the boxes of ``node (E,)`` (P-local at receivers
    ``point (E,)``) for planes ``normal (E, J, 3)``, ``offset (E, J)``; with the boxes' largest |x|."""
    c = take_rows(h.mid, node) - take_rows(points, point)                           # (E, 3)
    hw = take_rows(h.half, node)
    centre = (normal[..., 0] * c[:, 0:1] + normal[..., 1] * c[:, 1:2] + normal[..., 2] * c[:, 2:3]) - offset
    spread = (np.abs(normal[..., 0]) * hw[:, 0:1] + np.abs(normal[..., 1]) * hw[:, 1:2]
              + np.abs(normal[..., 2]) * hw[:, 2:3])
    xmax = (np.abs(c) + hw).max(axis=1)
    return centre - spread, centre + spread, xmax


def _box_top(h: TileHierarchy, node, point, normals, points):
    """:func:`_box_range`'s largest height and ``xmax`` for the receivers' own tangent planes (``normals``
    (m, 3) at ``points``, offset 0), ``(E,)`` each: the same products in the same order, one column."""
    c = take_rows(h.mid, node) - take_rows(points, point)                           # (E, 3)
    hw = take_rows(h.half, node)
    nrm = take_rows(normals, point)
    top = nrm[:, 0] * c[:, 0] + nrm[:, 1] * c[:, 1] + nrm[:, 2] * c[:, 2]
    top += np.abs(nrm[:, 0]) * hw[:, 0] + np.abs(nrm[:, 1]) * hw[:, 1] + np.abs(nrm[:, 2]) * hw[:, 2]
    ac = np.abs(c)
    ac += hw
    return top, np.maximum(np.maximum(ac[:, 0], ac[:, 1]), ac[:, 2])


def _node_tests(h: TileHierarchy, node, point, q, sv, points):
    """Per (node, volume) entry: ``(covered, outside)`` bool, decided with :data:`NODE_MARGIN` (the
    exact minimum and maximum of each plane over the box; their rounding is far below the margin)."""
    normal, offset = sv.rows(q)
    smin, smax, xmax = _box_range(h, node, point, normal, offset, points)
    margin = NODE_MARGIN * PLANE_EPS * (xmax[:, None] + np.abs(offset))             # (E, J)
    return (smin > margin).all(axis=1), (smax < -margin).any(axis=1)


def _enclosures(sol, points, normals):
    """Faces of closed convex solids that enclose each receiver: ``(ptr (m+1,), out (U, 3), point (U, 3),
    tilt (U,), noise (U,), solid (U,), solid face (U,))`` CSR over receivers, for :func:`_enclosed`.

    A receiver P inside a closed convex solid S (every face plane has P strictly on its inner side, or
    contains P — then P lies on that face, and the receiver's normal is the face's inward normal, so
    beyond that plane is below the horizon) sees nothing outside S: a segment from P to a point x above
    the horizon and strictly beyond a face plane f with P strictly inside f leaves S at some t > 0
    (it stays in the half-spaces of the planes containing P) through a face of S, which is opaque.
    The rooms of closed scenes are such solids. Listed: the faces f with P strictly inside.
    """
    m = len(points)
    empty = (np.zeros(m + 1, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0),
             np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if sol is None or sol.n == 0 or m == 0 or sol.hole.all():
        return empty
    fs = sol.face_solid
    d = np.einsum("mfc,fc->mf", points[:, None] - sol.face_point[None], sol.face_out)   # out . (P - x_f)
    rel_c = sol.centers[None] - points[:, None]
    scale = (np.linalg.norm(rel_c, axis=2) + sol.radii[None])[:, fs]                 # (m, F)
    p_noise = COORD_EPS * np.abs(points).max(axis=1)[:, None]
    tol = 8.0 * ((PLANE_EPS + sol.face_tilt[None]) * scale + sol.face_noise[None] + p_noise)
    inside = d < -tol
    # on a face: to rounding only (a few ulp of the scale), with the receiver's normal the face's inward
    # normal to rounding: what lies beyond that plane is below the horizon (up to a 1e-14 sliver)
    on = np.abs(d) <= 1e-14 * scale + 4.0 * (sol.face_noise[None] + p_noise)
    inward = -sol.face_out
    cross = np.linalg.norm(np.cross(normals[:, None, :], inward[None]), axis=2)
    on &= (cross <= 1e-14) & (np.einsum("mc,fc->mf", normals, inward) > 0)
    starts = sol.face_ptr[:-1]
    ok = np.logical_and.reduceat(inside | on, starts, axis=1) & ~sol.hole[None]      # (m, n_s)
    ok &= ~sol.is_virtual()[None]             # inside a virtual solid, what lies between it and its surface shows
    use = inside & ok[:, fs]
    up, uf = np.nonzero(use)
    ptr = np.zeros(m + 1, dtype=np.int64)
    np.add.at(ptr, up + 1, 1)
    return (np.cumsum(ptr), sol.face_out[uf], sol.face_point[uf], sol.face_tilt[uf], sol.face_noise[uf],
            fs[uf], uf)


def _root_beyond(h: TileHierarchy, sol):
    """``(beyond (F, n_o), size (F, n_o))`` for every solid face f and merged face o: the largest signed
    distance beyond f's plane over o's root box (world space; -inf where o has no tiles) and the size of
    the coordinates it comes from (L1 norms); None for more than 2**22 entries. Cached on ``h``."""
    cached = getattr(h, "_root_beyond", None)
    if cached is not None and cached[0] is sol:
        return cached[1]
    n_f, n_o = len(sol.face_out), len(h.root)
    table = None
    if n_f * n_o <= 2**22:
        has = h.root >= 0
        r = np.maximum(h.root, 0)
        mid, half = h.mid[r], h.half[r]                                                # (n_o, 3)
        out, fpt = sol.face_out, sol.face_point                                        # (F, 3)
        beyond = out @ mid.T - (out * fpt).sum(axis=1)[:, None] + np.abs(out) @ half.T
        beyond[:, ~has] = -np.inf
        size = (np.abs(mid).sum(axis=1) + np.abs(half).sum(axis=1))[None, :] + np.abs(fpt).sum(axis=1)[:, None]
        table = (beyond, size)
    h._root_beyond = (sol, table)
    return table


def _enclosed(h: TileHierarchy, enc, face_solid, node, point, points):
    """(E,) bool: the box of ``node`` lies strictly beyond (by 8× the plane tolerance) a face of a solid
    enclosing receiver ``point`` (see :func:`_enclosures`): everything of it above the horizon is hidden.
    ``face_solid (n_o,)``: the solid each merged face belongs to (-1: none); a solid's own faces are
    never beyond its planes and are not tested."""
    ptr = enc[0]
    # entries whose receiver is enclosed only by their node's own solid have nothing to test: they are
    # left out before the (entry, face) expansion (in a closed room, every entry of the room's walls)
    m = len(ptr) - 1
    n_s = int(face_solid.max()) + 2
    own = np.bincount(np.repeat(np.arange(m), np.diff(ptr)) * n_s + enc[5] + 1, minlength=m * n_s)
    n_own = own.reshape(m, n_s)[point, face_solid[h.face[node]] + 1]   # (E,) of them the node's solid's (-1: 0)
    sel = np.flatnonzero(ptr[point + 1] - ptr[point] > n_own)
    b, u = expand(point[sel], ptr, np.arange(ptr[-1]))
    b = sel[b]
    other = face_solid[h.face[node[b]]] != enc[5][u]
    b, u = b[other], u[other]
    if len(enc) > 7 and enc[7] is not None and len(b):
        # a node's box lies in its face's root box; where that lies inside the face plane by far more than
        # the test's rounding (~1e-15 of the coordinates), the box's smallest distance beyond the plane
        # is < 0 < its tolerance at any receiver: not hit, and left out before the test
        beyond, size = enc[7]
        flat = enc[6][u] * h.root.shape[0] + h.face[node[b]]
        maybe = np.take(beyond, flat) + 1e-9 * (np.take(size, flat) + np.abs(points[point[b]]).sum(axis=1)) >= 0
        b, u = b[maybe], u[maybe]
    if not len(b):
        return np.zeros(len(node), dtype=bool)
    out, fpt, tilt, noise = enc[1][u], enc[2][u], enc[3][u], enc[4][u]
    nb, pb = node[b], point[b]
    smin, _, xmax = _box_range(h, nb, pb, out[:, None, :], (np.einsum("ec,ec->e", out, fpt - points[pb]))[:, None],
                               points)
    rel = take_rows(h.centers, nb) - take_rows(points, pb)
    scale = np.sqrt(np.einsum("ec,ec->e", rel, rel)) + h.radii[nb]
    p_noise = COORD_EPS * np.abs(points[pb]).max(axis=1)
    tol = 8.0 * ((PLANE_EPS + tilt) * np.maximum(scale, xmax) + noise + p_noise)
    hit = smin[:, 0] > tol
    out_b = np.zeros(len(node), dtype=bool)
    out_b[b[hit]] = True
    return out_b


def visit_tiles(h: TileHierarchy, occ, sv, table, cov, points, normals, tile_wanted=None, clear_test=None) -> TilePairs:
    """Traverse the hierarchy for every receiver of a chunk (see the module doc): the surviving tiles.

    Args:
        h: the scene's hierarchy; occ: its occluders; sv, table: the chunk's shadow volumes
            (:func:`.visibility.shadow_volumes`); cov: level 1 (:func:`.visibility.coverage`);
        points, normals: (m, 3) receivers; tile_wanted: (T,) bool tiles with a member to project, or
            None (all).
        clear_test: None, or ``clear_test(ep, en) -> (clear (E,), side (E,))`` for (receiver, inner node)
            entries with no cutting volume left (:func:`.far_field.clear_node_test`): clear nodes are not
            expanded but returned whole in ``nodes`` (only with a tolerance; None keeps the exact path).
    Returns:
        :class:`TilePairs` (``nodes = (point, node, side)`` of the clear nodes when ``clear_test`` is given).
    """
    m, n_o, n_t = len(points), occ.n, h.n_tiles
    empty = np.zeros(0, dtype=np.int64)
    if n_t == 0 or m == 0:
        nodes = None if clear_test is None else (empty, empty, np.zeros(0))
        return TilePairs(empty, empty, np.zeros(0, dtype=bool), np.zeros(1, dtype=np.int64), empty, 0, nodes)
    wanted = None
    if tile_wanted is not None:
        # a node is wanted when one of its tiles is (prefix sums over the tree order)
        csum = np.concatenate([[0], np.cumsum(tile_wanted[h.perm])])
        wanted = csum[h.last_tile] > csum[h.first_tile]
    # roots: every (receiver, face) whose cluster is not hidden
    ep, eo = np.nonzero(np.broadcast_to(h.root >= 0, (m, n_o)))
    k = table[ep, eo]
    if len(cov.cluster_covered):
        hid = (k >= 0) & np.append(cov.cluster_covered, False)[k]
        ep, eo, k = ep[~hid], eo[~hid], k[~hid]
    en = h.root[eo]
    n_cut = np.zeros(len(k), dtype=np.int64)
    has_k = np.flatnonzero(k >= 0)
    n_cut[has_k] = cov.k_ptr[k[has_k] + 1] - cov.k_ptr[k[has_k]]
    cut = h.tiled[eo] & (k >= 0) & (n_cut > 0)
    lb, lq = expand(np.where(cut, k, 0)[cut], cov.k_ptr, cov.kq)
    e_idx = np.flatnonzero(cut)
    lb = e_idx[lb]                                  # (entry, volume) list, volumes in cluster-list order
    enc = _enclosures(occ.solids, points, normals)
    if enc[0][-1]:
        enc = enc + (_root_beyond(h, occ.solids),)
    face_solid = np.full(n_o, -1, dtype=np.int64)
    if occ.solids is not None and occ.solids.n:
        real = occ.solids.face_occ >= 0                # (virtual solids' faces are no occluders)
        face_solid[occ.solids.face_occ[real]] = occ.solids.face_solid[real]
    leaves_p, leaves_t, leaves_cut, leaves_k, leaf_lb, leaf_lq = [], [], [], [], [], []
    node_p, node_n, node_s = [], [], []
    visited = 0
    while len(ep):
        visited += len(ep)
        # horizon: the node's sphere (which contains every tile's sphere) below it drops all its tiles
        rel = take_rows(h.centers, en) - take_rows(points, ep)
        height = np.einsum("ij,ij->i", rel, take_rows(normals, ep))
        dist = np.sqrt(np.einsum("ij,ij->i", rel, rel))
        r = h.radii[en]
        alive = height + r > -PLANE_EPS * (dist + r)
        # a node wholly in the receiver's tangent plane (a floor under a receiver on it): every member's
        # vertices are within its own on-plane tolerance PLANE_EPS (distance + radius) >= PLANE_EPS (the
        # box's distance + the smallest member radius) of it, so each is culled as seen edge-on; allowing
        # the box formula's rounding (a few ulp of the coordinates)
        live = np.flatnonzero(alive)
        if len(live):
            top, xmax = _box_top(h, en[live], ep[live], normals, points)
            near = np.maximum(dist[live] - r[live], 0.0)
            flat = top <= 0.5 * PLANE_EPS * (near + h.min_radius[en[live]]) - 1e-15 * xmax
            alive[live[flat]] = False
        if wanted is not None:
            alive &= wanted[en]
        if enc[0][-1]:
            live = np.flatnonzero(alive)
            alive[live[_enclosed(h, enc, face_solid, en[live], ep[live], points)]] = False
        leaf = en < n_t
        inner = alive & ~leaf
        # covered / outside for the (inner node, volume) entries
        if len(lb):
            sel = np.flatnonzero(inner[lb])
            drop_l = ~alive[lb]
            if len(sel):
                covered, outside = _node_tests(h, en[lb[sel]], ep[lb[sel]], lq[sel], sv, points)
                alive[lb[sel[covered]]] = False
                drop_l[sel[outside]] = True
            keep_l = ~drop_l & alive[lb]
            lb, lq = lb[keep_l], lq[keep_l]
        if clear_test is not None:
            # inner nodes with a face instance and no cutting volume left: whole, if the test says so
            free = np.flatnonzero(inner & alive & (k >= 0) & (np.bincount(lb, minlength=len(ep)) == 0))
            if len(free):
                ok, side = clear_test(ep[free], en[free])
                hit = free[ok]
                node_p.append(ep[hit])
                node_n.append(en[hit])
                node_s.append(side[ok])
                alive[hit] = False
        # leaves go out; inner nodes expand to their children
        out = np.flatnonzero(alive & leaf)
        if len(out):
            leaves_p.append(ep[out])
            leaves_t.append(en[out])
            leaves_cut.append(cut[out])
            leaves_k.append(k[out])
            pos = np.full(len(ep), -1)
            pos[out] = np.arange(len(out)) + sum(len(x) for x in leaves_p[:-1])
            on = pos[lb] >= 0
            leaf_lb.append(pos[lb[on]])
            leaf_lq.append(lq[on])
        go = np.flatnonzero(inner & alive)
        b, child = expand(en[go], h.child_ptr, h.child)
        # each child inherits its parent's volume list
        newpos = np.full(len(ep), -1)
        newpos[go] = np.arange(len(go))
        on = newpos[lb] >= 0
        plb, plq = newpos[lb[on]], lq[on]
        order = np.argsort(plb, kind="stable")
        plb, plq = plb[order], plq[order]
        pptr = np.zeros(len(go) + 1, dtype=np.int64)
        np.add.at(pptr, plb + 1, 1)
        pptr = np.cumsum(pptr)
        cb, lq = expand(b, pptr, plq)
        lb = cb
        ep, en, cut, k = ep[go][b], child, cut[go][b], k[go][b]
    nodes = None
    if clear_test is not None:
        nodes = (np.concatenate(node_p or [empty]), np.concatenate(node_n or [empty]),
                 np.concatenate(node_s or [np.zeros(0)]))
    if not leaves_p:
        return TilePairs(empty, empty, np.zeros(0, dtype=bool), np.zeros(1, dtype=np.int64), empty, visited, nodes)
    tp, tt = np.concatenate(leaves_p), np.concatenate(leaves_t)
    tcut, tk = np.concatenate(leaves_cut), np.concatenate(leaves_k)
    lb, lq = np.concatenate(leaf_lb), np.concatenate(leaf_lq)
    # level 1.5, exactly: each tested tile's box against the volumes left in its list
    hidden = np.zeros(len(tp), dtype=bool)
    if len(lb):
        uniq, inv = np.unique(lb, return_inverse=True)
        inv = inv.reshape(-1)
        t_rel = occ.tile_centers[tt[uniq]] - points[tp[uniq]]
        ax_t, half_t, _ = _cone(t_rel, occ.tile_radii[tt[uniq]])
        corners = occ.tile_corners[tt[uniq]] - points[tp[uniq]][:, None, :]
        t_inf = None if sv.inf is None else np.broadcast_to(sv.inf[tk[uniq]][:, :1], corners.shape).copy()
        kept, covd, _ = _test_pairs(inv, lq, corners, t_inf, np.full(len(uniq), 8), t_rel,
                                   occ.tile_radii[tt[uniq]], sv, ax_t, half_t, cov.ax_o, cov.half_o)
        hidden[uniq[inv[kept][covd]]] = True
        live = kept[~covd]
        lb, lq = uniq[inv[live]], lq[live]
    keep = ~hidden
    order = np.lexsort((tt, tp))
    order = order[keep[order]]
    newpos = np.full(len(tp), -1)
    newpos[order] = np.arange(len(order))
    on = newpos[lb] >= 0
    lb, lq = newpos[lb[on]], lq[on]
    srt = np.argsort(lb, kind="stable")
    ptr = np.zeros(len(order) + 1, dtype=np.int64)
    np.add.at(ptr, lb + 1, 1)
    return TilePairs(tp[order], tt[order], tcut[order], np.cumsum(ptr), lq[srt], visited, nodes)
