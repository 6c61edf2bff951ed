"""Convex solids *inside* closed surfaces that are not convex: one more shadow volume, nothing replaced.

A rotated block whose coordinates were rounded to float32 (every Blender mesh) is no longer convex:
its faces fold by ~1e-6 rad and the outline of its top zigzags by ~3e-8 of its side, so neither its
faces merge (:mod:`.culling`) nor is it a convex solid (:mod:`.solids`), and what lies behind it is
hidden only by the union of ~4 sqrt(n) separate volumes, never by one. This module finds, for such a
surface, a convex polytope K strictly inside it; K's shadow volume is then used *in addition* to the
faces' own volumes (which still decide everything near the silhouette): a polygon wholly inside it is
hidden at once, and so is a whole tile of the hierarchy.

Why that is exact (a proof, not a tolerance). Let S be a closed oriented surface: the scene's convex
polygons of one edge-connected component, every directed edge matched by exactly one reverse edge, plus
at most one *base* (the fan from its centroid over the loop of unmatched edges, reversed: a block
without a bottom, standing on the floor). Triangulate every polygon as a fan. If from every point y of K
every triangle (a, b, c) of S has ``det(a - y, b - y, c - y) > 0`` (checked at K's vertices, with a
margin far above rounding; the determinant is affine in y, so it then holds on all of K), every triangle
subtends a positive solid angle from y; their sum over a closed surface is 4π w(y) with an integer
winding number w, hence w(y) >= 1. Let P lie strictly outside a convex set H containing S (here the
intersection of the outer half-spaces ``n_g . x <= max_S n_g . x``): w(P) = 0. So the segment from P to
any point y of K crosses S strictly between P and y, and not through the base, because P and K lie
strictly on the inner side of the base's plane (or, for a base in an exact axis plane such as z = 0,
P lies in that plane outside the base: the segment meets the plane only at P). The crossing is a scene
polygon, opaque: everything beyond K seen from P, i.e. K's shadow volume, is hidden exactly, and adding
that volume changes no result (only rounding: a few ulp of the form factors). Receivers not strictly
outside H — on the surface's own faces, under the block, inside it — do not use K.

K itself: the surface's polygon normals are grouped (within 1e-3 rad); each group's plane, with the
group's mean normal, is moved inward past every vertex of the group by the group's spread plus its
tilt over the surface's size and 1e-7 of that size; K is the intersection of those half-spaces (and
the base's), its vertices enumerated from triples of planes. Surfaces with more than
:data:`MAX_PLANES` groups, or whose K is empty, unbounded or fails the test, get none.
"""

from __future__ import annotations

import numpy as np

from .rowops import components, unique_rows
from .solids import Solids, no_solids
from .tolerances import COORD_EPS

__all__ = ["inner_solids"]

#: at most this many planes (normal groups, and the base) per polytope
MAX_PLANES = 12
#: normals within this angle (rad) form one group
GROUP_ANGLE = 1e-3
#: the polytope's faces lie this fraction of the surface's size inside the group planes' worst vertex
INSET = 1e-7
_EPS = np.finfo(np.float64).eps


def inner_solids(scene, members: np.ndarray, n_o: int, *, min_occluders: int = 8) -> Solids:
    """Convex polytopes strictly inside the closed surfaces of ``scene`` (see the module doc) as
    :class:`.solids.Solids` flagged ``virtual``: their faces are no occluders (``face_occ`` -1), their
    table columns are the union of the surface's occluders' (``cover_*``), and :attr:`.solids.Solids.rules`
    says at which receivers each applies. Only components whose polygons form at least ``min_occluders``
    occluders (``members (n,)``, -1 for duplicates) are tried: the others merged or are small."""
    n = scene.n_polygons
    if n == 0:
        return no_solids()
    reps = np.flatnonzero((scene.dup_rep == np.arange(n)) & (members >= 0))
    pv, pc = scene.poly_vertices, scene.poly_counts
    cnt = pc[reps]
    c_poly = np.repeat(reps, cnt)
    c_start = np.repeat(np.cumsum(cnt) - cnt, cnt)
    c_idx = np.arange(int(cnt.sum()))
    c_next = np.where(c_idx + 1 < c_start + np.repeat(cnt, cnt), c_idx + 1, c_start)
    pts = pv[reps][np.arange(pv.shape[1])[None, :] < cnt[:, None]]
    _, vid = unique_rows(np.ascontiguousarray(pts).view(np.int64).reshape(-1, 3))
    n_v = int(vid.max()) + 1
    a, b = vid, vid[c_next]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    srt = np.lexsort((hi, lo))
    same = (lo[srt][1:] == lo[srt][:-1]) & (hi[srt][1:] == hi[srt][:-1])
    root = components(n, c_poly[srt][1:][same], c_poly[srt][:-1][same])
    c_root = root[c_poly]
    occ_per = np.zeros(n, dtype=np.int64)
    pair = np.unique(np.stack([root[reps], members[reps]], axis=1), axis=0)
    np.add.at(occ_per, pair[:, 0], 1)
    found = []
    tried = np.flatnonzero(occ_per >= min_occluders)
    by_root = np.argsort(c_root, kind="stable")                 # corners grouped by component
    lo_c, hi_c = np.searchsorted(c_root[by_root], tried), np.searchsorted(c_root[by_root], tried, side="right")
    for s, e in zip(lo_c, hi_c):
        corners = by_root[s:e]
        k = _polytope(scene, corners, c_poly, a, b, n_v, pts)
        if k is not None:
            found.append((k, np.unique(members[c_poly[corners]])))
    if not found:
        return no_solids()
    return _as_solids(found)


def _polytope(scene, corners, c_poly, a, b, n_v, pts):
    """K for the component of ``corners`` (indices into the corner arrays), or None (see the module doc)."""
    key = a[corners] * n_v + b[corners]
    rkey = b[corners] * n_v + a[corners]
    order = np.argsort(key)
    sk = key[order]
    if (sk[1:] == sk[:-1]).any():
        return None                                   # a directed edge twice: not an oriented manifold
    at = np.minimum(np.searchsorted(sk, rkey), len(sk) - 1)
    matched = sk[at] == rkey
    polys = np.unique(c_poly[corners])
    nrm = scene.poly_normals[polys]
    v_all = pts[corners]
    size = float(np.linalg.norm(np.ptp(v_all, axis=0)))
    if not size > 0:
        return None
    planes_n, planes_spread = [], []
    # normal groups (greedy, within GROUP_ANGLE of each group's first normal)
    group = np.full(len(polys), -1)
    poly_pos = np.searchsorted(polys, c_poly[corners])
    cos_t = np.cos(GROUP_ANGLE)
    while (group < 0).any():
        i = int(np.flatnonzero(group < 0)[0])
        sel = (group < 0) & (nrm @ nrm[i] > cos_t)
        group[sel] = len(planes_n)
        g_n = nrm[sel].sum(axis=0)
        g_n /= np.linalg.norm(g_n)
        g_pts = v_all[sel[poly_pos]]
        tilt = float(np.linalg.norm(nrm[sel] - g_n, axis=1).max())
        planes_n.append(g_n)
        planes_spread.append((float((g_pts @ g_n).max() - (g_pts @ g_n).min()), tilt))
        if len(planes_n) + (not matched.all()) > MAX_PLANES:
            return None
    # the base: the loop of unmatched edges (one simple loop), closed by the fan from its centroid
    base = None
    if not matched.all():
        ua, ub = a[corners][~matched], b[corners][~matched]
        succ = dict(zip(ua.tolist(), ub.tolist()))
        if len(succ) != len(ua) or len(set(ub.tolist())) != len(ub):
            return None
        loop = [int(ua[0])]
        while len(loop) <= len(succ):
            nxt = succ.get(loop[-1])
            if nxt is None:
                return None
            if nxt == loop[0]:
                break
            loop.append(nxt)
        if len(loop) != len(succ):
            return None                                # several loops (holes), or a broken one
        ids, first = np.unique(a[corners], return_index=True)
        lp = v_all[first[np.searchsorted(ids, loop)]][::-1]     # the base runs the loop backwards
        centre = lp.mean(axis=0)
        newell = np.cross(lp - centre, np.roll(lp, -1, axis=0) - centre).sum(axis=0)
        if not np.linalg.norm(newell) > 0:
            return None
        hn = newell / np.linalg.norm(newell)
        axis = np.flatnonzero(np.abs(hn) > 1 - 1e-12)
        exact = False
        if len(axis) == 1 and np.all(lp[:, axis[0]] == lp[0, axis[0]]):
            hn = np.sign(hn[axis[0]]) * np.eye(3)[axis[0]]    # a base in an exact axis plane (z = 0)
            exact = True
        h_val = lp @ hn
        base = (hn, float(h_val.min()), float(h_val.max()), exact, centre, lp)
    outer = np.array([float((v_all @ g).max()) for g in planes_n])
    inner = outer - np.array([s + 4 * t * size + INSET * size for s, t in planes_spread])
    normals = np.array(planes_n)
    if base is not None:
        hn, h_lo, h_hi, exact = base[:4]
        normals = np.vstack([normals, hn])
        outer = np.append(outer, float((v_all @ hn).max()))
        inner = np.append(inner, h_lo - (h_hi - h_lo) - INSET * size)
    verts = _vertices(normals, inner, size)
    if verts is None:
        return None
    faces = _faces(verts, normals, inner, size)
    if faces is None:
        return None
    # the proof's test: every fan triangle of every polygon (and of the base) has det > 0 from K's vertices
    pv, pc = scene.poly_vertices[polys], scene.poly_counts[polys]
    tp, tj = np.nonzero(np.arange(pv.shape[1] - 2)[None, :] < (pc - 2)[:, None])      # fan (v0, v_j+1, v_j+2)
    tri = np.stack([pv[tp, 0], pv[tp, tj + 1], pv[tp, tj + 2]], axis=1)
    if base is not None:
        lp, centre = base[5], base[4]
        tri = np.concatenate([tri, np.stack([np.repeat(centre[None], len(lp), axis=0), lp, np.roll(lp, -1, axis=0)],
                                            axis=1)])                              # (T, 3, 3)
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    fair = area2 > 1e-14 * longest * longest                                      # zero solid angle either way
    tri, area2 = tri[fair], area2[fair]
    for y in verts:
        # det = |cross| x (height of y above the triangle's plane): above by 1e-9 of the size (the
        # polytope sits INSET inside), and far above the determinant's rounding
        r = tri - y
        det = np.einsum("tc,tc->t", r[:, 0], np.cross(r[:, 1], r[:, 2]))
        if not (det > np.maximum(1e-9 * size * area2, 64 * _EPS * np.prod(np.linalg.norm(r, axis=2), axis=1))).all():
            return None
    noise = COORD_EPS * float(np.abs(v_all).max())
    rules = (normals[:len(planes_n)], outer[:len(planes_n)], base, noise)
    return verts, faces, rules


def _vertices(normals, offsets, size):
    """Vertices of ``{x : normals . x <= offsets}`` from triples of planes, or None if it is empty or
    not bounded (fewer than 4 vertices, or a vertex far outside the surface's size)."""
    g = len(normals)
    out = []
    for i in range(g):
        for j in range(i + 1, g):
            for k in range(j + 1, g):
                m = normals[[i, j, k]]
                if abs(np.linalg.det(m)) < 1e-6:
                    continue
                x = np.linalg.solve(m, offsets[[i, j, k]])
                if (normals @ x - offsets <= 1e-12 * (size + np.abs(x).max())).all():
                    out.append(x)
    if len(out) < 4:
        return None
    v = np.array(out)
    keep = [0]
    for i in range(1, len(v)):
        if (np.abs(v[keep] - v[i]).max(axis=1) > 1e-12 * size).all():
            keep.append(i)
    v = v[keep]
    if len(v) < 4 or np.ptp(v, axis=0).max() > 4 * size:
        return None
    return v


def _faces(verts, normals, offsets, size):
    """The faces of the polytope: per plane its vertices counter-clockwise about the outward normal
    (planes touching it in fewer than 3 vertices are dropped); None unless every edge is in two faces."""
    faces = []
    for nv, off in zip(normals, offsets):
        on = np.flatnonzero(np.abs(verts @ nv - off) <= 1e-10 * size)
        if len(on) < 3:
            continue
        c = verts[on].mean(axis=0)
        e1 = verts[on[0]] - c
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(nv, e1)
        ang = np.arctan2((verts[on] - c) @ e2, (verts[on] - c) @ e1)
        faces.append((nv, on[np.argsort(ang)]))
    edges = {}
    for f, (_, ids) in enumerate(faces):
        for x, y in zip(ids, np.roll(ids, -1)):
            edges[(int(x), int(y))] = f
    if len(faces) < 4 or any((y, x) not in edges for x, y in edges):
        return None
    return faces


def _as_solids(found) -> Solids:
    """:class:`.solids.Solids` of the polytopes ``[((verts, faces, rules), cover occluders)]``."""
    face_ptr, face_out, face_point, face_center, ea, eb, ef, eg, es = [0], [], [], [], [], [], [], [], []
    centers, radii, cover_s, cover_o, rules = [], [], [], [], []
    for s, ((verts, faces, rule), cover) in enumerate(found):
        base = face_ptr[-1]
        where = {}
        for f, (nv, ids) in enumerate(faces):
            face_out.append(nv)
            face_point.append(verts[ids[0]])
            face_center.append(verts[ids].mean(axis=0))
            for x, y in zip(ids, np.roll(ids, -1)):
                where[(int(x), int(y))] = base + f
        for (x, y), f in where.items():
            if x < y:
                ea.append(verts[x]), eb.append(verts[y]), ef.append(f), eg.append(where[(y, x)]), es.append(s)
        face_ptr.append(base + len(faces))
        c = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
        centers.append(c)
        radii.append(float(np.linalg.norm(verts - c, axis=1).max()))
        cover_s.append(np.full(len(cover), s))
        cover_o.append(cover)
        rules.append(rule)
    n_f = face_ptr[-1]
    n_s = len(found)
    z3 = np.zeros((n_s, 3))
    noise = np.array([r[3] for r in rules])[np.repeat(np.arange(n_s), np.diff(face_ptr))]
    return Solids(np.array(face_ptr, dtype=np.int64), np.full(n_f, -1, dtype=np.int64), np.array(face_out),
                  np.array(face_point), np.array(face_center), 8 * _EPS * np.ones(n_f), noise,
                  np.zeros(n_s, dtype=bool), z3, z3, np.array(es, dtype=np.int64), np.array(ea), np.array(eb),
                  np.array(ef, dtype=np.int64), np.array(eg, dtype=np.int64), np.array(centers), np.array(radii),
                  virtual=np.ones(n_s, dtype=bool), cover_solid=np.concatenate(cover_s).astype(np.int64),
                  cover_occ=np.concatenate(cover_o).astype(np.int64), rules=rules)
