"""Quadrature points on the patches (input polygons) of a core Scene, for patch-to-patch form factors.

The patch-to-patch factor from patch i to polygon j is the area mean of the exact point-to-polygon factor
(the core's :func:`~hemisphere_local_pass.core.form_factors`, eq. 4 with exact visibility) over patch i:

    F_ij = 1/A_i ∫_{A_i} F(x -> j) dA(x)  ≈  1/A_i Σ_q w_q F(x_q -> j)

(Cohen & Wallace, "Radiosity and Realistic Image Synthesis", ch. 4: the inner integral exact, the
outer one by quadrature). The rule, per convex planar piece of a patch (the core's pieces):

* ``order=2`` (default): a triangle takes the 3-point rule with interior points at barycentric
  (2/3, 1/6, 1/6) and its permutations, weights A/3 (Strang & Fix; exact for quadratics); a
  quadrilateral the 2 × 2 Gauss–Legendre rule on its bilinear map, weighted by the Jacobian (exact
  for cubics on a parallelogram); a piece of k >= 5 vertices is fanned from its vertex mean into k
  triangles, one point at each one's centroid (exact for linear functions).
* ``order=1``: one point at each piece's area centroid, weight its area (exact for linear functions).

Every point lies strictly inside its piece, where the exact factors of a closed scene sum to 1, so the
rows of F sum to 1 whatever the quadrature error: energy is conserved exactly. The error is that of the
rule on ``x -> F(x -> j)``, which varies on the scale of the distance r between patches of size h:
relative O((h/r)^3) for the triangle rule, O((h/r)^4) for the 2 × 2 Gauss rule (symmetric: the odd terms
cancel), O((h/r)^2) for ``order=1``, where F is smooth; O(h/r) across a shadow boundary; O(1) for a
receiver touching the shooter (a small patch next to a large one). Measured for coaxial unit squares at
distance c (tests/core/test_first_pass.py): 2 × 2 Gauss 0.73 %, 0.13 %, 0.033 %, 2.4e-5 at c = 1, 2, 3, 6;
the centroid 19.8 %, 7.1 %, 3.4 %, 0.91 %. The solver reports the 1-point rule's difference as an
estimate (:mod:`.progressive`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PatchQuadrature", "patch_quadrature"]

_G = 0.5 / np.sqrt(3.0)
_GAUSS = (0.5 - _G, 0.5 + _G)


@dataclass
class PatchQuadrature:
    """Quadrature points of every patch, sorted by patch (CSR layout).

    Attributes:
        points: (Q, 3) float64 world-space points, strictly inside their pieces.
        normals: (Q, 3) float64 unit front normals of their pieces.
        weights: (Q,) float64 area weights (m²); they sum to the patch's area.
        patch: (Q,) int64 input polygon of every point (non-decreasing).
        start: (n_input + 1,) int64: patch i's points are ``start[i]:start[i + 1]``.
        areas: (n_input,) float64 patch areas (0 for polygons the scene dropped).
    """

    points: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    patch: np.ndarray
    start: np.ndarray
    areas: np.ndarray

    def of(self, patches: np.ndarray) -> np.ndarray:
        """(q,) indices of the points of ``patches`` (int array), patch by patch."""
        counts = self.start[patches + 1] - self.start[patches]
        first = np.repeat(self.start[patches] - np.cumsum(counts) + counts, counts)
        return first + np.arange(int(counts.sum()))


def _triangle_areas(a, b, c):
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=-1)


def patch_quadrature(scene, order: int = 2) -> PatchQuadrature:
    """Quadrature points of every input polygon of ``scene`` (a core Scene); ``order`` 1 or 2 (see module)."""
    if order not in (1, 2):
        raise ValueError(f"quadrature order must be 1 or 2, got {order}")
    verts, counts = scene.poly_vertices, scene.poly_counts
    pts, wts, src, nrm = [], [], [], []
    for k in np.unique(counts):
        sel = np.flatnonzero(counts == k)
        v = verts[sel, :k]                                              # (g, k, 3)
        if order == 1:
            # area centroid of the fan from vertex 0
            a = _triangle_areas(v[:, :1], v[:, 1:-1], v[:, 2:])         # (g, k-2)
            c = (v[:, :1] + v[:, 1:-1] + v[:, 2:]) / 3.0                # (g, k-2, 3)
            area = a.sum(axis=1)
            p = (a[..., None] * c).sum(axis=1) / area[:, None]
            groups = [(p, area)]
        elif k == 3:
            groups = []
            area = _triangle_areas(v[:, 0], v[:, 1], v[:, 2])
            for j in range(3):
                bary = np.full(3, 1.0 / 6.0)
                bary[j] = 2.0 / 3.0
                groups.append((np.einsum("j,gjc->gc", bary, v), area / 3.0))
        elif k == 4:
            groups = []
            for u in _GAUSS:
                for w in _GAUSS:
                    p = ((1 - u) * (1 - w) * v[:, 0] + u * (1 - w) * v[:, 1] + u * w * v[:, 2]
                         + (1 - u) * w * v[:, 3])
                    du = (1 - w) * (v[:, 1] - v[:, 0]) + w * (v[:, 2] - v[:, 3])
                    dw = (1 - u) * (v[:, 3] - v[:, 0]) + u * (v[:, 2] - v[:, 1])
                    groups.append((p, 0.25 * np.linalg.norm(np.cross(du, dw), axis=1)))
        else:
            groups = []
            mid = v.mean(axis=1)
            for j in range(k):
                a, b = v[:, j], v[:, (j + 1) % k]
                groups.append(((mid + a + b) / 3.0, _triangle_areas(mid, a, b)))
        for p, w in groups:
            pts.append(p)
            wts.append(w)
            src.append(scene.poly_source[sel])
            nrm.append(scene.poly_normals[sel])
    if pts:
        points, weights = np.concatenate(pts), np.concatenate(wts)
        patch, normals = np.concatenate(src), np.concatenate(nrm)
    else:
        points, normals, weights, patch = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64)
    order_ = np.argsort(patch, kind="stable")
    points, normals, weights, patch = points[order_], normals[order_], weights[order_], patch[order_]
    n = scene.n_input
    start = np.searchsorted(patch, np.arange(n + 1)).astype(np.int64)
    areas = np.bincount(patch, weights=weights, minlength=n)
    return PatchQuadrature(points, normals, weights, patch, start, areas)
