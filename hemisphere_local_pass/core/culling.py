"""Skipping work a scene does not need: merged occluders and the pair tests of sec. 3.4.

Occluders
---------
What hides a polygon A from P is the union of the *shadow volumes* of the other polygons: the part of
space beyond B's plane (seen from P) inside the cone from P over B. Coplanar polygons that tile a convex
region C have exactly the shadow volume of C (the union of their cones is C's cone), so for occlusion
the scene's subdivided walls and block faces are replaced by their merged convex faces. This is exact,
and it removes the needless splitting of fragments along the subdivision lines: a wall of 1,000 quads
occludes like one quad. Groups that do not merge into one convex polygon (holes, L-shapes, T-junctions,
overlaps) keep their polygons as individual occluders, which is exact too, only slower.

Pair tests
----------
Occlusion work is done only for (polygon, occluder) pairs where (a) some vertex of the polygon lies
strictly beyond the occluder's plane on the side away from P (precomputed per scene for both sides
— independent of P), and (b) the bounding cones of the two, seen from P, overlap. Everything else (the
clips) only runs for pairs that pass.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

# _ROUNDING: the plane distances' rounding, one value for _edge_separates and side_flags
from .depth_pairs import _ROUNDING, Bodies, DepthPairs, ball_pairs, beyond_lists, pair_flags, side_flags, solid_columns
from .inner_solids import inner_solids
from .rowops import components, pack_bits, unique_rows
from .scene import Scene, plane_uncertainty
from .solids import Solids, build_solids, join_solids, no_solids
from .tolerances import CONVEXITY_EPS, COORD_EPS, PLANARITY_EPS, PLANE_EPS

__all__ = ["Occluders", "VolumePairs", "build_occluders"]


@dataclass
class VolumePairs:
    """The receiver-independent (merged face, volume) pairs of :func:`.visibility.coverage`, sparse.

    Combination ``c = 2 s + t``: ``s = 0`` for ``occ_beyond_pos`` (a receiver behind the volume's
    plane), 1 for ``occ_beyond_neg``; ``t = 0`` for ``occ_reach_pos`` (a receiver in front of the
    face's plane), 1 for ``occ_reach_neg``. Pair (face f, volume o), ``o != f``, is in combination c
    when both flags hold. ``by_face_ptr (4, n_o+1)``, ``by_face_vol[c]``: CSR lists of the
    volumes of every face (ascending); ``by_vol_ptr (4, n_vol+1)``, ``by_vol_face[c]``: the faces of
    every volume (ascending); entries uint16 below 65,536 volumes, else int32: 4 (8) bytes a pair.
    """

    by_face_ptr: np.ndarray
    by_face_vol: list
    by_vol_ptr: np.ndarray
    by_vol_face: list


def _volume_pairs(beyond: tuple, reach: tuple) -> VolumePairs:
    """:class:`VolumePairs` from the dense ``(n_o, n_vol)`` tables ``beyond = (pos, neg)``, ``reach =
    (pos, neg)``, a block of faces (or volumes) at a time: temporaries of about 2**20 entries besides
    the lists (2 bytes an entry per orientation below 65,536 volumes, else 4), O(n_o n_vol) time."""
    n_o, n_vol = beyond[0].shape
    idx = np.uint16 if n_vol < 2**16 else np.int32           # 2 bytes an entry up to 65,535 volumes
    f_ptr, f_vol, v_ptr, v_face = [], [], [], []
    for s in (0, 1):
        for t in (0, 1):
            for by_vol in (False, True):
                n_r = n_vol if by_vol else n_o
                step = max(1, (1 << 20) // max(1, n_o if by_vol else n_vol))
                counts, vals = [np.zeros(1, dtype=np.int64)], []
                for a in range(0, n_r, step):
                    e = min(n_r, a + step)
                    blk = (beyond[s][:, a:e] & reach[t][:, a:e]).T if by_vol else beyond[s][a:e] & reach[t][a:e]
                    d = np.arange(a, min(e, n_o))
                    blk[d - a, d] = False                          # a face never hides itself
                    r, c = np.nonzero(blk)
                    counts.append(np.bincount(r, minlength=e - a))
                    vals.append(c.astype(idx))
                ptr = np.cumsum(np.concatenate(counts))
                (v_ptr if by_vol else f_ptr).append(ptr)
                (v_face if by_vol else f_vol).append(np.concatenate(vals) if vals else np.zeros(0, dtype=idx))
    return VolumePairs(np.array(f_ptr, dtype=np.int64).reshape(4, n_o + 1), f_vol,
                       np.array(v_ptr, dtype=np.int64).reshape(4, n_vol + 1), v_face)


@dataclass
class Occluders:
    """Convex occluders of a scene.

    Attributes:
        vertices: (n_o, K_o, 3) padded convex polygons (world space).
        counts: (n_o,) vertex counts.
        normals: (n_o, 3) unit plane normals.
        centers, radii: (n_o, 3), (n_o,) bounding spheres.
        members: (n,) occluder index of every convex polygon of the scene.
        beyond_pos, beyond_neg: (n, n_o) bool, packed as bits (:func:`.rowops.pack_bits`; read with
            :func:`.rowops.bit_at`, like every table below) — polygon i has a vertex strictly on the
            positive / negative side of occluder o's plane. A polygon can only be hidden by o from a point
            on the other side.
        occ_beyond_pos, occ_beyond_neg: (n_o, n_o) bool, as bits — the same between occluders.
        front_pos, front_neg: (n, n_o) bool, as bits — occluder o has a vertex strictly on the positive /
            negative side of polygon i's plane. o can only hide part of i from a receiver on a side o
            reaches to.
        tile_of: (n,) tile of every polygon; tiles split the members of large merged occluders into
            spatial groups of about :data:`TILE_SIZE` (sec. 3.4's voxels): tile_corners (T, 8, 3) the
            corners of each tile's bounding box, tile_centers (T, 3), tile_radii (T,), tile_occluder (T,);
            tile_ptr (T+1,), tile_members: CSR lists of every tile's polygons (the hierarchy's leaves).
        coplanar_ptr (n+1,), coplanar_occ: CSR lists of the occluders in whose plane polygon i lies
            without being part of them (overlapping duplicates, reversed copies).
        first_source: (n_o,) lowest input polygon index among each occluder's members (tie-break).
        tilt, noise: (n_o,) uncertainty of each occluder's plane (see :func:`.scene.plane_uncertainty`).
        solids: the convex solids among the occluders (:mod:`.solids`). A solid's volume is occluder
            ``n_o + s``: the tables above have ``n_o + n_s`` columns (``beyond_*`` True for solids,
            ``front_*`` the union over the solid's faces); occ_reach_pos, occ_reach_neg (n_o, n_o + n_s), bits:
            occluder (or solid) o has a vertex strictly on the positive / negative side of occluder k's
            plane (``[k, o]``); vol_centers (n_o + n_s, 3), vol_radii: bounding spheres of all volumes.
        vol_pairs: the pairs of occ_beyond_* and occ_reach_* as sparse lists (:class:`VolumePairs`).
        depth: for scenes of many merged faces (:func:`per_pair_depth`), the depth relations per pair
            (:class:`.depth_pairs.DepthPairs`) instead of all the tables above (then None) and vol_pairs.
        hull_cores: (n_o,) bool, the convex cores of :func:`_convex_cores`: the hull of their members,
            which lies in the tiling but may exceed the members' union by rounding slivers (the ring
            cells'), so such a face occludes exactly but is no exact tiling of its members (None: none).
    """

    vertices: np.ndarray
    counts: np.ndarray
    normals: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    members: np.ndarray
    beyond_pos: np.ndarray
    beyond_neg: np.ndarray
    occ_beyond_pos: np.ndarray
    occ_beyond_neg: np.ndarray
    front_pos: np.ndarray
    front_neg: np.ndarray
    tile_of: np.ndarray
    tile_corners: np.ndarray
    tile_centers: np.ndarray
    tile_radii: np.ndarray
    tile_occluder: np.ndarray
    tile_ptr: np.ndarray
    tile_members: np.ndarray
    coplanar_ptr: np.ndarray
    coplanar_occ: np.ndarray
    first_source: np.ndarray
    tilt: np.ndarray | None = None
    noise: np.ndarray | None = None
    solids: Solids | None = None
    occ_reach_pos: np.ndarray | None = None
    occ_reach_neg: np.ndarray | None = None
    vol_centers: np.ndarray | None = None
    vol_radii: np.ndarray | None = None
    vol_pairs: VolumePairs | None = None
    depth: DepthPairs | None = None
    hull_cores: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.counts)

    @property
    def n_vol(self) -> int:
        """Occluder columns of the tables: the merged faces, then the convex solids."""
        return len(self.vol_radii)


def _merged_faces(scene: Scene, *, cores: bool = False):
    """Merge coplanar, edge-connected convex polygons that tile one convex polygon (see the module doc).

    Vectorised over the whole scene (O(N log N) in the number of corners N): exact-coordinate vertex
    ids, plane groups, components through shared edges, then per component the boundary loop (directed
    edges without their reverse), which must be one simple loop, convex once collinear points are
    dropped, planar to rounding and of the members' total area.

    Returns ``members (n,)`` (occluder of every representative polygon, -1 for duplicates), and the
    occluders' vertex lists as ``occ_counts (n_o,)``, ``occ_points (Σ counts, 3)`` in occluder order
    (plane group, then first member; members of groups that do not merge are occluders on their own).
    With ``cores``, components that do not merge get convex cores (:func:`_convex_cores`, appended
    after the others) and a fourth array is returned, ``poly_core (n,)``: the core occluder of every
    polygon of such a component (-1 elsewhere).
    """
    n = scene.n_polygons
    pv, pc = scene.poly_vertices, scene.poly_counts
    size = float(np.ptp(scene.poly_centers, axis=0).max() + scene.poly_radii.max()) or 1.0
    key = np.concatenate([np.round(scene.poly_normals * 1e9), np.round(scene.poly_offsets / size * 1e9)[:, None]],
                         axis=1)
    _, plane_id = unique_rows(key)
    plane_id = plane_id.reshape(-1)
    # identical copies are projected once (Scene._find_duplicates): only representatives occlude
    reps = np.flatnonzero(scene.dup_rep == np.arange(n))
    order = reps[np.argsort(plane_id[reps], kind="stable")]
    pos = np.full(n, -1)
    pos[order] = np.arange(len(order))
    # corners of the representatives in group order, and their exact-coordinate vertex ids
    cnt = pc[order]
    c_poly = np.repeat(order, cnt)
    c_start = np.cumsum(cnt) - cnt
    c_idx = np.arange(int(cnt.sum()))
    c_first = np.repeat(c_start, cnt)
    c_next = np.where(c_idx + 1 < c_first + np.repeat(cnt, cnt), c_idx + 1, c_first)
    pts = pv[order][np.arange(pv.shape[1])[None, :] < cnt[:, None]]            # (N, 3)
    _, vid = unique_rows(np.ascontiguousarray(pts).view(np.int64).reshape(-1, 3))
    vid = vid.reshape(-1)
    n_v = int(vid.max()) + 1 if len(vid) else 0
    a, b = vid, vid[c_next]
    grp = plane_id[c_poly]
    # components: polygons of one plane group sharing an edge (a, b) / (b, a)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    srt = np.lexsort((hi, lo, grp))
    s_g, s_lo, s_hi, s_fwd = grp[srt], lo[srt], hi[srt], (a < b)[srt]
    new_run = np.ones(len(srt), dtype=bool)
    new_run[1:] = (s_g[1:] != s_g[:-1]) | (s_lo[1:] != s_lo[:-1]) | (s_hi[1:] != s_hi[:-1])
    run = np.cumsum(new_run) - 1
    n_run = int(run[-1]) + 1 if len(run) else 0
    fwd_n = np.bincount(run, weights=s_fwd, minlength=n_run)
    all_n = np.bincount(run, minlength=n_run)
    both = (fwd_n > 0) & (fwd_n < all_n)
    run_first = np.flatnonzero(new_run)
    link = both[run] & ~new_run
    root = components(n, c_poly[srt][run_first[run[link]]], c_poly[srt][link])
    comp_first = np.full(n, np.iinfo(np.int64).max)
    np.minimum.at(comp_first, root[order], pos[order])
    comp_size = np.bincount(root[order], minlength=n)
    # ---- the merge test, for every component of two or more polygons at once
    c_root = root[c_poly]
    multi = comp_size[c_root] > 1
    ok = np.zeros(n, dtype=bool)                 # by root: the component merges
    ok[np.unique(c_root[multi])] = True
    # a directed edge twice in one component: overlapping polygons
    srt2 = np.lexsort((b, a, c_root))
    d_a, d_b, d_r = a[srt2], b[srt2], c_root[srt2]
    twin = (d_a[1:] == d_a[:-1]) & (d_b[1:] == d_b[:-1]) & (d_r[1:] == d_r[:-1])
    ok[d_r[1:][twin]] = False
    # boundary edges: their run has one direction only
    boundary = np.zeros(len(a), dtype=bool)
    boundary[srt] = ~both[run]
    e = np.flatnonzero(boundary & multi & ok[c_root])
    # (two components of one plane group never share an edge run: runs that link are inside one)
    rank_root = np.unique(c_root[e], return_inverse=True)[1].reshape(-1) if len(e) else np.zeros(0, dtype=np.int64)
    e_key = rank_root * n_v + a[e]
    srt_e = np.argsort(e_key, kind="stable")
    sk = e_key[srt_e]
    twice = np.zeros(len(e), dtype=bool)
    if len(e):
        twice[srt_e[1:][sk[1:] == sk[:-1]]] = True          # a vertex with two outgoing boundary edges
    ok[c_root[e[twice]]] = False
    want = rank_root * n_v + b[e]
    at = np.minimum(np.searchsorted(sk, want), max(len(sk) - 1, 0))
    found = sk[at] == want if len(e) else np.zeros(0, dtype=bool)
    ok[c_root[e[~found]]] = False
    succ = np.where(found, srt_e[at], np.arange(len(e)))          # boundary edge index -> next one
    e_root = c_root[e]
    keep_e = ok[e_root]
    # the loop starts at the first boundary edge in corner order (as the dict walk did); rank along it
    # by pointer jumping from the edge before the start
    n_e = len(e)
    start = np.full(n, -1)
    if n_e:
        first = np.full(n, n_e)
        np.minimum.at(first, e_root, np.arange(n_e))                   # e is in corner order
        start = first
    is_start = np.zeros(n_e, dtype=bool)
    if n_e:
        is_start[start[e_root[keep_e]]] = True
    nxt = np.where(is_start[succ], np.arange(n_e), succ)               # the edge before the start ends
    dist = (nxt != np.arange(n_e)).astype(np.int64)
    loop_len = np.bincount(e_root, minlength=n)
    for _ in range(int(np.ceil(np.log2(max(2, loop_len.max(initial=2))))) + 1):
        dist = dist + dist[nxt]
        nxt = nxt[nxt]
    if n_e:
        single = dist[start[e_root]] == loop_len[e_root] - 1
        ok[e_root[keep_e & ~single]] = False
    e_ok = np.flatnonzero(ok[e_root]) if n_e else np.zeros(0, dtype=np.int64)
    lp_root = e_root[e_ok]
    lp_pos = loop_len[lp_root] - 1 - dist[e_ok]
    srt_l = np.lexsort((lp_pos, comp_first[lp_root]))
    lp_root, lp_corner = lp_root[srt_l], e[e_ok][srt_l]
    lp_pts = pts[lp_corner]                                            # (L, 3) loops, component by component
    new_l = np.ones(len(lp_root), dtype=bool)
    new_l[1:] = lp_root[1:] != lp_root[:-1]
    l_start = np.flatnonzero(new_l)
    l_len = np.diff(np.append(l_start, len(lp_root)))
    l_roots = lp_root[l_start]
    # normal of the component's first member (in group order)
    first_member = np.full(n, -1)
    first_member[root[order][::-1]] = order[::-1]
    nrm = scene.poly_normals[first_member[lp_root]]                    # (L, 3)
    li = np.arange(len(lp_root))
    l_first = np.repeat(l_start, l_len)
    prv = np.where(li > l_first, li - 1, l_first + np.repeat(l_len, l_len) - 1)
    nxl = np.where(li + 1 < l_first + np.repeat(l_len, l_len), li + 1, l_first)
    e1 = lp_pts - lp_pts[prv]
    e2 = lp_pts[nxl] - lp_pts
    turn = (np.cross(e1, e2) * nrm).sum(axis=1)
    lens = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    reflex = turn < -CONVEXITY_EPS * lens
    kept = turn > 1e-9 * lens
    bad = np.bincount(np.repeat(np.arange(len(l_start)), l_len), weights=reflex, minlength=len(l_start)) > 0
    n_kept = np.bincount(np.repeat(np.arange(len(l_start)), l_len), weights=kept, minlength=len(l_start))
    bad |= n_kept < 3
    # planarity (only polygons coplanar to rounding merge: triangles of a non-planar face keep their
    # planes) and the area: the loop's area must be the members' total (winding, overlaps)
    cm = np.flatnonzero(multi & ok[c_root])
    cm_root = c_root[cm]
    ref = np.full(n, -1)
    ref[cm_root[::-1]] = cm[::-1]                                       # the component's first corner
    cm_nrm = scene.poly_normals[first_member[cm_root]]
    hts = ((pts[cm] - pts[ref[cm_root]]) * cm_nrm).sum(axis=1)
    hmax = np.full(n, -np.inf)
    hmin = np.full(n, np.inf)
    np.maximum.at(hmax, cm_root, hts)
    np.minimum.at(hmin, cm_root, hts)
    cmax = np.full((n, 3), -np.inf)
    cmin = np.full((n, 3), np.inf)
    np.maximum.at(cmax, cm_root, pts[cm])
    np.minimum.at(cmin, cm_root, pts[cm])
    rel = pv - pv[:, :1]
    p_area = 0.5 * np.linalg.norm(np.cross(rel, np.roll(rel, -1, axis=1)).sum(axis=1), axis=1)
    area = np.zeros(n)
    mem = order[multi[c_start]] if len(order) else order
    np.add.at(area, root[mem], p_area[mem])
    lr = l_roots
    bad |= 0.5 * (hmax[lr] - hmin[lr]) > PLANARITY_EPS * (cmax[lr] - cmin[lr]).max(axis=1)
    kp = np.flatnonzero(kept)
    k_loop = np.repeat(np.arange(len(l_start)), l_len)[kp]
    k_pts = lp_pts[kp]
    k_cnt = np.bincount(k_loop, minlength=len(l_start))
    k_start = np.cumsum(k_cnt) - k_cnt
    k_ref = k_pts[k_start[k_loop]] if len(kp) else k_pts
    k_rel = k_pts - k_ref
    ki = np.arange(len(kp))
    k_first = k_start[k_loop]
    k_nx = np.where(ki + 1 < k_first + k_cnt[k_loop], ki + 1, k_first)
    cr = np.cross(k_rel, k_rel[k_nx]) if len(kp) else k_rel
    cr_sum = np.zeros((len(l_start), 3))
    np.add.at(cr_sum, k_loop, cr)
    loop_area = 0.5 * (cr_sum * scene.poly_normals[first_member[lr]]).sum(axis=1)
    ext = np.full((len(l_start), 3), -np.inf)
    ext_lo = np.full((len(l_start), 3), np.inf)
    l_of = np.repeat(np.arange(len(l_start)), l_len)
    np.maximum.at(ext, l_of, lp_pts)
    np.minimum.at(ext_lo, l_of, lp_pts)
    lsize = (ext - ext_lo).max(axis=1) if len(l_start) else np.zeros(0)
    bad |= np.abs(loop_area - area[lr]) > 1e-9 * np.maximum(area[lr], lsize * lsize * 1e-12)
    ok[lr[bad]] = False
    # ---- occluders: merged components (one each) and the rest (one per polygon), in today's order
    merged = ok & (comp_size > 1)
    single_polys = order[~merged[root[order]]]
    merged_roots = np.flatnonzero(merged)
    o_first = np.concatenate([pos[single_polys], comp_first[merged_roots]])
    o_second = np.concatenate([pos[single_polys], np.full(len(merged_roots), -1)])
    o_order = np.lexsort((o_second, o_first))
    n_single = len(single_polys)
    occ_of_item = np.empty(len(o_order), dtype=np.int64)
    occ_of_item[o_order] = np.arange(len(o_order))
    members = np.full(n, -1)
    members[single_polys] = occ_of_item[:n_single]
    merged_occ = np.full(n, -1)
    merged_occ[merged_roots] = occ_of_item[n_single:]
    in_merged = order[merged[root[order]]]
    members[in_merged] = merged_occ[root[in_merged]]
    # vertex lists
    lg = merged[lr]
    m_loop = np.flatnonzero(lg)
    kept_mask = lg[k_loop]
    counts_o = np.zeros(len(o_order), dtype=np.int64)
    counts_o[members[single_polys]] = pc[single_polys]
    counts_o[merged_occ[lr[m_loop]]] = k_cnt[m_loop]
    o_start = np.cumsum(counts_o) - counts_o
    points = np.empty((int(counts_o.sum()), 3))
    sv = pv[single_polys][np.arange(pv.shape[1])[None, :] < pc[single_polys][:, None]]
    dst = np.repeat(o_start[members[single_polys]], pc[single_polys]) + (
        np.arange(len(sv)) - np.repeat(np.cumsum(pc[single_polys]) - pc[single_polys], pc[single_polys]))
    points[dst] = sv
    kk = np.flatnonzero(kept_mask)
    k_occ = merged_occ[lr[k_loop[kk]]]
    points[o_start[k_occ] + (kk - k_start[k_loop[kk]])] = k_pts[kk]
    if not cores:
        return members, counts_o, points
    rejected = np.flatnonzero(~ok & (comp_size >= 9))
    return _convex_cores(scene, order, root, rejected, members, counts_o, points)


def _convex_cores(scene: Scene, reps, root, rejected, members, counts, points):
    """Convex cores of coplanar tilings that do not merge because their outline is not convex.

    Rounded to float32, the cells of a rotated block's flat top no longer have straight outer edges
    (the vertices along an edge zigzag by ~3e-8 of its length): the union U is not convex and every cell
    stayed an occluder of its own. The shadow volume of U is, exactly, the union of those of any convex
    pieces that lie in U and cover it. Here: the *ring* (every cell with a vertex on U's outline, each
    its own occluder) and the core K = the convex hull of the other cells' vertices, which covers them
    and is accepted only when it lies in U: every vertex of K strictly (by 1e-9 of the lengths, far
    above rounding) inside the inner half-plane of every outline edge, i.e. in U's kernel. Only
    components whose cells are coplanar to rounding (:data:`PLANARITY_EPS`), bounded by one simple loop
    without overlaps, qualify; the interior cells become K's members (K contains them), the ring cells
    keep their occluders, and K never hides its own component's cells (they are coplanar with it).

    ``reps`` (r,) the representative polygons, ``root`` (n,) their components, ``rejected`` the roots of
    components that did not merge; returns ``members, counts, points`` (cores appended) and
    ``poly_core (n,)``.
    """
    n = scene.n_polygons
    pv, pc = scene.poly_vertices, scene.poly_counts
    poly_core = np.full(n, -1)
    if not len(rejected):
        return members, counts, points, poly_core
    n_o = len(counts)
    o_start = np.cumsum(counts) - counts
    by_root = reps[np.argsort(root[reps], kind="stable")]
    r_sorted = root[by_root]
    drop = np.zeros(n_o, dtype=bool)
    cores, core_polys, core_comp = [], [], []
    for r in rejected:
        polys = by_root[np.searchsorted(r_sorted, r):np.searchsorted(r_sorted, r, side="right")]
        if (members[polys] < 0).any() or (counts[members[polys]] != pc[polys]).any():
            continue
        nrm = scene.poly_normals[polys[0]]
        corners = [pv[p, :pc[p]] for p in polys]
        allv = np.concatenate(corners)
        h = (allv - allv[0]) @ nrm
        if 0.5 * (h.max() - h.min()) > PLANARITY_EPS * float(np.ptp(allv, axis=0).max()):
            continue
        _, vid = np.unique(allv, axis=0, return_inverse=True)
        vid = vid.reshape(-1)
        ids, at = [], 0
        for c in corners:
            ids.append(vid[at:at + len(c)])
            at += len(c)
        edges = {}
        for p_ids in ids:
            for a, b in zip(p_ids, np.roll(p_ids, -1)):
                edges[(int(a), int(b))] = edges.get((int(a), int(b)), 0) + 1
        if max(edges.values()) > 1:
            continue                                                           # overlapping cells
        succ = {}
        for a, b in edges:
            if (b, a) not in edges:
                if a in succ:
                    break
                succ[a] = b
        else:
            loop = [next(iter(succ))]
            while len(loop) <= len(succ) and succ.get(loop[-1], -1) != loop[0]:
                loop.append(succ.get(loop[-1], -1))
                if loop[-1] < 0:
                    break
            if len(loop) != len(succ) or loop[-1] < 0:
                continue                                                       # holes, several loops
            on_loop = np.zeros(int(vid.max()) + 1, dtype=bool)
            on_loop[loop] = True
            inner = np.array([not on_loop[p_ids].any() for p_ids in ids])
            if not inner.any():
                continue
            # the hull of the interior cells' vertices, counter-clockwise about nrm (monotone chain)
            ax = np.eye(3)[int(np.argmin(np.abs(nrm)))]
            e1 = np.cross(nrm, ax)
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(nrm, e1)
            pts = np.unique(np.concatenate([c for c, i in zip(corners, inner) if i]), axis=0)
            rel = pts - pts[0]
            uv = np.stack([rel @ e1, rel @ e2], axis=1)
            srt = np.lexsort((uv[:, 1], uv[:, 0]))
            hull = []
            for sweep in (srt, srt[::-1]):
                chain = []
                for j in sweep:
                    while len(chain) >= 2:
                        o, a = uv[chain[-2]], uv[chain[-1]]
                        if (a[0] - o[0]) * (uv[j][1] - o[1]) - (a[1] - o[1]) * (uv[j][0] - o[0]) > 0:
                            break
                        chain.pop()
                    chain.append(j)
                hull += chain[:-1]
            # K in U's kernel: strictly inside every outline edge's inner half-plane; a core with few
            # sides around the hull if it still is (the volumes' plane count is the occluders' largest)
            first_of = np.full(int(vid.max()) + 1, -1)
            first_of[vid[::-1]] = np.arange(len(vid))[::-1]
            la = allv[first_of[loop]]
            e = np.roll(la, -1, axis=0) - la
            k_pts = _fewer_sides(pts[0], e1, e2, uv[hull])
            if k_pts is None or not _hull_ok(k_pts, la, e, nrm):
                k_pts = pts[hull]
                if not _hull_ok(k_pts, la, e, nrm):
                    continue
            drop[members[polys[inner]]] = True
            cores.append(k_pts)
            core_polys.append(polys)
            core_comp.append(polys[inner])
    if not cores:
        return members, counts, points, poly_core
    keep = ~drop
    new_index = np.cumsum(keep) - 1
    kept_pts = np.concatenate([points[o_start[o]:o_start[o] + counts[o]] for o in np.flatnonzero(keep)]) \
        if keep.any() else np.zeros((0, 3))
    members = np.where(members >= 0, new_index[np.maximum(members, 0)], -1)
    n_keep = int(keep.sum())
    for j, (polys, inner_polys) in enumerate(zip(core_polys, core_comp)):
        members[inner_polys] = n_keep + j
        poly_core[polys] = n_keep + j
    counts = np.concatenate([counts[keep], [len(c) for c in cores]]).astype(np.int64)
    points = np.concatenate([kept_pts] + cores)
    return members, counts, points, poly_core


def build_occluders(scene: Scene, *, solids: bool = True, step=None) -> Occluders:
    """Merge coplanar edge-connected convex polygons into convex occluders (exact; see module doc).

    With ``solids`` the convex solids among them are found too (:mod:`.solids`); without, every face
    occludes on its own (the same result, slower; for tests and benchmarks). ``step(name)``, if given,
    is called after each phase (``"merged faces"``, ``"depth tables"``, ``"tiles"``, ``"solids"``): the
    scene preparation's progress and cancel hook (see :func:`.chunk.prepare_scene`).
    """
    step = step or (lambda name: None)
    n = scene.n_polygons
    if n:
        members, counts, points, poly_core = _merged_faces(scene, cores=True)
    else:
        members, counts, points = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        poly_core = np.zeros(0, dtype=np.int64)
    n_loops = len(counts)
    kmax = int(counts.max(initial=3))
    # padded (n_o, kmax, 3): padding repeats the last vertex
    o_start = np.cumsum(counts) - counts
    slot = np.minimum(np.arange(kmax)[None, :], np.maximum(counts, 1)[:, None] - 1)
    verts = points[o_start[:, None] + slot] if n_loops else np.zeros((0, kmax, 3))
    rel = verts - verts[:, :1]
    area_vec = 0.5 * np.cross(rel, np.roll(rel, -1, axis=1)).sum(axis=1)
    normals = area_vec / np.linalg.norm(area_vec, axis=1, keepdims=True) if n_loops else np.zeros((0, 3))
    valid = np.arange(kmax)[None, :] < counts[:, None]
    centers = (verts * valid[..., None]).sum(axis=1) / np.maximum(counts, 1)[:, None]
    radii = np.where(valid, np.linalg.norm(verts - centers[:, None], axis=2), 0.0).max(axis=1) if n_loops \
        else np.zeros(0)

    step("merged faces")
    occ_tilt, occ_noise = plane_uncertainty(verts)
    n_o = n_loops
    # convex solids: their volumes are extra occluder columns of the tables (see :mod:`.solids`)
    sol = build_solids(verts, counts, normals, occ_tilt, occ_noise) if solids else no_solids()
    hull_cores = np.zeros(n_o, dtype=bool)
    hull_cores[poly_core[poly_core >= 0]] = True
    if per_pair_depth(n_o):
        # (the per-pair relations take the convex solids only, not the inner polytopes of :mod:`.inner_solids`)
        out = _occluders_per_pair(scene, step, verts, counts, normals, centers, radii, members, poly_core,
                                  occ_tilt, occ_noise, sol)
        out.hull_cores = hull_cores
        return out
    if solids and n:
        # polytopes inside closed surfaces that are not convex (float32-rounded blocks), see :mod:`.inner_solids`
        sol = join_solids(sol, inner_solids(scene, members, n_o))
    # beyond tests, independent of the receiver, for the polygons and for the occluders themselves
    o_tabs = _beyond(verts, counts, verts, normals, occ_tilt)
    o_pos, o_neg, ob_pos, ob_neg = o_tabs
    fs, f_occ = sol.covers()

    def per_solid(table):  # (r, n_o) -> (r, n_s): any face of the solid (of its surface, if virtual)
        out = np.zeros((table.shape[0], sol.n), dtype=bool)
        if sol.n:
            np.logical_or.at(out.T, fs, table.T[f_occ])
        return out

    def with_solids(table, solid_cols):
        return np.concatenate([table, solid_cols], axis=1)

    # a polygon alone in its occluder is that occluder's body (the same vertices in the same order): its
    # rows are the occluder's, bit for bit (padding repeats the last vertex in both); only the others are
    # computed (in a scene whose polygons do not merge, that is none). The converse (does occluder o
    # reach to either side of polygon i's plane: it can only hide a part of i from a receiver on a side
    # it reaches to) reuses the occluder's columns where the polygon's plane (normal, tilt) is its
    # occluder's bit for bit.
    alone = np.zeros(n, dtype=bool)
    same = alone
    mapped = members[scene.dup_rep] if n else members
    if n:
        n_mem = np.bincount(members[members >= 0], minlength=n_o)
        alone = (members >= 0) & (n_mem[np.maximum(members, 0)] == 1)
        same = alone & (scene.poly_normals == normals[np.maximum(members, 0)]).all(axis=1) \
            & (scene.poly_tilt == occ_tilt[np.maximum(members, 0)])
    # polygons against occluders, a block of rows at a time (temporaries ~2**20 entries), stored as bits
    # (an eighth of the bools: the tables go to every worker)
    n_bytes = (n_o + sol.n + 7) // 8
    beyond_pos, beyond_neg, front_pos, front_neg = (np.zeros((n, n_bytes), dtype=np.uint8) for _ in range(4))
    cis, cos = [], []
    rows_at_once = max(1, (1 << 20) // max(1, n_o))
    o_cols = [t.T for t in o_tabs]
    true_r = np.ones((min(n, rows_at_once), sol.n), dtype=bool)
    for start in range(0, n, rows_at_once):
        r = np.arange(start, min(n, start + rows_at_once))
        b_pos, b_neg, bb_pos, bb_neg = _rows_reusing(
            alone[r], members[r], o_tabs,
            lambda q, r=r: _beyond(scene.poly_vertices[r[q]], scene.poly_counts[r[q]], verts, normals, occ_tilt))
        f_pos, f_neg, fb_pos, fb_neg = _rows_reusing(
            same[r], members[r], o_cols,
            lambda q, r=r: [t.T for t in _beyond(verts, counts, scene.poly_vertices[r[q]], scene.poly_normals[r[q]],
                                                 scene.poly_tilt[r[q]])])
        # Two surfaces are coplanar when each lies in the other's plane within that plane's uncertainty,
        # all of the surface within the tolerance of its farthest vertex (``*_body``); coplanar pairs keep
        # those flags. Other pairs use each vertex's own tolerance: a sliver through P is "beyond" the
        # plane of a 1e-6 triangle by its vertex at P even though its far end is within that plane's
        # uncertainty. A surface within the (poorly known) plane of the other but not vice versa — a huge
        # polygon 1e3 from the plane of a 1e-6 one far from the origin — may lie on either side of it:
        # the flags are filters, so both are set and the exact per-vertex tests decide.
        on_b, on_f = ~(bb_pos | bb_neg), ~(fb_pos | fb_neg)
        coplanar = on_b & on_f
        tr = true_r[:len(r)]
        beyond_pos[r] = pack_bits(with_solids(np.where(coplanar, bb_pos, b_pos) | (on_b & ~on_f), tr))
        beyond_neg[r] = pack_bits(with_solids(np.where(coplanar, bb_neg, b_neg) | (on_b & ~on_f), tr))
        fp = np.where(coplanar, fb_pos, f_pos) | (on_f & ~on_b)
        front_pos[r] = pack_bits(with_solids(fp, per_solid(fp)))
        fn = np.where(coplanar, fb_neg, f_neg) | (on_f & ~on_b)
        front_neg[r] = pack_bits(with_solids(fn, per_solid(fn)))
        # coplanar overlapping surfaces (duplicates, reversed copies): polygon i lies in the plane of
        # occluder o but is not part of it; the visibility stage lets one of them win where they overlap
        coplanar[np.arange(len(r)), mapped[r]] = False
        core_r = poly_core[scene.dup_rep[r]]
        has = np.flatnonzero(core_r >= 0)
        coplanar[has, core_r[has]] = False             # a core never hides its own tiling's cells
        c_i, c_o = np.nonzero(coplanar)
        cis.append(c_i + start)
        cos.append(c_o)
    del o_cols
    on_o = ~(ob_pos | ob_neg)
    occ_coplanar = on_o & on_o.T
    occ_pos = np.where(occ_coplanar, ob_pos, o_pos) | (on_o & ~on_o.T)
    occ_neg = np.where(occ_coplanar, ob_neg, o_neg) | (on_o & ~on_o.T)
    del o_tabs, o_pos, o_neg, ob_pos, ob_neg, on_o, occ_coplanar
    true_o = np.ones((n_o, sol.n), dtype=bool)
    reach_pos = with_solids(occ_pos.T, per_solid(occ_pos.T))
    reach_neg = with_solids(occ_neg.T, per_solid(occ_neg.T))
    occ_pos, occ_neg = with_solids(occ_pos, true_o), with_solids(occ_neg, true_o)
    pairs = _volume_pairs((occ_pos, occ_neg), (reach_pos, reach_neg))
    occ_pos, occ_neg, reach_pos, reach_neg = (pack_bits(t) for t in (occ_pos, occ_neg, reach_pos, reach_neg))
    step("depth tables")
    members = mapped
    tiles = _tiles(scene, members, n_o)
    step("tiles")
    ci = np.concatenate(cis) if cis else np.zeros(0, dtype=np.int64)
    co = np.concatenate(cos) if cos else np.zeros(0, dtype=np.int64)
    cop_ptr, co, first_source = _coplanar_lists(scene, verts, counts, normals, members, ci, co)
    step("solids")
    return Occluders(verts, counts, normals, centers, radii, members, beyond_pos, beyond_neg, occ_pos, occ_neg,
                     front_pos, front_neg, *tiles, cop_ptr, co, first_source, occ_tilt, occ_noise,
                     sol, reach_pos, reach_neg, np.concatenate([centers, sol.centers]),
                     np.concatenate([radii, sol.radii]), pairs, hull_cores=hull_cores)


def _coplanar_lists(scene, verts, counts, normals, members, ci, co):
    """The coplanar overlaps of :class:`Occluders` from candidate pairs ``(polygon ci, merged face co)`` in
    row-major order, and each face's lowest source index: ``(coplanar_ptr (n+1,), coplanar_occ,
    first_source (n_o,))`` (``members (n,)``: every polygon's merged face)."""
    n, n_o = scene.n_polygons, len(counts)
    # only pairs that can overlap: coplanar neighbours that merely touch (the cells of a face that did
    # not merge, e.g. a float32-rounded face whose boundary is no longer straight) never hide each other
    keep = ~_separated(scene.poly_vertices[ci], scene.poly_counts[ci], scene.poly_normals[ci],
                       verts[co], counts[co], normals[co])
    ci, co = ci[keep], co[keep]
    cop_ptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(cop_ptr, ci + 1, 1)
    first_source = np.full(n_o, np.iinfo(np.int64).max)
    if n:
        np.minimum.at(first_source, members, scene.poly_source)
    return np.cumsum(cop_ptr), co, first_source


#: the depth relations per pair (:mod:`.depth_pairs`) instead of tables from this many merged faces on
#: (None: never; tests set 0 to compare both on small scenes; the environment variable
#: HLP_PER_PAIR_DEPTH_FROM sets it for a whole run, e.g. 0 to run a test suite per pair)
PER_PAIR_DEPTH_FROM: int | None = int(os.environ.get("HLP_PER_PAIR_DEPTH_FROM", "4096"))


def per_pair_depth(n_o: int) -> bool:
    """Whether a scene of ``n_o`` merged faces gets :class:`.depth_pairs.DepthPairs` instead of tables."""
    return PER_PAIR_DEPTH_FROM is not None and n_o >= PER_PAIR_DEPTH_FROM


def _occluders_per_pair(scene, step, verts, counts, normals, centers, radii, members, poly_core, occ_tilt,
                        occ_noise, sol) -> Occluders:
    """:func:`build_occluders` without the (polygon × merged face) tables: the depth relations are
    computed per pair where the receivers need them (:mod:`.depth_pairs`); O(n log n) time and O(n)
    memory besides the solids' columns (polygons × solids)."""
    n, n_o = scene.n_polygons, len(counts)
    polys = Bodies(scene.poly_vertices, scene.poly_counts, scene.poly_normals, scene.poly_tilt)
    faces = Bodies(verts, counts, normals, occ_tilt)
    args = (sol.face_ptr, sol.face_occ, sol.centers, sol.radii)
    depth = DepthPairs(polys, faces, *(pack_bits(t) for t in solid_columns(polys, faces, *args)),
                       *(pack_bits(t) for t in solid_columns(faces, faces, *args)), beyond_lists(faces))
    step("depth tables")
    mapped = members[scene.dup_rep] if n else members
    tiles = _tiles(scene, mapped, n_o)
    step("tiles")
    # coplanar overlapping surfaces: polygon i in the plane of a merged face o it is not part of (only
    # pairs whose bounding spheres meet can overlap; _separated below drops the others as the tables do)
    pad = 1e-6
    r_p = scene.poly_radii * (1 + pad) + 1e3 * COORD_EPS * np.abs(scene.poly_centers).max(axis=1, initial=0.0)
    r_o = radii * (1 + pad) + 1e3 * COORD_EPS * np.abs(centers).max(axis=1, initial=0.0)
    big = 1.0001 * max(float(r_p.max(initial=0.0)), float(r_o.max(initial=0.0)), 1e-300)
    ci, co = ball_pairs(np.zeros(n, dtype=np.int64), scene.poly_centers, r_p, np.zeros(n_o, dtype=np.int64),
                        centers, r_o, big)
    ok = pair_flags(polys, ci, faces, co)[4] & (co != mapped[ci])
    core_i = poly_core[scene.dup_rep[ci]] if n else ci
    ok &= ~((core_i >= 0) & (co == core_i))                # a core never hides its own tiling's cells
    ci, co = ci[ok], co[ok]
    order = np.lexsort((co, ci))                           # the tables' row-major order
    ci, co = ci[order], co[order]
    cop_ptr, co, first_source = _coplanar_lists(scene, verts, counts, normals, mapped, ci, co)
    step("solids")
    return Occluders(verts, counts, normals, centers, radii, mapped, None, None, None, None, None, None, *tiles,
                     cop_ptr, co, first_source, occ_tilt, occ_noise, sol, None, None,
                     np.concatenate([centers, sol.centers]), np.concatenate([radii, sol.radii]), None, depth)


def _rows_reusing(reuse, members, tables, compute):
    """Four ``(n, n_o)`` bool tables: rows ``i`` with ``reuse[i]`` are ``tables[t][members[i]]``, the others
    ``compute(rows)[t]`` (each ``(len(rows), n_o)``)."""
    n = len(reuse)
    out = [np.empty((n, t.shape[1]), dtype=bool) for t in tables]
    idx = np.flatnonzero(reuse)
    rest = np.flatnonzero(~reuse)
    for o, t in zip(out, tables):
        o[idx] = t[members[idx]]
    if len(rest):
        for o, t in zip(out, compute(rest)):
            o[rest] = t
    return out


#: target number of member polygons per tile of a merged occluder
TILE_SIZE = 16


def _tiles(scene: Scene, members: np.ndarray, n_o: int):
    """Spatial tiles of every occluder's members: a grid over the face's two longest extents
    (about :data:`TILE_SIZE` members per cell), all occluders at once (O(n log n))."""
    n = scene.n_polygons
    if not n:
        z = np.zeros(0, dtype=np.int64)
        return z, np.zeros((0, 8, 3)), np.zeros((0, 3)), np.zeros(0), z, np.zeros(1, dtype=np.int64), z
    order = np.argsort(members, kind="stable")
    m_sorted = members[order]
    g_start = np.flatnonzero(np.r_[True, m_sorted[1:] != m_sorted[:-1]])
    g_size = np.diff(np.append(g_start, n))
    cells = np.maximum(1, np.rint(np.sqrt(g_size / TILE_SIZE))).astype(np.int64)
    t_srt, t_start, _ = grid_cells(scene.poly_centers[order], g_start, cells)
    tile_of = np.empty(n, dtype=np.int64)
    tile_of[order[t_srt]] = np.repeat(np.arange(len(t_start)), np.diff(np.append(t_start, n)))
    lo, hi = member_boxes(scene.poly_vertices[order[t_srt]], t_start)
    bits = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=bool)   # (8, 3)
    corners = np.where(bits[None], hi[:, None, :], lo[:, None, :])
    occ_of = m_sorted[t_srt][t_start]
    centers = corners.mean(axis=1)
    radii = np.linalg.norm(corners - centers[:, None], axis=2).max(axis=1)
    tile_members = np.argsort(tile_of, kind="stable")
    tile_ptr = np.zeros(len(corners) + 1, dtype=np.int64)
    np.add.at(tile_ptr, tile_of + 1, 1)
    return tile_of, corners, centers, radii, occ_of.astype(np.int64), np.cumsum(tile_ptr), tile_members


def grid_cells(c: np.ndarray, g_start: np.ndarray, cells: np.ndarray):
    """Every group of points split by a ``cells × cells`` grid over the group's two longest extents.

    Args:
        c: (n, 3) points, sorted by group; g_start: (G,) each group's first point (``g_start[0] = 0``, no
            group empty); cells: (G,) int >= 1 grid cells per side (1: the group stays whole).
    Returns:
        ``order (n,)`` the points by (group, cell), stable within a cell; ``start (C,)`` each non-empty
        cell's first position in ``order``; ``group (C,)`` each cell's group.
    """
    n = len(c)
    g_of = np.repeat(np.arange(len(g_start)), np.diff(np.append(g_start, n)))
    keys = np.zeros(n, dtype=np.int64)
    split = cells[g_of] > 1
    if split.any():
        c_lo = np.minimum.reduceat(c, g_start, axis=0)
        ext = np.maximum.reduceat(c, g_start, axis=0) - c_lo
        axes = np.argsort(ext, axis=1, kind="stable")[:, ::-1]
        rows = np.flatnonzero(split)
        g = g_of[rows]
        cg = cells[g]
        ij = []
        for col in (0, 1):
            ax = axes[g, col]
            e = ext[g, ax]
            ij.append(np.minimum((c[rows, ax] - c_lo[g, ax]) / np.maximum(e, 1e-300) * cg, cg - 1).astype(np.int64))
        keys[rows] = ij[0] * cg + ij[1]
    order = np.lexsort((keys, g_of))
    sk_g, sk_k = g_of[order], keys[order]
    start = np.flatnonzero(np.r_[True, (sk_g[1:] != sk_g[:-1]) | (sk_k[1:] != sk_k[:-1])]) if n \
        else np.zeros(0, dtype=np.int64)
    return order, start, sk_g[start]


def member_boxes(pv: np.ndarray, start: np.ndarray):
    """``(lo, hi)`` (C, 3): the axis-aligned box of each run ``start[i]:start[i+1]`` of polygons ``pv (n, K,
    3)`` (padding slots repeat a vertex)."""
    if not len(start):
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.minimum.reduceat(pv.min(axis=1), start, axis=0), np.maximum.reduceat(pv.max(axis=1), start, axis=0)


def _hull_ok(k_pts, la, e, nrm) -> bool:
    """Every point of ``k_pts (k, 3)`` strictly inside every edge ``la (L, 3) + t e (L, 3)``'s inner
    half-plane (about ``nrm``), by 1e-9 of the lengths."""
    rel = k_pts[None, :, :] - la[:, None, :]
    side = (np.cross(e[:, None, :], rel) * nrm).sum(axis=2)
    return len(k_pts) >= 3 and bool((side > 1e-9 * np.linalg.norm(e, axis=1)[:, None]
                                     * np.linalg.norm(rel, axis=2)).all())


def _fewer_sides(origin, e1, e2, uv, angle=1e-3):
    """A convex polygon with few sides around the convex hull ``uv (h, 2)`` (counter-clockwise, in the
    frame ``origin + u e1 + v e2``): runs of hull edges turning by less than ``angle`` (a float32-ragged
    straight side) become one side, the supporting line of all hull points along the run's chord normal
    pushed out by 1e-9 of the hull's size; ``(s, 3)`` corners, or None when fewer than 3 sides remain.
    The result contains the hull; the caller checks it still lies in the tiling's kernel."""
    h = len(uv)
    edge = np.roll(uv, -1, axis=0) - uv
    theta = np.arctan2(edge[:, 1], edge[:, 0])
    turn = np.abs((np.roll(theta, -1) - theta + np.pi) % (2 * np.pi) - np.pi)     # at vertex i+1
    brk = np.flatnonzero(np.roll(turn, 1) > angle)                                  # edges starting a side
    if len(brk) < 3:
        return None
    size = float(np.ptp(uv, axis=0).max())
    normals, offsets = [], []
    for a, b in zip(brk, np.roll(brk, -1)):
        chord = uv[b % h] - uv[a]
        d = np.array([chord[1], -chord[0]]) / np.linalg.norm(chord)                 # outward
        normals.append(d)
        offsets.append((uv @ d).max() + 1e-9 * size)
    normals, offsets = np.array(normals), np.array(offsets)
    nxt = np.roll(np.arange(len(normals)), -1)
    a_mat = np.stack([normals, normals[nxt]], axis=1)                               # (s, 2, 2)
    corners = np.linalg.solve(a_mat, np.stack([offsets, offsets[nxt]], axis=1)[..., None])[..., 0]
    return origin + corners[:, :1] * e1 + corners[:, 1:] * e2


def _edge_separates(a_verts, a_counts, a_normals, b_verts, b_counts):
    """(p,) bool: some edge line of convex polygon a has every vertex of b on its outer side or on it.

    ``a_verts (p, K, 3)`` counter-clockwise about ``a_normals (p, 3)``, ``b_verts (p, K', 3)``; padding
    repeats the last vertex (a zero edge, never separating; repeated b vertices change nothing). The
    outward distance ``((e × n) · (v - a)) / |e|`` is exactly 0 for a vertex that *is* an endpoint of
    the edge (shared vertices of a tiling); any other vertex must lie outside beyond rounding and the
    coordinate noise of both, so a pair is only called separated when it surely is.
    """
    k = a_verts.shape[1]
    nxt = np.where(np.arange(k)[None, :] + 1 < a_counts[:, None], np.arange(k)[None, :] + 1, 0)
    a0 = a_verts
    a1 = np.take_along_axis(a_verts, nxt[..., None], axis=1)
    e = a1 - a0                                                                  # (p, K, 3)
    out = np.cross(e, a_normals[:, None, :])                                     # outward, |out| = |e|
    elen = np.linalg.norm(e, axis=2)                                             # (p, K)
    rel = b_verts[:, None, :, :] - a0[:, :, None, :]                             # (p, K, K', 3)
    d = np.einsum("pkc,pkjc->pkj", out, rel)                                     # |e| × distance
    reach = np.abs(rel).max(axis=3)
    noise = COORD_EPS * (np.abs(a_verts).max(axis=(1, 2)) + np.abs(b_verts).max(axis=(1, 2)))   # (p,)
    tol = (_ROUNDING * reach + noise[:, None, None]) * elen[..., None]
    on_end = (rel == 0).all(axis=3) | (b_verts[:, None, :, :] == a1[:, :, None, :]).all(axis=3)
    outside = on_end | (d > tol)
    return ((outside.all(axis=2)) & (elen > 0)).any(axis=1)


def _separated(a_verts, a_counts, a_normals, b_verts, b_counts, b_normals):
    """(p,) bool: coplanar convex polygons a and b surely share no area (a separating edge line of
    either, see :func:`_edge_separates`; for two convex polygons in one plane one exists iff their
    interiors are disjoint). Pairs are processed in blocks to bound the (p, K, K', 3) temporaries."""
    p = len(a_counts)
    res = np.zeros(p, dtype=bool)
    step = max(1, int(2e6 // max(1, a_verts.shape[1] * b_verts.shape[1] * 3)))
    for s in range(0, p, step):
        sl = slice(s, s + step)
        res[sl] = (_edge_separates(a_verts[sl], a_counts[sl], a_normals[sl], b_verts[sl], b_counts[sl])
                   | _edge_separates(b_verts[sl], b_counts[sl], b_normals[sl], a_verts[sl], a_counts[sl]))
    return res


def _beyond(body_verts, body_counts, occ_verts, occ_normals, occ_tilt):
    """(B, n_o) bool pairs: body b has a vertex strictly on the positive / negative side of occluder o.

    Returns ``(pos, neg, pos_body, neg_body)``: ``pos, neg`` with each vertex's own tolerance (the plane's
    tilt moves a point by tilt × its distance from the plane's reference vertex; a vertex off the plane
    by more than rounding but within that tolerance counts for both sides), and ``pos_body,
    neg_body`` with the body's largest tolerance for all its vertices, which decides coplanarity (a
    surface is in a plane when all of it is within that plane's uncertainty).

    Signed distances are taken relative to a vertex of the occluder: differences of nearby world
    coordinates are exact, so scenes far from the origin keep their precision. "Strictly" allows for
    the occluder plane's own uncertainty ``occ_tilt (n_o,)`` (see :func:`.scene.plane_uncertainty`) and
    for the coordinate noise of both (see :data:`.tolerances.COORD_EPS`).
    """
    b_n, k = body_verts.shape[:2]
    n_o = len(occ_verts)
    pos = np.zeros((b_n, n_o), dtype=bool)
    neg = np.zeros((b_n, n_o), dtype=bool)
    pos_body = np.zeros((b_n, n_o), dtype=bool)
    neg_body = np.zeros((b_n, n_o), dtype=bool)
    valid = np.arange(k)[None, :] < body_counts[:, None]
    step = max(1, int(2e6 // max(1, n_o * k)))
    noise_b = COORD_EPS * np.abs(body_verts).max(axis=(1, 2))                           # (B,)
    noise_o = COORD_EPS * np.abs(occ_verts).max(axis=(1, 2))                            # (n_o,)
    o0 = [np.ascontiguousarray(occ_verts[:, 0, c]) for c in range(3)]
    on = [np.ascontiguousarray(occ_normals[:, c]) for c in range(3)]
    coef = 4 * PLANE_EPS + occ_tilt[None, :]
    for s in range(0, b_n, step):
        bv = body_verts[s:s + step]
        noise = noise_b[s:s + step, None] + noise_o[None, :]                         # (b, n_o)
        # slot by slot, (b, n_o) per coordinate: the same sums in the same order as over a last axis of 3
        ds, rs = [], []
        for j in range(k):
            rel = [bv[:, j, c][:, None] - o0[c] for c in range(3)]
            d = rel[0] * on[0] + rel[1] * on[1] + rel[2] * on[2]
            rs.append(np.maximum(np.maximum(np.abs(rel[0]), np.abs(rel[1])), np.abs(rel[2])))
            ds.append(np.where(valid[s:s + step, j, None], d, 0.0))
        pos[s:s + step], neg[s:s + step], pos_body[s:s + step], neg_body[s:s + step] = side_flags(ds, rs, coef,
                                                                                                  noise)
    return pos, neg, pos_body, neg_body
