"""Vectorised ray casting against a :class:`~.scene.Scene` (camera rays, Monte Carlo, baselines).

Exact ray / convex-polygon intersection in float64, watertight on shared edges:

* the *inside* test follows Woop, Benthin & Wald (2013, "Watertight ray/triangle intersection"):
  every vertex is projected along the ray onto the plane across the ray's dominant axis, and the
  side of each edge is the 2D cross product of its projected end points. A vertex shared by
  several polygons is projected identically in each, and IEEE arithmetic makes the 2D cross
  product exactly antisymmetric (``a x b == -(b x a)``), so two polygons sharing an edge get exact
  negatives: with the inclusive test (all ``>= 0`` or all ``<= 0``) a ray through a shared edge or
  vertex always hits at least one of the polygons — no cracks, whatever the rounding. The test
  does not use the computed hit point, so it is independent of where the polygon's plane is hit.
* the ray parameter is ``t = n . (v_0 - o) / (n . d)`` in ray-local coordinates (``v_0 - o`` first),
  so scenes far from the origin lose nothing.

Acceleration: a bounding-volume hierarchy over the polygons' axis-aligned boxes. The tree is a
complete binary tree (implicit heap layout) built top down by object-median splits along the
longest axis of each node's polygon centres (one vectorised sort per level), with leaves of
``LEAF_SIZE`` polygons; node boxes are reduced bottom up. Traversal is breadth first and
vectorised over (ray, node) pairs: each level keeps the pairs whose box the ray segment enters,
the leaves give candidate (ray, polygon) pairs, and the exact test runs on those.

Memory bound: rays are processed ``chunk`` at a time; if the (ray, node) or (ray, polygon) pairs of a
chunk exceed ``max_pairs`` the chunk is split in halves (down to one ray), so the working set stays
below about ``max_pairs * (K * 24 + 300)`` bytes (K = padded vertex count; ~210 MB for the default
``max_pairs = 2**19`` and K = 4; pass a smaller ``max_pairs`` to go lower) plus ``O(n)`` for the
tree — except when a single ray alone meets more than ``max_pairs`` nodes, which needs a scene of
more than ``max_pairs`` polygons.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .tolerances import RAY_EPS

__all__ = ["RAY_EPS", "RayHits", "Bvh", "box_query", "build_bvh", "cast_rays", "default_t_min"]


#: Polygons per BVH leaf.
LEAF_SIZE = 4


class RayHits(NamedTuple):
    """Closest hits of ``r`` rays.

    Attributes:
        t: (r,) float64 ray parameter of the hit (distance when ``d`` is a unit vector); ``inf`` for a miss.
        polygon: (r,) int64 convex-polygon index into the scene's ``poly_*`` arrays, -1 for a miss.
        source: (r,) int64 input polygon index (``scene.poly_source``), -1 for a miss.
        point: (r, 3) float64 hit point ``o + t d``; NaN for a miss.
        front: (r,) bool True where the ray hit the front (emitting, ``poly_normals``) side.
    """

    t: np.ndarray
    polygon: np.ndarray
    source: np.ndarray
    point: np.ndarray
    front: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(r,) bool: the ray hit a polygon."""
        return self.polygon >= 0


class Bvh(NamedTuple):
    """Implicit complete binary tree over leaves of ``leaf_size`` polygons.

    Attributes:
        levels: list over depth 0..D of (6, 2**depth) float64 boxes (rows min x, y, z, max x, y, z;
            NaN for empty nodes, which are never entered). Node i has children 2i, 2i+1.
        leaf_polys: (2**D, leaf_size) int64 convex-polygon indices of each leaf, -1 padding.
        center: (3,) centre of the scene's bounding box; radius: float half its diagonal.
    """

    levels: list
    leaf_polys: np.ndarray
    center: np.ndarray
    radius: float


def build_bvh(scene, leaf_size: int = LEAF_SIZE) -> Bvh:
    """Build the BVH of ``scene``'s convex polygons; O(n log n) time, O(n) memory."""
    verts = scene.poly_vertices  # (n, K, 3); padding repeats a real vertex, so min/max are exact
    n = len(verts)
    if n == 0:
        return Bvh([np.full((6, 1), np.nan)], np.full((1, leaf_size), -1, dtype=np.int64), np.zeros(3), 0.0)
    pmin = verts.min(axis=1)  # (n, 3)
    pmax = verts.max(axis=1)
    lo, hi = pmin.min(axis=0), pmax.max(axis=0)
    center = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    # Boxes grow by a relative margin so that rounding in the slab test can only keep too much
    # (the exact polygon test follows), never cull a polygon the ray touches.
    pad = 1e-9 * (radius + float(np.abs(center).max())) + 1e-300
    pmin = pmin - pad
    pmax = pmax + pad
    n_leaves = -(-n // leaf_size)
    depth = max(int(np.ceil(np.log2(n_leaves))), 0)
    n_slots = (2**depth) * leaf_size
    # Top-down object-median split along the longest axis of each node's centre bounds, all nodes
    # of a level at once: the slots form (2**level, n_slots / 2**level) segments, sorted by key.
    cen = np.full((n_slots, 3), np.nan)
    cen[:n] = 0.5 * (pmin + pmax)
    order = np.arange(n_slots)
    for level in range(depth):
        seg = order.reshape(2**level, -1)  # (nodes, slots per node)
        c = cen[seg]  # (nodes, s, 3); NaN marks padding slots
        real = ~np.isnan(c[..., 0])
        span = np.where(real[..., None], c, -np.inf).max(axis=1) - np.where(real[..., None], c, np.inf).min(axis=1)
        axis = np.argmax(np.nan_to_num(span, nan=-1.0, neginf=-1.0), axis=1)  # (nodes,)
        key = np.take_along_axis(c, axis[:, None, None], axis=2)[..., 0]
        key = np.where(real, key, np.inf)  # padding sorts last
        order = np.take_along_axis(seg, np.argsort(key, axis=1, kind="stable"), axis=1).reshape(-1)
    leaf_polys = np.where(order < n, order, -1).reshape(2**depth, leaf_size)
    bmin = np.full((n_slots, 3), np.inf)
    bmax = np.full((n_slots, 3), -np.inf)
    real = order < n
    bmin[real] = pmin[order[real]]
    bmax[real] = pmax[order[real]]
    cur_min = bmin.reshape(2**depth, leaf_size, 3).min(axis=1)
    cur_max = bmax.reshape(2**depth, leaf_size, 3).max(axis=1)
    levels_min, levels_max = [cur_min], [cur_max]
    while len(cur_min) > 1:  # bottom-up: node i of a level has children 2i, 2i+1 one level down
        cur_min = cur_min.reshape(-1, 2, 3).min(axis=1)
        cur_max = cur_max.reshape(-1, 2, 3).max(axis=1)
        levels_min.append(cur_min)
        levels_max.append(cur_max)
    levels = []
    for lo_, hi_ in zip(levels_min[::-1], levels_max[::-1], strict=True):
        box = np.concatenate([lo_.T, hi_.T])  # (6, nodes)
        box[:, ~(lo_[:, 0] <= hi_[:, 0])] = np.nan  # empty nodes
        levels.append(np.ascontiguousarray(box))
    return Bvh(levels, leaf_polys, center, radius)


def default_t_min(scene_or_bvh, origins: np.ndarray) -> np.ndarray:
    """Default ``t_min (r,)`` for ``origins (r, 3)``: ``RAY_EPS`` times the ray's length scale."""
    bvh = scene_or_bvh if isinstance(scene_or_bvh, Bvh) else build_bvh(scene_or_bvh)
    scale = np.linalg.norm(origins - bvh.center, axis=1) + bvh.radius
    return RAY_EPS * scale


def _inverse_directions(d: np.ndarray) -> np.ndarray:
    """``(3, r)`` reciprocal direction components for the slab test; zero components become a
    huge finite value of either sign so that a ray parallel to a slab is kept whenever its origin
    lies in the slab (also on its boundary) and dropped otherwise, without inf * 0 = NaN."""
    dt = d.T
    return 1.0 / np.where(dt == 0.0, 1e-300, dt)


def _slab(box: np.ndarray, o: np.ndarray, inv: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """Does the segment ``o + t d, t in [t0, t1]`` meet the boxes?

    ``box (6, p)`` rows min x, y, z, max x, y, z (NaN for empty nodes, which are never entered);
    ``o, inv (3, p)`` origins and reciprocal directions; ``t0, t1 (p,)``. Returns ``(p,)`` bool.
    Column-wise arithmetic: reductions over an axis of length 3 are slow in numpy.
    """
    with np.errstate(over="ignore"):  # huge reciprocal * large distance -> +-inf, which is fine
        ta = (box[:3] - o) * inv
        tb = (box[3:] - o) * inv
    near = np.minimum(ta, tb)
    far = np.maximum(ta, tb)
    tn = np.maximum(np.maximum(near[0], near[1]), np.maximum(near[2], t0))
    tf = np.minimum(np.minimum(far[0], far[1]), np.minimum(far[2], t1))
    return tn <= tf  # NaN (empty node) compares False


def _intersect_pairs(scene, o, d, poly, t_lo, t_hi):
    """Exact test of rays ``o, d (3, p)`` (column layout) against convex polygons ``poly (p,)``.

    Returns ``t (p,)`` (inf where the ray misses the polygon or ``t`` is outside ``[t_lo, t_hi]``).
    """
    verts = scene.poly_vertices
    k = verts.shape[1]
    # (K, 3, p) vertices of the candidate polygons; np.take is faster than fancy indexing
    pv = np.take(verts.transpose(1, 2, 0), poly, axis=2)
    # Project every vertex along the ray onto the plane across the ray's dominant axis kz
    # (Woop, Benthin & Wald 2013, "Watertight ray/triangle intersection"). Each vertex is projected
    # the same way in every polygon that shares it, and the 2D edge function of an edge is exactly
    # antisymmetric in its two vertices, so rays through shared edges and vertices cannot slip
    # between polygons (a 3D triple product d . (a x b) would cancel catastrophically there).
    kz = np.argmax(np.abs(d), axis=0)  # (p,)
    sel = [kz == 0, kz == 1]

    def pick(x):  # component kz of (3, p) columns
        return np.where(sel[0], x[0], np.where(sel[1], x[1], x[2]))

    dz = pick(d)
    dz = np.where(dz == 0.0, 1.0, dz)  # only for d == 0, which never hits (den == 0 below)

    def project(v):  # (3, p) vertex relative to the origin, sheared along d to the plane across kz
        a = v - o
        return a - (pick(a) / dz) * d, a

    first, first_rel = project(pv[0])
    a = first
    pos = np.ones(len(poly), dtype=bool)
    neg = np.ones(len(poly), dtype=bool)
    for j in range(k):  # K is small (4 for quads); padded edges are zero-length -> edge function 0
        b = project(pv[j + 1])[0] if j + 1 < k else first
        # component kz of a x b: the 2D edge function in the projection plane
        e = np.where(sel[0], a[1] * b[2] - a[2] * b[1],
                     np.where(sel[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]))
        pos &= e >= 0.0
        neg &= e <= 0.0
        a = b
    n = np.take(scene.poly_normals.T, poly, axis=1)  # (3, p)
    den = n[0] * d[0] + n[1] * d[1] + n[2] * d[2]
    num = n[0] * first_rel[0] + n[1] * first_rel[1] + n[2] * first_rel[2]
    ok = (pos | neg) & (den != 0.0)
    t = np.full(len(poly), np.inf)
    t[ok] = num[ok] / den[ok]
    t[~((t >= t_lo) & (t <= t_hi))] = np.inf
    return t


def _cast_chunk(scene, bvh: Bvh, o, d, t_lo, t_hi, exclude, max_pairs):
    """Closest hit (t, polygon) of one chunk of rays ``o, d (r, 3)``; splits itself when the pairs
    exceed ``max_pairs``."""
    r = len(o)
    ot = np.ascontiguousarray(o.T)  # (3, r)
    dt = np.ascontiguousarray(d.T)
    inv = _inverse_directions(d)
    ray = np.arange(r)
    node = np.zeros(r, dtype=np.int64)
    depth = len(bvh.levels) - 1
    for level in range(depth + 1):
        # np.take is several times faster than fancy indexing for these gathers (numpy 2.x)
        keep = _slab(np.take(bvh.levels[level], node, axis=1), np.take(ot, ray, axis=1),
                     np.take(inv, ray, axis=1), np.take(t_lo, ray), np.take(t_hi, ray))
        ray, node = ray[keep], node[keep]
        if level < depth:
            if 2 * len(ray) > max_pairs and r > 1:
                return _split(scene, bvh, o, d, t_lo, t_hi, exclude, max_pairs)
            ray = np.repeat(ray, 2)
            node = (2 * node[:, None] + np.arange(2)).reshape(-1)
    polys = np.take(bvh.leaf_polys, node, axis=0)  # (q, leaf_size)
    if polys.size > max_pairs and r > 1:
        return _split(scene, bvh, o, d, t_lo, t_hi, exclude, max_pairs)
    ray = np.repeat(ray, polys.shape[1])
    poly = polys.reshape(-1)
    valid = poly >= 0
    if exclude is not None:
        valid &= scene.poly_source[np.maximum(poly, 0)] != exclude[ray]
    ray, poly = ray[valid], poly[valid]
    t = _intersect_pairs(scene, np.take(ot, ray, axis=1), np.take(dt, ray, axis=1), poly,
                         np.take(t_lo, ray), np.take(t_hi, ray))
    best_t = np.full(r, np.inf)
    np.minimum.at(best_t, ray, t)
    # ties (a ray through a shared edge or vertex): the lowest polygon index wins, deterministically
    win = np.isfinite(t) & (t == best_t[ray])
    best_p = np.full(r, np.iinfo(np.int64).max)
    np.minimum.at(best_p, ray[win], poly[win])
    best_p[~np.isfinite(best_t)] = -1
    return best_t, best_p


def _split(scene, bvh, o, d, t_lo, t_hi, exclude, max_pairs):
    h = len(o) // 2
    ex_a = None if exclude is None else exclude[:h]
    ex_b = None if exclude is None else exclude[h:]
    ta, pa = _cast_chunk(scene, bvh, o[:h], d[:h], t_lo[:h], t_hi[:h], ex_a, max_pairs)
    tb, pb = _cast_chunk(scene, bvh, o[h:], d[h:], t_lo[h:], t_hi[h:], ex_b, max_pairs)
    return np.concatenate([ta, tb]), np.concatenate([pa, pb])


def cast_rays(
    scene,
    origins,
    directions,
    *,
    t_min=None,
    t_max=None,
    exclude=None,
    bvh: Bvh | None = None,
    chunk: int = 16384,
    max_pairs: int = 2**19,
) -> RayHits:
    """Closest intersection of every ray ``origins + t * directions`` with the scene's polygons.

    Polygons are opaque from both sides (``front`` tells which side was hit).

    Args:
        scene: a :class:`~.scene.Scene`.
        origins: (r, 3) float ray origins (world space).
        directions: (r, 3) float ray directions, not necessarily unit (``t`` is in units of ``|d|``);
            zero directions never hit.
        t_min: scalar or (r,) smallest accepted ``t`` (inclusive). Default :func:`default_t_min`:
            a relative offset so that rays leaving a surface do not hit it again.
        t_max: scalar or (r,) largest accepted ``t`` (inclusive); default ``inf``. For a shadow ray
            to a point ``x`` use ``d = x - o`` and ``t_max = 1 - eps``.
        exclude: optional (r,) int input polygon (``poly_source``) each ray ignores, e.g. the one it
            leaves; -1 for none.
        bvh: a prebuilt :func:`build_bvh` of ``scene`` (reuse it across calls).
        chunk: rays per batch; ``max_pairs`` bounds the (ray, node) pairs per batch (module docstring).

    Returns:
        :class:`RayHits` with arrays of length r.
    """
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 3:
        raise ValueError(f"origins must have shape (r, 3), got {o.shape}")
    if d.shape != o.shape:
        raise ValueError(f"directions must have shape {o.shape}, got {d.shape}")
    if not (np.isfinite(o).all() and np.isfinite(d).all()):
        raise ValueError("origins and directions must be finite")
    r = len(o)
    if bvh is None:
        bvh = build_bvh(scene)
    lo = default_t_min(bvh, o) if t_min is None else np.broadcast_to(np.asarray(t_min, dtype=np.float64), (r,))
    hi = np.broadcast_to(np.asarray(np.inf if t_max is None else t_max, dtype=np.float64), (r,))
    ex = None if exclude is None else np.broadcast_to(np.asarray(exclude, dtype=np.int64), (r,))
    t = np.full(r, np.inf)
    poly = np.full(r, -1, dtype=np.int64)
    if scene.n_polygons and r:
        for s in range(0, r, chunk):
            e = min(s + chunk, r)
            t[s:e], poly[s:e] = _cast_chunk(
                scene, bvh, o[s:e], d[s:e], lo[s:e], hi[s:e], None if ex is None else ex[s:e], max_pairs
            )
    hit = poly >= 0
    point = np.full((r, 3), np.nan)
    point[hit] = o[hit] + t[hit, None] * d[hit]
    source = np.where(hit, scene.poly_source[np.maximum(poly, 0)] if scene.n_polygons else -1, -1)
    front = np.zeros(r, dtype=bool)
    front[hit] = np.einsum("rc,rc->r", scene.poly_normals[poly[hit]], d[hit]) < 0.0
    return RayHits(t, poly, source.astype(np.int64), point, front)


def box_query(bvh, lo, hi):
    """Pairs ``(query, polygon)`` whose boxes overlap: ``lo, hi (q, 3)`` query boxes; convex-polygon ids."""
    q = np.arange(len(lo))
    node = np.zeros(len(lo), dtype=np.int64)
    for level, box in enumerate(bvh.levels):
        b = np.take(box, node, axis=1)  # (6, pairs)
        keep = np.all((b[:3] <= hi[q].T) & (b[3:] >= lo[q].T), axis=0)  # NaN (empty node) is False
        q, node = q[keep], node[keep]
        if level < len(bvh.levels) - 1:
            q = np.repeat(q, 2)
            node = (2 * node[:, None] + np.arange(2)).reshape(-1)
    polys = np.take(bvh.leaf_polys, node, axis=0)  # (pairs, leaf)
    q = np.repeat(q, polys.shape[1])
    polys = polys.reshape(-1)
    ok = polys >= 0
    return q[ok], polys[ok]
