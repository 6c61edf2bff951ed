"""Unoccluded point-to-polygon form factors (paper eq. 4), clipped to the receiver's hemisphere.

    F = 1/(2π) Σ_edges N · Γ_e,   Γ_e = unit(a × b) γ_e,   γ_e = atan2(|a × b|, a · b)

(Baum, Rushmeier & Winget 1989) with ``a, b`` the edge's end points relative to the receiver P. This is
the cost floor of any exact local pass (every polygon, no visibility) and the unoccluded factor of the
ray-traced form factors (Wallace, Elmquist & Haines 1989). Pure numpy, vectorised over points × polygons.
"""

from __future__ import annotations

import numpy as np

__all__ = ["clip_to_hemisphere", "contour_form_factor", "front_mask", "unoccluded_form_factors"]

_INV_2PI = 1.0 / (2.0 * np.pi)


def clip_to_hemisphere(a: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Clip receiver-local polygons ``a (..., K, 3)`` to the half-space ``normal · x >= 0``.

    ``normal (..., 3)`` broadcasts against ``a[..., 0, :]``. Returns ``(..., 2K, 3)``: every edge
    contributes its start vertex (if above) and its crossing point (if it crosses); dropped slots
    repeat the previous kept point (zero-length edges, which add nothing to eq. 4). A polygon
    entirely below gives all-zero vertices (F = 0).
    """
    s = np.einsum("...kc,...c->...k", a, normal)  # (..., K) heights above the tangent plane
    b = np.roll(a, -1, axis=-2)
    sb = np.roll(s, -1, axis=-1)
    above = s >= 0.0
    cross = (s > 0.0) & (sb < 0.0) | (s < 0.0) & (sb > 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(cross, s / np.where(cross, s - sb, 1.0), 0.0)  # crossing parameter along a -> b
    hit = a + w[..., None] * (b - a)  # (..., K, 3)
    cand = np.stack([a, hit], axis=-2).reshape(*a.shape[:-2], 2 * a.shape[-2], 3)  # (..., 2K, 3)
    keep = np.stack([above, cross], axis=-1).reshape(*a.shape[:-2], 2 * a.shape[-2])  # (..., 2K)
    # forward-fill dropped slots with the previous kept slot (cyclically): zero-length edges
    n2 = keep.shape[-1]
    idx = np.where(keep, np.arange(n2), -1)
    last = np.maximum.accumulate(idx, axis=-1)
    wrap = idx.max(axis=-1, keepdims=True)  # leading dropped slots repeat the last kept one
    src = np.where(last < 0, wrap, last)
    out = np.take_along_axis(cand, np.maximum(src, 0)[..., None], axis=-2)
    return np.where((src >= 0)[..., None], out, 0.0)


def contour_form_factor(a: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """|Eq. 4| of receiver-local polygons ``a (..., K, 3)`` lying in the closed upper hemisphere.

    ``normal (..., 3)`` unit receiver normals. Returns ``(...,)`` non-negative (the sign of the
    contour integral only tells the winding). ``atan2(|a×b|, a·b)`` keeps full precision for tiny
    or distant polygons where ``acos`` loses half the digits.
    """
    # component arrays (..., K): np.cross on (..., 3) copies and is several times slower
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = (np.roll(x, -1, axis=-1) for x in (ax, ay, az))
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    s = np.sqrt(cx * cx + cy * cy + cz * cz)  # |a x b|
    d = ax * bx + ay * by + az * bz  # a . b
    gamma = np.arctan2(s, d)
    ratio = np.divide(gamma, s, out=np.zeros_like(s), where=s > 0.0)
    nx, ny, nz = (normal[..., i, None] for i in range(3))
    proj = cx * nx + cy * ny + cz * nz
    return np.abs(_INV_2PI * (proj * ratio).sum(axis=-1))


def front_mask(scene, points: np.ndarray) -> np.ndarray:
    """``(m, n)`` bool: receiver m lies on the front (emitting) side of convex polygon n's plane."""
    return points @ scene.poly_normals.T > scene.poly_offsets[None, :]


def unoccluded_form_factors(scene, points, normals, *, front_only: bool = False,
                            max_pairs: int = 2**20) -> np.ndarray:
    """Unoccluded form factor ``(m, n)`` of every convex polygon from every receiver.

    Polygons are clipped to each receiver's upper hemisphere (only those straddling its tangent plane
    need it); polygons entirely below, and polygons whose plane contains the receiver (seen edge-on),
    contribute 0. With ``front_only`` only polygons whose front side faces the receiver count (the
    cost floor of irradiance: back faces never emit). Work is on (receiver, polygon) pairs in
    receiver-local coordinates, in batches of at most ``max_pairs`` pairs (~``max_pairs × K × 200``
    bytes).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    verts = scene.poly_vertices  # (n, K, 3)
    n_poly, k = verts.shape[:2]
    out = np.zeros((len(p), n_poly))
    if n_poly == 0:
        return out
    step = max(1, max_pairs // n_poly)
    for s in range(0, len(p), step):
        e = min(s + step, len(p))
        pc, nc = p[s:e], nrm[s:e]
        # heights of all vertices above each receiver's tangent plane: (c, n, K)
        h = np.einsum("nkc,mc->mnk", verts, nc) - np.einsum("mc,mc->m", pc, nc)[:, None, None]
        plane = pc @ scene.poly_normals.T - scene.poly_offsets[None, :]  # (c, n) signed distance to the plane
        scale = np.linalg.norm(pc[:, None, :] - scene.poly_centers[None], axis=2) + scene.poly_radii[None]
        need = (h.max(axis=2) > 0.0) & (np.abs(plane) > 1e-12 * scale)
        if front_only:
            need &= plane > 0.0
        pm, pp = np.nonzero(need)
        if len(pm) == 0:
            continue
        # np.take: several times faster than fancy indexing for these gathers
        a = np.take(verts, pp, axis=0) - np.take(pc, pm, axis=0)[:, None, :]  # (q, K, 3) receiver-local
        nq = np.take(nc, pm, axis=0)
        straddle = np.take(h.reshape(-1, k), pm * n_poly + pp, axis=0).min(axis=1) < 0.0
        f = np.empty(len(pm))
        f[~straddle] = contour_form_factor(a[~straddle], nq[~straddle])
        if straddle.any():
            f[straddle] = contour_form_factor(clip_to_hemisphere(a[straddle], nq[straddle]), nq[straddle])
        out.reshape(-1)[(s + pm) * n_poly + pp] = f
    return out
