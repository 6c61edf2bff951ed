"""Shooting clusters: neighbouring coplanar patches of one material merged, each shot from one point.

Substructuring (Cohen, Greenberg, Immel & Brock 1986, "An efficient radiosity approach for realistic
image synthesis"): the scene's polygons are the *elements* that receive light and carry the solution;
for shooting *reflected* light they are merged into clusters, each shot from one point. A cluster is a
set of elements with

* the same plane (unit normal and offset of their first convex piece, equal to ``1e-9`` of the scene's
  size), the same reflectivity and emission (so a light is never merged with the ceiling around it), and
* centroids in the same cell of a cubic grid of side ``h = sqrt(A / target)`` (A: the total area,
  ``target``: about how many clusters are wanted), so clusters are about ``h × h``.

The cluster's point is the area centroid of its element nearest to the cluster's centroid (weighted by
the power its elements hold after the direct light, or by area; only elements holding at least half the
cluster's mean power per area are eligible, so a cluster is not shot from a floor cell hidden under a
block): it lies
strictly inside that element, where the exact factors of a closed scene sum to 1, so a cluster shot
conserves energy exactly, like an element's. Its normal is that element's.

**The rule and its error.** A cluster shoots the summed unshot power of its elements from its point:
element j receives ``ΔΦ_c F(x_c → j)`` instead of ``Σ_{i∈c} ΔΦ_i F_ij``. The error is that of a
one-point rule over the cluster on ``x ↦ F(x → j)`` weighted by where in the cluster the power is:
relative O(h/r) for a receiver at distance r (O((h/r)²) when the power is spread uniformly and x_c is at
its centroid), O(1) for receivers within about h of the point (the corner regions next to a cluster).
The solver estimates it by a 4-point rule (:func:`quadrant_points`) on a sample of the cluster shots.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .quadrature import PatchQuadrature

__all__ = ["Clusters", "make_clusters", "quadrant_points"]


@dataclass
class Clusters:
    """Elements grouped into shooting clusters.

    Attributes:
        of: (n,) int64 cluster of every element (-1: an element without area, never shot).
        count: number of clusters.
        point: (count, 3) float64 shooting point of every cluster (strictly inside one of its elements).
        normal: (count, 3) float64 unit front normal there.
        element: (count,) int64 the element holding the point.
        size: the grid cell side h (m).
        members: (n_members,) int64 elements sorted by cluster; cluster c's are ``members[start[c]:start[c+1]]``.
        start: (count + 1,) int64.
        element_point, element_normal, element_centroid: (n, 3) every element's order-1 point of its largest
            convex piece, that piece's normal, and the element's area centroid.
    """

    of: np.ndarray
    count: int
    point: np.ndarray
    normal: np.ndarray
    element: np.ndarray
    size: float
    members: np.ndarray
    start: np.ndarray
    element_point: np.ndarray
    element_normal: np.ndarray
    element_centroid: np.ndarray


def _largest_piece_points(quad: PatchQuadrature) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per patch (n,): the order-1 point of its largest convex piece, its normal, and the patch centroid."""
    n = len(quad.areas)
    order = np.lexsort((-quad.weights, quad.patch))            # by patch, largest weight first
    first = order[np.searchsorted(quad.patch[order], np.arange(n)).clip(0, max(len(order) - 1, 0))]
    centroid = np.zeros((n, 3))
    for c in range(3):
        centroid[:, c] = np.bincount(quad.patch, weights=quad.weights * quad.points[:, c], minlength=n)
    centroid = np.divide(centroid, quad.areas[:, None], out=np.zeros_like(centroid), where=quad.areas[:, None] > 0)
    if not len(order):
        return np.zeros((n, 3)), np.zeros((n, 3)), centroid
    return quad.points[first], quad.normals[first], centroid


def make_clusters(quad1: PatchQuadrature, reflectivity: np.ndarray, emission: np.ndarray, target: int,
                  weights: np.ndarray | None = None, scene=None) -> Clusters:
    """Group the patches of ``quad1`` (the order-1 quadrature of a scene) into about ``target`` clusters.

    Args:
        quad1: :func:`~.quadrature.patch_quadrature` with ``order=1`` (one point per convex piece).
        reflectivity, emission: (n, 3) per patch; clusters never mix different values.
        target: about how many clusters (>= 1); the count found depends on the geometry (a curved
            surface, whose polygons are all in different planes, is not merged at all).
        weights: (n,) >= 0, e.g. the power each element holds: the point is then on the element nearest to
            the weighted centroid among the cluster's elements holding at least half its mean weight per
            area (all of them when none holds any); default: the area.
        scene: the core Scene of ``quad1``; with it, the point is the weighted centroid itself when that
            lies in (the closure of) the chosen element's largest convex piece, moved 2 % of the way toward
            the piece's centroid so that it is strictly inside (a convex piece: a combination of a point of
            it and an interior point is interior). A cluster of 2 × 2 grid cells is then shot from next to
            its centre vertex, not from one cell's centre (an O(h/r) error term less) — unless one of five
            rays from there (the normal and four 45° off it) hits a back face first (inside a solid).
    """
    n = len(quad1.areas)
    point, normal, centroid = _largest_piece_points(quad1)
    has_area = quad1.areas > 0
    total = float(quad1.areas.sum())
    h = np.sqrt(total / max(int(target), 1)) if total > 0 else 1.0
    ext = float(np.ptp(centroid[has_area], axis=0).max()) if has_area.any() else 1.0
    scale = max(ext, h, 1e-300)
    lo = centroid[has_area].min(axis=0) if has_area.any() else np.zeros(3)
    offset = np.einsum("ij,ij->i", normal, point)
    # keys: plane (normal, offset to 1e-9 of the scene), material, grid cell
    q = 1e-9
    key = np.concatenate([
        np.round(normal / q), np.round(offset / (q * scale))[:, None],
        np.round(np.asarray(reflectivity, dtype=np.float64) / 1e-12), np.round(np.asarray(emission) / 1e-12),
        np.floor((centroid - lo) / h)], axis=1)
    of = np.full(n, -1, dtype=np.int64)
    sel = np.flatnonzero(has_area)
    if len(sel):
        _, inv = np.unique(key[sel], axis=0, return_inverse=True)
        of[sel] = inv.reshape(-1)
    count = int(of.max()) + 1 if len(sel) else 0
    members = sel[np.argsort(of[sel], kind="stable")]
    start = np.searchsorted(of[members], np.arange(count + 1)).astype(np.int64)
    # cluster centroid (weighted), then the member element of positive weight nearest to it
    a = quad1.areas[members]
    eligible = a > 0
    if weights is not None:
        wm = np.asarray(weights, dtype=np.float64)[members]
        has = np.bincount(of[members], weights=(wm > 0).astype(float), minlength=count) > 0
        a = np.where(has[of[members]], wm, a)
        # the point's element must hold at least half the cluster's mean power density: not one mostly
        # hidden (a floor cell half under a block), whose corner could lie inside the block
        density = wm / quad1.areas[members]
        mean = np.bincount(of[members], weights=wm, minlength=count) / np.bincount(
            of[members], weights=quad1.areas[members], minlength=count)
        eligible = np.where(has[of[members]], density >= 0.5 * mean[of[members]], True)
    csum = np.zeros((count, 3))
    for c in range(3):
        csum[:, c] = np.bincount(of[members], weights=a * centroid[members, c], minlength=count)
    carea = np.bincount(of[members], weights=a, minlength=count)
    cc = csum / np.where(carea > 0, carea, 1.0)[:, None]
    d2 = ((centroid[members] - cc[of[members]]) ** 2).sum(axis=1)
    d2[~eligible] = np.inf
    best = np.lexsort((d2, of[members]))                        # by cluster, nearest first
    element = members[best[start[:-1]]] if count else np.zeros(0, dtype=np.int64)
    at = point[element].copy()
    if scene is not None and count:
        at = _centred(scene, element, cc, at)
    return Clusters(of=of, count=count, point=at, normal=normal[element], element=element,
                    size=float(h), members=members, start=start, element_point=point, element_normal=normal,
                    element_centroid=centroid)


def quadrant_points(clusters: Clusters, quad1: PatchQuadrature, c: int, power: np.ndarray):
    """A 4-point rule for cluster ``c`` (for the error estimate): its elements split into quadrants about the
    cluster's point along two in-plane axes; each quadrant shoots its own unshot power ``power (n, 3)`` from
    the order-1 point of its element nearest to the quadrant's area centroid. Returns ``(points (k, 3),
    normals (k, 3), powers (k, 3))``, k <= 4 (empty quadrants left out)."""
    mem = clusters.members[clusters.start[c]:clusters.start[c + 1]]
    pts, nrm, cen = clusters.element_point[mem], clusters.element_normal[mem], clusters.element_centroid[mem]
    nz = clusters.normal[c]
    t = np.cross(nz, [1.0, 0.0, 0.0] if abs(nz[0]) < 0.9 else [0.0, 1.0, 0.0])
    t /= np.linalg.norm(t)
    b = np.cross(nz, t)
    d = cen - clusters.point[c]
    quadrant = (d @ t > 0).astype(int) + 2 * (d @ b > 0).astype(int)
    out_p, out_n, out_w = [], [], []
    a = quad1.areas[mem]
    for k in range(4):
        s = np.flatnonzero(quadrant == k)
        if not len(s):
            continue
        qc = (a[s, None] * cen[s]).sum(axis=0) / a[s].sum()
        j = s[np.argmin(((cen[s] - qc) ** 2).sum(axis=1))]
        out_p.append(pts[j])
        out_n.append(nrm[j])
        out_w.append(power[mem[s]].sum(axis=0))
    return np.array(out_p), np.array(out_n), np.array(out_w)



def _centred(scene, element: np.ndarray, target: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """``target (c, 3)`` moved 2 % toward ``inner`` where it lies in the closure of ``element``'s largest convex
    piece (``inner``: that piece's centroid, strictly inside); ``inner`` elsewhere."""
    v, k = scene.poly_vertices, scene.poly_counts
    a = np.zeros(scene.n_polygons)
    for m in np.unique(k):
        sel = np.flatnonzero(k == m)
        w = v[sel, :m]
        a[sel] = 0.5 * np.linalg.norm(np.cross(w[:, 1:-1] - w[:, :1], w[:, 2:] - w[:, :1]), axis=-1).sum(axis=1)
    order = np.lexsort((-a, scene.poly_source))
    piece = order[np.searchsorted(scene.poly_source[order], element)]          # (c,) largest piece
    pv = v[piece]                                                              # (c, K, 3), padded
    nrm = scene.poly_normals[piece]
    edge = np.roll(pv, -1, axis=1) - pv
    side = np.einsum("ckx,cx->ck", np.cross(edge, target[:, None, :] - pv), nrm)
    scale = np.linalg.norm(edge, axis=2).max(axis=1)
    inside = (side >= -1e-12 * scale[:, None] ** 2).all(axis=1)
    moved = target + 0.02 * (inner - target)
    # a moved point inside a solid (a floor cell's corner under a block) sees the solid's back faces: five
    # rays (the normal and four 45° off it) that hit a back face first send it back to the piece's centroid
    sel = np.flatnonzero(inside)
    if len(sel):
        from ..core.raycast import cast_rays

        nz = nrm[sel]
        t = np.cross(nz, np.where(np.abs(nz[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        b = np.cross(nz, t)
        dirs = [nz] + [nz + sgn * e for e in (t, b) for sgn in (1.0, -1.0)]
        o = np.concatenate([moved[sel]] * 5)
        hits = cast_rays(scene, o, np.concatenate(dirs), exclude=np.tile(element[sel], 5))
        hidden = (hits.hit & ~hits.front).reshape(5, -1).any(axis=0)
        inside[sel[hidden]] = False
    return np.where(inside[:, None], moved, inner)
