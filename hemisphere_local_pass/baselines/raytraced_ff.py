"""Ray-traced form factors (Wallace, Elmquist & Haines 1989) as the paper used them.

For every receiver P and every polygon above its horizon: the unoccluded form factor by eq. 4 (the
paper's change to WEH89, which used a disk approximation) times the fraction of shadow rays from P
to sample points on the polygon that reach it. The number of rays adapts to the polygon's size as
seen from P: ``clip(ceil(rays · F_unoccluded), 1, max_rays_per_polygon)``, so near and large
polygons get many rays and small distant ones a single one. Sample points are uniform over the
polygon's area (area-weighted fan triangles).

Unlike the exact method the factors are not consistent with each other: where polygons are partly
hidden the visible fractions are estimates, so the sum over a closed scene deviates from 1 (the
paper: 0.12 at 176 polygons, 0.40 at 9,504).
"""

from __future__ import annotations

import numpy as np

from ..core.raycast import build_bvh, cast_rays
from .analytic import front_mask, unoccluded_form_factors
from .result import BaselineResult

__all__ = ["raytraced_form_factors", "sample_polygons"]


def sample_polygons(scene, polys: np.ndarray, rng) -> np.ndarray:
    """One uniform random point ``(q, 3)`` on each convex polygon ``polys (q,)`` (by area)."""
    v = scene.poly_vertices[polys]  # (q, K, 3)
    a0 = v[:, :1, :]
    tri_area = 0.5 * np.linalg.norm(np.cross(v[:, 1:-1] - a0, v[:, 2:] - a0), axis=2)  # (q, K-2) fan
    cum = np.cumsum(tri_area, axis=1)
    pick = (cum < rng.random(len(polys))[:, None] * cum[:, -1:]).sum(axis=1)
    pick = np.minimum(pick, tri_area.shape[1] - 1)
    rows = np.arange(len(polys))
    b, c = v[rows, pick + 1], v[rows, pick + 2]
    r1, r2 = rng.random(len(polys)), rng.random(len(polys))
    s = np.sqrt(r1)  # uniform in the triangle (a0, b, c)
    return (1 - s)[:, None] * a0[:, 0] + (s * (1 - r2))[:, None] * b + (s * r2)[:, None] * c


def raytraced_form_factors(scene, points, normals, rays: float = 64.0, *, max_rays_per_polygon: int = 64,
                           rng=None, bvh=None, max_batch: int = 2**18) -> BaselineResult:
    """WEH89 form factors and irradiance at every receiver.

    Args:
        scene: core Scene; points, normals: (m, 3) receivers and their normals.
        rays: shadow rays per unit of unoccluded form factor (the adaptive ray density).
        max_rays_per_polygon: cap on the rays to one polygon.
        rng: numpy Generator or seed. bvh: prebuilt BVH. max_batch: rays per cast (memory bound).

    Returns:
        :class:`BaselineResult` (``stderr`` None).
    """
    p_all = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n_all = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    n_all = n_all / np.linalg.norm(n_all, axis=1, keepdims=True)
    m = len(p_all)
    rng = np.random.default_rng(rng)
    bvh = build_bvh(scene) if bvh is None else bvh
    ff = np.zeros((m, scene.n_input))
    irr = np.zeros((m, 3))
    step = max(1, max_batch // max(1, scene.n_polygons))
    for s in range(0, m, step):
        e = min(s + step, m)
        p = p_all[s:e]
        fu = unoccluded_form_factors(scene, p, n_all[s:e])  # (c, n)
        pm, pp = np.nonzero(fu > 0.0)
        nr = np.clip(np.ceil(rays * fu[pm, pp]), 1, max_rays_per_polygon).astype(np.int64)
        pair = np.repeat(np.arange(len(pm)), nr)
        visible = np.zeros(len(pm))
        for b0 in range(0, len(pair), max_batch):
            pr = pair[b0:b0 + max_batch]
            target = sample_polygons(scene, pp[pr], rng)
            o = p[pm[pr]]
            # shadow ray to the sample point; the target polygon itself never blocks
            h = cast_rays(scene, o, target - o, t_max=1.0 - 1e-9, exclude=scene.poly_source[pp[pr]], bvh=bvh)
            visible += np.bincount(pr, weights=(~h.hit).astype(np.float64), minlength=len(pm))
        f = fu[pm, pp] * visible / nr
        np.add.at(ff, (s + pm, scene.poly_source[pp]), f)
        lit = front_mask(scene, p)[pm, pp] | scene.double_sided
        for ch in range(3):  # H = π Σ L F
            irr[s:e, ch] = np.pi * np.bincount(pm, weights=f * lit * scene.poly_radiance[pp, ch], minlength=e - s)
    return BaselineResult(ff, irr, None)
