"""Error-bounded far field: uniform faces as one polygon, clear tree nodes summed whole, weak edges bounded.

Only with a user ``tolerance > 0`` (absolute, W m^-2, per channel; :func:`.local_pass.irradiance`); at
``tolerance = 0`` nothing here runs and the result is the exact path's, bit for bit. Half the tolerance
goes to the proxies, half to the edges left out; the bound actually used is returned per receiver
(:class:`FarFieldStats`).

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

__all__ = ["FarFieldStats", "NodeEdges", "clear_node_test", "far_field_irradiance", "node_edges", "proxy_scene"]

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


@dataclass
class FarFieldStats:
    """What a call of :func:`.local_pass.irradiance` with ``return_stats=True`` bounded.

    Attributes:
        tolerance: (3,) the absolute tolerance asked for (W m^-2 per channel).
        error_bound: (m, 3) bound on ``|H − H_exact|`` per receiver and channel: what the far field left
            out plus the rounding allowance (0 at tolerance 0, where H is exact).
        edges_skipped, edges_summed: (m,) welded edges left out (bounded) and summed per receiver by the
            far field (0 at tolerance 0); clear_nodes: (m,) hierarchy nodes above the tiles summed whole.
    """

    tolerance: np.ndarray
    error_bound: np.ndarray
    edges_skipped: np.ndarray | None = None
    edges_summed: np.ndarray | None = None
    clear_nodes: np.ndarray | None = None

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
                     tilt, noise, dn, d0)


def clear_node_test(ne: NodeEdges, h, points, normals, ep, en):
    """For (receiver, inner node) entries ``ep, en (E,)`` whose face has a volume instance and whose list
    of cutting volumes is empty: ``(clear (E,) bool, side (E,) float ±1)``.

    Clear: every tile below the node would be a clear tile (:func:`.clear_tiles.clear_pairs`) — its box's
    corners are above the horizon by more than the flat and below-horizon tolerances of the tiles' tests
    (PLANE_EPS × (distance + 2 radius) of the node: a tile's are no larger), and P is off every tile's
    plane by more than :data:`NODE_SIDE_FACTOR` times the tile test's margin, the tiles' plane spread
    (``dn``, ``d0``) included.
    """
    ok = ne.usable[en]
    corners = h.corners[en] - points[ep][:, None, :]
    height = np.matmul(corners, normals[ep][:, :, None])[..., 0].min(axis=1)
    rel = h.centers[en] - points[ep]
    dist = np.sqrt(np.einsum("ij,ij->i", rel, rel))
    r = h.radii[en]
    scale = dist + r
    ok &= height > PLANE_EPS * (scale + r) + 1e-15 * np.abs(corners).max(axis=(1, 2))
    d = np.einsum("ij,ij->i", ne.normal[en], ne.point[en] - points[ep])
    plane_tol = ((PLANE_EPS + ne.tilt[en]) * scale + ne.noise[en] + COORD_EPS * np.abs(points[ep]).max(axis=1))
    spread = ne.dn[en] * dist + ne.d0[en]
    ok &= np.abs(d) - spread > NODE_SIDE_FACTOR * (SIDE_MARGIN * scale + 4.0 * plane_tol)
    return ok, np.sign(d)


def far_field_irradiance(ne: NodeEdges, h, point, node, side, points, normals, tolerance):
    """``H`` of the clear nodes and tiles ``(point (P,), node (P,), side (P,) ±1)`` (the lit ones) and its
    bound.

    Args:
        ne: the scene's :class:`NodeEdges`; h: its hierarchy (bounding spheres); point, node: the
            pairs; points, normals: (m, 3) receivers; tolerance: (3,) absolute tolerance on H.
    Returns:
        ``H (m, 3)`` (W m^-2, the ``π ·`` of eq. 3 included), ``bound (m, 3)`` (see the module doc),
        ``skipped (m,)`` edges left out and ``summed (m,)`` edges computed per receiver.
    """
    m = len(points)
    out = np.zeros((m, 3))
    bound = np.zeros((m, 3))
    if not len(point):
        return out, bound, np.zeros(m), np.zeros(m)
    tol = np.broadcast_to(np.asarray(tolerance, dtype=np.float64), (3,))
    n_pairs = np.bincount(point, minlength=m)
    share = tol[None, :] * (1.0 - SAFETY) / np.maximum(n_pairs[point], 1)[:, None]           # (P, 3)
    rel = h.centers[node] - points[point]
    d = np.sqrt(np.einsum("ij,ij->i", rel, rel)) - h.radii[node]
    start, n_e = ne.ptr[node], ne.ptr[node + 1] - ne.ptr[node]
    # longest prefix with ½ mass / d × (1 + SAFETY) <= share in every channel: binary search per pair
    limit = np.where(d[:, None] > 0, 2.0 * share * np.maximum(d, 0.0)[:, None] / (1.0 + SAFETY), -1.0)
    lo = np.zeros(len(node), dtype=np.int64)           # skippable count: mass[start + lo - 1] fits
    hi = n_e.copy()
    while True:
        act = lo < hi
        if not act.any():
            break
        mid = (lo + hi + 1) // 2
        idx = np.maximum(start + mid - 1, 0)
        fits = act & (ne.mass[idx] <= limit).all(axis=1) & (mid > 0)
        lo = np.where(fits, mid, lo)
        hi = np.where(act & ~fits, mid - 1, hi)
    skip = lo
    used = np.where(skip[:, None] > 0, ne.mass[np.maximum(start + skip - 1, 0)], 0.0)
    pair_bound = 0.5 * used / np.where(d > 0, d, 1.0)[:, None] * (1.0 + SAFETY)
    for c in range(3):
        bound[:, c] = np.bincount(point, weights=pair_bound[:, c], minlength=m)
    # the remaining edges, in batches of about 2**14 terms
    n_run = n_e - skip
    ends = np.cumsum(n_run)
    cuts = np.searchsorted(ends, np.arange(2**14, ends[-1] if len(ends) else 0, 2**14), side="right")
    bounds_ = np.unique(np.concatenate([[0], cuts, [len(node)]]))
    mag = np.zeros((m, 3))
    vsum = np.zeros((m, 3))
    has_v = bool((ne.weight[:, 3:] != 0).any()) if len(ne.weight) else False
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
        w = ne.weight[pos]
        # per pair (its edges are consecutive), then per receiver
        run = np.flatnonzero(cnt > 0)
        first = (np.cumsum(cnt) - cnt)[run]
        per = np.add.reduceat(t[:, None] * w, first, axis=0) * side[s:e][run, None]            # (P', 6)
        per_mag = np.add.reduceat(np.abs(t)[:, None] * np.abs(w[:, :3]), first, axis=0)
        pp = point[s:e][run]
        np.add.at(out, pp, per[:, :3])
        np.add.at(mag, pp, per_mag)
        if has_v:
            np.add.at(vsum, pp, per[:, 3:])
    # H = π × side/2π × Σ W t
    out *= 0.5
    # the proxies' radiance bound: π Σ ½ range F over clear proxies, = ½ Σ side V t (>= 0 exactly)
    bound += ROUNDING * 0.5 * mag + 0.5 * np.abs(vsum) * (1.0 + SAFETY)
    return out, bound, np.bincount(point, weights=skip, minlength=m), np.bincount(point, weights=n_run, minlength=m)


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


def proxy_scene(scene, occ, tolerance):
    """The scene with every nearly uniform merged face replaced by one polygon, and its radiance bound.

    A merged face (:func:`.culling.build_occluders`: coplanar, edge-connected convex polygons that tile
    one convex polygon exactly) whose members' radiance spans ``range_c <= 2 tolerance_c / π`` in every
    channel, with no duplicate or coplanar-overlapping member, is replaced by that convex polygon with
    the mid-range radiance. The occluding geometry is the same (the union of the members is the
    polygon), so ``|H − H_proxy| <= π Σ_f ½ range_f F_f`` with ``F_f`` the proxy's visible form factor;
    the visible parts of different faces do not overlap on the hemisphere (``Σ_f F_f <= 1``), so this
    is at most ``tolerance``: the caller computes it per receiver from the proxies' visible form factors
    and half ranges (:func:`.local_pass.irradiance` gives the proxies half its tolerance, the edges left
    out the other half).

    Returns ``(proxy scene, half_range (n_p, 3) or None)`` (``scene`` itself and None when no face
    qualifies); cached on ``scene`` for the set of qualifying faces. The proxy scene has the same
    ``double_sided``; its polygons are the kept convex polygons of ``scene`` and the proxies.
    """
    if scene.linear or occ.n == 0:
        return scene, None
    tol = np.broadcast_to(np.asarray(tolerance, dtype=np.float64), (3,))
    lo, hi, size, dirty = _face_ranges(scene, occ)
    ok = (size >= 2) & ~dirty & ((hi - lo) * (0.5 * np.pi) <= tol[None, :]).all(axis=1) & np.isfinite(hi).all(axis=1)
    if not ok.any():
        return scene, None
    key = ok.tobytes()
    cached = getattr(scene, "_proxy", None)
    if cached is not None and cached[0] is occ and cached[1] == key:
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
    scene._proxy = (occ, key, sp, half_range)
    return sp, half_range
