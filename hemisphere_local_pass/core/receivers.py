"""Receivers as the core takes them: validated points, unit normals and one-sided limit directions."""

from __future__ import annotations

import numpy as np

__all__ = ["TOUCH_EPS", "idle_limits_dropped", "limit_groups", "prepare_receivers"]

#: A polygon *touches* a receiver when its bounding box, grown by ``TOUCH_EPS`` times the scene's largest
#: coordinate, contains P and its plane passes within that distance of P (:func:`idle_limits_dropped`);
#: generous against the core's own plane tolerances (``PLANE_EPS``, ``COORD_EPS``: ~1e-15 relative), so
#: that every polygon the limit path treats apart is kept.
TOUCH_EPS = 1e-7


def prepare_receivers(points, normals, limit_directions=None, *, single=False):
    """Validate receivers; return ``P (m, 3)``, unit ``N (m, 3)`` and tangent ``U (m, 3)`` or None."""
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if single:
        p, n = p.reshape(1, -1), n.reshape(1, -1)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (m, 3), got {p.shape}")
    if n.shape != p.shape:
        raise ValueError(f"normals must have shape {p.shape}, got {n.shape}")
    bad = np.flatnonzero(~(np.isfinite(p).all(axis=1) & np.isfinite(n).all(axis=1)))
    if len(bad):
        raise ValueError(f"receiver {int(bad[0])} has a non-finite point or normal ({p[bad[0]]}, {n[bad[0]]})")
    length = np.linalg.norm(n, axis=1)
    bad = np.flatnonzero(~(length > 0))
    if len(bad):
        raise ValueError(f"receiver {int(bad[0])} has a zero normal")
    n = n / length[:, None]
    u = None
    if limit_directions is not None:
        u = np.asarray(limit_directions, dtype=np.float64)
        if single:
            u = u.reshape(1, -1)
        if u.shape != p.shape:
            raise ValueError(f"limit_directions must have shape {p.shape}, got {u.shape}")
        if not np.isfinite(u).all():
            raise ValueError("limit_directions must be finite")
        u = u - np.einsum("mc,mc->m", u, n)[:, None] * n       # keep it in the tangent plane
        ul = np.linalg.norm(u, axis=1)
        u = np.where((ul > 1e-12)[:, None], u / np.where(ul > 0, ul, 1.0)[:, None], 0.0)
        if not u.any():
            u = None
    return p, n, u


def limit_groups(u) -> list:
    """The receivers of one chunk in the groups the visibility stage must see apart: ``[(at, u_at)]``,
    ``at`` the receivers' indices (None: all of them) and ``u_at`` their limit directions (None: none).

    One receiver with a one-sided limit (a non-zero row of ``u (m, 3)``) puts a whole call on the
    infinitesimal path (no sub-tile refinement, the ``inf`` columns), which sums the other receivers' terms
    in another order: their last bits then depended on whether a neighbour had a limit (245 of 299
    receivers moved, by up to 1.3e-15, on the 175-polygon box, 2026-12-07). Receivers with and without a
    limit therefore run apart, and one without gets the value of a call without limits."""
    if u is None:
        return [(None, None)]
    free = ~u.any(axis=1)
    if free.all():
        return [(None, None)]
    if not free.any():
        return [(None, u)]
    lim = np.flatnonzero(~free)
    return [(np.flatnonzero(free), None), (lim, u[lim])]


def idle_limits_dropped(scene, points, normals, u):
    """``u (m, 3)`` with the rows zeroed where the one-sided limit cannot differ from the value at P, or
    None when no row is left.

    The limit at ``P + εu`` (ε → 0+, ``u`` in the receiver's tangent plane) differs from the value at P
    only through polygons that touch P and are not coplanar with the receiver (the foot of a wall, a
    block standing on the floor, the adjacent wall of a room corner): a polygon at a positive distance
    from P moves continuously with P, and a coplanar one stays edge-on while P moves in its plane. The
    limit path itself is exact but slow: a chunk with one limit runs without sub-tile refinement
    (~10× the time per receiver on the 9,468-polygon box, 2026-12-08), and a mesh's interior vertices,
    which vertices mode hands in with limits, need none. The test is conservative (a bounding-box query
    on the scene's BVH, then the plane distance, both within :data:`TOUCH_EPS`); a receiver whose limit is
    dropped gets the value at P, equal to the limit's up to rounding (1e-12 relative, measured on the
    interior vertices of the 9,468-polygon box; tests/core/test_limit_directions.py).
    """
    if u is None:
        return None
    rows = np.flatnonzero(u.any(axis=1))
    if not len(rows) or not scene.n_polygons:
        return u
    from .raycast import box_query, build_bvh

    bvh = getattr(scene, "_touch_bvh", None)
    if bvh is None:
        bvh = scene._touch_bvh = build_bvh(scene)
    verts = scene.poly_vertices
    r = TOUCH_EPS * max(float(np.abs(verts).max()), 1e-300)
    p = points[rows]
    q, c = box_query(bvh, p - r, p + r)
    lo, hi = verts.min(axis=1), verts.max(axis=1)
    pq = p[q]
    inside = ((lo[c] - r <= pq) & (pq <= hi[c] + r)).all(axis=1)
    q, c, pq = q[inside], c[inside], pq[inside]
    near_plane = np.abs(np.einsum("ij,ij->i", scene.poly_normals[c], pq - verts[c, 0])) <= r
    # coplanar: the same plane up to the rounding of two unit normals (a tilt of 4e-8 rad or more is kept)
    coplanar = np.abs(np.einsum("ij,ij->i", scene.poly_normals[c], normals[rows][q])) >= 1.0 - 1e-15
    touched = np.zeros(len(rows), dtype=bool)
    touched[q[near_plane & ~coplanar]] = True
    out = u.copy()
    out[rows[~touched]] = 0.0
    return out if out.any() else None
