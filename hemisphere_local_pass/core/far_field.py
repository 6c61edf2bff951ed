"""Error-bounded far field: uniform faces as one polygon, clear tree nodes summed whole (over their welded
edges, or as a linear proxy), weak edges bounded.

Only with a user ``tolerance > 0`` (absolute, W m^-2, per channel; :func:`.local_pass.irradiance`); at
``tolerance = 0`` nothing here runs and the result is the exact path's, bit for bit. Half the tolerance
goes to the uniform-face proxies when there are any, the rest to the clear nodes: their linear proxies
take up to :data:`LINEAR_SHARE` of it (each within its own form factor's share), the edges left out what
the proxies leave; the bound actually used is returned per receiver (:class:`FarFieldStats`).

**Linear proxies** (:func:`node_fits`, :func:`linear_node_test`, :func:`linear_node_irradiance`). With
radiance that varies from polygon to polygon (a first-pass solution) few faces are uniform and few
welded edges cancel. A node whose members fill a few rectangles exactly gets the affine radiance fitted
to its members' values at their centroids; a receiver that sees the node whole takes ``π ∫ L_lin dF``
(a 3×3 Gauss rule per rectangle) less the staircase's sawtooth term, when the bound on what that misses
(the fit's residual against the kernel's Hessian, the sawtooth's remainder, the rule's own error) is
within the tolerance times a lower bound of the node's form factor: the nodes a receiver takes see
disjoint parts of its hemisphere, so their bounds sum to at most the tolerance.

**Uniform faces** (:func:`proxy_scene`). A merged face whose members' radiance range is small is
replaced by its one convex polygon with the mid-range radiance: same occluding geometry, error at most
``π Σ_f ½ range_f F_f`` (the proxies' visible form factors, computed with the rest).

**Clear nodes.** A clear tile (:mod:`.clear_tiles`) contributes ``Σ_i L_i F_i = side/2π · Σ_e W_e t_e``
over its welded edges, ``W_e = Σ_i σ_ei L_i``. The same holds for any set of coplanar polygons that are
all wholly visible and uncut from P: a node of the tile hierarchy (:mod:`.hierarchy`) whose box is above
the horizon, with P clearly on one side of its plane and no cutting volume left in its list, is summed
over the welded edges of *all* its members at once, and the traversal stops there. Welding the node's
tiles together cancels their shared boundaries: an edge between two members of equal radiance has
``W_e = L_a − L_b = 0`` exactly and is dropped when the lists are built (its term is exactly zero), so a
wall of constant radiance costs its outline, not its 25,600 quads. The lists are built bottom-up
(:func:`node_edges`); a node is given one only when welding shortens its children's lists to at most
:data:`SHRINK` of their total (memory stays O(edges)); other nodes are traversed as before.

**The bound.** What welding leaves is summed exactly except the *weak* edges, ``|W_e|`` small: eq. 4's
term obeys ``|t_e| <= θ_e <= len_e / d`` (θ_e the angle the edge subtends at P, d the distance from P to
the node's bounding sphere), so leaving out a set S of edges changes ``H = π Σ L_i F_i = ½ Σ_e W_e t_e``
by at most ``½ Σ_{e∈S} |W_e,c| len_e / d`` in channel c. Each node's list is sorted by ``max_c |W_e,c|
len_e``; a (receiver, node) pair may leave out the longest prefix of its list whose bound fits its share
of the tolerance (the edges' half of the receiver's tolerance split evenly over its clear pairs), and
the bound it used is returned. A bright patch among dim ones, a chequerboard, or a receiver close to
the node gets no skip: its bound would not fit.

**Never dearer than exact where it saves nothing.** A proxy is tested only where a necessary condition
on the distance says it can pass (:func:`linear_may_fit`), and a clear tile whose welded list would sum
about as many edges as the tile has is summed over its tile edges as the exact path sums them
(:func:`_tile_sums`, :data:`PLAIN_RATIO`), nothing skipped.

The returned bound per receiver and channel is the sum of the pairs' bounds plus a rounding allowance
(:data:`ROUNDING`, relative to ``½ Σ |W_e,c t_e|`` of the terms summed): the welded sum adds the same
terms in another order than the exact path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .clear_tiles import SIDE_MARGIN
from .csr import expand
from .rowops import unique_rows
from .scene import Scene
from .tolerances import COORD_EPS, PLANE_EPS

__all__ = ["FarFieldStats", "NodeEdges", "ProxyCredit", "clear_node_test", "far_field_irradiance", "node_edges",
           "proxy_scene"]

#: a node gets its own welded list only when it has at most this fraction of its children's edges
SHRINK = 0.75
#: relative rounding allowance on ``½ Σ |W t|`` per receiver: the welded and the per-tile sums add the
#: same terms in different orders (each sum within n u Σ|terms|, n <= 10^5 terms, u = 1.1e-16)
ROUNDING = 2.0**-33
#: the bounds are computed in floating point: scale them up by this much, and spend at most this
#: fraction less than the tolerance
SAFETY = 1e-9
#: the node-level side test asks for this multiple of the tile-level margin (see :func:`clear_node_test`)
NODE_SIDE_FACTOR = 4.0
#: a clear tile is summed as the exact path sums it (nothing skipped) when its tile edges are at most this
#: many times what its welded list would sum (the welded sum costs ~1.2× per edge: it also sums magnitudes)
PLAIN_RATIO = 1.2


@dataclass
class FarFieldStats:
    """What a call of :func:`.local_pass.irradiance` with ``return_stats=True`` bounded.

    Attributes:
        tolerance: (3,) the absolute tolerance asked for (W m^-2 per channel).
        error_bound: (m, 3) bound on ``|H − H_exact|`` per receiver and channel: what the far field left
            out plus the rounding allowance (0 at tolerance 0, where H is exact).
        edges_skipped, edges_summed: (m,) welded edges left out (bounded) and summed per receiver by the
            far field (0 at tolerance 0); clear_nodes: (m,) hierarchy nodes above the tiles summed whole;
        linear_proxies: (m,) nodes and tiles summed as their linear proxy (:func:`linear_node_test`).
    """

    tolerance: np.ndarray
    error_bound: np.ndarray
    edges_skipped: np.ndarray | None = None
    edges_summed: np.ndarray | None = None
    clear_nodes: np.ndarray | None = None
    linear_proxies: np.ndarray | None = None

    @property
    def max_error_bound(self) -> float:
        """The largest bound over receivers and channels."""
        return float(self.error_bound.max(initial=0.0))


@dataclass
class NodeEdges:
    """Welded edges of the members of every hierarchy node (``N`` nodes: leaves are the tiles).

    Attributes:
        ptr: (N+1,) CSR ranges of each node's edges, sorted by ``max_c |W_e,c| len_e`` (ascending);
            nodes without a list (``usable`` False) have an empty range.
        a_xyz, b_xyz: (3, E) end points; weight: (E, 6) ``W_e`` and ``V_e`` (the same fold of the
            proxies' half radiance ranges, :func:`proxy_scene`; zero without proxies), never all zero;
            mass: (E, 3) the inclusive prefix sums, within each node's list, of ``(|W_e,c| + |V_e,c|) len_e``.
        usable: (N,) node may be summed as a whole (a list, every tile eligible).
        normal, point: (N, 3) a plane of the node's members (its first tile's); tilt, noise: (N,) the
            members' largest plane uncertainties; dn, d0: (N,) how far the tiles' planes can be from
            the node's: ``|d_t(x) − d_v(x)| <= dn |x − c_v| + d0`` for the signed distances d of any x.
        fit: the nodes' linear proxies (:class:`NodeFits`, :func:`node_fits`).
    """

    ptr: np.ndarray
    a_xyz: np.ndarray
    b_xyz: np.ndarray
    weight: np.ndarray
    mass: np.ndarray
    usable: np.ndarray
    normal: np.ndarray
    point: np.ndarray
    tilt: np.ndarray
    noise: np.ndarray
    dn: np.ndarray
    d0: np.ndarray
    fit: NodeFits | None = None


def _levels(h) -> np.ndarray:
    """(N,) height of every node above the leaves (children have lower ids than their parent)."""
    n = len(h.radii)
    level = np.zeros(n, dtype=np.int64)
    n_child = np.diff(h.child_ptr)
    inner = np.flatnonzero(n_child > 0)
    parent = np.repeat(np.arange(n), n_child)
    while True:
        new = np.zeros(n, dtype=np.int64)
        np.maximum.at(new, parent, level[h.child] + 1)
        new[n_child == 0] = 0
        if np.array_equal(new, level):
            return level
        level = new
        if not len(inner):
            return level


def _weld(node, ga, gb, w):
    """Sum ``w (R, C)`` over equal ``(node, ga, gb)`` (ga < gb) and drop the sums that are zero."""
    if not len(node):
        return node, ga, gb, w
    uniq, inv = unique_rows(np.column_stack([node, ga, gb]))
    ws = np.zeros((len(uniq), w.shape[1]))
    for c in range(w.shape[1]):
        ws[:, c] = np.bincount(inv, weights=w[:, c], minlength=len(uniq))
    keep = (ws != 0.0).any(axis=1)
    return uniq[keep, 0], uniq[keep, 1], uniq[keep, 2], ws[keep]


def _segment_prefix(values: np.ndarray, seg_start: np.ndarray) -> np.ndarray:
    """Inclusive prefix sums of ``values (E, 3)`` (>= 0) within segments; ``seg_start (E,)`` the index of
    each element's segment start. Hillis–Steele doubling: every sum only adds elements of its own segment
    (log2 of the longest segment passes), so its rounding is relative to the segment's own sums."""
    out = values.copy()
    idx = np.arange(len(values))
    shift = 1
    while True:
        src = idx - shift
        ok = src >= seg_start
        if not ok.any():
            return out
        add = np.zeros_like(out)
        add[ok] = out[src[ok]]
        out = out + add
        shift *= 2


def node_edges(scene, occ, h, te) -> NodeEdges:
    """The :class:`NodeEdges` of hierarchy ``h`` over occluders ``occ`` with tile edges ``te``
    (:func:`.clear_tiles.tile_edges`; constant radiance only)."""
    n_nodes, n_t = len(h.radii), h.n_tiles
    # weld every tile's vertices across the whole scene (te welds within each tile)
    _, gv = unique_rows(te.vertices)
    ga, gb = gv[te.edge_a], gv[te.edge_b]
    flip = ga > gb
    w6 = np.zeros((len(ga), 6))
    w6[:, :3] = te.weight
    half = getattr(scene, "_half_range", None)
    if half is not None:
        # the proxies' half radiance ranges folded into their edges as the weights are (for the bound)
        e_glob = te.edge_ptr[np.repeat(np.arange(n_t), np.diff(te.inc_ptr))] + te.inc_edge
        np.add.at(w6[:, 3:], e_glob, te.inc_sign[:, None] * half[te.inc_poly])
    w = np.where(flip[:, None], -w6, w6)
    ga, gb = np.minimum(ga, gb), np.maximum(ga, gb)
    tile_of = np.repeat(np.arange(n_t), np.diff(te.edge_ptr))
    lists = [_weld(tile_of, ga, gb, w)]                       # level 0: the tiles, zero weights dropped
    count = np.zeros(n_nodes, dtype=np.int64)
    count[:n_t] = np.bincount(lists[0][0], minlength=n_t)
    usable = np.zeros(n_nodes, dtype=bool)
    usable[:n_t] = te.eligible
    # the tiles' plane data, aggregated upward
    normal = np.zeros((n_nodes, 3))
    point = np.zeros((n_nodes, 3))
    tilt = np.zeros(n_nodes)
    noise = np.zeros(n_nodes)
    dn = np.zeros(n_nodes)
    d0 = np.zeros(n_nodes)
    normal[:n_t], point[:n_t], tilt[:n_t], noise[:n_t] = te.plane_normal, te.plane_point, te.plane_tilt, te.plane_noise
    level = _levels(h)
    n_child = np.diff(h.child_ptr)
    # each edge's owner per level: the current lists' nodes
    for lv in range(1, int(level.max(initial=0)) + 1):
        par = np.flatnonzero(level == lv)
        b, ch = expand(par, h.child_ptr, h.child)
        pv = par[b]
        # plane of the parent: its first child's (down to its first tile), spreads by the triangle rule
        first = ch[np.r_[0, np.cumsum(n_child[par])[:-1]]]
        normal[par], point[par] = normal[first], point[first]
        np.maximum.at(tilt, pv, tilt[ch])
        np.maximum.at(noise, pv, noise[ch])
        dnn = np.linalg.norm(normal[ch] - normal[pv], axis=1)
        np.maximum.at(dn, pv, dn[ch] + dnn)
        cdist = np.linalg.norm(h.centers[pv] - h.centers[ch], axis=1)
        gap = np.abs(np.einsum("ij,ij->i", normal[ch], h.centers[pv] - point[ch])
                     - np.einsum("ij,ij->i", normal[pv], h.centers[pv] - point[pv]))
        np.maximum.at(d0, pv, d0[ch] + dn[ch] * cdist + gap)
        # welded lists: only for parents whose children all have one
        all_ok = np.ones(n_nodes, dtype=bool)
        np.logical_and.at(all_ok, pv, usable[ch])
        use = all_ok[pv]
        if not use.any():
            continue
        cand = np.unique(pv[use])
        parent_of = np.full(n_nodes, -1, dtype=np.int64)
        parent_of[ch[use]] = pv[use]
        child_total = np.zeros(n_nodes, dtype=np.int64)
        np.add.at(child_total, pv[use], count[ch[use]])
        cat_node = np.concatenate([x[0] for x in lists])
        take = parent_of[cat_node] >= 0
        nd, a2, b2, w2 = _weld(parent_of[cat_node[take]], np.concatenate([x[1] for x in lists])[take],
                               np.concatenate([x[2] for x in lists])[take], np.concatenate([x[3] for x in lists])[take])
        got = np.bincount(nd, minlength=n_nodes)
        good = np.zeros(n_nodes, dtype=bool)
        good[cand] = got[cand] <= SHRINK * child_total[cand]
        keep = good[nd]
        lists.append((nd[keep], a2[keep], b2[keep], w2[keep]))
        count[cand] = got[cand]
        usable[cand] = good[cand]
    # every tile of a usable node must be eligible (leaves: te.eligible; parents: by construction)
    nd = np.concatenate([x[0] for x in lists])
    ga = np.concatenate([x[1] for x in lists])
    gb = np.concatenate([x[2] for x in lists])
    w = np.concatenate([x[3] for x in lists])
    keep = usable[nd]
    nd, ga, gb, w = nd[keep], ga[keep], gb[keep], w[keep]
    verts = unique_rows(te.vertices)[0]
    a, b = verts[ga], verts[gb]
    length = np.linalg.norm(b - a, axis=1)
    m = (np.abs(w[:, :3]) + np.abs(w[:, 3:])) * length[:, None]
    order = np.lexsort((m.max(axis=1), nd))
    nd, a, b, w, m = nd[order], a[order], b[order], w[order], m[order]
    ptr = np.zeros(n_nodes + 1, dtype=np.int64)
    ptr[1:] = np.cumsum(np.bincount(nd, minlength=n_nodes))
    mass = _segment_prefix(m, ptr[nd])
    return NodeEdges(ptr, np.ascontiguousarray(a.T), np.ascontiguousarray(b.T), w, mass, usable, normal, point,
                     tilt, noise, dn, d0, node_fits(scene, occ, h, te.eligible))


def clear_node_test(ne: NodeEdges, h, points, normals, ep, en, tolerance=None, credit=None):
    """For (receiver, inner node) entries ``ep, en (E,)`` whose face has a volume instance and whose list
    of cutting volumes is empty: ``(clear (E,) bool, side (E,) float ±1)`` (side 0 where not tested).

    A clear node is summed whole: over its welded list (``ne.usable``), or by its linear proxy when that
    fits :data:`LINEAR_SHARE` of ``tolerance`` (3,) (:func:`linear_node_test`; None: lists only).

    Clear: every tile below the node would be a clear tile (:func:`.clear_tiles.clear_pairs`) — its box's
    corners are above the horizon by more than the flat and below-horizon tolerances of the tiles' tests
    (PLANE_EPS × (distance + 2 radius) of the node: a tile's are no larger), and P is off every tile's
    plane by more than :data:`NODE_SIDE_FACTOR` times the tile test's margin, the tiles' plane spread
    (``dn``, ``d0``) included.
    """
    # only nodes with a list, or a proxy that can fit here, are tested (side is 0 for the others)
    ok = np.zeros(len(en), dtype=bool)
    side = np.zeros(len(en))
    lin = np.zeros(len(en), dtype=bool)
    if tolerance is not None and ne.fit is not None:
        c = np.flatnonzero(~ne.usable[en] & ne.fit.ok[en])
        lin[c[linear_may_fit(ne.fit, h, points, ep[c], en[c], LINEAR_SHARE * np.asarray(tolerance))]] = True
    sel = np.flatnonzero(ne.usable[en] | lin)
    if not len(sel):
        return ok, side
    ep, en, lin = ep[sel], en[sel], lin[sel]
    pts = np.take(points, ep, axis=0)
    nr = np.take(normals, ep, axis=0)
    px, py, pz = pts[:, 0], pts[:, 1], pts[:, 2]
    nx, ny, nz = nr[:, 0], nr[:, 1], nr[:, 2]
    # the box's lowest corner above P's horizon and its largest coordinate, corner by corner along the
    # entries (components, not (E, 8, 3) rows: see .rowops)
    ct = np.take(_corner_columns(h), en, axis=1)                             # (24, E)
    height = big = None
    for j in range(8):
        cx, cy, cz = ct[3 * j] - px, ct[3 * j + 1] - py, ct[3 * j + 2] - pz
        hj = cx * nx + cy * ny + cz * nz
        mj = np.maximum(np.maximum(np.abs(cx), np.abs(cy)), np.abs(cz))
        if height is None:
            height, big = hj, mj
        else:
            np.minimum(height, hj, out=height)
            np.maximum(big, mj, out=big)
    cen = np.take(h.centers, en, axis=0)
    rx, ry, rz = cen[:, 0] - px, cen[:, 1] - py, cen[:, 2] - pz
    dist = np.sqrt(rx * rx + ry * ry + rz * rz)
    r = h.radii[en]
    scale = dist + r
    geo = height > PLANE_EPS * (scale + r) + 1e-15 * big
    nv = np.take(ne.normal, en, axis=0)
    nq = np.take(ne.point, en, axis=0)
    d = nv[:, 0] * (nq[:, 0] - px) + nv[:, 1] * (nq[:, 1] - py) + nv[:, 2] * (nq[:, 2] - pz)
    far = np.maximum(np.maximum(np.abs(px), np.abs(py)), np.abs(pz))
    plane_tol = (PLANE_EPS + ne.tilt[en]) * scale + ne.noise[en] + COORD_EPS * far
    spread = ne.dn[en] * dist + ne.d0[en]
    geo &= np.abs(d) - spread > NODE_SIDE_FACTOR * (SIDE_MARGIN * scale + 4.0 * plane_tol)
    ok_s = geo & ne.usable[en]
    cand = np.flatnonzero(geo & lin)
    if len(cand):
        share = LINEAR_SHARE * np.broadcast_to(np.asarray(tolerance, dtype=np.float64), (3,))
        fits, b, floor = linear_node_test(ne.fit, h, points, normals, ep[cand], en[cand], share, return_floor=True)
        if credit is not None:
            fits = credit.spend(ne, h, ep[cand], en[cand], fits, b, floor, share)
        ok_s[cand] = fits
    ok[sel] = ok_s
    side[sel] = np.sign(d)
    return ok, side



def _corner_columns(h) -> np.ndarray:
    """(24, N): the hierarchy's box corners, corner j's x, y, z in rows 3j .. 3j + 2 (cached on ``h``)."""
    cached = getattr(h, "_corner_columns", None)
    if cached is None or cached[0] is not h.corners:
        cached = (h.corners, np.ascontiguousarray(h.corners.reshape(len(h.corners), 24).T))
        h._corner_columns = cached
    return cached[1]


class ProxyCredit:
    """Per receiver of one traversal: the proxies' bounds spent so far ``spent (m, 3)`` and the lower bounds
    of their form factors ``floor (m,)``; ``free (m,)`` the receivers whose nodes may be taken (or None).

    The proxies a receiver takes see disjoint parts of its hemisphere, so those still to come (each
    within ``share × F_lower``, :func:`linear_node_test`) sum to at most ``share × (1 − Σ_taken F_v) <=
    share × (1 − floor)``. While ``spent <= share × floor`` (per channel), every proxy taken and to come
    sums to at most ``share``: a node whose bound exceeds its own share may be taken on the credit that
    nodes below theirs left (:meth:`spend`), the coarsest first (the traversal is breadth first)."""

    def __init__(self, m: int, free=None):
        self.spent = np.zeros((m, 3))
        self.floor = np.zeros(m)
        self.free = free

    def spend(self, ne, h, ep, en, fits, bound, floor, share):
        """``fits (E,)`` with the nodes taken on credit added (only nodes without a welded list: the far
        field takes those as given, :func:`far_field_irradiance`); the taken ones are booked."""
        m = len(self.floor)
        if self.free is not None:
            fits = fits & self.free[ep]
        for c in range(3):
            self.spent[:, c] += np.bincount(ep[fits], weights=bound[fits, c], minlength=m)
        self.floor += np.bincount(ep[fits], weights=floor[fits], minlength=m)
        sc = np.flatnonzero(~fits & np.isfinite(bound).all(axis=1) & ~ne.usable[en]
                            & (True if self.free is None else self.free[ep]))
        if not len(sc):
            return fits
        excess = bound[sc] - share[None, :] * floor[sc, None]                      # (S, 3)
        room = share[None, :] * self.floor[:, None] * (1.0 - SAFETY) - self.spent  # (m, 3)
        work = (h.last_tile[en[sc]] - h.first_tile[en[sc]]).astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            key = np.where(share > 0, np.maximum(excess, 0.0) / np.where(share > 0, share, 1.0), np.inf).max(axis=1)
        order = np.lexsort((key / work, ep[sc]))
        sc, excess = sc[order], excess[order]
        rp = ep[sc]
        first = np.flatnonzero(np.r_[True, rp[1:] != rp[:-1]])
        size = np.diff(np.r_[first, len(sc)])
        run = np.cumsum(excess, axis=0)
        run -= np.repeat(np.r_[np.zeros((1, 3)), run[first[1:] - 1]], size, axis=0)
        # every prefix within the credit (the accepted set as a whole then is)
        bad = ~(run <= room[rp]).all(axis=1)
        grp = np.repeat(np.arange(len(first)), size)
        stop = np.full(len(first), len(sc))
        np.minimum.at(stop, grp[bad], np.flatnonzero(bad))
        acc = sc[np.arange(len(sc)) < stop[grp]]
        for c in range(3):
            self.spent[:, c] += np.bincount(ep[acc], weights=bound[acc, c], minlength=m)
        self.floor += np.bincount(ep[acc], weights=floor[acc], minlength=m)
        fits = fits.copy()
        fits[acc] = True
        return fits


def far_field_irradiance(ne: NodeEdges, h, point, node, side, points, normals, tolerance, te=None):
    """``H`` of the clear nodes and tiles ``(point (P,), node (P,), side (P,) ±1)`` (the lit ones) and its
    bound.

    Args:
        ne: the scene's :class:`NodeEdges`; h: its hierarchy (bounding spheres); point, node: the
            pairs; points, normals: (m, 3) receivers; tolerance: (3,) absolute tolerance on H; te: the
            scene's :class:`.clear_tiles.TileEdges` (or None): a tile without uniform-face proxies whose
            tile edges are at most :data:`PLAIN_RATIO` times what its welded list would sum (after the
            edges it may skip) is summed over them, nothing skipped, as the exact path sums it (cheaper
            per edge: no magnitudes).
    Returns:
        ``H (m, 3)`` (W m^-2, the ``π ·`` of eq. 3 included), ``bound (m, 3)`` (see the module doc),
        ``skipped (m,)`` edges left out, ``summed (m,)`` edges computed and ``linear (m,)`` linear
        proxies taken per receiver.
    """
    m = len(points)
    out = np.zeros((m, 3))
    bound = np.zeros((m, 3))
    if not len(point):
        return out, bound, np.zeros(m), np.zeros(m), np.zeros(m)
    tol = np.broadcast_to(np.asarray(tolerance, dtype=np.float64), (3,))
    # linear proxies: nodes without a list that the traversal took for their proxy, and nodes and tiles
    # whose proxy fits and is shorter than their list
    h_lin = np.zeros((m, 3))
    b_lin = np.zeros((m, 3))
    n_lin = np.zeros(m)
    if ne.fit is not None:
        n_list = ne.ptr[node + 1] - ne.ptr[node]
        forced = ~ne.usable[node] & ne.fit.ok[node]
        cand = np.flatnonzero(ne.fit.ok[node] & ((n_list > LINEAR_EDGES) | forced))
        # the full test only where it can pass (or the traversal already took the proxy)
        cand = cand[forced[cand] | linear_may_fit(ne.fit, h, points, point[cand], node[cand], LINEAR_SHARE * tol)]
        fits, lb = linear_node_test(ne.fit, h, points, normals, point[cand], node[cand], LINEAR_SHARE * tol)
        take = fits | forced[cand]
        sel, lb = cand[take], lb[take]
        lin = np.zeros(len(point), dtype=bool)
        lin[sel] = True
        if len(sel):
            hl, rnd = linear_node_irradiance(ne.fit, point[sel], node[sel], points, normals)
            for c in range(3):
                h_lin[:, c] = np.bincount(point[sel], weights=hl[:, c], minlength=m)
                b_lin[:, c] = np.bincount(point[sel], weights=lb[:, c] + rnd[:, c], minlength=m)
            n_lin = np.bincount(point[sel], minlength=m).astype(np.float64)
            point, node, side = point[~lin], node[~lin], side[~lin]
    if not len(point):
        return h_lin, b_lin, np.zeros(m), np.zeros(m), n_lin
    # the edges left out: what the proxies left of the tolerance, split evenly over the receiver's pairs
    n_pairs = np.bincount(point, minlength=m)
    rest = np.maximum(tol[None, :] * (1.0 - SAFETY) - b_lin, 0.0)
    share = rest[point] / np.maximum(n_pairs[point], 1)[:, None]                               # (P, 3)
    rel = h.centers[node] - points[point]
    d = np.sqrt(np.einsum("ij,ij->i", rel, rel)) - h.radii[node]
    start, n_e = ne.ptr[node], ne.ptr[node + 1] - ne.ptr[node]
    # longest prefix with ½ mass / d × (1 + SAFETY) <= share in every channel: binary search per pair
    limit = np.where(d[:, None] > 0, 2.0 * share * np.maximum(d, 0.0)[:, None] / (1.0 + SAFETY), -1.0)
    # (only over the pairs whose first edge fits: the others skip nothing)
    skip = np.zeros(len(node), dtype=np.int64)
    srch = np.flatnonzero((n_e > 0) & (ne.mass[np.minimum(start, max(len(ne.mass) - 1, 0))] <= limit).all(axis=1)) \
        if len(ne.mass) else np.zeros(0, dtype=np.int64)
    lo = np.ones(len(srch), dtype=np.int64)            # skippable count: mass[start + lo - 1] fits
    hi = n_e[srch]
    s_start, s_limit = start[srch], limit[srch]
    while True:
        act = lo < hi
        if not act.any():
            break
        mid = (lo + hi + 1) // 2
        fits = act & (ne.mass[s_start + mid - 1] <= s_limit).all(axis=1)
        lo = np.where(fits, mid, lo)
        hi = np.where(act & ~fits, mid - 1, hi)
    skip[srch] = lo
    # without proxies only W's three columns are gathered (contiguous, with their magnitudes)
    has_v, w_cols, w_abs, no_v = _weights(ne)
    plain = np.zeros(len(node), dtype=bool)
    if te is not None:
        # tiles whose welded list, less what it may skip, is not much shorter than their tile edges: the
        # exact path's own sums over all of these (cheaper per edge), nothing skipped
        n_te = np.diff(te.edge_ptr)[np.minimum(node, len(te.edge_ptr) - 2)]
        plain = (node < h.n_tiles) & no_v[node] & (n_te > 0) & (n_te <= PLAIN_RATIO * (n_e - skip))
        skip[plain] = 0
    used = np.where(skip[:, None] > 0, ne.mass[np.maximum(start + skip - 1, 0)], 0.0)
    pair_bound = 0.5 * used / np.where(d > 0, d, 1.0)[:, None] * (1.0 + SAFETY)
    for c in range(3):
        bound[:, c] = np.bincount(point, weights=pair_bound[:, c], minlength=m)
    n_run = n_e - skip
    summed = np.bincount(point, weights=n_run, minlength=m)
    skipped = np.bincount(point, weights=skip, minlength=m)
    mag = np.zeros((m, 3))
    if plain.any():
        out, mag = _tile_sums(te, point[plain], node[plain], side[plain], points, normals, m)
        summed += np.bincount(point[plain], weights=n_te[plain] - n_run[plain], minlength=m)
        keep = ~plain
        point, node, side, start, skip, n_run = (x[keep] for x in (point, node, side, start, skip, n_run))
    # the remaining edges, in batches of about 2**14 terms
    ends = np.cumsum(n_run)
    cuts = np.searchsorted(ends, np.arange(2**14, ends[-1] if len(ends) else 0, 2**14), side="right")
    bounds_ = np.unique(np.concatenate([[0], cuts, [len(node)]]))
    vsum = np.zeros((m, 3))
    px_all = [np.ascontiguousarray(points[:, i]) for i in range(3)]
    nx_all = [np.ascontiguousarray(normals[:, i]) for i in range(3)]
    for s, e in zip(bounds_[:-1], bounds_[1:]):
        cnt = n_run[s:e]
        b = np.repeat(np.arange(s, e), cnt)
        pos = np.arange(len(b)) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(start[s:e] + skip[s:e], cnt)
        p = point[b]
        px, py, pz = (x[p] for x in px_all)
        ax, ay, az = ne.a_xyz[0][pos] - px, ne.a_xyz[1][pos] - py, ne.a_xyz[2][pos] - pz
        bx, by, bz = ne.b_xyz[0][pos] - px, ne.b_xyz[1][pos] - py, ne.b_xyz[2][pos] - pz
        ex, ey, ez = bx - ax, by - ay, bz - az
        cx = ay * ez - az * ey
        cy = az * ex - ax * ez
        cz = ax * ey - ay * ex
        sn = np.sqrt(cx * cx + cy * cy + cz * cz)
        dd = ax * bx + ay * by + az * bz
        ratio = np.divide(np.arctan2(sn, dd), sn, out=np.zeros_like(sn), where=sn > 0.0)
        nx, ny, nz = (x[p] for x in nx_all)
        t = (cx * nx + cy * ny + cz * nz) * ratio
        # per pair (its edges are consecutive), then per receiver
        run = np.flatnonzero(cnt > 0)
        first = (np.cumsum(cnt) - cnt)[run]
        per = np.add.reduceat(t[:, None] * w_cols[pos], first, axis=0) * side[s:e][run, None]   # (P', 6 or 3)
        per_mag = np.add.reduceat(np.abs(t)[:, None] * w_abs[pos], first, axis=0)
        pp = point[s:e][run]
        np.add.at(out, pp, per[:, :3])
        np.add.at(mag, pp, per_mag)
        if has_v:
            np.add.at(vsum, pp, per[:, 3:])
    # H = π × side/2π × Σ W t
    out *= 0.5
    # the proxies' radiance bound: π Σ ½ range F over clear proxies, = ½ Σ side V t (>= 0 exactly)
    bound += ROUNDING * 0.5 * mag + 0.5 * np.abs(vsum) * (1.0 + SAFETY)
    return out + h_lin, bound + b_lin, skipped, summed, n_lin


#: the traversal takes nodes on the credit their receiver's earlier proxies left (:class:`ProxyCredit`)
PROXY_CREDIT = True
def _tile_sums(te, point, tile, side, points, normals, m):
    """``Σ side W_e t_e`` of clear tiles ``(point, tile, side) (P,)`` over their tile edges, as the exact path
    sums them (:func:`.clear_tiles.clear_irradiance`: the same edge terms, the same per-pair sums, bit for
    bit), and ``Σ |per-pair sum|`` per receiver: ``(m, 3)`` each. Only the sums over the pairs differ from the
    exact path's (other pairs in between): their rounding is within ``ROUNDING × ½ Σ |per pair|`` of H."""
    from .clear_tiles import ClearPairs, _batches, _edge_terms

    out = np.zeros((m, 3))
    mag = np.zeros((m, 3))
    pairs = ClearPairs(point, tile, side, np.arange(len(point)))
    for sub in _batches(te, pairs):
        _, e, t = _edge_terms(te, sub, points, normals)
        n_edges = np.diff(te.edge_ptr)[sub.tile]
        starts = np.cumsum(n_edges) - n_edges
        for c in range(3):
            # one channel at a time, as clear_irradiance: contiguous gathers, the same per-pair sums
            per_pair = np.add.reduceat(t * np.take(te.w_cols[c], e), starts)                     # (P',)
            out[:, c] += np.bincount(sub.point, weights=sub.side * per_pair, minlength=m)
            mag[:, c] += np.bincount(sub.point, weights=np.abs(per_pair), minlength=m)
    return out, mag


def _weights(ne: NodeEdges):
    """``(has_v, W (E, 6) or (E, 3), |W[:, :3]| (E, 3), no_v (N,))`` for the edge sums: some edge has a proxy
    weight V (:func:`proxy_scene`); the weights to gather (W's three columns alone, contiguous, without);
    the nodes whose list has no V; cached on ``ne``."""
    cached = getattr(ne, "_w3", None)
    if cached is None:
        v_edge = (ne.weight[:, 3:] != 0).any(axis=1)
        has_v = bool(v_edge.any())
        n_nodes = len(ne.ptr) - 1
        owner = np.repeat(np.arange(n_nodes), np.diff(ne.ptr))
        no_v = np.bincount(owner[v_edge], minlength=n_nodes) == 0
        cached = (has_v, ne.weight if has_v else np.ascontiguousarray(ne.weight[:, :3]), np.abs(ne.weight[:, :3]),
                  no_v)
        ne._w3 = cached
    return cached


def _face_ranges(scene, occ):
    """Per merged face: ``lo, hi (n_o, 3)`` its members' smallest and largest radiance, ``size (n_o,)`` its
    members, ``dirty (n_o,)`` a member has a copy or a coplanar overlap (cached on the scene)."""
    cached = getattr(scene, "_face_ranges", None)
    if cached is not None and cached[0] is occ:
        return cached[1]
    mem = occ.members
    n, n_o = scene.n_polygons, occ.n
    copies = np.bincount(scene.dup_rep, minlength=n)
    clean = (scene.dup_rep == np.arange(n)) & (copies == 1) & (np.diff(occ.coplanar_ptr) == 0)
    sel = np.flatnonzero(mem >= 0)
    order = sel[np.argsort(mem[sel], kind="stable")]
    face = mem[order]
    size = np.bincount(face, minlength=n_o)
    lo = np.full((n_o, 3), np.inf)
    hi = np.full((n_o, 3), -np.inf)
    if len(order):
        starts = np.flatnonzero(np.r_[True, face[1:] != face[:-1]])
        rad = scene.poly_radiance[order]
        lo[face[starts]] = np.minimum.reduceat(rad, starts, axis=0)
        hi[face[starts]] = np.maximum.reduceat(rad, starts, axis=0)
    dirty = np.bincount(face, weights=~clean[order], minlength=n_o) > 0
    out = (lo, hi, size, dirty)
    scene._face_ranges = (occ, out)
    return out


#: proxy scenes kept per scene (one per set of qualifying faces, the latest first)
PROXY_KEEP = 2


def proxy_scene(scene, occ, tolerance):
    """The scene with every nearly uniform merged face replaced by one polygon, and its radiance bound.

    A merged face (:func:`.culling.build_occluders`: coplanar, edge-connected convex polygons that tile
    one convex polygon exactly; not a convex core, ``occ.hull_cores``) whose members' radiance spans
    ``range_c <= 2 tolerance_c / π`` in every channel, with no duplicate or coplanar-overlapping member,
    is replaced by that convex polygon with the mid-range radiance. The occluding geometry is the same (the
    union of the members is the polygon), so ``|H − H_proxy| <= π Σ_f ½ range_f F_f`` with ``F_f`` the proxy's
    visible form factor; the visible parts of different faces do not overlap on the hemisphere (``Σ_f F_f <=
    1``), so this is at most ``tolerance``: the caller computes it per receiver from the proxies' visible form
    factors and half ranges (:func:`.local_pass.irradiance` gives the proxies half its tolerance, the edges left
    out the other half).

    Returns ``(proxy scene, half_range (n_p, 3) or None)`` (``scene`` itself and None when no face
    qualifies); cached on ``scene`` for the set of qualifying faces (the last :data:`PROXY_KEEP` sets). The
    proxy scene has the same ``double_sided``; its polygons are the kept convex polygons of ``scene`` and the proxies.
    """
    if scene.linear or occ.n == 0:
        return scene, None
    tol = np.broadcast_to(np.asarray(tolerance, dtype=np.float64), (3,))
    lo, hi, size, dirty = _face_ranges(scene, occ)
    ok = (size >= 2) & ~dirty & ((hi - lo) * (0.5 * np.pi) <= tol[None, :]).all(axis=1) & np.isfinite(hi).all(axis=1)
    if occ.hull_cores is not None:
        # a convex core (float32-rounded tilings) may exceed its members' union by slivers of the ring cells:
        # as an emitter it would count them twice, outside the bound
        ok &= ~occ.hull_cores
    if not ok.any():
        return scene, None
    key = ok.tobytes()
    # the last PROXY_KEEP proxy scenes: the adaptive pass alternates two tolerances (its samples' and its
    # final samples'), and a proxy scene rebuilt is one re-prepared and re-shipped to the workers
    kept = [c for c in getattr(scene, "_proxy", ()) if c[0] is occ]
    for cached in kept:
        if cached[1] == key:
            return cached[2], cached[3]
    has = occ.members >= 0
    keep = np.flatnonzero(~(has & ok[np.where(has, occ.members, 0)]))   # polygons not replaced (duplicates too)
    faces = np.flatnonzero(ok)
    kc = scene.poly_counts[keep]
    fc = occ.counts[faces]
    kv = scene.poly_vertices[keep][np.arange(scene.poly_vertices.shape[1])[None, :] < kc[:, None]]
    fv = occ.vertices[faces][np.arange(occ.vertices.shape[1])[None, :] < fc[:, None]]
    verts = np.concatenate([kv, fv])
    counts = np.concatenate([kc, fc])
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    rad = np.concatenate([scene.poly_radiance[keep], 0.5 * (lo[faces] + hi[faces])])
    half = np.concatenate([np.zeros((len(keep), 3)), 0.5 * (hi[faces] - lo[faces])])
    sp = Scene.from_arrays(verts, np.arange(len(verts), dtype=np.int64), starts, counts, rad,
                           double_sided=scene.double_sided)
    half_range = half[sp.poly_source]
    sp._half_range = half_range
    scene._proxy = ([(occ, key, sp, half_range)] + kept)[:PROXY_KEEP]
    return sp, half_range


# --- linear proxies of whole nodes -------------------------------------------------------------------

#: share of the clear nodes' tolerance the linear proxies may use (the edges left out get the rest, and
#: whatever the proxies leave unused)
LINEAR_SHARE = 0.9
#: a node with a welded list of at most this many edges is summed over them rather than by its proxy
LINEAR_EDGES = 8
#: the members of a node fill its rectangle when their areas sum to it within this fraction
RECT_FILL = 1e-9
#: (node, member) pairs per batch of the fits (memory)
FIT_BATCH = 2**18
#: a node's proxy is integrated over at most this many rectangles
MAX_RECTS = 4
#: Gauss–Legendre nodes per side of a proxy's rectangles (the rule's error is bounded and budgeted)
QUAD_NODES = 3


def _merge_rects(rects: list) -> list:
    """Rectangles ``(lo1, hi1, lo2, hi2)`` with disjoint interiors, two merged while they share a whole side."""
    rects = list(rects)
    merged = True
    while merged and len(rects) > 1:
        merged = False
        for i in range(len(rects)):
            a = rects[i]
            for j in range(i + 1, len(rects)):
                b = rects[j]
                if a[2] == b[2] and a[3] == b[3] and (a[1] == b[0] or b[1] == a[0]):
                    rects[i] = (min(a[0], b[0]), max(a[1], b[1]), a[2], a[3])
                elif a[0] == b[0] and a[1] == b[1] and (a[3] == b[2] or b[3] == a[2]):
                    rects[i] = (a[0], a[1], min(a[2], b[2]), max(a[3], b[3]))
                else:
                    continue
                del rects[j]
                merged = True
                break
            if merged:
                break
    return rects


@dataclass
class NodeFits:
    """Linear proxies of the hierarchy's nodes (``N`` nodes; see :func:`node_fits`).

    Attributes:
        ok: (N,) the node has a proxy: its members (all of eligible tiles) fill at most
            :data:`MAX_RECTS` rectangles exactly.
        rect: (R, 4, 3) those rectangles (world coordinates), rect_ptr: (N+1,) each node's range.
        normal: (N, 3) its unit normal; centre: (N, 3) the members' centroid c (on the plane).
        value: (N, 3) ``a``, grad: (N, 3, 3) ``g`` (world vector per channel, in the plane): the
            affine radiance ``L_lin(x) = a + g·(x − c)`` fitted (area-weighted least squares) to the
            members' constant radiance at their centroids.
        resid: (N, 3) ``max_i |ε_i|``, ``ε_i = L_i − L_lin(c_i)`` at the members' centroids c_i;
            resid_moment: (N, 3) ``Σ_i |ε_i| ∫_i |x − c|² dA`` (at most ``max|ε| I``: the residual term
            of the bound weighs each member's residual by its own moment); gnorm: (N, 3) ``|g|``.
        inertia: (N,) ``I = ∫ |x − c|² dA`` over the members; area: (N,) ``A``; jsum: (N, 3, 3)
            ``Σ_i J_i``, ``J_i = ∫_i (x − c_i)(x − c_i)ᵀ dA``; saw: (N,) ``Σ_i tr J_i (|c_i − c| + ρ_i / 2)``
            (``ρ_i`` member i's largest vertex distance from c_i).
        defect0, defect1: (N, 3) bounds on ``|Σ A_i ε_i|`` and ``|Σ A_i ε_i (c_i − c)|`` (zero for the
            exact least-squares fit, here its rounding).
        mismatch: (N, 3) ``lmax × Σ (|A_rect − A| + RECT_FILL A)`` over the tiles: what the rectangles'
            area beyond the members' can add; lmax: (N, 3) ``|a| + |g| × diagonal`` (>= |L_lin| on the
            node); half_side: (N,) the largest half side of its rectangles.
        eps2: (N, 3, 3) per channel ``E2 = Σ_i ε_i ∫_i (x − c)(x − c)ᵀ dA`` in the node's frame, as its
            components (11, 12, 22): the residual's second moment, whose term against the kernel's
            Hessian at c the proxy adds; frame: (N, 2, 3) that frame's in-plane unit axes e1, e2;
            resid_moment3: (N, 3) ``Σ_i |ε_i| A_i (|c_i − c| + ρ_i)³ >= Σ_i |ε_i| ∫_i |x − c|³ dA`` (what
            is left of the residual's term is third order: :func:`linear_node_test`).
    """

    ok: np.ndarray
    rect: np.ndarray
    rect_ptr: np.ndarray
    normal: np.ndarray
    centre: np.ndarray
    value: np.ndarray
    grad: np.ndarray
    resid: np.ndarray
    gnorm: np.ndarray
    inertia: np.ndarray
    jsum: np.ndarray
    saw: np.ndarray
    area: np.ndarray
    defect0: np.ndarray
    defect1: np.ndarray
    mismatch: np.ndarray
    resid_moment: np.ndarray | None = None
    lmax: np.ndarray | None = None
    half_side: np.ndarray | None = None
    eps2: np.ndarray | None = None
    resid_moment3: np.ndarray | None = None
    frame: np.ndarray | None = None


def _polygon_moments(verts, counts):
    """Area ``(n,)``, centroid ``(n, 3)``, central second moment ``∫ (x−c)(x−c)ᵀ dA (n, 3, 3)`` and the
    largest vertex distance from the centroid ``(n,)`` of convex planar polygons ``verts (n, K, 3)``."""
    n, K = verts.shape[:2]
    o = verts[:, 0]
    area = np.zeros(n)
    s1 = np.zeros((n, 3))
    tris = []
    for k in range(1, K - 1):
        a, b = verts[:, k] - o, verts[:, k + 1] - o
        w = np.where(k + 1 < counts, 0.5 * np.linalg.norm(np.cross(a, b), axis=1), 0.0)
        area += w
        s1 += w[:, None] * (a + b) / 3.0
        tris.append((a, b, w))
    cen_rel = s1 / np.where(area > 0, area, 1.0)[:, None]
    second = np.zeros((n, 3, 3))
    for a, b, w in tris:
        # a triangle about its own centroid t: A/12 Σ_j e_j e_jᵀ (e_j = v_j − t), then moved to the polygon's
        t = (a + b) / 3.0
        for e in (-t, a - t, b - t):
            second += (w / 12.0)[:, None, None] * e[:, :, None] * e[:, None, :]
        dt = t - cen_rel
        second += w[:, None, None] * dt[:, :, None] * dt[:, None, :]
    cen = o + cen_rel
    valid = np.arange(K)[None, :] < counts[:, None]
    rho = np.where(valid, np.linalg.norm(verts - cen[:, None, :], axis=2), 0.0).max(axis=1)
    return area, cen, second, rho


def node_fits(scene, occ, h, eligible) -> NodeFits:
    """The :class:`NodeFits` of hierarchy ``h`` over ``occ`` (tiles ``eligible (T,)``; constant radiance).

    A node gets a proxy when all its tiles are eligible and its members exactly fill a rectangle whose
    sides follow the first edge of its first member (subdivided walls, block faces: every node of a
    grid tiling up to its ragged border). Costs O(n × depth), vectorised in batches of nodes."""
    n_nodes = len(h.radii)
    area_p, cen_p, sec_p, rho_p = _polygon_moments(scene.poly_vertices, scene.poly_counts)
    rad = scene.poly_radiance
    # members of every node, grouped by node: tiles perm[first:last], then each tile's members
    mem_count_rank = np.diff(occ.tile_ptr)[h.perm]                          # members per tile, tree order
    csum = np.concatenate([[0], np.cumsum(mem_count_rank)])
    mem_of_node = csum[h.last_tile] - csum[h.first_tile]
    # members in tree order (tile perm[0]'s, then perm[1]'s, ...)
    _, mem_tree = expand(h.perm, occ.tile_ptr, occ.tile_members)
    elig_rank = np.concatenate([[0], np.cumsum(~eligible[h.perm])])
    all_elig = (elig_rank[h.last_tile] - elig_rank[h.first_tile]) == 0
    first_mem = mem_tree[np.minimum(csum[h.first_tile], len(mem_tree) - 1)] if len(mem_tree) else \
        np.zeros(n_nodes, dtype=np.int64)
    z3 = np.zeros((n_nodes, 3))
    out = NodeFits(np.zeros(n_nodes, dtype=bool), np.zeros((0, 4, 3)), np.zeros(n_nodes + 1, dtype=np.int64),
                   z3.copy(), z3.copy(), z3.copy(),
                   np.zeros((n_nodes, 3, 3)), z3.copy(), z3.copy(), np.zeros(n_nodes), np.zeros((n_nodes, 3, 3)),
                   np.zeros(n_nodes), np.zeros(n_nodes), z3.copy(), z3.copy(), z3.copy(), z3.copy())
    out.eps2 = np.zeros((n_nodes, 3, 3))
    out.frame = np.zeros((n_nodes, 2, 3))
    out.resid_moment3 = z3.copy()
    if not len(mem_tree):
        return out
    # every node of a face in its root's frame: normal of the root's first member, e1 along that member's
    # first edge, origin the root's sphere centre moved into that member's plane
    root = h.root[h.face]
    fm = first_mem[root]
    nrm = scene.poly_normals[fm]
    e1 = scene.poly_vertices[fm, 1] - scene.poly_vertices[fm, 0]
    e1 -= np.einsum("ij,ij->i", e1, nrm)[:, None] * nrm
    e1 /= np.maximum(np.linalg.norm(e1, axis=1), 1e-300)[:, None]
    e2 = np.cross(nrm, e1)
    rc0 = h.centers[root]
    ref = rc0 - np.einsum("ij,ij->i", rc0 - scene.poly_vertices[fm, 0], nrm)[:, None] * nrm
    box_q = np.zeros((n_nodes, 4))           # members' extent in the frame: lo1, hi1, lo2, hi2
    leaf_rect = np.zeros(n_nodes, dtype=bool)
    slack = np.zeros(n_nodes)
    fit_good = np.zeros(n_nodes, dtype=bool)
    nodes = np.flatnonzero(all_elig & (mem_of_node > 0))
    ends = np.cumsum(mem_of_node[nodes])
    cuts = np.searchsorted(ends, np.arange(FIT_BATCH, ends[-1] if len(ends) else 0, FIT_BATCH), side="right")
    for part in np.split(nodes, np.unique(cuts)):
        if not len(part):
            continue
        cnt = mem_of_node[part]
        b = np.repeat(np.arange(len(part)), cnt)
        pos = np.arange(len(b)) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(csum[h.first_tile[part]], cnt)
        mem = mem_tree[pos]
        v = part[b]
        starts = np.concatenate([[0], np.cumsum(cnt)[:-1]])
        # the rectangle test: extent of the members' vertices along e1, e2 against their total area
        rel = scene.poly_vertices[mem] - ref[v][:, None, :]
        e1v, e2v = e1[v], e2[v]                                          # each member's node frame
        u1 = np.einsum("ikj,ij->ik", rel, e1v)
        u2 = np.einsum("ikj,ij->ik", rel, e2v)
        off = np.abs(np.einsum("ikj,ij->ik", rel, nrm[v])).max(axis=1)       # coplanar with the frame
        lo1, hi1 = np.minimum.reduceat(u1.min(axis=1), starts), np.maximum.reduceat(u1.max(axis=1), starts)
        lo2, hi2 = np.minimum.reduceat(u2.min(axis=1), starts), np.maximum.reduceat(u2.max(axis=1), starts)
        flat = np.maximum.reduceat(off, starts)
        A = np.add.reduceat(area_p[mem], starts)
        a_rect = (hi1 - lo1) * (hi2 - lo2)
        size = np.maximum(hi1 - lo1, hi2 - lo2)
        good = (A > 0) & (flat <= 1e-9 * size)
        box_q[part] = np.stack([lo1, hi1, lo2, hi2], axis=1)
        leaf_rect[part] = np.abs(a_rect - A) <= RECT_FILL * A
        slack[part] = np.abs(a_rect - A) + RECT_FILL * A
        # the fit: area-weighted least squares of the members' values at their centroids, about the
        # members' centroid c (then Σ A_i ε_i = 0 and Σ A_i ε_i (c_i − c) = 0, ε_i = L_i − L_lin(c_i))
        ap = area_p[mem]
        d = cen_p[mem] - ref[v]
        dq = np.stack([np.einsum("ij,ij->i", d, e1v), np.einsum("ij,ij->i", d, e2v)], axis=1)       # (P, 2)
        cq = np.add.reduceat(ap[:, None] * dq, starts) / np.where(A > 0, A, 1.0)[:, None]
        dc = dq - cq[b]
        L = rad[mem]
        C2 = np.add.reduceat(ap[:, None, None] * dc[:, :, None] * dc[:, None, :], starts)
        l0 = np.add.reduceat(ap[:, None] * L, starts)                                           # (B, 3)
        lc1 = np.add.reduceat(ap[:, None, None] * dc[:, :, None] * L[:, None, :], starts)         # (B, 2, 3)
        det = C2[:, 0, 0] * C2[:, 1, 1] - C2[:, 0, 1] ** 2
        tr = C2[:, 0, 0] + C2[:, 1, 1]
        good &= det > 1e-10 * tr * tr
        inv = np.stack([np.stack([C2[:, 1, 1], -C2[:, 0, 1]], 1), np.stack([-C2[:, 0, 1], C2[:, 0, 0]], 1)], 1) \
            / np.where(good, det, 1.0)[:, None, None]
        gq = np.einsum("bij,bjc->bic", inv, lc1)                                                # (B, 2, 3)
        a0 = l0 / np.where(A > 0, A, 1.0)[:, None]
        eps = L - a0[b] - np.einsum("pi,pic->pc", dc, gq[b])                                    # (P, 3)
        res = np.maximum.reduceat(np.abs(eps), starts)
        gnorm = np.sqrt((gq ** 2).sum(axis=1))                                                  # (B, 3)
        # the members' own second moments: ∫ |x − c|², the sawtooth's sum Σ J_i and its remainder weight
        tr_i = np.trace(sec_p[mem], axis1=1, axis2=2)
        dcn = np.sqrt((dc ** 2).sum(axis=1))
        moment_i = tr_i + ap * dcn**2                                    # ∫_i |x − c|² dA (parallel axes)
        inertia = np.add.reduceat(moment_i, starts)
        res_moment = np.add.reduceat(np.abs(eps) * moment_i[:, None], starts)
        # the residual's second moment about c in the frame, ∫_i (x − c)(x − c)ᵀ = J_i + A_i dc dcᵀ
        sj = sec_p[mem]
        m_i = np.stack([np.einsum("pi,pij,pj->p", e1v, sj, e1v) + ap * dc[:, 0] ** 2,
                        np.einsum("pi,pij,pj->p", e1v, sj, e2v) + ap * dc[:, 0] * dc[:, 1],
                        np.einsum("pi,pij,pj->p", e2v, sj, e2v) + ap * dc[:, 1] ** 2], axis=1)   # (P, 3)
        eps2 = np.add.reduceat(eps[:, :, None] * m_i[:, None, :], starts)                      # (B, 3, 3)
        res_moment3 = np.add.reduceat(np.abs(eps) * (ap * (dcn + rho_p[mem]) ** 3)[:, None], starts)
        jsum = np.add.reduceat(sec_p[mem], starts)                                              # (B, 3, 3)
        saw = np.add.reduceat(tr_i * (dcn + 0.5 * rho_p[mem]), starts)
        # orthogonality defects as computed, plus their rounding
        lab = np.add.reduceat(ap[:, None] * np.abs(L), starts)
        i0 = np.add.reduceat(ap[:, None] * eps, starts)
        i1 = np.add.reduceat(ap[:, None, None] * dc[:, :, None] * eps[:, None, :], starts)
        scale1 = np.add.reduceat(ap[:, None] * np.abs(L) * dcn[:, None], starts)
        d0 = np.abs(i0) + 1e-12 * lab
        d1 = np.sqrt((i1 ** 2).sum(axis=1)) + 1e-12 * scale1
        lmax = np.abs(a0) + gnorm * np.hypot(hi1 - lo1, hi2 - lo2)[:, None]
        fit_good[part] = good & np.isfinite(res).all(axis=1) & np.isfinite(gnorm).all(axis=1)
        e1p, e2p = e1[part], e2[part]
        out.normal[part] = nrm[part]
        out.centre[part] = ref[part] + cq[:, :1] * e1p + cq[:, 1:] * e2p
        out.value[part] = a0
        out.grad[part] = e1p[:, :, None] * gq[:, None, 0, :] + e2p[:, :, None] * gq[:, None, 1, :]
        out.resid[part] = res
        out.resid_moment[part] = res_moment
        out.eps2[part] = eps2
        out.frame[part] = np.stack([e1[part], e2[part]], axis=1)
        out.resid_moment3[part] = res_moment3
        out.gnorm[part] = gnorm
        out.inertia[part] = inertia
        out.jsum[part] = jsum
        out.saw[part] = saw
        out.area[part] = A
        out.defect0[part] = d0
        out.defect1[part] = d1
        out.mismatch[part] = lmax
    # rectangles: a tile whose members fill their extent is one; a parent's are its children's, merged
    # where two share a whole side (exact coordinates: welded vertices project identically)
    rects: list = [None] * n_nodes
    for t in np.flatnonzero(leaf_rect[:h.n_tiles] & fit_good[:h.n_tiles]):
        rects[t] = [tuple(box_q[t])]
    n_child = np.diff(h.child_ptr)
    for v in range(h.n_tiles, n_nodes):
        kids = h.child[h.child_ptr[v]:h.child_ptr[v + 1]]
        if not n_child[v] or any(rects[k] is None for k in kids):
            continue
        slack[v] = slack[kids].sum()
        merged = _merge_rects([r for k in kids for r in rects[k]])
        if len(merged) <= MAX_RECTS:
            rects[v] = merged
    has = np.array([r is not None for r in rects], dtype=bool) & fit_good
    out.ok = has
    out.lmax = out.mismatch.copy()
    out.mismatch *= slack[:, None]
    counts = np.array([len(r) if (r is not None and ok) else 0 for r, ok in zip(rects, has)], dtype=np.int64)
    out.rect_ptr = np.concatenate([[0], np.cumsum(counts)])
    q = np.array([r for rr, ok in zip(rects, has) if ok for r in rr], dtype=np.float64).reshape(-1, 4)
    owner = np.repeat(np.arange(n_nodes), counts)
    c1 = np.stack([q[:, 0], q[:, 1], q[:, 1], q[:, 0]], axis=1)
    c2 = np.stack([q[:, 2], q[:, 2], q[:, 3], q[:, 3]], axis=1)
    out.rect = ref[owner][:, None, :] + c1[..., None] * e1[owner][:, None, :] + c2[..., None] * e2[owner][:, None, :]
    half = 0.5 * np.maximum(q[:, 1] - q[:, 0], q[:, 3] - q[:, 2])
    out.half_side = np.zeros(n_nodes)
    if len(half):
        np.maximum.at(out.half_side, owner, half)
    return out


def linear_node_test(fit: NodeFits, h, points, normals, ep, en, tolerance, return_floor=False):
    """Whether receiver ``ep`` may take node ``en``'s linear proxy, and the proxy's bound ``(fits (E,),
    bound (E, 3))`` (inf where the node is not wholly in front of P), for (receiver, node) entries whose
    node is wholly visible and above the horizon.

    The proxy (:func:`linear_node_irradiance`) gives ``π ∫ L_lin k dA`` over the rectangle minus the
    sawtooth term ``π g·(Σ_i J_i) ∇k(c)``, for the exact ``π Σ_i L_i ∫_i k dA``; ``k(x) = |δ| (N·u) /
    (π |u|⁴)`` is the kernel of dF (``u = x − P``, ``δ`` P's distance from the plane). Inside member i,
    ``L_i − L_lin(x) = ε_i − g·(x − c_i)``, so the error is, per channel,

    * ``π ∫ ε k``, ε piecewise constant with ``∫ ε = ∫ ε (x − c) = 0`` (the fit's normal equations),
      less the term the proxy adds for it, ``C2 = π ½ ∇²k(c) : E2`` (``eps2``, the residual's second
      moment about c): ``π ∫ ε (k − k(c) − ∇k(c)·(x − c)) − C2``. Two bounds, the smaller is used:
      ``π ½ H Σ_i |ε_i| ∫_i |x − c|² dA`` (``resid_moment``: a shadow edge's large ε weighs only its own
      members' moments) plus ``|C2| <= π ½ H_c × resid_moment`` (``H_c = κ |δ| / (π r_c⁵)``, the same
      Hessian bound at c alone: E2 is a sum of ε_i times in-plane positive semi-definite moments); or the
      Taylor remainder of third order, ``π H3 / 6 Σ_i |ε_i| ∫_i |x − c|³ dA`` (``resid_moment3``), with
      ``H3 = κ3 |δ| / (π r_min⁶)`` a bound on k's third in-plane derivative over the sphere
      (:func:`_third_factor`). The first wins near P, the second once the node is small against its
      distance (the ratio is about ``2 R / r_min``);
    * ``π Σ_i g·∫_i (x − c_i)(k(x) − k(c_i))`` minus the sawtooth term: Taylor about c_i to second order,
      then ``∇k(c_i) = ∇k(c) + O(H |c_i − c|)``: at most ``π |g| H Σ_i tr J_i (|c_i − c| + ρ_i / 2)``;

    with ``H = κ |δ| / (π r_min⁵)`` a bound on k's Hessian in the node's plane over its bounding sphere
    (every segment used lies in the plane and in the sphere; ``r_min`` its distance from P): for unit v,
    ``|u|⁵ vᵀ ∇²((N·u)|u|^-4) v = −8 (N·v)(û·v) + cosθ (24 (û·v)² − 4)`` (``cosθ = N·û``); v in the plane
    has ``|û·v| <= s``, ``s² = 1 − δ² / r_max²`` (û's component along the plane normal is ``δ / |u| >= δ /
    r_max``), so ``κ = 8 s + max(4, 24 s² − 4)`` (:func:`_hessian_factor`): 4 head-on, at most ``8 + 20 =
    28`` at grazing; and the rounding of the fit (``k <= |δ| / (π r³)``, ``|∇k| <= 3 |δ| / (π r⁴)`` at c)
    and the rectangle's area beyond the members':

        |error| <= |δ| (min(κ/2 resid_moment (1 / r_min⁵ + 1 / r_c⁵), κ3/6 resid_moment3 / r_min⁶)
                        + κ |g| saw / r_min⁵ + defect0 / r_c³ + 3 defect1 / r_c⁴ + mismatch / r_min³)
                 + the rule's error (:func:`_quadrature_factor`)

    (``r_c = |c − P|``). The proxy is taken when this is at most the tolerance times a lower bound of the
    node's form factor ``F_v``: the larger of ``A |δ| h_min / (π r_max⁴)`` (``h_min`` the members' lowest
    height above P's horizon, from the bounding sphere or box, ``r_max`` the sphere's farthest point)
    and ``A k(c) − κ/2 |δ| I / (π r_min⁵)`` (Taylor about the centroid; with ``return_floor`` it is
    returned too, (E,), 0 where the node is not wholly in front of P). The proxies a receiver takes see
    disjoint parts of its hemisphere, ``Σ F_v <= 1``, so their bounds sum to at most the tolerance.
    """
    tol = np.broadcast_to(np.asarray(tolerance, dtype=np.float64), (3,))
    # every receiver-independent term of the entries, one contiguous row per field (structure of arrays:
    # each product below runs along the entries, none broadcasts a column against (E, 3))
    row = np.take(_test_columns(fit, h), en, axis=1)                         # (36, E)

    def col(name, j=0):
        return row[_TEST_START[_TEST_FIELDS.index(name)] + j]

    ok = col("ok") > 0
    pts = np.take(points, ep, axis=0)
    nr = np.take(normals, ep, axis=0)
    px, py, pz = pts[:, 0], pts[:, 1], pts[:, 2]
    nx, ny, nz = nr[:, 0], nr[:, 1], nr[:, 2]
    rx, ry, rz = col("centers", 0) - px, col("centers", 1) - py, col("centers", 2) - pz
    rs = np.sqrt(rx * rx + ry * ry + rz * rz)
    rad = col("radii")
    rmin = rs - rad
    rmax = rs + rad
    ux, uy, uz = col("centre", 0) - px, col("centre", 1) - py, col("centre", 2) - pz
    rc = np.sqrt(ux * ux + uy * uy + uz * uz)
    delta = np.abs(col("normal", 0) * ux + col("normal", 1) * uy + col("normal", 2) * uz)
    # h_min, a lower bound of the members' heights above P's horizon: the bounding sphere's lowest point,
    # or, where that is not above the horizon, the box's lowest corner (both contain every member)
    hmin = rx * nx + ry * ny + rz * nz - rad
    low = np.flatnonzero(hmin <= 0)
    if len(low):
        hmin[low] = np.matmul(h.corners[en[low]] - pts[low][:, None, :], nr[low][:, :, None])[..., 0].min(axis=1)
    ok &= (rmin > 0) & (hmin > 0) & (delta > 0)
    geo = ok.copy()
    rmin = np.where(ok, rmin, 1.0)
    rc = np.where(ok, rc, 1.0)
    i_r = 1.0 / rmin
    i_c = 1.0 / rc
    i_r3 = i_r * i_r * i_r
    i_r5 = i_r3 * i_r * i_r
    i_c3 = i_c * i_c * i_c
    kappa, kappa3 = _kernel_factors(delta, rmax)
    # the residual's term: second order (with |C2| at c), or third order once the node is small enough
    second = 0.5 * kappa * (i_r5 + i_c3 * i_c * i_c)
    third = kappa3 / 6.0 * i_r5 * i_r
    saw = kappa * i_r5 * col("saw")
    quad, reach = _quadrature_factor(col("half_side"), col("area"), delta, rmin, rmax)
    # a lower bound of F_v: the members' lowest height and farthest point, or k at the centroid less the
    # Hessian's remainder (the first-order term integrates to zero about the centroid)
    area = col("area")
    f_box = area * delta * np.maximum(hmin, 0.0) / (np.pi * rmax**4)
    nu = nx * ux + ny * uy + nz * uz
    f_mid = delta * (area * nu * (i_c3 * i_c) - 0.5 * kappa * col("inertia") * i_r5) / np.pi
    floor = np.maximum(f_box, f_mid * (1.0 - 1e-12))
    bound = np.empty((len(en), 3))
    for c in range(3):
        gn = col("gnorm", c)
        b = np.minimum(second * col("resid_moment", c), third * col("resid_moment3", c))
        b += gn * saw
        b += col("defect0", c) * i_c3
        b += 3.0 * col("defect1", c) * (i_c3 * i_c)
        b += col("mismatch", c) * i_r3
        b *= delta
        b *= 1.0 + SAFETY
        b += (col("lmax", c) + reach * gn) * quad
        bound[:, c] = b
        ok &= b <= tol[c] * floor * (1.0 - SAFETY)
    if return_floor:
        return ok, np.where(geo[:, None], bound, np.inf), np.where(geo, np.maximum(floor, 0.0), 0.0)
    return ok, np.where(geo[:, None], bound, np.inf)


#: what :func:`linear_node_test` reads per node, in :func:`_test_columns`'s row order, and the widths
_TEST_FIELDS = ("centers", "radii", "centre", "normal", "resid_moment", "gnorm", "saw", "defect0", "defect1",
                "mismatch", "lmax", "area", "inertia", "half_side", "ok", "resid_moment3")
_TEST_WIDTHS = (3, 1, 3, 3, 3, 3, 1, 3, 3, 3, 3, 1, 1, 1, 1, 3)
_TEST_START = np.concatenate([[0], np.cumsum(_TEST_WIDTHS)])


def _test_columns(fit: NodeFits, h) -> np.ndarray:
    """(36, N) per node the :data:`_TEST_FIELDS` (``centers``, ``radii`` the hierarchy's bounding spheres,
    the rest ``fit``'s, ``ok`` as 1.0 / 0.0), one row per component, cached on ``fit``:
    :func:`linear_node_test` and :func:`linear_may_fit` gather them in one ``np.take`` along the nodes, and
    every field's gathered values are then contiguous."""
    cached = getattr(fit, "_test_cache", None)
    if cached is not None and cached[0] is h and cached[1] is fit.ok:
        return cached[2]
    rows = np.column_stack([getattr(h if f in ("centers", "radii") else fit, f).astype(np.float64)
                            for f in _TEST_FIELDS])
    cols = np.ascontiguousarray(rows.T)
    fit._test_cache = (h, fit.ok, cols)
    return cols


def _kernel_factors(delta, rmax):
    """``(κ, κ3)`` (E,) each: :func:`_hessian_factor` and :func:`_third_factor` from one ``s²``."""
    s2 = np.clip(1.0 - (delta / rmax) ** 2, 0.0, 1.0)
    s = np.sqrt(s2)
    q = np.maximum(4.0, 24.0 * s2 - 4.0)
    cubic = np.maximum(np.abs(192.0 * s2 * s - 72.0 * s), np.where(s2 >= 0.125, 12.0 * np.sqrt(2.0), 0.0))
    return (8.0 * s + q) * (1.0 + 1e-12), (3.0 * q + cubic) * (1.0 + 1e-12)


def _hessian_factor(delta, rmax):
    """(E,) ``κ = 8 s + max(4, 24 s² − 4)``, ``s² = 1 − (δ / r_max)²``: ``|u|⁵`` times a bound on the
    in-plane Hessian of ``(N·u)|u|^-4`` over a node's bounding sphere (see :func:`linear_node_test`); 28
    where the plane is seen edge on, 4 head on. Rounded up by a relative 1e-12."""
    return _kernel_factors(delta, rmax)[0]


def _third_factor(delta, rmax):
    """(E,) ``κ3 = 3 max(4, 24 s² − 4) + max_{|t| <= s} |192 t³ − 72 t|`` (``s`` as in
    :func:`_hessian_factor`): ``|u|⁶`` times a bound on the third in-plane derivative of ``(N·u)|u|^-4``
    over a node's bounding sphere. For unit v, ``t = û·v``: ``D³_v [(N·u) g] = 3 (N·v) D²_v g + (N·u) D³_v g``
    with ``g = |u|^-4``, ``|u|⁶ D²_v g = 24 t² − 4`` and ``|u|⁷ D³_v g = 72 t − 192 t³``; ``|N·v|, |N·û| <= 1``,
    and v in the plane has ``|t| <= s``. The cubic's largest magnitude on [0, s] is at s or at its
    turning point ``1/√8`` (``12√2``). 29 head on, at most 180 at grazing. Rounded up by a relative 1e-12."""
    return _kernel_factors(delta, rmax)[1]


def linear_may_fit(fit: NodeFits, h, points, ep, en, tolerance) -> np.ndarray:
    """(E,) bool: entries that :func:`linear_node_test` could pass at ``tolerance`` (3,); False ones cannot.

    A necessary condition at the cost of two distances per entry. Of the test's bound, the residual and
    sawtooth terms alone are at least ``|δ| (min(κ a_c / r_min⁵, κ3 b_c / r_min⁶) + κ s_c / r_min⁵)`` (``a =
    ½ resid_moment``, ``b = resid_moment3 / 6``, ``s = |g| saw`` per node; κ, κ3 from δ and r_max,
    :func:`_hessian_factor`, :func:`_third_factor`), and the form factor's lower bound is at most ``A |δ|
    / (π r_min³)`` (``h_min <= r_max``, ``N·u <= r_c``, and ``r_c >= r_min``: the members and their
    centroid are in the node's bounding sphere). So passing needs, in every channel, ``r_min² / κ >= π (a
    + s) / (tol A)``, or both ``r_min³ / κ3 >= π b / (tol A)`` and ``r_min² / κ >= π s / (tol A)``
    (the three thresholds per node and channel cached for the tolerance). They are relaxed by 1 % for
    their rounding: a False is certain, a True only means "run the test"."""
    tol = np.broadcast_to(np.asarray(tolerance, dtype=np.float64), (3,))
    key = tol.tobytes()
    cached = getattr(fit, "_reach", None)
    if cached is None or cached[0] != key:
        saw = fit.gnorm * fit.saw[:, None]                                                     # (N, 3)
        usable = fit.ok & (fit.area > 0)
        area = np.where(fit.area > 0, fit.area, 1.0)[:, None]

        def threshold(k):
            with np.errstate(divide="ignore", invalid="ignore"):
                q = np.where(k > 0, k / tol[None, :], 0.0)                                     # inf: tol_c = 0
                t = np.where(usable[:, None], np.pi * q / area, np.inf)
            return 0.99 * np.nan_to_num(t, nan=np.inf)

        rows = np.concatenate([threshold(0.5 * fit.resid_moment + saw), threshold(fit.resid_moment3 / 6.0),
                               threshold(saw)], axis=1)                                        # (N, 9)
        cached = (key, np.ascontiguousarray(rows.T))                                           # (9, N)
        fit._reach = cached
    row = np.take(_test_columns(fit, h)[:_TEST_START[4]], en, axis=1)    # sphere centre, radius, centroid, normal
    pts = np.take(points, ep, axis=0)
    px, py, pz = pts[:, 0], pts[:, 1], pts[:, 2]
    rx, ry, rz = row[0] - px, row[1] - py, row[2] - pz
    rs = np.sqrt(rx * rx + ry * ry + rz * rz)
    rmin = rs - row[3]
    delta = np.abs(row[7] * (row[4] - px) + row[8] * (row[5] - py) + row[9] * (row[6] - pz))
    kappa, kappa3 = _kernel_factors(delta, rs + row[3])
    t = np.take(cached[1], en, axis=1)
    # divided rather than multiplied: a finite threshold near the float maximum must not overflow
    r2k = rmin * rmin / kappa
    r3k = rmin * rmin * rmin / kappa3
    ok = rmin > 0
    for c in range(3):
        ok &= (r2k >= t[c]) | ((r3k >= t[3 + c]) & (r2k >= t[6 + c]))
    return ok


def _quadrature_factor(half, area, delta, rmin, rmax):
    """``(q, y2)`` (E,) each: the :data:`QUAD_NODES`² Gauss–Legendre rule of :func:`linear_node_irradiance`
    errs on an entry's rectangles by at most ``(lmax_c + y2 |g_c|) q`` per channel, times π included (per
    entry its node's ``half_side``, ``area`` from :class:`NodeFits`; ``lmax``, ``|g|`` per channel).

    The integrand ``f = L_lin k`` is analytic where ``u·u ≠ 0``. Continue one coordinate into the
    complex plane by at most ``y = r_min / 4``: real parts stay within y of the rectangle (``|Re u| >=
    0.75 r_min``), so ``|u·u| >= |Re u|² − y² >= r_min² / 2``, ``|N·u| <= r_max + 2y``, ``|L_lin| <= lmax + 2
    |g| y``: ``|f| <= M = (lmax + 2 |g| y) |δ| (r_max + 2y) / (π r_min⁴ / 4)``. The Bernstein ellipse of
    a side of half-length h with semi-minor axis y has ``ρ = y/h + √(1 + (y/h)²)``; Gauss with n nodes
    errs by at most ``(64/15) M h ρ^-2n / (ρ² − 1)`` per unit of the other side (Trefethen, ATAP Thm
    19.3), and the tensor rule by at most ``(64/15) M A ρ^-2n / (ρ² − 1)`` over a rectangle of area A
    (one term per direction, each side <= the largest, ``h``)."""
    y = 0.25 * rmin
    q = np.minimum(y / np.maximum(half, 1e-300), 1e100)                  # (no rectangles: not taken)
    rho2 = q + np.sqrt(1.0 + q * q)
    rho2 *= rho2
    m = delta * (rmax + 2.0 * y) / (0.25 * np.pi * rmin**4)
    area = area * (1.0 + 2 * RECT_FILL)
    return np.pi * (64.0 / 15.0) * m * (area * rho2 ** (-QUAD_NODES) / (rho2 - 1.0)), 2.0 * y


def linear_node_irradiance(fit: NodeFits, point, node, points, normals):
    """The proxies of (receiver, node) pairs ``point, node (P,)``: ``π ∫ L_lin k dA`` over the node's
    rectangles by a :data:`QUAD_NODES`² Gauss–Legendre rule each, minus the sawtooth term ``π g·(Σ J_i)
    ∇k(c)``, plus the residual's term ``π ½ ∇²k(c) : E2`` (see :func:`linear_node_test`): ``(P, 3)``, and
    the rounding allowance ``(P, 3)`` (the rule's own error is in :func:`_quadrature_factor`). Pairs go
    :data:`PROXY_BATCH` at a time (the rule's (pairs, n, n) arrays stay in cache)."""
    h = np.zeros((len(point), 3))
    allowance = np.zeros((len(point), 3))
    for s in range(0, len(point), PROXY_BATCH):
        e = min(len(point), s + PROXY_BATCH)
        h[s:e], allowance[s:e] = _proxy_batch(fit, point[s:e], node[s:e], points, normals)
    return h, allowance


#: (receiver, node) pairs per batch of :func:`linear_node_irradiance`
PROXY_BATCH = 4096
_QX, _QW = np.polynomial.legendre.leggauss(QUAD_NODES)
_QA = 0.5 * (_QX + 1.0)                                                     # the rule's nodes on [0, 1]
_QW2 = 0.25 * np.outer(_QW, _QW).ravel()                                    # its weights (sum to 1), a-major


def _proxy_batch(fit: NodeFits, point, node, points, normals):
    """:func:`linear_node_irradiance` for one batch of pairs.

    Component arrays throughout (structure of arrays): the rule's n² nodes are a loop over (P,) arrays,
    not (P, n, n) arrays broadcast against per-pair columns (numpy's slow buffered path)."""
    rect_rows, node_rows = _rect_terms(fit)
    p = np.take(points, point, axis=0)
    nn = np.take(normals, point, axis=0)
    nd = np.take(node_rows, node, axis=0)                                   # (P, 42)
    cux, cuy, cuz = nd[:, 0] - p[:, 0], nd[:, 1] - p[:, 1], nd[:, 2] - p[:, 2]
    nx, ny, nz = nn[:, 0], nn[:, 1], nn[:, 2]
    delta = np.abs(nd[:, 3] * cux + nd[:, 4] * cuy + nd[:, 5] * cuz)
    # every pair's rectangles (a pair's are consecutive)
    k, rid = expand(node, fit.rect_ptr, np.arange(len(fit.rect)))
    one = len(k) == len(node)                                               # one rectangle each: k is the identity
    rr = np.take(rect_rows, rid, axis=0)                                    # (R, 24)
    if one:
        px, py, pz, kx, ky, kz, dk = p[:, 0], p[:, 1], p[:, 2], nx, ny, nz, delta
    else:
        px, py, pz = (np.take(p[:, i], k) for i in range(3))
        kx, ky, kz = (np.take(nn[:, i], k) for i in range(3))
        dk = np.take(delta, k)
    r0x, r0y, r0z = rr[:, 0] - px, rr[:, 1] - py, rr[:, 2] - pz
    s1x, s1y, s1z, s2x, s2y, s2z = (rr[:, i] for i in range(3, 9))
    # over a rectangle u = r0 + a s1 + b s2 (s1 ⊥ s2, a, b in [0, 1]) N·u is affine and |u|² separable
    # in (a, b): both on the rule's n × n grid from per-side terms
    n0 = r0x * kx + r0y * ky + r0z * kz
    n1 = s1x * kx + s1y * ky + s1z * kz
    n2 = s2x * kx + s2y * ky + s2z * kz
    c1 = 2.0 * (s1x * r0x + s1y * r0y + s1z * r0z)
    c2 = 2.0 * (s2x * r0x + s2y * r0y + s2z * r0z)
    rr0 = r0x * r0x + r0y * r0y + r0z * r0z
    l1, l2 = rr[:, 9], rr[:, 10]
    ua = [(c1 + l1 * a) * a + rr0 for a in _QA]
    ub = [(c2 + l2 * b) * b for b in _QA]
    na = [n0 + n1 * a for a in _QA]
    nb = [n2 * b for b in _QA]
    # the weighted moments Σ w k, Σ w k a, Σ w k b of π k / |δ| (>= 0) on the grid
    m0, m1, m2 = np.zeros(len(rid)), np.zeros(len(rid)), np.zeros(len(rid))
    for i in range(QUAD_NODES):
        for j in range(QUAD_NODES):
            uu = ua[i] + ub[j]
            uu *= uu
            kij = na[i] + nb[j]
            kij /= uu
            kij *= _QW2[i * QUAD_NODES + j]
            m0 += kij
            m1 += _QA[i] * kij
            m2 += _QA[j] * kij
    # L_lin = coef_0 + a coef_1 + b coef_2 per channel
    scale = rr[:, 11] * dk
    m0 *= scale
    m1 *= scale
    m2 *= scale
    h_r = [m0 * rr[:, 12 + c] + m1 * rr[:, 15 + c] + m2 * rr[:, 18 + c] for c in range(3)]
    mag = [m0 * rr[:, 21 + c] for c in range(3)]
    if not one:
        first = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
        h_r = [np.add.reduceat(x, first) for x in h_r]
        mag = [np.add.reduceat(x, first) for x in mag]
    # π ∇k(c) = |δ| (N / r⁴ − 4 (N·u) u / r⁶)
    r2 = cux * cux + cuy * cuy + cuz * cuz
    nu = nx * cux + ny * cuy + nz * cuz
    r4 = r2 * r2
    r6 = r4 * r2
    a4, b6 = delta / r4, 4.0 * delta * nu / r6
    pg = (a4 * nx - b6 * cux, a4 * ny - b6 * cuy, a4 * nz - b6 * cuz)
    # the sawtooth term g·(Σ J) π∇k(c): v = (Σ J) π∇k(c), then v · g per channel
    v = [nd[:, 6 + 3 * r] * pg[0] + nd[:, 7 + 3 * r] * pg[1] + nd[:, 8 + 3 * r] * pg[2] for r in range(3)]
    saw = [v[0] * nd[:, 15 + c] + v[1] * nd[:, 18 + c] + v[2] * nd[:, 21 + c] for c in range(3)]
    # the residual's term at c: C2 = π ½ ∇²k(c) : E2, π ∇²k = |δ| (−4 (N uᵀ + u Nᵀ) / r⁶ − 4 (N·u) I / r⁶
    # + 24 (N·u) u uᵀ / r⁸), E2 symmetric and in the plane: u and N by their components along e1, e2
    ua_ = nd[:, 24] * cux + nd[:, 25] * cuy + nd[:, 26] * cuz
    ub_ = nd[:, 27] * cux + nd[:, 28] * cuy + nd[:, 29] * cuz
    na_ = nd[:, 24] * nx + nd[:, 25] * ny + nd[:, 26] * nz
    nb_ = nd[:, 27] * nx + nd[:, 28] * ny + nd[:, 29] * nz
    # C2 = α E11 + β E12 + γ E22 per channel
    a6, a8 = delta / r6, 12.0 * delta * nu / (r6 * r2)
    diag = -2.0 * nu * a6
    alpha = diag - 4.0 * a6 * na_ * ua_ + a8 * ua_ * ua_
    beta = -4.0 * a6 * (na_ * ub_ + nb_ * ua_) + 2.0 * a8 * ua_ * ub_
    gamma = diag - 4.0 * a6 * nb_ * ub_ + a8 * ub_ * ub_
    # its rounding: each of its terms is at most 36 |δ| |E2| / r_c⁵, |E2| <= resid_moment, and E2 is a sum
    # of up to 10^6 terms (a relative 1e-9 covers both many times over)
    c2_round = 1e-9 * 36.0 * delta / (r4 * np.sqrt(r2))
    h = np.empty((len(point), 3))
    allowance = np.empty((len(point), 3))
    for c in range(3):
        c2 = alpha * nd[:, 30 + c] + beta * nd[:, 33 + c] + gamma * nd[:, 36 + c]
        h[:, c] = h_r[c] - saw[c] + c2
        allowance[:, c] = 1e-12 * (mag[c] + np.abs(saw[c])) + c2_round * nd[:, 39 + c]
    return h, allowance


def _rect_terms(fit: NodeFits):
    """Per rectangle and per node of ``fit`` what :func:`linear_node_irradiance` reads, one row each (one
    gather per pair and rectangle; cached on ``fit``): ``(rect_rows (R, 24), node_rows (N, 42))``.

    A rectangle's row: corner 0 (3), its sides ``s1 = corner 1 − corner 0``, ``s2 = corner 3 − corner 0``
    (6), their squared lengths (2), its area (1), ``coef`` (9: rows the affine radiance ``L_lin`` at corner
    0 and its steps along s1 and s2, per channel) and the rows' absolute values summed (3, the rounding
    allowance's weight). A node's (42): centroid (3), normal (3), ``jsum`` (9), ``grad`` (9), ``frame`` (6),
    ``eps2`` (9: E11, E12, E22 of the channels) and ``resid_moment`` (3)."""
    cached = getattr(fit, "_rect_cache", None)
    if cached is not None and cached[0] is fit.rect:
        return cached[1]
    owner = np.repeat(np.arange(len(fit.rect_ptr) - 1), np.diff(fit.rect_ptr))
    s1 = fit.rect[:, 1] - fit.rect[:, 0]
    s2 = fit.rect[:, 3] - fit.rect[:, 0]
    g = fit.grad[owner]                                                     # (R, 3 xyz, 3 channels)
    coef = np.stack([fit.value[owner] + np.einsum("ri,ric->rc", fit.rect[:, 0] - fit.centre[owner], g),
                     np.einsum("ri,ric->rc", s1, g), np.einsum("ri,ric->rc", s2, g)], axis=1)
    len2 = np.stack([np.einsum("ri,ri->r", s1, s1), np.einsum("ri,ri->r", s2, s2)], axis=1)
    area = np.linalg.norm(np.cross(s1, s2), axis=1)
    rect_rows = np.column_stack([fit.rect[:, 0], s1, s2, len2, area, coef.reshape(-1, 9), np.abs(coef).sum(axis=1)])
    n = len(fit.rect_ptr) - 1
    node_rows = np.column_stack([fit.centre, fit.normal, fit.jsum.reshape(n, 9), fit.grad.reshape(n, 9),
                                 fit.frame.reshape(n, 6), fit.eps2.transpose(0, 2, 1).reshape(n, 9),
                                 fit.resid_moment])
    out = (rect_rows, node_rows)
    fit._rect_cache = (fit.rect, out)
    return out

