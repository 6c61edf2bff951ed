"""Exact hidden-part removal on the hemisphere (paper sec. 2.3–2.4), order-independent.

A point x of polygon A is hidden from P by polygon B exactly when the segment P→x crosses B, i.e. when
x lies in B's *shadow volume*: beyond B's plane (on the side away from P) and inside the cone from P
over B. The cone is bounded by the planes through P and B's edges — the great circles of B's projected
edges (sec. 2.3) — so the shadow volume of a convex B is a convex polyhedron bounded by k + 1 planes.

The visible part of A is A minus the union of its occluders' shadow volumes. Subtracting a convex
polyhedron from a convex polygon is a chain of plane clips: the part outside plane 1 is kept, the part
inside continues to plane 2, and so on; what is inside all planes is hidden. Because the depth test is
B's own plane, the part of A on P's side of B's plane is never hidden by B, which resolves depth order,
cyclic overlaps and interpenetrating polygons (sec. 2.4) without any sort. Every test and every
intersection is a plane evaluation in 3D, P-local coordinates.

All fragments of all receivers of a chunk are processed together: round r subtracts the r-th occluder
(nearest first) of every fragment's polygon, vectorised over fragments. A fragment that turns out not
to meet a shadow volume is kept whole (no needless splitting).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .clipping import classify, pad_repeat_last, split_convex
from .culling import Occluders
from .projection import Candidates, receiver_side
from .tolerances import PLANE_EPS

__all__ = ["Fragments", "ShadowVolumes", "occluder_pairs", "shadow_volumes", "subtract_shadow_volumes"]


@dataclass
class Fragments:
    """Visible fragments (P-local), flat over all receivers of a chunk.

    Attributes: verts (F, K, 3); inf (F, K, 3) or None; counts (F,); point (F,) receiver; poly (F,)
    convex polygon; side (F,) receiver side of the polygon's plane (+1 behind, -1 in front).
    """

    verts: np.ndarray
    inf: np.ndarray | None
    counts: np.ndarray
    point: np.ndarray
    poly: np.ndarray
    side: np.ndarray


@dataclass
class ShadowVolumes:
    """Shadow volumes of the occluders active at each receiver (flat over instances q).

    ``x`` is inside instance q's volume when ``normal[q, j] . x - offset[q, j] > 0`` for every j.
    Unused plane slots have a zero normal and offset -1 (always inside).

    Attributes: point (Q,), occluder (Q,), side (Q,) receiver side of the occluder's plane, normal (Q, J, 3), offset (Q, J), offset_inf (Q, J) or None,
    near (Q,) distance from P to the nearest point of the occluder's bounding sphere (for ordering).
    """

    point: np.ndarray
    occluder: np.ndarray
    side: np.ndarray
    normal: np.ndarray
    offset: np.ndarray
    offset_inf: np.ndarray | None
    near: np.ndarray


def _cone(rel_c: np.ndarray, radius: np.ndarray):
    """Bounding cone (axis (.., 3), half-angle (..,)) of spheres at ``rel_c`` with ``radius`` seen from P."""
    dist = np.linalg.norm(rel_c, axis=-1)
    axis = rel_c / np.where(dist > 0, dist, 1.0)[..., None]
    ratio = np.where(dist > radius, radius / np.where(dist > 0, dist, 1.0), 1.0)
    half = np.where(dist > radius, np.arcsin(np.minimum(ratio, 1.0)), np.pi)
    return axis, half, dist


def shadow_volumes(occ: Occluders, points, normals, limit=None) -> tuple[ShadowVolumes, np.ndarray]:
    """Shadow volumes of every occluder that can hide something above each receiver's horizon.

    Returns the volumes and an ``(m, n_o)`` int table of instance index (-1: inactive).
    """
    m, n_o = len(points), occ.n
    rel_c = occ.centers[None] - points[:, None]                                 # (m, n_o, 3)
    dist_c = np.linalg.norm(rel_c, axis=2)
    scale = dist_c + occ.radii[None]
    side = receiver_side(occ.normals, occ.vertices[None, :, 0] - points[:, None], scale, limit)
    # an occluder can only hide points above the horizon with its own part above the horizon
    height_c = np.einsum("moc,mc->mo", rel_c, normals)
    active = (side != 0) & (height_c + occ.radii[None] > PLANE_EPS * scale)
    qp, qo = np.nonzero(active)
    x = occ.vertices[qo] - points[qp, None]                                     # (Q, Ko, 3)
    counts = occ.counts[qo]
    k = x.shape[1]
    valid = np.arange(k)[None] < counts[:, None]
    xs = np.abs(x).max(axis=(1, 2))
    up = ((np.einsum("qkc,qc->qk", x, normals[qp]) > PLANE_EPS * xs[:, None]) & valid).any(axis=1)
    qp, qo, x, counts, valid, xs = qp[up], qo[up], x[up], counts[up], valid[up], xs[up]
    sigma = side[qp, qo].astype(np.float64)                                     # (Q,)
    q = len(qp)

    # plane 0: the occluder's own plane, inside = beyond it (away from P)
    nrm = occ.normals[qo]
    normal = np.zeros((q, k + 1, 3))
    offset = np.full((q, k + 1), -1.0)
    normal[:, 0] = sigma[:, None] * nrm
    offset[:, 0] = sigma * np.einsum("qc,qc->q", nrm, x[:, 0])
    offset_inf = None
    if limit is not None:
        offset_inf = np.zeros((q, k + 1))
        offset_inf[:, 0] = sigma * -(np.einsum("qc,qc->q", nrm, limit[qp]))
    # planes 1..k: through P and each edge, inside = inside the cone over the occluder
    xn = np.roll(x, -1, axis=1)
    xn = np.where((np.arange(k)[None] + 1 < counts[:, None])[..., None], xn, x[:, :1])  # close the loop
    c = np.cross(x, xn)                                                         # (Q, Ko, 3)
    cn = np.linalg.norm(c, axis=2)
    lens = np.linalg.norm(x, axis=2) * np.linalg.norm(xn, axis=2)
    ok = valid & (cn > PLANE_EPS * lens)
    if limit is not None:
        # an edge through P (one-sided limit only): its plane is the limit of the plane through P + εu
        u = -limit[qp][:, None, :]
        at_p = valid & ~ok
        if at_p.any():
            c_inf = np.cross(np.broadcast_to(u, x.shape), xn) + np.cross(x, np.broadcast_to(u, x.shape))
            cin = np.linalg.norm(c_inf, axis=2)
            use = at_p & (cin > PLANE_EPS * np.maximum(np.linalg.norm(xn, axis=2), np.linalg.norm(x, axis=2)))
            c = np.where(use[..., None], c_inf, c)
            cn = np.where(use, cin, cn)
            ok |= use
    unit = c / np.where(ok, cn, 1.0)[..., None]
    normal[:, 1:] = np.where(ok[..., None], sigma[:, None, None] * unit, 0.0)
    offset[:, 1:] = np.where(ok, 0.0, -1.0)
    near = dist_c[qp, qo] - occ.radii[qo]
    table = np.full((m, n_o), -1, dtype=np.int64)
    table[qp, qo] = np.arange(q)
    return ShadowVolumes(qp, qo, side[qp, qo], normal, offset, offset_inf, near), table


def occluder_pairs(cand: Candidates, sv: ShadowVolumes, table: np.ndarray, occ: Occluders, scene, points):
    """Occluders of every candidate that can hide part of it, nearest first.

    Returns ``ptr (C+1,), ids`` (CSR lists of shadow-volume instances) and ``hidden (C,)``: candidates
    that lie wholly inside one shadow volume and need no further work.

    A pair is kept when the candidate has a vertex strictly beyond the occluder's plane on the side
    away from P (precomputed, per side) and their bounding cones from P overlap.
    """
    c_n = len(cand.point)
    if c_n == 0 or len(sv.point) == 0:
        return np.zeros(c_n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(c_n, dtype=bool)
    # dense over (candidate, occluder) in blocks of candidates
    n_o = occ.n
    ids_all, owner_all, near_all = [], [], []
    block = max(1, int(2e6 // max(1, n_o)))
    for s in range(0, c_n, block):
        cp = cand.point[s:s + block]
        ci = cand.poly[s:s + block]
        q = table[cp]                                                           # (b, n_o)
        has = q >= 0
        qs = np.where(has, q, 0)
        sig_pos = sv.side[qs] > 0                                               # (b, n_o)
        beyond = np.where(sig_pos, occ.beyond_pos[ci], occ.beyond_neg[ci]) & has
        beyond &= occ.members[ci][:, None] != np.arange(n_o)[None]
        if not beyond.any():
            continue
        b_idx, o_idx = np.nonzero(beyond)
        qq = q[b_idx, o_idx]
        # bounding cones, seen from the receiver
        p = cp[b_idx]
        ax_c, half_c, _ = _cone(scene.poly_centers[ci[b_idx]] - points[p], scene.poly_radii[ci[b_idx]])
        ax_o, half_o, _ = _cone(occ.centers[o_idx] - points[p], occ.radii[o_idx])
        cosang = np.clip(np.einsum("pc,pc->p", ax_c, ax_o), -1.0, 1.0)
        overlap = np.arccos(cosang) <= half_c + half_o + 1e-9
        ids_all.append(qq[overlap])
        owner_all.append(s + b_idx[overlap])
        near_all.append(sv.near[qq[overlap]])
    empty = np.zeros(c_n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(c_n, dtype=bool)
    if not ids_all:
        return empty
    ids = np.concatenate(ids_all)
    owner = np.concatenate(owner_all)
    near = np.concatenate(near_all)
    # exact prefilter on the candidate's clipped vertices: a candidate wholly outside one plane of a
    # shadow volume does not meet it; one wholly inside every plane is hidden entirely
    meets = np.zeros(len(ids), dtype=bool)
    covered = np.zeros(len(ids), dtype=bool)
    step = max(1, int(2e6 // (cand.verts.shape[1] * sv.normal.shape[1])))
    for s in range(0, len(ids), step):
        q, c = ids[s:s + step], owner[s:s + step]
        v, cnt = cand.verts[c], cand.counts[c]
        inf = None if cand.inf is None else cand.inf[c]
        outside_one = np.zeros(len(q), dtype=bool)
        inside_all = np.ones(len(q), dtype=bool)
        scale = np.abs(v).max(axis=(1, 2))
        for j in range(sv.normal.shape[1]):
            side = _plane_sides(v, inf, cnt, scale, sv, q, j)[0]
            outside_one |= ~(side > 0).any(axis=1)
            inside_all &= ~(side < 0).any(axis=1)
        meets[s:s + step] = ~outside_one
        covered[s:s + step] = inside_all & ~outside_one
    hidden = np.zeros(c_n, dtype=bool)
    hidden[owner[covered]] = True
    keep = meets & ~hidden[owner]
    ids, owner, near = ids[keep], owner[keep], near[keep]
    order = np.lexsort((near, owner))
    ids, owner = ids[order], owner[order]
    ptr = np.zeros(c_n + 1, dtype=np.int64)
    np.add.at(ptr, owner + 1, 1)
    return np.cumsum(ptr), ids, hidden


def _plane_sides(verts, inf, counts, scale, sv: ShadowVolumes, q: np.ndarray, j):
    """Sides (W, K) of fragment vertices w.r.t. plane ``j`` of volumes ``q`` (W,); invalid slots 0.

    ``scale (W,)`` is the fragments' length scale (max |x|) for the on-plane tolerance.
    """
    nrm = sv.normal[q, j]
    off = sv.offset[q, j]
    s_re = np.einsum("wkc,wc->wk", verts, nrm) - off[:, None]
    s_inf = None
    if inf is not None:
        s_inf = np.einsum("wkc,wc->wk", inf, nrm) - sv.offset_inf[q, j][:, None]
    eps = PLANE_EPS * (scale + np.abs(off))
    side = classify(s_re, eps, s_inf)
    side[np.arange(verts.shape[1])[None, :] >= counts[:, None]] = 0
    return side, s_re, s_inf, eps


def subtract_shadow_volumes(frags: Fragments, owner: np.ndarray, ptr: np.ndarray, ids: np.ndarray,
                            sv: ShadowVolumes) -> tuple[Fragments, np.ndarray]:
    """Remove from every fragment the parts inside its occluders' shadow volumes.

    Args:
        frags: fragments; owner: (F,) candidate of each fragment; ptr, ids: the candidates' occluder
            instances (CSR, nearest first); sv: the shadow volumes.
    Returns:
        the visible fragments and their owners.
    """
    dual = frags.inf is not None
    n_occ = np.diff(ptr)
    j_planes = sv.normal.shape[1]
    done: list[tuple] = []
    work = _FragSet.of(frags, owner)
    r = 0
    while len(work.owner):
        finished = n_occ[work.owner] <= r
        if finished.any():
            done.append(work.take(finished))
            work = work.take(~finished)
            if not len(work.owner):
                break
        n_w = len(work.owner)
        q_of = ids[ptr[work.owner] + r]                                           # (W,)
        width = work.verts.shape[1] + j_planes
        cur_v = _fit(work.verts, work.counts, width)
        cur_i = _fit(work.inf, work.counts, width) if dual else None
        cur_c = work.counts.copy()
        scale = np.abs(work.verts).max(axis=(1, 2))
        item = np.arange(n_w)
        pieces = []
        for j in range(j_planes):
            side, s_re, s_inf, eps = _plane_sides(cur_v, cur_i, cur_c, scale[item], sv, q_of[item], j)
            has_in = (side > 0).any(axis=1)
            has_out = (side < 0).any(axis=1)
            # wholly outside this plane: the fragment does not meet the volume and stays whole;
            # wholly inside (or on) it: carry on unchanged to the next plane
            cut = np.flatnonzero(has_in & has_out)
            if len(cut):
                k = int(cur_c[cut].max())
                (iv, ic, ii), (ov, oc, oi) = split_convex(
                    cur_v[cut, :k], cur_c[cut], s_re[cut, :k], eps[cut],
                    inf=cur_i[cut, :k] if dual else None, s_inf=s_inf[cut, :k] if dual else None)
                pieces.append((item[cut], ov, oc, oi))
                cur_v[cut, : k + 1] = iv
                cur_v[cut, k + 1:] = iv[:, -1:]
                if dual:
                    cur_i[cut, : k + 1] = ii
                    cur_i[cut, k + 1:] = ii[:, -1:]
                cur_c[cut] = ic
            item, cur_v, cur_c = item[has_in], cur_v[has_in], cur_c[has_in]
            cur_i = cur_i[has_in] if dual else None
            if len(item) == 0:
                break
        hidden = np.zeros(n_w, dtype=bool)
        hidden[item] = True          # these fragments have a non-empty hidden part
        if hidden.any():
            parts = [work.take(~hidden)]
            for it, pv, pc, pi in pieces:
                sel = hidden[it]
                if sel.any():
                    parts.append(work.pieces(it[sel], pv[sel], pc[sel], pi[sel] if dual else None))
            work = _FragSet.concat(parts)
        r += 1
    done.append(work)
    out = _FragSet.concat(done)
    return Fragments(out.verts, out.inf, out.counts, out.point, out.poly, out.side), out.owner


@dataclass
class _FragSet:
    """Fragments with their owning candidates, as one set of parallel arrays (internal)."""

    verts: np.ndarray
    inf: np.ndarray | None
    counts: np.ndarray
    point: np.ndarray
    poly: np.ndarray
    side: np.ndarray
    owner: np.ndarray

    @classmethod
    def of(cls, f: Fragments, owner: np.ndarray) -> _FragSet:
        return cls(f.verts, f.inf, f.counts, f.point, f.poly, f.side, owner)

    def take(self, sel) -> _FragSet:
        return _FragSet(self.verts[sel], None if self.inf is None else self.inf[sel], self.counts[sel],
                        self.point[sel], self.poly[sel], self.side[sel], self.owner[sel])

    def pieces(self, src, verts, counts, inf) -> _FragSet:
        """New fragments ``verts (p, K, 3)`` cut from fragments ``src (p,)`` of this set."""
        return _FragSet(verts, inf, counts, self.point[src], self.poly[src], self.side[src], self.owner[src])

    @staticmethod
    def concat(parts: list[_FragSet]) -> _FragSet:
        parts = [p for p in parts if len(p.owner)] or parts[:1]
        width = max(3, max(int(p.counts.max(initial=3)) for p in parts))
        dual = parts[0].inf is not None
        return _FragSet(
            np.concatenate([_fit(p.verts, p.counts, width) for p in parts]),
            np.concatenate([_fit(p.inf, p.counts, width) for p in parts]) if dual else None,
            np.concatenate([p.counts for p in parts]),
            np.concatenate([p.point for p in parts]),
            np.concatenate([p.poly for p in parts]),
            np.concatenate([p.side for p in parts]),
            np.concatenate([p.owner for p in parts]),
        )


def _fit(v: np.ndarray, c: np.ndarray, width: int) -> np.ndarray:
    """Pad or trim padded polygons ``v (F, K, 3)`` to ``width`` slots (``width >= counts``)."""
    if v.shape[1] == width:
        return v
    if v.shape[1] > width:
        return v[:, :width]
    return pad_repeat_last(v, c, width)
