"""Projection of polygons onto the hemisphere over each receiver point (paper sec. 2.2).

For receiver points ``P`` with normals ``N``, every polygon is moved into P-local coordinates (``v - P``;
far-away scenes lose nothing), back- and front-facing polygons are both kept (they are opaque from
both sides), polygons entirely below the tangent plane are culled, and the rest are clipped by the
tangent plane ``N · x = 0`` — a plane through P, so the clip is exact in 3D, and "all projected
vertices lie on half of the unit sphere" (sec. 2.2). The central projection itself is only ever needed
as directions: normalising a fragment's vertices gives its spherical polygon, whose edges are great
circles, which is what :class:`.inspection.Projection` hands to the inspector.

A polygon whose plane contains P is seen edge-on: it contributes nothing and hides nothing. In a
one-sided limit (``limit_direction u``: the value at ``P + εu``, ε → 0+) such a polygon is on the side
of its plane given by ``u`` instead; see :mod:`.clipping` for the first-order coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .clipping import split_convex
from .csr import expand
from .form_factor import edge_noise
from .rowops import any_rows, sides, take_rows
from .scene import Scene
from .tolerances import COORD_EPS, PLANE_EPS

__all__ = ["Candidates", "flat_rows", "hemisphere_candidates", "onto_planes_through_p", "receiver_side"]


def _side(d, tol, d_inf, tilt=0.0):
    """+1 / -1 / 0 (int8) from plane distances ``d`` with tolerance ``tol``; where ``d`` is within it,
    from the first-order distances ``d_inf()`` (a callable: computed only if needed; ``-n . u``, known to
    the plane's angular uncertainty ``tilt``) or 0."""
    side = sides(d, tol)
    if d_inf is not None:
        on = side == 0
        if on.any():
            di = d_inf()[on]
            tol_inf = PLANE_EPS + np.broadcast_to(tilt, side.shape)[on]
            side[on] = sides(di, tol_inf)
    return side


def receiver_side(normals, first_vertex_rel, scale, limit, tilt=0.0, noise=0.0):
    """Side of each plane the receiver is on, ``(m, n)`` int8: +1 behind (plane normal points away
    from P), -1 in front, 0 in the plane (edge-on).

    Args:
        normals: (n, 3) plane normals; first_vertex_rel: (m, n, 3) a plane vertex minus P;
        scale: (m, n) length scale for the tolerance; limit: (m, 3) limit directions or None.
        tilt, noise: the planes' angular uncertainty (n,) and the absolute coordinate noise of planes
            and receivers (broadcast to (m, n)), see :func:`.scene.plane_uncertainty`.
    """
    r = first_vertex_rel
    d = r[..., 0] * normals[:, 0] + r[..., 1] * normals[:, 1] + r[..., 2] * normals[:, 2]   # n . (v0 - P)
    # at P + εu the plane distance is n.(v0 - P) - ε n.u
    return _side(d, (PLANE_EPS + tilt) * scale + noise, None if limit is None else (lambda: -(limit @ normals.T)),
                 tilt)


def plane_side(normals, rel_center, center_offset, scale, limit, tilt=0.0, noise=0.0):
    """Side of each plane the receiver is on for sparse (receiver, plane) pairs, ``(C,)`` int8.

    Args:
        normals: (C, 3) plane normals; rel_center: (C, 3) polygon centre minus P; center_offset: (C,)
        ``n . (centre - v0)`` (the centre's rounding-level distance from its own plane); scale: (C,);
        limit: (C, 3) limit directions or None; tilt, noise: (C,) as for :func:`receiver_side`.
        +1: P behind the plane, -1 in front, 0 in it.
    """
    d = np.einsum("ij,ij->i", normals, rel_center) - center_offset             # n . (v0 - P)
    return _side(d, (PLANE_EPS + tilt) * scale + noise,
                 None if limit is None else (lambda: -(limit * normals).sum(axis=1)), tilt)


def flat_rows(normals, first_vertex_rel, tol, limit, verts):
    """In a one-sided limit, the rows whose plane contains P within ``tol (C,)`` (their side comes from
    the limit direction), ``(C,)`` bool; their vertices ``verts (C, K, 3)`` (P-local) are moved exactly
    into the plane through P (in place), by at most ``tol``: seen from P + εu only directions matter,
    and the directions of vertices a few ulp from P would otherwise be noise."""
    d = (normals * first_vertex_rel).sum(axis=1)
    flat = (np.abs(d) <= tol) & limit.any(axis=1)
    if flat.any():
        verts[flat] = onto_planes_through_p(verts[flat], normals[flat])
    return flat


def onto_planes_through_p(verts: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``verts (C, K, 3)`` (P-local) moved along ``normals (C, 3)`` (unit) into the planes through P."""
    return verts - np.matmul(verts, normals[:, :, None]) * normals[:, None, :]


def snap_to_receiver(verts: np.ndarray, eps: np.ndarray) -> None:
    """In a one-sided limit, make vertices within ``eps (C,)`` of P exactly P (in place).

    Such a vertex has no direction of its own: its direction is its first-order part ``-u``. Left at
    ~1e-22 from P by rounding, it would define edge planes of arbitrary orientation.
    """
    at_p = (np.abs(verts) <= eps[:, None, None]).all(axis=2)
    if at_p.any():
        verts[at_p] = 0.0


@dataclass
class Candidates:
    """Polygons above the horizon of each receiver, clipped to it (P-local, flat over pairs).

    Attributes:
        point: (C,) receiver index; poly: (C,) convex polygon index; side: (C,) receiver side of the
        polygon's plane (+1 behind, -1 in front); verts: (C, K, 3) clipped P-local vertices;
        inf: (C, K, 3) first-order parts or None; counts: (C,); flat: (C,) bool or None — in a
        one-sided limit, the candidates whose plane contains P (their vertices were moved exactly into
        the plane through P, see :func:`flat_rows`, and so must every piece cut from them);
        pair: (C,) the (receiver, tile) pair of :class:`.hierarchy.TilePairs` each candidate came from.
    """

    point: np.ndarray
    poly: np.ndarray
    side: np.ndarray
    verts: np.ndarray
    inf: np.ndarray | None
    counts: np.ndarray
    flat: np.ndarray | None = None
    pair: np.ndarray | None = None


def hemisphere_candidates(scene: Scene, points, normals, limit, include, member_lists, tiles) -> Candidates:
    """Cull and clip every polygon to the upper hemisphere of every receiver.

    Args:
        points, normals: (m, 3) receivers; limit: (m, 3) limit directions (zero rows: none) or None.
        include: optional bool of pairs to consider at all (e.g. emitters only), broadcast to (m, n).
        member_lists: ``(ptr, members)`` the CSR member lists that ``tiles.tile`` indexes (the scene's
            tiles, ``Occluders.tile_ptr, tile_members``, or their quarters, :class:`.hierarchy.SubTiles`);
        tiles: the (receiver, tile) pairs whose members are to be projected (:class:`.hierarchy.TilePairs`:
            above the horizon, not known to be hidden, not taken by the fast path), so polygons elsewhere
            cost nothing here.
    Returns:
        the candidates (polygons seen edge-on, with P in their plane, are left out).
    """
    pair, ci = expand(tiles.tile, *member_lists)
    cp = tiles.point[pair]
    if include is not None:
        inc = np.asarray(include)
        if inc.ndim == 2 and (inc.shape[0] == 1 or inc.strides[0] == 0):      # one row for every receiver
            keep = inc[0][ci]
        else:
            keep = np.broadcast_to(inc, (len(points), scene.n_polygons)).ravel()[cp * scene.n_polygons + ci]
        cp, ci, pair = cp[keep], ci[keep], pair[keep]
    # horizon culling by bounding sphere first (conservative, cheap), then by the vertices
    rel_ci = take_rows(scene.poly_centers, ci)
    rel_ci -= take_rows(points, cp)                                             # (C, 3)
    height_c = np.einsum("ij,ij->i", rel_ci, take_rows(normals, cp))
    scale = np.sqrt(np.einsum("ij,ij->i", rel_ci, rel_ci)) + scene.poly_radii[ci]
    mask = height_c + scene.poly_radii[ci] > PLANE_EPS * scale
    mask = np.flatnonzero(mask)
    cp, ci, rel_ci, scale, pair = cp[mask], ci[mask], take_rows(rel_ci, mask), scale[mask], pair[mask]
    point_noise = COORD_EPS * np.abs(points).max(axis=1)                        # (m,) the receivers' own
    side = plane_side(take_rows(scene.poly_normals, ci), rel_ci, scene.poly_center_offsets[ci], scale,
                      None if limit is None else limit[cp], scene.poly_tilt[ci],
                      scene.poly_noise[ci] + point_noise[cp])
    keep = side != 0
    cp, ci, side, scale, pair = cp[keep], ci[keep], side[keep], scale[keep], pair[keep]
    eps = PLANE_EPS * scale
    # one spare slot: clipping a convex polygon by one plane adds at most one vertex
    verts = take_rows(scene.poly_vertices_spare, ci)                            # (C, K+1, 3)
    verts -= take_rows(points, cp)[:, None, :]
    flat = None
    if limit is not None:
        flat = flat_rows(scene.poly_normals[ci], verts[:, 0], (PLANE_EPS + scene.poly_tilt[ci]) * scale
                         + scene.poly_noise[ci] + point_noise[cp], limit[cp], verts)
    counts = scene.poly_counts[ci]
    nc = take_rows(normals, cp)
    height = np.multiply(verts[..., 0], nc[:, 0:1])                             # (C, K+1) above the horizon
    tmp = np.multiply(verts[..., 1], nc[:, 1:2])                                # (x0 n0 + x1 n1) + x2 n2, in place
    height += tmp
    height += np.multiply(verts[..., 2], nc[:, 2:3], out=tmp)
    # a vertex's height is rounded by ~ε|x| (the horizon is exactly the plane through P normal to N), so
    # each vertex has its own tolerance: the polygon's (PLANE_EPS × its scale) put a vertex 1.5e-11 from
    # P at height 2.9e-13 on the horizon, so the clip cut its edge at that vertex instead of 8e-13 along,
    # which seen from so near is a wedge of F = 1e-4. (|x|_∞ >= |x| / √3: at least half the polygon's tolerance at its
    # nearest point, as the clear tiles' horizon test assumes.) Vertices that a one-sided limit snaps
    # onto P (below) keep the polygon's.
    # Only vertices on the horizon by the polygon's tolerance can change side (|x| <= scale).
    valid = np.arange(verts.shape[1])[None, :] < counts[:, None]
    gt, lt = height > eps[:, None], height < -eps[:, None]
    eps_v = eps
    on = np.nonzero(~(gt | lt) & (height != 0.0))                               # (0 is on at any tolerance)
    if len(on[0]):
        x = np.abs(verts[on])
        own = PLANE_EPS * np.maximum(np.maximum(x[:, 0], x[:, 1]), x[:, 2])
        if limit is not None:
            own = np.where((x <= eps[on[0], None]).all(axis=1) & limit[cp[on[0]]].any(axis=1), eps[on[0]], own)
        gt[on], lt[on] = height[on] > own, height[on] < -own
        eps_v = np.repeat(eps[:, None], verts.shape[1], axis=1)                 # (C, K+1)
        eps_v[on] = own
    above = any_rows(gt & valid)
    straddle = any_rows(lt & valid)
    if not above.all():
        up = np.flatnonzero(above)
        side, cp, ci, verts, counts, height, eps, eps_v, straddle, pair = (
            take_rows(x, up) for x in (side, cp, ci, verts, counts, height, eps, eps_v, straddle, pair))
        flat = None if flat is None else flat[up]
    inf = None
    if limit is not None:
        inf = np.broadcast_to(-limit[cp, None, :], verts.shape).copy()
        snap_to_receiver(verts, np.where(limit[cp].any(axis=1), eps, -1.0))  # zero rows: exact at P
    if straddle.any():
        s = np.flatnonzero(straddle)
        k = verts.shape[1] - 1
        through = None
        if inf is not None:  # an edge through P (one-sided limit) crosses the horizon at P
            a = verts[s, :k]
            nxt = np.arange(k)[None, :] + 1
            b = np.take_along_axis(a, np.where(nxt < counts[s, None], nxt, 0)[..., None], axis=1)  # as split_convex
            line_tol = edge_noise(a, b, COORD_EPS * np.abs(points[cp[s]]).max(axis=1))
            through = ((np.linalg.norm(np.cross(a, b), axis=2)
                        <= PLANE_EPS * np.linalg.norm(a, axis=2) * np.linalg.norm(b, axis=2)
                        + line_tol * np.linalg.norm(b - a, axis=2))
                       & ((a * b).sum(axis=2) < 0))
        (iv, ic, iinf), _ = split_convex(
            take_rows(verts, s)[:, :k], counts[s], take_rows(height, s)[:, :k],
            eps_v[s] if eps_v.ndim == 1 else take_rows(eps_v, s)[:, :k],
            inf=None if inf is None else inf[s, :k],
            s_inf=None if inf is None else np.zeros_like(height[s, :k]),  # N . u = 0: u is tangent
            origin_edges=through, outside=False,
        )
        if iv.shape[1] > verts.shape[1]:  # rounding made a nearly degenerate polygon cross twice more
            verts = np.concatenate([verts, np.repeat(verts[:, -1:], iv.shape[1] - verts.shape[1], axis=1)], axis=1)
            if inf is not None:
                inf = np.concatenate([inf, np.repeat(inf[:, -1:], iv.shape[1] - inf.shape[1], axis=1)], axis=1)
        verts[s], counts[s] = iv, ic
        if inf is not None:
            inf[s] = iinf
    return Candidates(cp, ci, side, verts, inf, counts, flat, pair)
