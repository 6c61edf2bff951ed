"""Point-to-polygon form factors by Lambert's contour integral (paper eq. 4).

    F = 1/(2π) Σ_edges N · Γ_e,   Γ_e = unit(a × b) · γ_e,   γ_e = atan2(|a × b|, a · b)

with ``a, b`` the edge's end points relative to the receiver P (Baum, Rushmeier & Winget 1989). The
formula only needs directions from P, so it holds for the spherical fragments of the exact projection
(sec. 2.5) as well as for whole polygons. ``atan2(|a×b|, a·b)`` keeps full relative precision for tiny
or distant polygons, where ``acos(a·b)`` loses half the digits; and ``γ/|a×b|`` is evaluated as one
quotient so that it tends smoothly to ``1/(a·b)`` as the edge shrinks.
"""

from __future__ import annotations

import numpy as np

from .rowops import sum_rows
from .tolerances import COORD_EPS, PLANE_EPS

__all__ = ["CANCELLATION", "contour_integral", "contour_integral_bounded", "directions", "edge_noise"]

_INV_2PI = 1.0 / (2.0 * np.pi)


def directions(verts: np.ndarray, inf: np.ndarray | None) -> np.ndarray:
    """Effective vertex vectors ``(F, K, 3)`` for the contour integral.

    A vertex at the receiver itself (real part zero within tolerance) only exists in a one-sided limit;
    its direction is its first-order part ``inf`` (see :mod:`.clipping`). Only directions matter to eq. 4.
    """
    if inf is None:
        return verts
    return _directions(verts, inf)[0]


def _directions(verts, inf):
    """:func:`directions` and the ``(F, K)`` mask of the vertices at P (or None: none)."""
    length = np.linalg.norm(verts, axis=2)                                   # (F, K)
    scale = length.max(axis=1, keepdims=True)
    # rows without a limit direction (inf = 0) keep their real directions, however short
    at_p = (length <= PLANE_EPS * scale) & (np.abs(inf) > 0).any(axis=2)
    if not at_p.any():
        return verts, None
    return np.where(at_p[..., None], inf * scale[..., None], verts), at_p


def edge_noise(a: np.ndarray, b: np.ndarray, receiver_noise) -> np.ndarray:
    """Coordinate noise ``(F, K)`` of the lines of edges ``a -> b (F, K, 3)`` (receiver-local) near P.

    An edge passes through the receiver when its line is nearer to P than the rounding of the world
    coordinates involved (``receiver_noise (F,)``: ``COORD_EPS · max |P|``, plus ``COORD_EPS`` times the
    edge's extent from P). Every test for an edge through P (occluder cones, horizon clip, eq. 4) uses it.
    """
    extent = np.maximum(np.abs(a).max(axis=-1), np.abs(b).max(axis=-1))
    return np.asarray(receiver_noise)[..., None] + COORD_EPS * extent


def contour_integral(verts: np.ndarray, normal: np.ndarray, inf: np.ndarray | None = None,
                     noise=None, planes: np.ndarray | None = None) -> np.ndarray:
    """Signed form factor ``(F,)`` of padded polygons ``verts (F, K, 3)`` (receiver-local).

    ``normal`` is the receiver's unit normal, ``(F, 3)`` or ``(3,)``. The sign is positive when the
    vertices run counter-clockwise about the direction from the receiver to the polygon (i.e. the
    receiver is behind the polygon's right-handed normal); callers multiply by the orientation.
    Padding slots (repeated last vertex) give zero-length edges, which contribute exactly zero.
    The polygon must lie in the receiver's closed upper hemisphere (clip it first). ``noise (F,)``: the
    receivers' coordinate noise (see :func:`edge_noise`), for edges through P in one-sided limits.
    ``planes (F, 3)`` (one-sided limits only): the unit normal of the plane through P that a row's polygon
    lies in (zero rows: none); every edge of such a polygon not through P then has that plane as its
    great circle, exactly: its endpoints only give it to ``ε |x| / (distance of the edge's line from P)``
    (a cut 1e-6 from P along a 7e5 polygon tilted it by 1e-5 rad, and lost 3.5e-7 of the limit factor).
    """
    if inf is None:
        return _contour_slot_major(verts, normal)[0]
    # one-sided limits: vertices at P take their first-order directions, and edges through P their
    # first-order great circles
    a, at_p = _directions(verts, inf)
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]                              # (F, K) each
    # next vertex along the contour; padding slots repeat the last vertex, so the only wrap-around
    # edge that matters is slot K-1 -> 0
    bx = np.concatenate([ax[:, 1:], ax[:, :1]], axis=1)
    by = np.concatenate([ay[:, 1:], ay[:, :1]], axis=1)
    bz = np.concatenate([az[:, 1:], az[:, :1]], axis=1)
    far = _far_ends(np.einsum("fki,fki->fk", a, a), 1)
    (ex, ey, ez), (cx, cy, cz), s, d, gamma = _edge_geometry(ax, ay, az, bx, by, bz, far)
    # an edge through P in a one-sided limit: its end points are antipodal seen from P (a×b = 0,
    # γ = π) and its great circle is the limit of the planes through P + εu: use the first-order
    # part of the cross product, (a + ε a')×(b + ε b') = a×b + ε (a×b' + a'×b)
    tol = PLANE_EPS * np.sqrt((ax * ax + ay * ay + az * az) * (bx * bx + by * by + bz * bz))
    if noise is not None:
        b3 = np.stack([bx, by, bz], axis=-1)
        tol = tol + edge_noise(a, b3, noise) * np.sqrt(ex * ex + ey * ey + ez * ez)
    through = (s <= tol) & (d < 0)
    through &= (np.abs(inf) > 0).any(axis=2)                              # only rows with a limit
    if through.any():
        ia = inf[through]
        ib = np.concatenate([inf[:, 1:], inf[:, :1]], axis=1)[through]
        a_t = np.stack([ax[through], ay[through], az[through]], axis=-1)
        b_t = np.stack([bx[through], by[through], bz[through]], axis=-1)
        c1 = np.cross(a_t, ib) + np.cross(ia, b_t)
        cx, cy, cz = cx.copy(), cy.copy(), cz.copy()
        cx[through], cy[through], cz[through] = c1[:, 0], c1[:, 1], c1[:, 2]
        s = s.copy()
        s[through] = np.linalg.norm(c1, axis=1)
        gamma = gamma.copy()
        gamma[through] = np.pi
    fixed = through
    if planes is not None:
        # an edge in a plane through P (not through P, nor from it) lies on that plane's great circle: keep
        # |a × b| and take its direction from the plane, oriented as a × b (its sign is sure: an edge's
        # line farther from P than the noise above has |a × b| far above its rounding)
        px, py, pz = planes[:, 0:1], planes[:, 1:2], planes[:, 2:3]
        inplane = ((px != 0) | (py != 0) | (pz != 0)) & ~through & (s > 0)
        if at_p is not None:  # an edge from P runs on its first-order great circle (through P + εu)
            inplane &= ~(at_p | np.concatenate([at_p[:, 1:], at_p[:, :1]], axis=1))
        if inplane.any():
            ss = np.where(cx * px + cy * py + cz * pz < 0, -s, s)
            cx, cy, cz = (np.where(inplane, ss * pc, c) for pc, c in ((px, cx), (py, cy), (pz, cz)))
            fixed = through | inplane
    ratio = np.divide(gamma, s, out=np.zeros_like(s), where=s > 0.0)          # γ/|a×b|
    nrm = np.broadcast_to(normal, (a.shape[0], 3))
    proj = cx * nrm[:, 0:1] + cy * nrm[:, 1:2] + cz * nrm[:, 2:3]
    terms = proj * ratio                                                      # (F, K)
    total = sum_rows(terms)
    # Where the edge terms cancel (a small factor from large terms: a wall seen from near its foot, a
    # sliver near the horizon) each term's rounding is amplified by Σ|t| / |Σ t|; redo those rows in
    # extended precision (80-bit on x86; where longdouble is double this changes nothing).
    cond = sum_rows(np.abs(terms))
    bad = cond > CANCELLATION * np.abs(total)
    if bad.any() and np.finfo(np.longdouble).eps < np.finfo(np.float64).eps:
        far_bad = None
        if far is not None:
            m = np.zeros(s.shape, dtype=bool)
            m[far] = True
            far_bad = m[bad]
        total[bad] = _terms_extended(a[bad], nrm[bad], s[bad] > 0.0, (through[bad], fixed[bad]),
                                     (cx[bad], cy[bad], cz[bad]), far_bad)
    return _INV_2PI * total


def contour_integral_bounded(verts: np.ndarray, normal: np.ndarray, inf: np.ndarray | None = None,
                             noise=None, planes: np.ndarray | None = None):
    """:func:`contour_integral` for a caller with a tolerance: ``(F (F,), bound (F,))``, ``bound`` on
    ``|F − contour_integral(...)|`` (the same arguments).

    Rows whose terms cancel (the ones :func:`contour_integral` redoes in extended precision) and whose
    edges all span less than 90° seen from P (``a · b > 0``) keep their float64 sum, with the bound on
    its rounding (:func:`_plain_bound`); every other row is :func:`contour_integral`'s, bound 0. At
    190,000 polygons two thirds of the visible fragments' rows cancel (small polygons seen from afar:
    terms ~ size / distance summing to ~ (size / distance)²), and their extended redo was a tenth of a
    call's time."""
    if inf is not None:
        return contour_integral(verts, normal, inf, noise, planes), np.zeros(len(verts))
    return _contour_slot_major(verts, normal, bounded=True)


def _plain_bound(ex, ey, ez, na, terms, rows):
    """(R,) bound on ``|Σ_j t_j − Σ_j t_j^ext| / 2π`` for the float64 eq. 4 sums of ``rows`` (R,) of the
    ``(K, F)`` slot-major arrays (``e = b − a``, ``na = |a|²``, ``terms`` the float64 ``t_j``), every edge
    with ``a · b > 0`` (γ < π/2).

    Per edge, u = 2^-53 (:func:`_edge_geometry`'s formulas): ``a × b`` is computed from the end x with
    ``|x| <= 4 min(|a|, |b|)``, within ``4.3 u |x| |e|``; ``a · b`` within ``3 u |a| |b|``; with ``s² + d²
    = |a|² |b|²`` the angle γ is within ``17.2 u |e| / M + 10.6 u`` (``M = max(|a|, |b|)``), and the unit
    great-circle normal within ``2 |δc| / s + 6 u`` where ``γ <= (π/2) s / (|a| |b|)`` turns it into
    ``54 u |e| / M + 9.5 u``: ``|δt| <= 71.2 u |e| / M + 20.1 u + 2 u |t|``; the sum of K terms adds
    ``(K − 1) u Σ |t|``. Taken here as ``u (128 |e| / M + 32 + (K + 4) |t|)`` per edge, which also covers
    the extended sum's own error (its unit is 2^-11 of u)."""
    u = np.finfo(np.float64).eps / 2
    k = terms.shape[0]
    e_len = np.sqrt(ex[:, rows] ** 2 + ey[:, rows] ** 2 + ez[:, rows] ** 2)
    na = na[:, rows]
    big = np.sqrt(np.maximum(na, np.roll(na, -1, axis=0)))                  # max(|a|, |b|), b the next slot
    rel = np.divide(e_len, big, out=np.zeros_like(e_len), where=big > 0)
    per = 128.0 * rel + 32.0 + (k + 4) * np.abs(terms[:, rows])
    return u * _INV_2PI * per.sum(axis=0)


def _contour_slot_major(verts: np.ndarray, normal: np.ndarray, bounded: bool = False):
    """:func:`contour_integral` without one-sided limits, on ``(K, F)`` arrays: contiguous along the long
    axis, so that the per-polygon normal broadcasts along it (a per-row ``(F, 1)`` operand against
    ``(F, K)`` goes through numpy's buffered iterator, about 5× slower). The same formulas in the same
    order as the general path: bitwise equal results. Returns ``(F (F,), bound (F,) or None)``: with
    ``bounded`` (:func:`contour_integral_bounded`) the cancelling rows with every ``a · b > 0`` stay in
    float64 and ``bound`` holds their rounding bound; otherwise None."""
    f = verts.shape[0]
    t = np.ascontiguousarray(verts.transpose(2, 1, 0))                        # (3, K, F)
    ax, ay, az = t[0], t[1], t[2]
    bx = np.concatenate([ax[1:], ax[:1]])
    by = np.concatenate([ay[1:], ay[:1]])
    bz = np.concatenate([az[1:], az[:1]])
    na = np.einsum("ikf,ikf->kf", t, t)
    far = _far_ends(na, 0)
    (ex, ey, ez), (cx, cy, cz), s, d, gamma = _edge_geometry(ax, ay, az, bx, by, bz, far)
    # γ/|a×b|, 0 where a×b = 0 (then γ is 0 or π: γ/∞ = 0, bitwise as a masked divide, without the mask)
    ratio = gamma
    ratio /= np.where(s > 0.0, s, np.inf)
    nrm = np.broadcast_to(normal, (f, 3))
    cx *= nrm[:, 0]                                                           # proj = c · N, in place
    cy *= nrm[:, 1]
    cz *= nrm[:, 2]
    cx += cy
    cx += cz
    terms = cx
    terms *= ratio                                                            # (K, F)
    total = terms[0].copy()
    cond = np.abs(terms[0])
    for j in range(1, terms.shape[0]):
        total += terms[j]
        cond += np.abs(terms[j])
    bad = cond > CANCELLATION * np.abs(total)
    bound = np.zeros(f) if bounded else None
    if bounded and bad.any():
        # rows that may stay in float64: every edge under 90° (the bound's premise)
        plain = bad & (d > 0.0).all(axis=0)
        rows = np.flatnonzero(plain)
        if len(rows):
            bound[rows] = _plain_bound(ex, ey, ez, na, terms, rows)
            bad &= ~plain
    if bad.any() and np.finfo(np.longdouble).eps < np.finfo(np.float64).eps:
        far_bad = None
        if far is not None:
            m = np.zeros(s.shape, dtype=bool)
            m[far] = True
            far_bad = m[:, bad].T
        total[bad] = _terms_extended(verts[bad], nrm[bad], (s[:, bad] > 0.0).T, None, None, far_bad)
    return _INV_2PI * total, bound


def _far_ends(na: np.ndarray, axis: int):
    """Index (a tuple for the ``(F, K)`` or ``(K, F)`` component arrays) of the edges ``a -> b`` whose end b
    is much nearer P than a (``|b| < |a| / 4``), or None; ``na`` the squared norms of the vertices, the
    slots along ``axis`` (b is the next slot round the polygon)."""
    n = na if axis == 0 else na.T
    nb16 = n * _NEAR_END_RATIO2
    inner = nb16[1:] < n[:-1]                                                  # edges j -> j+1
    wrap = nb16[0] < n[-1]                                                     # the closing edge K-1 -> 0
    if not (inner.any() or wrap.any()):
        return None
    j, k = np.nonzero(np.concatenate([inner, wrap[None]]))
    return (j, k) if axis == 0 else (k, j)


def _edge_geometry(ax, ay, az, bx, by, bz, far=None):
    """Per edge ``a -> b`` (components as arrays of any one shape; ``far`` the index of the edges whose b
    is much nearer P, see :func:`_far_ends`): ``(b − a)``, ``a × b``, ``|a × b|``, ``a · b`` and the edge
    angle ``γ = atan2(|a × b|, a · b)``.

    ``a × b`` is computed as ``a × (b − a)``: the same vector, but for a short edge far from P the raw
    products of ``a × b`` cancel to the last digits (a 1e-6 polygon at distance 1 would lose six). Its
    rounding is ``~ε |a| |b − a|``, so where b is much nearer P than a it is computed as ``b × (b − a)``
    (the same vector again): from the far end, an edge from 0.37 away to a vertex 1e-9 from P had
    ``|a × b|`` = 5e-10 from products ~0.1, its great circle tilted by 1e-8 and its term off by 2.5e-9.
    "Much nearer" is ``|b| < |a| / 4``: elsewhere the far end's rounding is at most 4 times the near
    end's, and redoing the few such edges costs less than choosing the end everywhere (+35 % on eq. 4)."""
    ex, ey, ez = bx - ax, by - ay, bz - az
    tmp = np.empty_like(ex)                       # the products below as written out, without temporaries
    cx = np.multiply(ay, ez)
    cx -= np.multiply(az, ey, out=tmp)
    cy = np.multiply(az, ex)
    cy -= np.multiply(ax, ez, out=tmp)
    cz = np.multiply(ax, ey)
    cz -= np.multiply(ay, ex, out=tmp)
    if far is not None:
        i = far
        x, y, z, dx, dy, dz = bx[i], by[i], bz[i], ex[i], ey[i], ez[i]
        cx[i] = y * dz - z * dy
        cy[i] = z * dx - x * dz
        cz[i] = x * dy - y * dx
    s = np.multiply(cx, cx)                                                   # |a×b|
    s += np.multiply(cy, cy, out=tmp)
    s += np.multiply(cz, cz, out=tmp)
    np.sqrt(s, out=s)
    d = np.multiply(ax, bx)                                                   # a·b
    d += np.multiply(ay, by, out=tmp)
    d += np.multiply(az, bz, out=tmp)
    return (ex, ey, ez), (cx, cy, cz), s, d, np.arctan2(s, d)


#: (|a| / |b|)² above which eq. 4 computes an edge's a × b from its end b (see :func:`_edge_geometry`)
_NEAR_END_RATIO2 = 16.0


#: relative cancellation in eq. 4 above which a row is recomputed in extended precision: float64
#: rounding (~4e-16 per term) then stays below 1e-13 relative
CANCELLATION = 250.0


def _terms_extended(a, normal, nonzero, masks, first_order, far=None):
    """Σ of eq. 4's edge terms in ``np.longdouble`` for rows ``a (R, K, 3)`` (see contour_integral).

    One-sided limits: ``masks = (through, fixed)`` (R, K) and ``first_order`` the float64 ``a × b`` whose
    direction is kept where ``fixed`` (edges through P, with γ = π there, and edges in a plane through P).
    ``far (R, K)`` or None: the edges whose a × b is taken from their end b (as in float64)."""
    if first_order is not None:
        cx, cy, cz = first_order
    a = a.astype(np.longdouble)
    b = np.concatenate([a[:, 1:], a[:, :1]], axis=1)
    e = b - a
    x = a if far is None else np.where(far[..., None], b, a)
    c = np.stack([x[..., 1] * e[..., 2] - x[..., 2] * e[..., 1],
                  x[..., 2] * e[..., 0] - x[..., 0] * e[..., 2],
                  x[..., 0] * e[..., 1] - x[..., 1] * e[..., 0]], axis=-1)
    s = np.sqrt((c * c).sum(axis=-1))
    d = (a * b).sum(axis=-1)
    gamma = np.arctan2(s, d)
    if first_order is not None:
        through, fixed = masks
        c = np.where(fixed[..., None], np.stack([cx, cy, cz], axis=-1).astype(np.longdouble), c)
        s = np.where(fixed, np.sqrt((c * c).sum(axis=-1)), s)
        gamma = np.where(through, np.longdouble(np.pi), gamma)
    ok = nonzero & (s > 0)
    ratio = np.where(ok, gamma / np.where(ok, s, 1), 0)
    proj = (c * normal.astype(np.longdouble)[:, None, :]).sum(axis=-1)
    return np.asarray((proj * ratio).sum(axis=1), dtype=np.float64)
