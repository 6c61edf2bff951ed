"""The depth relations of :mod:`.culling` computed per pair, for scenes whose polygons do not merge.

:func:`.culling.build_occluders` tabulates, for every (polygon, merged face) and (merged face, merged face)
pair, whether one reaches strictly beyond the other's plane on either side (``beyond_*``, ``front_*``,
``occ_beyond_*``, ``occ_reach_*``). For a scene whose n polygons merge into few faces those tables are
small; for a curved mesh (a UV sphere, a character) every face is a merged face of its own and they are
n² entries — dense relations (every face of a sphere is beyond every other face's plane), built in
O(n²) time (the 8,192-face sphere: ~25 s of its preparation, 0.8 GB). :class:`DepthPairs` keeps only
what the tests read per object (vertices, plane, tilt, coordinate noise) and answers the same questions
for the pairs that reach the per-receiver stage, with the same floating-point operations in the same
order as the tables' :func:`.culling._beyond` (bit-identical answers). Only two things are tabulated:

* the convex solids' columns (``front_*`` of a solid = the OR over its faces), through a support
  vertex first and, where that does not decide, only the faces near the plane (:func:`solid_columns`);
* the coplanar overlapping pairs, from the pairs whose bounding spheres meet (:func:`ball_pairs`).

:func:`ball_pairs` (pairs of balls that meet, grouped, vectorised over groups) also gives the per-receiver
stage its (cluster, volume) pairs whose bounding cones from the receiver meet (chord ≤ angle), instead
of receiver-independent lists of n² entries.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .tolerances import COORD_EPS, PLANE_EPS

__all__ = ["Bodies", "BeyondLists", "DepthPairs", "ball_pairs", "beyond_lists", "face_tree", "pair_flags",
           "side_flags", "solid_columns", "tree_above"]

#: relative rounding of the plane distances (differences of coordinates and a unit normal, each a few ulp):
#: :func:`side_flags`, and :func:`.culling._edge_separates`, which imports it
_ROUNDING = 64 * np.finfo(np.float64).eps


def side_flags(ds: list, rs: list, coef, noise):
    """The side decisions of a body's vertices against a plane, shared by the tables
    (:func:`.culling._beyond`) and the pairs (:func:`_beyond_pairs`), so that both decide bit for bit alike.

    ``ds, rs``: per vertex slot, the signed distances from the plane and the largest |coordinate
    difference| from its reference vertex (padding slots: distance 0), arrays of one shape; ``coef``, ``noise``
    broadcast to it (``4 PLANE_EPS + tilt`` and both bodies' coordinate noise). Returns ``(pos, neg,
    pos_body, neg_body)`` bool: a vertex beyond its own tolerance ``coef × reach + noise`` (one off the plane
    by more than rounding but within it counts for both sides), and beyond the body's largest tolerance."""
    eps_body = coef * np.maximum.reduce(rs) + noise
    p, ng, pb, nb, unsure = (np.zeros(np.shape(ds[0]), dtype=bool) for _ in range(5))
    for d, reach in zip(ds, rs):
        eps = coef * reach + noise
        ad = np.abs(d)
        # a vertex off the plane by more than rounding but within the decision tolerance may be on
        # either side: as a filter, it counts for both. Rounding here is that of d itself (a few ulp
        # of |rel|): the relative tolerance 4 PLANE_EPS |rel| is far wider for a vertex far from the
        # plane's reference vertex (a 1e6 quad seen against a 1e-6 triangle's plane: 3e-6 > the
        # quad's true 1e-6 reach to the triangle's near side, which decides whether it can hide it)
        unsure |= (ad > _ROUNDING * reach + noise) & (ad <= eps)
        p |= d > eps
        ng |= d < -eps
        pb |= d > eps_body
        nb |= d < -eps_body
    return p | unsure, ng | unsure, pb, nb


@dataclass
class Bodies:
    """Convex polygons as bodies and as planes of the depth tests.

    vertices (n, K, 3) padded by repeating the last vertex, counts (n,), normals (n, 3) unit, tilt (n,)
    the plane's uncertainty, noise (n,) = COORD_EPS × max |coordinate| (as :func:`.culling._beyond`).
    """

    vertices: np.ndarray
    counts: np.ndarray
    normals: np.ndarray
    tilt: np.ndarray

    def __post_init__(self):
        n = len(self.counts)
        self.noise = COORD_EPS * np.abs(self.vertices).max(axis=(1, 2)) if n else np.zeros(0)
        # bounding spheres (for the pre-tests only): the vertices' box centre, radius with a margin
        self.centers = 0.5 * (self.vertices.min(axis=1) + self.vertices.max(axis=1)) if n else np.zeros((0, 3))
        self.radii = (np.linalg.norm(self.vertices - self.centers[:, None], axis=2).max(axis=1) * (1 + 1e-9)
                      if n else np.zeros(0))


def _beyond_pairs(body: Bodies, b: np.ndarray, occ: Bodies, o: np.ndarray):
    """:func:`.culling._beyond` for the pairs ``(body b[e], plane of occ o[e])`` only: ``(pos, neg,
    pos_body, neg_body)``, each ``(E,)`` bool, bit for bit the tables' entries (the same operations in
    the same order, element by element)."""
    bv = body.vertices[b]
    k = bv.shape[1]
    valid = np.arange(k)[None, :] < body.counts[b][:, None]
    o0 = occ.vertices[o, 0]
    on = occ.normals[o]
    noise = body.noise[b] + occ.noise[o]
    coef = 4 * PLANE_EPS + occ.tilt[o]
    ds, rs = [], []
    for j in range(k):
        rel = [bv[:, j, c] - o0[:, c] for c in range(3)]
        d = rel[0] * on[:, 0] + rel[1] * on[:, 1] + rel[2] * on[:, 2]
        rs.append(np.maximum(np.maximum(np.abs(rel[0]), np.abs(rel[1])), np.abs(rel[2])))
        ds.append(np.where(valid[:, j], d, 0.0))
    return side_flags(ds, rs, coef, noise)


def pair_flags(body: Bodies, b: np.ndarray, occ: Bodies, o: np.ndarray, step: int = 1 << 18):
    """The combined flags of :func:`.culling.build_occluders` for pairs (body b, merged face o):
    ``(beyond_pos, beyond_neg, front_pos, front_neg, coplanar)``, each ``(E,)`` bool — the entries
    ``[b, o]`` of the tables ``beyond_*`` / ``front_*`` (bodies = polygons) or ``occ_beyond_*`` /
    ``occ_reach_*`` (bodies = the merged faces), and the coplanarity of the two surfaces."""
    out = [np.zeros(len(b), dtype=bool) for _ in range(5)]
    for s in range(0, len(b), step):
        bs, os_ = b[s:s + step], o[s:s + step]
        b_pos, b_neg, bb_pos, bb_neg = _beyond_pairs(body, bs, occ, os_)
        f_pos, f_neg, fb_pos, fb_neg = _beyond_pairs(occ, os_, body, bs)
        on_b, on_f = ~(bb_pos | bb_neg), ~(fb_pos | fb_neg)
        coplanar = on_b & on_f
        out[0][s:s + step] = np.where(coplanar, bb_pos, b_pos) | (on_b & ~on_f)
        out[1][s:s + step] = np.where(coplanar, bb_neg, b_neg) | (on_b & ~on_f)
        out[2][s:s + step] = np.where(coplanar, fb_pos, f_pos) | (on_f & ~on_b)
        out[3][s:s + step] = np.where(coplanar, fb_neg, f_neg) | (on_f & ~on_b)
        out[4][s:s + step] = coplanar
    return tuple(out)


def solid_columns(body: Bodies, occ: Bodies, face_ptr: np.ndarray, face_occ: np.ndarray, centers: np.ndarray,
                  radii: np.ndarray):
    """``(front_pos, front_neg)`` ``(n_b, n_s)`` bool: some face of solid s reaches strictly to the + / -
    side of body b's plane — the OR over the solid's faces of :func:`pair_flags`' ``front_*``, as the
    tables' ``per_solid`` columns, bit for bit.

    Per (body, solid): the face holding the vertex farthest along (against) the body's normal decides
    when its flag is True; otherwise every vertex is within the tests' tolerance of the plane on that
    side, and only the faces with a vertex within a bound ``T`` of every tolerance of the tests (see
    below) can have the flag: those are tested exactly. Small solids: O(n_b × solid vertices)
    multiply-adds for the support search (blocks of ~2**22); from ``SUPPORT_TREE_FROM`` padded vertices
    on, both searches go through a tree of bounding spheres (:func:`_tree_columns`; on a sphere about
    O(√V) nodes per body). O(n_b) exact pair tests for a convex solid.
    """
    n_b, n_s = len(body.counts), len(face_ptr) - 1
    fp = np.zeros((n_b, n_s), dtype=bool)
    fn = np.zeros((n_b, n_s), dtype=bool)
    if n_b == 0 or n_s == 0:
        return fp, fn
    o0 = body.vertices[:, 0]
    coef = 4 * PLANE_EPS + body.tilt
    for s in range(n_s):
        faces = face_occ[face_ptr[s]:face_ptr[s + 1]]
        fv = occ.vertices[faces]                                             # (F, K, 3), padding repeats
        f_k = fv.shape[1]
        pts = fv.reshape(-1, 3) - centers[s]              # about the solid's centre: rounding ~ eps reach
        # a bound on every tolerance of the tests (eps = coef reach + noise; reach <= |v - o0|), doubled,
        # plus the rounding of the pruning distances themselves
        reach = np.linalg.norm(centers[s] - o0, axis=1) + radii[s]
        t_bound = 2.0 * (coef * reach + body.noise + occ.noise[faces].max()) + 1e-12 * reach
        if SUPPORT_TREE_FROM is not None and len(pts) >= SUPPORT_TREE_FROM:
            _tree_columns(body, occ, faces, f_k, pts, o0 - centers[s], reach, t_bound, fp[:, s], fn[:, s])
            continue
        step = max(1, (1 << 22) // len(pts))
        for a in range(0, n_b, step):
            rows = np.arange(a, min(n_b, a + step))
            nb = body.normals[rows]
            d = pts @ nb.T - ((o0[rows] - centers[s]) * nb).sum(axis=1)                    # (V, b)
            for sign, table, col in ((1.0, fp, 2), (-1.0, fn, 3)):
                sd = sign * d
                best = np.argmax(sd, axis=0) // f_k                                       # (b,) face
                got = pair_flags(body, rows, occ, faces[best])[col]
                rest = np.flatnonzero(~got)
                if len(rest):
                    near = (sd[:, rest] >= -t_bound[rows[rest]]).reshape(len(faces), f_k, len(rest)).any(axis=1)
                    fi, ri = np.nonzero(near)                                            # (face, row) pairs
                    if len(fi):
                        hit = pair_flags(body, rows[rest[ri]], occ, faces[fi])[col]
                        got[rest[np.unique(ri[hit])]] = True
                table[rows, s] = got
    return fp, fn


#: solids with at least this many (padded) vertices search their support vertex and their faces near a
#: plane in a tree of bounding spheres (:func:`_tree_columns`, O(log V) per body) instead of against every
#: vertex (O(V) per body); None: never. Both give the same columns bit for bit (the column is the OR over
#: the solid's faces of exact pair tests either way; the search only chooses which faces are tested).
SUPPORT_TREE_FROM: int | None = 512

_LEAF = 8


def _sphere_tree(uv: np.ndarray):
    """A binary tree of bounding spheres over the points ``uv (U, 3)``: ``(order, lo, hi, left, right,
    center, radius)`` — node i holds ``uv[order[lo[i]:hi[i]]]``; children ``left/right`` (-1 at leaves,
    at most ``_LEAF`` points); ``center`` the points' box centre, ``radius`` their largest distance to it."""
    order = np.arange(len(uv))
    lo, hi, left, right = [0], [len(uv)], [-1], [-1]
    stack = [0]
    while stack:
        i = stack.pop()
        a, b = lo[i], hi[i]
        if b - a <= _LEAF:
            continue
        seg = uv[order[a:b]]
        axis = int(np.argmax(seg.max(axis=0) - seg.min(axis=0)))
        m = (b - a) // 2
        part = np.argpartition(seg[:, axis], m, kind="introselect")
        order[a:b] = order[a:b][part]
        for c0, c1 in ((a, a + m), (a + m, b)):
            lo.append(c0), hi.append(c1), left.append(-1), right.append(-1)
            stack.append(len(lo) - 1)
        left[i], right[i] = len(lo) - 2, len(lo) - 1
    lo, hi = np.array(lo), np.array(hi)
    center = np.empty((len(lo), 3))
    radius = np.empty(len(lo))
    for i in range(len(lo)):
        seg = uv[order[lo[i]:hi[i]]]
        center[i] = 0.5 * (seg.min(axis=0) + seg.max(axis=0))
        radius[i] = np.sqrt(((seg - center[i]) ** 2).sum(axis=1).max())
    return order, lo, hi, np.array(left), np.array(right), center, radius


def _tree_columns(body, occ, faces, f_k, pts, rel0, reach, t_bound, col_pos, col_neg, step: int = 4096):
    """:func:`solid_columns` for one solid through a tree of bounding spheres over its distinct vertices:
    per body and side, a branch-and-bound search for the support vertex (the largest signed distance;
    ties: the vertex's first appearance in ``pts``, as ``np.argmax``), its face's exact pair test, and
    where that is False, the faces with a vertex at signed distance ``>= -t_bound`` (found by pruning the
    spheres entirely below it), tested exactly. Writes ``col_pos``, ``col_neg (n_b,)``."""
    uv, first, inv = np.unique(pts, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    by_vertex = np.argsort(inv, kind="stable")                     # padded slots grouped by vertex
    v_ptr = np.concatenate([[0], np.cumsum(np.bincount(inv, minlength=len(uv)))])
    v_face = by_vertex // f_k                                      # local face of every slot
    order, lo, hi, left, right, center, radius = _sphere_tree(uv)
    scale = float(np.abs(pts).max()) + 1.0
    radius = radius * (1 + 1e-9) + 1e-12 * scale
    n_b = len(body.counts)
    for a in range(0, n_b, step):
        rows = np.arange(a, min(n_b, a + step))
        nb = body.normals[rows]
        off = (rel0[rows] * nb).sum(axis=1)                        # (b,)
        margin = 1e-12 * reach[rows]                               # rounding of the pruning distances
        for sign, col_out, col in ((1.0, col_pos, 2), (-1.0, col_neg, 3)):
            best = _tree_support(uv, first, order, lo, hi, left, right, center, radius, nb, off, sign, margin)
            got = pair_flags(body, rows, occ, faces[best // f_k])[col]
            rest = np.flatnonzero(~got)
            if len(rest):
                rr, vv = _tree_above(uv, order, lo, hi, left, right, center, radius, nb[rest], off[rest], sign,
                                     -t_bound[rows[rest]] - margin[rest])
                if len(rr):
                    cnt = v_ptr[vv + 1] - v_ptr[vv]
                    ri = np.repeat(rr, cnt)
                    slot = np.arange(len(ri)) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(v_ptr[vv], cnt)
                    fi = v_face[slot]
                    key = np.unique(ri * len(faces) + fi)
                    ri, fi = key // len(faces), key % len(faces)
                    hit = pair_flags(body, rows[rest[ri]], occ, faces[fi])[col]
                    got[rest[np.unique(ri[hit])]] = True
            col_out[rows] = got


def _descend(pairs_r, pairs_n, left, right, keep_leaf):
    """Children of the kept internal nodes; the kept leaves appended to ``keep_leaf``."""
    leaf = left[pairs_n] < 0
    keep_leaf.append((pairs_r[leaf], pairs_n[leaf]))
    r, n = pairs_r[~leaf], pairs_n[~leaf]
    return np.concatenate([r, r]), np.concatenate([left[n], right[n]])


def _dot(a, b):
    """Row-wise dot products of ``(N, 3)`` arrays."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _leaf_points(leaves, order, lo, hi):
    """``(row, point)`` for every point of the kept leaves."""
    r = np.concatenate([x[0] for x in leaves]) if leaves else np.zeros(0, dtype=np.int64)
    n = np.concatenate([x[1] for x in leaves]) if leaves else np.zeros(0, dtype=np.int64)
    cnt = hi[n] - lo[n]
    rep = np.repeat(r, cnt)
    pos = np.arange(len(rep)) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(lo[n], cnt)
    return rep, order[pos]


def _tree_support(uv, first, order, lo, hi, left, right, center, radius, nb, off, sign, margin):
    """Per row, the index in ``pts`` of the support vertex along ``sign nb`` (signed distance
    ``sign (v . n - off)``; ties: the smallest first appearance), by branch and bound: a sphere is dropped
    when its upper bound is below another sphere's lower bound of the same row (by more than ``margin``)."""
    m = len(nb)
    pr, pn = np.arange(m), np.zeros(m, dtype=np.int64)
    leaves = []
    rep = uv[order[lo]]                     # a vertex of every sphere: its distance is a lower bound
    low = np.full(m, -np.inf)               # the best vertex seen so far, per row
    while len(pr):
        n_r = nb[pr]
        c = sign * (_dot(center[pn], n_r) - off[pr])
        np.maximum.at(low, pr, sign * (_dot(rep[pn], n_r) - off[pr]))
        ok = c + radius[pn] >= low[pr] - margin[pr]
        pr, pn = _descend(pr[ok], pn[ok], left, right, leaves)
    r, u = _leaf_points(leaves, order, lo, hi)
    d = sign * (_dot(uv[u], nb[r]) - off[r])
    top = np.full(m, -np.inf)
    np.maximum.at(top, r, d)
    at = d == top[r]
    idx = np.full(m, np.iinfo(np.int64).max)
    np.minimum.at(idx, r[at], first[u[at]])
    return idx


def _tree_above(uv, order, lo, hi, left, right, center, radius, nb, off, sign, floor):
    """``(row, vertex)`` pairs with signed distance ``sign (v . n - off) >= floor[row]`` (a superset by
    the rounding: the pruning keeps a sphere whose upper bound reaches ``floor``)."""
    m = len(nb)
    pr, pn = np.arange(m), np.zeros(m, dtype=np.int64)
    leaves = []
    while len(pr):
        c = sign * (_dot(center[pn], nb[pr]) - off[pr])
        ok = c + radius[pn] >= floor[pr]
        pr, pn = _descend(pr[ok], pn[ok], left, right, leaves)
    r, u = _leaf_points(leaves, order, lo, hi)
    d = sign * (_dot(uv[u], nb[r]) - off[r])
    ok = d >= floor[r]
    return r[ok], u[ok]


def ball_pairs(group_a, center_a, radius_a, group_b, center_b, radius_b, big: float):
    """Pairs ``(i, j)`` of balls ``a_i``, ``b_j`` in the same group that meet: every pair with
    ``|center_a[i] - center_b[j]| <= radius_a[i] + radius_b[j]`` (to a relative 1e-9, so a few more),
    each once, in no particular order.

    Balls of radius ``>= big`` (or not finite) are paired with every ball of their group; the others go
    to a hierarchy of hashed grids: level L holds the balls of radius ``<= R_L = big / 2**(L/2)`` in
    cells of ``2 R_L``; two meeting balls are within one cell of the coarser one's level, so a query
    looks at the 3 × 3 × 3 cells around its centre there. Vectorised over all groups; O((A + B) levels
    log(A + B) + candidates), the candidates a few times the pairs.
    """
    group_a, group_b = np.asarray(group_a, dtype=np.int64), np.asarray(group_b, dtype=np.int64)
    big_a = ~(radius_a < big)
    big_b = ~(radius_b < big)
    out_i, out_j = [], []
    # the big balls against everything of their group (by sorting the other side by group)
    for bigs, grp_big, grp_all, swap in ((np.flatnonzero(big_a), group_a, group_b, False),
                                         (np.flatnonzero(big_b), group_b, group_a, True)):
        if not len(bigs):
            continue
        others = np.arange(len(grp_all))
        if swap:
            others = others[~big_a]                                          # big-big pairs once
        order = others[np.argsort(grp_all[others], kind="stable")]
        g_sorted = grp_all[order]
        lo = np.searchsorted(g_sorted, grp_big[bigs], side="left")
        hi = np.searchsorted(g_sorted, grp_big[bigs], side="right")
        i, j = _ranges(bigs, lo, hi, order)
        out_i.append(j if swap else i)
        out_j.append(i if swap else j)
    sa, sb = np.flatnonzero(~big_a), np.flatnonzero(~big_b)
    max_level = 40

    def level(r):
        lv = np.floor(2.0 * np.log2(big / np.maximum(r, big * 2.0 ** (-max_level / 2))))
        return np.clip(lv, 0, max_level).astype(np.int64)

    la, lb = level(radius_a[sa]), level(radius_b[sb])
    offsets = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)], dtype=np.int64)
    for lv in np.union1d(la, lb):
        cell = 2.000001 * big / 2.0 ** (lv / 2)          # a little over 2 R_L: margin for rounding
        for stored, s_lv, s_grp, s_c, queries, q_lv, q_grp, q_c, swap in (
                (sa, la, group_a, center_a, sb, lb, group_b, center_b, False),
                (sb, lb, group_b, center_b, sa, la, group_a, center_a, True)):
            st = stored[s_lv == lv]
            qs = queries[(q_lv > lv) if swap else (q_lv >= lv)]   # pairs of equal level in the first pass
            if not len(st) or not len(qs):
                continue
            s_cell = np.floor(s_c[st] / cell).astype(np.int64)
            key_s = _hash(s_grp[st], s_cell)
            order = np.argsort(key_s, kind="stable")
            key_sorted, st_sorted, cell_sorted = key_s[order], st[order], s_cell[order]
            q_cell = np.floor(q_c[qs] / cell).astype(np.int64)
            for off in offsets:
                want = q_cell + off
                key_q = _hash(q_grp[qs], want)
                lo = np.searchsorted(key_sorted, key_q, side="left")
                hi = np.searchsorted(key_sorted, key_q, side="right")
                q_loc, pos = _ranges(np.arange(len(qs)), lo, hi, np.arange(len(st)))
                qi, sj = qs[q_loc], st_sorted[pos]
                # that very cell of that group (hash collisions), and balls that meet
                ok = (s_grp[sj] == q_grp[qi]) & (cell_sorted[pos] == want[q_loc]).all(axis=1)
                qi, sj = qi[ok], sj[ok]
                gap = q_c[qi] - s_c[sj]
                r = radius_a[qi if swap else sj] + radius_b[sj if swap else qi]
                ok = (gap * gap).sum(axis=1) <= (r * (1 + 1e-9)) ** 2
                qi, sj = qi[ok], sj[ok]
                out_i.append(qi if swap else sj)
                out_j.append(sj if swap else qi)
    if not out_i:
        e = np.zeros(0, dtype=np.int64)
        return e, e
    return np.concatenate(out_i), np.concatenate(out_j)


def _ranges(owner, lo, hi, values):
    """For every ``owner[q]``, the entries ``values[lo[q]:hi[q]]``: ``(owner repeated, value)``."""
    n = hi - lo
    rep = np.repeat(np.arange(len(owner)), n)
    pos = np.arange(len(rep)) - np.repeat(np.cumsum(n) - n, n) + np.repeat(lo, n)
    return owner[rep], values[pos]


def _hash(group, cell):
    """One int64 per (group, cell ``(N, 3)``) (collisions possible; the caller checks the group and the
    exact distance)."""
    h = group * np.int64(0x9E3779B97F4A7C15 - (1 << 64))
    for c in range(3):
        h = (h ^ cell[:, c]) * np.int64(0x100000001B3)
    return h


@dataclass
class DepthPairs:
    """What the per-pair depth tests need instead of the tables (see the module doc).

    ``polys``, ``faces``: :class:`Bodies` of the scene's polygons and of the merged faces; ``solid_front_pos,
    solid_front_neg (n, n_s)`` and ``solid_reach_pos, solid_reach_neg (n_o, n_s)``: the solids' columns of
    ``front_*`` and ``occ_reach_*`` (bits, :func:`.rowops.pack_bits`).
    """

    polys: Bodies
    faces: Bodies
    solid_front_pos: np.ndarray
    solid_front_neg: np.ndarray
    solid_reach_pos: np.ndarray
    solid_reach_neg: np.ndarray
    lists: BeyondLists | None = None

    def can_hide(self, polys: bool, b: np.ndarray, o: np.ndarray, beyond_pos: np.ndarray, front_pos: np.ndarray):
        """``(E,)`` bool: volume o (merged face ``o < n_o``, else solid ``o - n_o``) can hide part of body b
        (a polygon if ``polys``, else a merged face): ``beyond_*[b, o]`` by ``beyond_pos (E,)`` (True: the
        + side) and ``front_*[b, o]`` by ``front_pos (E,)`` — what the tables' lookups give, bit for bit."""
        n_o = len(self.faces.counts)
        body = self.polys if polys else self.faces
        sp, sn = (self.solid_front_pos, self.solid_front_neg) if polys else (self.solid_reach_pos,
                                                                             self.solid_reach_neg)
        out = np.zeros(len(b), dtype=bool)
        face = np.flatnonzero(o < n_o)
        if len(face):
            # cheap necessary conditions first: b reaches within every tolerance of the chosen side of o's
            # plane, and o of the chosen side of b's plane (bounding spheres; see :func:`_reaches`)
            bf, of = b[face], o[face]
            face = face[_reaches(body, bf, self.faces, of, beyond_pos[face])
                        & _reaches(self.faces, of, body, bf, front_pos[face])]
            bp, bn, fp, fn, _ = pair_flags(body, b[face], self.faces, o[face])
            out[face] = np.where(beyond_pos[face], bp, bn) & np.where(front_pos[face], fp, fn)
        sol = np.flatnonzero(o >= n_o)
        if len(sol):                     # a solid's volume: beyond always, front as any of its faces
            bs, os_ = b[sol], o[sol] - n_o
            out[sol] = np.where(front_pos[sol], _bit_at(sp, bs, os_), _bit_at(sn, bs, os_))
        return out


def _reaches(body: Bodies, b, plane: Bodies, o, pos):
    """``(E,)`` bool, a necessary condition for :func:`_beyond_pairs`' flags of the pairs (body b, plane of
    o) on the + side (``pos``) or the - side to hold (combined as :func:`pair_flags` does): the body's
    bounding sphere reaches to within ``T`` of that side, ``T`` twice a bound on every tolerance of the
    tests (``coef reach + noise``, reach <= |centre - o0| + radius) plus the rounding of this test."""
    o0 = plane.vertices[o, 0]
    rel = body.centers[b] - o0
    d = (rel * plane.normals[o]).sum(axis=1)
    reach = np.sqrt((rel * rel).sum(axis=1)) + body.radii[b]
    t = 2.0 * ((4 * PLANE_EPS + plane.tilt[o]) * reach + body.noise[b] + plane.noise[o]) + 1e-12 * reach
    return np.where(pos, d, -d) + body.radii[b] >= -t


def _bit_at(bits, i, j):
    """``a[i, j]`` of a table packed by :func:`.rowops.pack_bits` (as :func:`.rowops.bit_at`)."""
    return ((bits[i, j >> 3] >> (j & 7).astype(np.uint8)) & 1).astype(bool)


#: leaves of :func:`beyond_lists`' tree (merged faces per leaf)
LEAF = 4
#: a (face, side) whose tree search keeps more nodes than this at some level is *open*: its list is not
#: kept (the faces beyond that side of its plane are many; the receivers pair them by their cones)
OPEN_NODES = 160
#: ... or whose nodes wholly beyond that side hold more faces than this
OPEN_FACES = 64


@dataclass
class BeyondLists:
    """For every merged face o and side (0: +, 1: -), the merged faces k != o with ``occ_beyond_*[k, o]``
    (k reaches strictly beyond that side of o's plane), where those are few: ``faces[ptr[side, o]:
    ptr[side, o + 1]]`` (ascending); ``open (2, n_o)`` bool where no list is kept (many faces beyond
    that side: the receivers pair them by their cones)."""

    ptr: np.ndarray
    faces: np.ndarray
    open: np.ndarray


def face_tree(faces: Bodies):
    """The tree of :func:`tree_above` (built once for several searches)."""
    return _tree(faces)


def _tree(faces: Bodies):
    """A complete binary tree over the faces (leaves of :data:`LEAF`): the faces ordered by recursive
    median splits of their centres along each node's longest extent, so that every node is a compact
    patch (a Morton order's fixed-size ranges jump between distant cells: boxes and slabs many times a
    patch's size, whose bounds keep ~n^½ nodes near a face of a curved shell); per level (root first)
    one ``(14, N)`` array per node: the box holding every member's vertices (centre c, half extents h),
    the members' mean normal m, the range of ``m · (x - c)`` over their vertices and their largest
    distance from the axis (c, m), |h|, the members' largest ``noise``; and the sorted face order."""
    n = len(faces.counts)
    n_leaf = max(1, -(-n // LEAF))
    depth = int(np.ceil(np.log2(n_leaf))) if n_leaf > 1 else 0
    width = (1 << depth) * LEAF
    order = _median_order(faces.centers, width)
    slot = np.minimum(np.arange(width), n - 1)                         # pad by repeating the last face
    fv = faces.vertices[order[slot]]                                   # (width, K, 3)
    bmin, bmax = fv.min(axis=1), fv.max(axis=1)
    fn = faces.normals[order[slot]]
    noise = faces.noise[order[slot]]
    k = fv.shape[1]
    levels = []
    size = LEAF
    while True:
        b_lo = bmin.reshape(-1, size, 3).min(axis=1)
        b_hi = bmax.reshape(-1, size, 3).max(axis=1)
        c = 0.5 * (b_lo + b_hi)
        h = 0.5 * (b_hi - b_lo) * (1 + 1e-9)                          # the box's half extents
        # a slab along the members' mean normal m and the distance from the axis (c, m): a curved patch
        # is thin along m, which bounds its reach along nearby normals far tighter than its box
        m = fn.reshape(-1, size, 3).sum(axis=1)
        m_len = np.linalg.norm(m, axis=1)
        m = np.where(m_len[:, None] > 1e-6 * size, m / np.maximum(m_len, 1e-300)[:, None], np.array([1.0, 0, 0]))
        rel = fv.reshape(len(c), size * k, 3) - c[:, None]
        along = np.einsum("nvc,nc->nv", rel, m)
        perp = np.linalg.norm(rel - along[..., None] * m[:, None], axis=2).max(axis=1)
        nz = noise.reshape(-1, size).max(axis=1)
        packed = np.concatenate([c.T, h.T, m.T, along.min(axis=1)[None], along.max(axis=1)[None], perp[None],
                                 np.linalg.norm(h, axis=1)[None], nz[None]])
        levels.append((packed,))
        if size >= width:
            break
        size *= 2
    return levels[::-1], order


def _median_order(centers: np.ndarray, width: int) -> np.ndarray:
    """``(n,)`` an order of the points ``centers (n, 3)`` such that every aligned range of ``width / 2**L``
    slots (the nodes of level L; slots from n on are padding) splits at its middle between the lower and
    the upper half of its members along the longest extent of their box. O(n log² n) (a stable sort per
    level), deterministic."""
    n = len(centers)
    order = np.arange(n)
    size = width
    while size > LEAF:
        starts = np.arange(0, n, size)
        c = centers[order]
        ext = np.maximum.reduceat(c, starts, axis=0) - np.minimum.reduceat(c, starts, axis=0)
        node = np.arange(n) // size
        key = c[np.arange(n), ext.argmax(axis=1)[node]]
        order = order[np.lexsort((key, node))]
        size //= 2
    return order


def _support(node_level, node, nrm, both: bool = False):
    """``(E,)`` an upper bound (to rounding) on ``nrm · (x - c)`` over the vertices x of the nodes (their
    box centre c), for unit ``nrm (3, E)`` (by component): the smaller of the box's and the slab's bounds.
    Also returns ``(d_c (3, E) = c, |h| (E,))`` of the nodes for the caller; with ``both``, first the bound
    for ``-nrm`` too (the same bits as ``_support(node_level, node, -nrm)[0]``: negation is exact)."""
    g = node_level[-1][:, node]                       # (14, E): c, h, m, a_lo, a_hi, perp, |h|
    c, h, m = g[0:3], g[3:6], g[6:9]
    box = np.abs(nrm[0]) * h[0] + np.abs(nrm[1]) * h[1] + np.abs(nrm[2]) * h[2]
    nm = nrm[0] * m[0] + nrm[1] * m[1] + nrm[2] * m[2]
    w0, w1, w2 = nrm[0] - nm * m[0], nrm[1] - nm * m[1], nrm[2] - nm * m[2]
    w = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    lo, hi = nm * g[9], nm * g[10]
    pad = 1e-12 * g[12]
    sup = np.minimum(box, (np.maximum(lo, hi) + w * g[11]) * (1 + 1e-9) + pad)
    if not both:
        return sup, c, g[12]
    neg = np.minimum(box, (np.maximum(-lo, -hi) + w * g[11]) * (1 + 1e-9) + pad)
    return sup, neg, c, g[12]


def beyond_lists(faces: Bodies) -> BeyondLists:
    """:class:`BeyondLists` by a search of a tree over the faces for every (face, side) at once: a node is
    kept while its box reaches within every tolerance of that side of the face's plane (a necessary
    condition of the flag, see :func:`_reaches`), the leaves' faces are tested exactly (:func:`pair_flags`).
    O(n_o log n_o) node tests for a mesh whose faces have few others beyond one side of their plane."""
    n_o = len(faces.counts)
    is_open = np.zeros((2, n_o), dtype=bool)
    if n_o == 0:
        return BeyondLists(np.zeros((2, 1), dtype=np.int64), np.zeros(0, dtype=np.int64), is_open)
    levels, order = _tree(faces)
    found = []
    for a in range(0, n_o, BLOCK):                     # blocks of faces: temporaries ~BLOCK x 2 x 320 nodes
        o, side, k = _beyond_block(faces, levels, order, np.arange(a, min(n_o, a + BLOCK)), is_open)
        found.append((o, side, k))
    o, side, k = (np.concatenate(x) for x in zip(*found))
    srt = np.lexsort((k, o, side))
    o, side, k = o[srt], side[srt], k[srt]
    ptr = np.zeros((2, n_o + 1), dtype=np.int64)
    np.add.at(ptr, (side, o + 1), 1)
    ptr = np.cumsum(ptr.ravel()).reshape(2, n_o + 1)
    ptr[1] -= ptr[1, 0] - ptr[0, -1]                     # side 1 starts where side 0 ends
    return BeyondLists(ptr, k, is_open)


#: faces per block of :func:`beyond_lists`' and :func:`tree_above`'s searches
BLOCK = 2048


def _beyond_block(faces: Bodies, levels, order, block, is_open):
    """:func:`beyond_lists` for the faces ``block``: ``(o, side, k)`` the listed pairs (``is_open`` set
    in place)."""
    n_o = len(faces.counts)
    o = np.repeat(block, 2)
    side = np.tile(np.array([0, 1]), len(block))
    node = np.zeros(2 * len(block), dtype=np.int64)
    tilt_c = 4 * PLANE_EPS + faces.tilt
    o0 = faces.vertices[:, 0]
    o0t, nt = np.ascontiguousarray(o0.T), np.ascontiguousarray(faces.normals.T)
    for lv, lvl in enumerate(levels):
        sgn = np.where(side == 0, 1.0, -1.0)
        nrm = nt[:, o] * sgn                                               # towards the side searched
        sup, sup_neg, c, h_len = _support(lvl, node, nrm, both=True)
        r0, r1, r2 = c[0] - o0t[0, o], c[1] - o0t[1, o], c[2] - o0t[2, o]
        d = r0 * nrm[0] + r1 * nrm[1] + r2 * nrm[2]
        reach = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) + h_len
        t = 2.0 * (tilt_c[o] * reach + lvl[0][13, node] + faces.noise[o]) + 1e-12 * reach
        keep = d + sup >= -t
        # nodes wholly beyond that side (their faces are all on the list): many such faces open it early
        wholly = keep & (d - sup_neg > t)
        size = LEAF << (len(levels) - 1 - lv)
        key = 2 * o + side
        many = np.bincount(key[wholly], minlength=2 * n_o) * size > OPEN_FACES
        o, side, node = o[keep], side[keep], node[keep]
        key = key[keep]
        many |= np.bincount(key, minlength=2 * n_o) > OPEN_NODES
        if many.any():
            idx = np.flatnonzero(many)
            is_open[idx % 2, idx // 2] = True
            drop = many[key]
            o, side, node = o[~drop], side[~drop], node[~drop]
        if lv + 1 < len(levels):
            o, side, node = np.repeat(o, 2), np.repeat(side, 2), np.stack([2 * node, 2 * node + 1], axis=1).ravel()
    # leaves: their faces (padding repeats the last face: drop repeats), tested exactly
    k = order[np.minimum(node[:, None] * LEAF + np.arange(LEAF), len(order) - 1)]
    o, side = np.repeat(o, LEAF), np.repeat(side, LEAF)
    k = k.ravel()
    real = (node[:, None] * LEAF + np.arange(LEAF) < len(order)).ravel() & (k != o)
    o, side, k = o[real], side[real], k[real]
    near = _reaches(faces, k, faces, o, side == 0)                     # the face's own sphere first
    o, side, k = o[near], side[near], k[near]
    bp, bn = pair_flags(faces, k, faces, o)[:2]
    hit = np.where(side == 0, bp, bn)
    o, side, k = o[hit], side[hit], k[hit]
    return o, side, k


def tree_above(faces: Bodies, o0: np.ndarray, nrm: np.ndarray, thr: np.ndarray, cap: int = 256, tree=None):
    """For planes ``o0 + x, nrm · x = 0`` (E of them, unit ``nrm (E, 3)``): the faces that may have a vertex x
    with ``nrm · (x - o0) > thr`` (a search of :func:`_tree`: a node is kept while its bound reaches
    ``thr``, to rounding). Returns ``(e, k)`` candidate (plane, face) pairs and ``(E,)`` bool: planes
    whose search kept more than ``cap`` nodes at some level (no candidates listed for them). ``tree``:
    ``_tree(faces)`` if already built."""
    n_e = len(thr)
    many = np.zeros(n_e, dtype=bool)
    levels, order = _tree(faces) if tree is None else tree
    out = [_above_block(levels, order, o0, nrm, thr, cap, np.arange(a, min(n_e, a + BLOCK)), many)
           for a in range(0, n_e, BLOCK)]
    if not out:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), many
    e, k = (np.concatenate(x) for x in zip(*out))
    return e, k, many


def _above_block(levels, order, o0, nrm, thr, cap, e, many):
    """:func:`tree_above` for the planes ``e`` (``many`` set in place)."""
    n_e = len(thr)
    node = np.zeros(len(e), dtype=np.int64)
    o0t, nt = np.ascontiguousarray(o0.T), np.ascontiguousarray(nrm.T)
    for lv, lvl in enumerate(levels):
        nv = nt[:, e]
        sup, c, h_len = _support(lvl, node, nv)
        r0, r1, r2 = c[0] - o0t[0, e], c[1] - o0t[1, e], c[2] - o0t[2, e]
        d = r0 * nv[0] + r1 * nv[1] + r2 * nv[2]
        reach = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) + h_len
        keep = d + sup >= thr[e] - 1e-12 * reach
        e, node = e[keep], node[keep]
        over = np.bincount(e, minlength=n_e) > cap
        if over.any():
            many |= over
            drop = over[e]
            e, node = e[~drop], node[~drop]
        if lv + 1 < len(levels):
            e, node = np.repeat(e, 2), np.stack([2 * node, 2 * node + 1], axis=1).ravel()
    slots = node[:, None] * LEAF + np.arange(LEAF)
    real = slots < len(order)
    k = order[np.minimum(slots, len(order) - 1)][real]
    return np.repeat(e, LEAF)[real.ravel()], k
