"""Batched clipping of convex polygons by planes (Sutherland–Hodgman), both sides at once.

All geometry is in receiver-local coordinates (the receiver point P at the origin). Every clip of the
exact projection is a clip by a plane: the tangent plane of P (the horizon), the plane through P and an
edge of an occluder (a great circle on the sphere, sec. 2.3 of the paper: "all tests and intersection
calculations are done in three dimensional space"), or the plane of an occluder (depth, sec. 2.4).
Clipping the 3D polygon instead of its projection keeps fragments planar and in their source polygon's
plane, so depth and radiance stay defined on them.

First-order ("dual") coordinates
--------------------------------
For the one-sided limit at ``P + εu`` (ε → 0+) every vertex is ``x = x_re + ε x_inf``. Signs of plane
distances come from the real part, and from the ε part where the real part vanishes (a vertex at P
itself); intersection parameters are carried to first order. Callers that do not need limits pass
``inf=None`` and pay nothing for it.

Polygons are padded arrays: ``verts (F, K, 3)`` with ``counts (F,)``; slots past the count repeat the last
vertex, so every edge ``j -> j+1`` past the count has zero length and the closing edge is ``K-1 -> 0``.
"""

from __future__ import annotations

import numpy as np

from .rowops import any_rows, nonzero_rows, sides, sum_rows
from .tolerances import PLANE_EPS

__all__ = ["classify", "pad_repeat_last", "split_convex"]


def classify(s_re: np.ndarray, eps: np.ndarray, s_inf: np.ndarray | None = None) -> np.ndarray:
    """Side of each vertex: +1, -1, or 0 (on the plane within ``eps``).

    Args:
        s_re: (F, K) signed distances (real part).
        eps: (F,) absolute on-plane tolerance per polygon, or (F, K) per vertex.
        s_inf: (F, K) first-order part of the distances, or None. Decides the side where the real part
            is within tolerance (a vertex at the receiver in a one-sided limit).
    Returns:
        (F, K) int8.
    """
    side = sides(s_re, eps if eps.ndim == 2 else eps[:, None])
    if s_inf is not None:
        on = side == 0
        if on.any():
            side[on] = sides(s_inf[on], PLANE_EPS)
    return side


def pad_repeat_last(verts: np.ndarray, counts: np.ndarray, width: int) -> np.ndarray:
    """Re-pad ``verts (F, K, 3)`` to ``(F, width, 3)`` repeating the last real vertex (counts >= 1)."""
    idx = np.minimum(np.arange(width)[None, :], np.maximum(counts, 1)[:, None] - 1)
    return _gather_slots(verts, idx)


def _gather_slots(verts: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``verts[f, idx[f, w]]`` for ``verts (F, K, 3)``, ``idx (F, W)``: one flat gather (faster than
    ``take_along_axis``, which broadcasts index grids)."""
    f, k, _ = verts.shape
    flat = (np.arange(f)[:, None] * k + idx).ravel()
    return np.take(verts.reshape(-1, 3), flat, axis=0).reshape(f, idx.shape[1], 3)


def _resolve_isolated_zeros(side: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Give every on-plane vertex whose nearest off-plane neighbours (both ways round the polygon)
    lie on the same side that side. ``side (R, K)`` int8 with both signs present in every row."""
    r, k = side.shape
    idx = np.arange(k)
    out = side.copy()
    prev_nz = np.zeros((r, k), dtype=np.int8)
    next_nz = np.zeros((r, k), dtype=np.int8)
    last = np.zeros(r, dtype=np.int8)
    for j in list(range(k)) * 2:  # two passes round the cycle: the wrap-around is seen
        live = j < counts
        prev_nz[live, j] = last[live]
        last = np.where(live & (side[:, j] != 0), side[:, j], last)
    last[:] = 0
    for j in list(range(k - 1, -1, -1)) * 2:
        live = j < counts
        next_nz[live, j] = last[live]
        last = np.where(live & (side[:, j] != 0), side[:, j], last)
    fix = (side == 0) & (prev_nz == next_nz) & (prev_nz != 0) & (idx[None, :] < counts[:, None])
    out[fix] = prev_nz[fix]
    return out


def _compact(cand: np.ndarray, keep: np.ndarray, width: int, counts: np.ndarray):
    """Pack the kept slots of ``cand (F, S, 3)`` left, padded to ``width`` by repeating the last
    (``width <= S``; ``counts (F,)``: kept slots per row); rows with nothing kept are all zeros."""
    f, s = keep.shape
    flat = np.flatnonzero(keep)                                       # kept slots, row by row, in order
    row = flat // s
    first = np.cumsum(counts) - counts                                # position in ``flat`` of each row's first
    full = counts > 0
    last = np.zeros(f, dtype=np.int64)
    last[full] = flat[first[full] + counts[full] - 1]
    src = np.repeat(last[:, None], width, axis=1)                     # flat source slot of every output slot
    src.ravel()[row * width + (np.arange(len(flat)) - first[row])] = flat
    out = np.take(cand.reshape(-1, 3), src.ravel(), axis=0).reshape(f, width, 3)
    if not full.all():
        out[~full] = 0.0
    return out, counts


def split_convex(
    verts: np.ndarray,
    counts: np.ndarray,
    s_re: np.ndarray,
    eps: np.ndarray,
    *,
    inf: np.ndarray | None = None,
    s_inf: np.ndarray | None = None,
    origin_edges: np.ndarray | None = None,
    outside: bool = True,
):
    """Split convex polygons by a plane given through the signed distances of their vertices.

    The *inside* is ``s > 0``; vertices on the plane go to both sides. A side is empty unless some
    vertex lies strictly in it, except that a polygon lying wholly on the plane goes to the outside.

    Args:
        verts: (F, K, 3) padded polygons; counts: (F,) vertex counts (0 = empty polygon).
        s_re: (F, K) signed distance of every vertex slot; eps: (F,) on-plane tolerance, or (F, K) per
            vertex slot.
        inf, s_inf: (F, K, 3) and (F, K) first-order parts (see module docstring), or None.
        origin_edges: (F, K) bool or None: edges ``j -> j+1`` whose line passes through the origin, for a
            plane through the origin: their crossing is the origin itself (exactly; interpolating a
            grazing edge would leave it far off by the rounding of the distances).
        outside: False to build the inside pieces only (the outside is then None).
    Returns:
        ``(inside, outside)``, each a tuple ``(verts (F, W, 3), counts (F,), inf or None)`` with
        ``W >= K+1`` (K+1 for convex input); a side's count is 0 where it is empty.
    """
    f, k, _ = verts.shape
    dual = inf is not None
    side = classify(s_re, eps, s_inf if dual else None)
    valid = np.arange(k)[None, :] < counts[:, None]
    side = side * valid
    any_in = any_rows(side > 0)
    any_out = any_rows(side < 0)
    in_ok = any_in
    out_ok = any_out | ~any_in
    # On-plane vertices bound both pieces. Rounding can put a vertex "on" the plane between two
    # neighbours on the same side — impossible for a convex polygon, and it would make both pieces
    # contain a sliver; such a vertex takes its neighbours' side.
    mixed = any_in & any_out & any_rows(valid & (side == 0))
    if mixed.any():
        side[mixed] = _resolve_isolated_zeros(side[mixed], counts[mixed])
    # side of the next vertex round each polygon (padding slots have side 0)
    side_n = np.concatenate([side[:, 1:], side[:, :1]], axis=1)
    short = np.flatnonzero((counts < k) & (counts > 0))
    side_n.ravel()[short * k + counts[short] - 1] = side[short, 0]
    crossing = valid & (side * side_n < 0)

    cand_v = np.zeros((f, 2 * k, 3))
    cand_v[:, 0::2] = verts
    cand_inf = None
    if dual:
        cand_inf = np.zeros((f, 2 * k, 3))
        cand_inf[:, 0::2] = inf
    if crossing.any():
        r, j = nonzero_rows(crossing)
        jn = np.where(j + 1 < counts[r], j + 1, 0)
        at, an = r * k + j, r * k + jn                                    # flat slots of both ends
        a0 = np.take(s_re.ravel(), at)
        b0 = np.take(s_re.ravel(), an)
        ea, eb = (np.take(eps.ravel(), at), np.take(eps.ravel(), an)) if eps.ndim == 2 else (eps[r], eps[r])
        # real parts within tolerance count as zero, so that a vertex whose side came from its
        # first-order part interpolates consistently (and an on-plane vertex is its own crossing)
        a0 = np.where(np.abs(a0) > ea, a0, 0.0)
        b0 = np.where(np.abs(b0) > eb, b0, 0.0)
        flat_v = verts.reshape(-1, 3)
        xa, xb = np.take(flat_v, at, axis=0), np.take(flat_v, an, axis=0)
        dest = r * (2 * k) + 2 * j + 1                                    # flat slot of the crossing
        if dual:
            a1, b1 = np.take(s_inf.ravel(), at), np.take(s_inf.ravel(), an)
            both0 = (a0 == 0.0) & (b0 == 0.0)
            den0 = np.where(both0, 1.0, a0 - b0)
            den1 = np.where(both0 & (a1 != b1), a1 - b1, 1.0)
            t0 = np.where(both0, np.where(a1 != b1, a1 / den1, 0.0), a0 / den0)
            u0 = np.where(both0, np.where(a1 != b1, -b1 / den1, 1.0), -b0 / den0)      # 1 - t0
            t1 = np.where(both0, 0.0, (a0 * b1 - a1 * b0) / (den0 * den0))
            flat_i = inf.reshape(-1, 3)
            ia, ib = np.take(flat_i, at, axis=0), np.take(flat_i, an, axis=0)
            cand_inf.reshape(-1, 3)[dest] = ia + t0[:, None] * (ib - ia) + t1[:, None] * (xb - xa)
        else:
            same = a0 == b0  # both rounded onto the plane (a resolved zero next to another)
            den = np.where(same, 1.0, a0 - b0)
            t0 = np.where(same, 0.0, a0 / den)
            u0 = np.where(same, 1.0, -b0 / den)                                   # 1 - t0
        # interpolate from the endpoint nearer the plane: the new vertex then stays within one
        # rounding of the plane whichever way the edge is walked (neighbours share the point). Its
        # parameter from that end is its own quotient, not 1 - t0: near 1, t0's rounding (1e-16) is
        # the whole of a small 1 - t0 (a cut 1e-9 from the near end was put 1e-16 off the edge's
        # point, 1e-7 of its distance from P where that end is P's neighbour)
        near_a = np.abs(a0) <= np.abs(b0)
        cand_v.reshape(-1, 3)[dest] = np.where(near_a[:, None], xa + t0[:, None] * (xb - xa),
                                               xb + u0[:, None] * (xa - xb))
        if origin_edges is not None:
            through = np.take(origin_edges.ravel(), at)
            cand_v.reshape(-1, 3)[dest[through]] = 0.0

    keep_cross = np.zeros((f, 2 * k), dtype=bool)
    keep_cross[:, 1::2] = crossing
    keeps = []
    for ok, keep_side in ((in_ok, side >= 0), (out_ok, side <= 0))[: 2 if outside else 1]:
        keep = keep_cross.copy()
        keep[:, 0::2] = valid & keep_side
        keep &= ok[:, None]
        keeps.append(keep)
    # a convex polygon gains at most one vertex; rounding can make a nearly degenerate one cross more
    kept_n = [sum_rows(kp) for kp in keeps]
    width = max(k + 1, int(max(n.max(initial=0) for n in kept_n)))
    results = []
    for keep, n in zip(keeps, kept_n):
        out_v, out_c = _compact(cand_v, keep, width, n)
        out_inf = _compact(cand_inf, keep, width, n)[0] if dual else None
        results.append((out_v, out_c, out_inf))
    # a polygon that lies wholly on one side is passed through unchanged (no rounding at all)
    whole_in = in_ok & ~any_out
    whole_out = ~any_in
    for res, whole in zip(results, (whole_in, whole_out)):
        if whole.any():
            res[0][whole] = pad_repeat_last(verts[whole], counts[whole], width)
            res[1][whole] = counts[whole]
            if dual:
                res[2][whole] = pad_repeat_last(inf[whole], counts[whole], width)
    return results[0], results[1] if outside else None
