"""The hemicube (Cohen & Greenberg 1985): item-buffer z-buffer rasterisation onto five faces, in numpy.

For every receiver P with normal N a hemicube of half-size 1 is set up in a frame (T1, T2, N) turned
by a random angle about N (as the paper did, to decorrelate aliasing between pixels). Every polygon
is rasterised onto the top face (``res × res`` pixels over [-1, 1]², at distance 1 along N) and the
four side faces (``res × res/2`` pixels over [-1, 1] × [0, 1], at distance 1 along ±T1, ±T2).

Rasterisation is homogeneous (Olano & Greer 1997), so polygons behind or straddling a face's eye
plane need no clipping: a pixel centre's direction ``r`` lies in polygon A's cone when ``r · (a_j ×
a_j+1)`` has the same sign for every edge (``a`` = vertices relative to P) and the plane of A is hit
in front (depth ``t = n·a_0 / n·r > 0``). Only the candidate pixels inside each polygon's projected
bounding box are tested (the box of the part in front of the eye plane, clipped to the face). The
nearest polygon per pixel wins (z-buffer); its delta form factor

    top:  ΔF = Δu Δv / (π (u² + v² + 1)²)         side: ΔF = v Δu Δv / (π (u² + v² + 1)²)

is added to the polygon's form factor. The table sums to 1 + 2.17e-4 at 50² and 1 + 1.35e-5 at 200²
(the paper's figures): the sum of the form factors in a closed scene only measures that table, while
the per-polygon error is dominated by aliasing.

Memory: receivers in chunks of ``chunk`` (``(chunk, n, K, 3)`` local vertices), candidate pixel tests
in batches of at most ``max_tests`` (about ``max_tests × 200`` bytes).
"""

from __future__ import annotations

import numpy as np

from .analytic import front_mask
from .result import BaselineResult

__all__ = ["delta_form_factors", "hemicube"]


def _faces(res: int):
    """Pixel grids of the 5 faces: list of (u (p,), v (p,), dff (p,), nu, nv, u0, v0, du)."""
    du = 2.0 / res
    c = -1.0 + (np.arange(res) + 0.5) * du
    out = []
    uu, vv = np.meshgrid(c, c, indexing="ij")  # top: pixel (i, j) -> i * res + j
    out.append((uu.ravel(), vv.ravel(), du * du / (np.pi * (uu * uu + vv * vv + 1.0) ** 2), res, res, -1.0, -1.0))
    half = res // 2
    cv = (np.arange(half) + 0.5) * du
    uu, vv = np.meshgrid(c, cv, indexing="ij")
    side = vv * du * du / (np.pi * (uu * uu + vv * vv + 1.0) ** 2)
    for _ in range(4):
        out.append((uu.ravel(), vv.ravel(), side, res, half, -1.0, 0.0))
    return [(u, v, np.asarray(f).ravel(), nu, nv, u0, v0, du) for (u, v, f, nu, nv, u0, v0) in out]


def delta_form_factors(resolution: int) -> np.ndarray:
    """All delta form factors of a hemicube of ``resolution`` (top ``res²`` then 4 × ``res²/2``)."""
    return np.concatenate([f[2] for f in _faces(int(resolution))])


def _frames(normals: np.ndarray, angles: np.ndarray):
    """Orthonormal (T1, T2) for unit ``normals (m, 3)``, turned by ``angles (m,)`` about the normal."""
    helper = np.where(np.abs(normals[:, :1]) < 0.6, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    return c * t1 + s * t2, -s * t1 + c * t2


def hemicube(
    scene,
    points,
    normals,
    resolution: int = 50,
    *,
    rng=None,
    rotate: bool = True,
    chunk: int = 4,
    max_tests: int = 2**21,
) -> BaselineResult:
    """Hemicube form factors and irradiance at every receiver.

    Args:
        scene: core Scene (its ``poly_radiance`` gives the irradiance; front side only unless double sided).
        points, normals: (m, 3) receivers (world space) and their normals.
        resolution: pixels along the top face (even); side faces are ``res × res/2``.
        rng: numpy Generator or seed for the random rotation about the normal.
        rotate: turn each hemicube by a random angle (the paper's "randomly rotated hemicube").

    Returns:
        :class:`BaselineResult` with ``form_factors (m, n_input)`` and ``irradiance (m, 3)``
        (``H = π Σ L F``); ``stderr`` is None.
    """
    res = int(resolution)
    if res < 2 or res % 2:
        raise ValueError(f"resolution must be even and >= 2, got {resolution}")
    p_all = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n_all = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    n_all = n_all / np.linalg.norm(n_all, axis=1, keepdims=True)
    m = len(p_all)
    rng = np.random.default_rng(rng)
    angles = rng.uniform(0.0, 2.0 * np.pi, m) if rotate else np.zeros(m)
    t1_all, t2_all = _frames(n_all, angles)
    faces = _faces(res)
    n_poly = scene.n_polygons
    ff = np.zeros((m, scene.n_input))
    irr = np.zeros((m, 3))
    if n_poly == 0 or m == 0:
        return BaselineResult(ff, irr, None)
    verts = scene.poly_vertices  # (n, K, 3)
    pn = scene.poly_normals
    for s in range(0, m, chunk):
        e = min(s + chunk, m)
        c = e - s
        p, nrm, t1, t2 = p_all[s:e], n_all[s:e], t1_all[s:e], t2_all[s:e]
        a = verts[None] - p[:, None, None, :]  # (c, n, K, 3) receiver-local vertices
        cones = np.cross(a, np.roll(a, -1, axis=2))  # (c, n, K, 3) normals of the planes P-edge
        depth_num = np.einsum("nc,mnc->mn", pn, a[:, :, 0, :])  # (c, n) n · a0
        scale = np.linalg.norm(a, axis=3).max(axis=2)  # (c, n)
        # a polygon whose plane contains P is seen edge-on: covers nothing, hides nothing
        usable = np.abs(depth_num) > 1e-9 * scale
        lit = front_mask(scene, p) if not scene.double_sided else np.ones((c, n_poly), dtype=bool)
        axes = [(nrm, t1, t2), (t1, t2, nrm), (-t1, -t2, nrm), (t2, -t1, nrm), (-t2, t1, nrm)]
        for (axis, uax, vax), (fu, fv, dff, nu, nv, u0, v0, du) in zip(axes, faces, strict=True):
            z = np.einsum("mnkc,mc->mnk", a, axis)  # (c, n, K) depth along the face axis
            u = np.einsum("mnkc,mc->mnk", a, uax)
            v = np.einsum("mnkc,mc->mnk", a, vax)
            box = _projected_boxes(z, u, v, 1e-7 * scale)  # (4, c, n): umin, umax, vmin, vmax
            i0 = np.clip(np.ceil((box[0] - u0) / du - 0.5), 0, nu)
            i1 = np.clip(np.floor((box[1] - u0) / du - 0.5), -1, nu - 1)
            j0 = np.clip(np.ceil((box[2] - v0) / du - 0.5), 0, nv)
            j1 = np.clip(np.floor((box[3] - v0) / du - 0.5), -1, nv - 1)
            cnt_i = np.where(usable, np.maximum(i1 - i0 + 1, 0), 0).astype(np.int64)
            cnt_j = np.maximum(j1 - j0 + 1, 0).astype(np.int64)
            counts = cnt_i * cnt_j  # (c, n) candidate pixels per (receiver, polygon)
            pm, pp = np.nonzero(counts)
            if len(pm) == 0:
                continue
            cnt = counts[pm, pp]
            zbuf = np.full(c * nu * nv, np.inf)
            item = np.full(c * nu * nv, -1, dtype=np.int64)
            ends = np.cumsum(cnt)
            start = 0
            while start < len(pm):  # batches of pairs with at most max_tests pixel tests
                stop = max(start + 1, int(np.searchsorted(ends, (ends[start - 1] if start else 0) + max_tests)))
                sl = slice(start, stop)
                bm, bp, bc = pm[sl], pp[sl], cnt[sl]
                pair = np.repeat(np.arange(len(bm)), bc)
                offs = np.arange(len(pair)) - np.repeat(np.cumsum(bc) - bc, bc)
                ncols = cnt_j[bm, bp][pair]
                pi = (i0[bm, bp][pair] + offs // ncols).astype(np.int64)
                pj = (j0[bm, bp][pair] + offs % ncols).astype(np.int64)
                pix = pi * nv + pj
                rm, rp = bm[pair], bp[pair]
                # direction of the pixel centre: axis + u U + v V (not normalised; depths compare per pixel)
                r = axis[rm] + fu[pix][:, None] * uax[rm] + fv[pix][:, None] * vax[rm]  # (q, 3)
                cn = cones[rm, rp]  # (q, K, 3)
                side = np.einsum("qkc,qc->qk", cn, r)
                inside = (side >= 0.0).all(axis=1) | (side <= 0.0).all(axis=1)
                den = np.einsum("qc,qc->q", pn[rp], r)
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = np.where(den != 0.0, depth_num[rm, rp] / np.where(den != 0.0, den, 1.0), -1.0)
                ok = inside & (t > 0.0)
                key = rm[ok] * (nu * nv) + pix[ok]
                tk, pk = t[ok], rp[ok]
                np.minimum.at(zbuf, key, tk)
                win = tk == zbuf[key]
                item[key[win]] = pk[win]
                start = stop
            item = item.reshape(c, nu * nv)
            hit = item >= 0
            rows = np.nonzero(hit)[0]
            polys = item[hit]
            w = np.broadcast_to(dff, (c, nu * nv))[hit]
            np.add.at(ff, (s + rows, scene.poly_source[polys]), w)
            wl = w * lit[rows, polys]
            for ch in range(3):  # H = π Σ L ΔF
                irr[s:e, ch] += np.pi * np.bincount(rows, weights=wl * scene.poly_radiance[polys, ch], minlength=c)
    return BaselineResult(ff, irr, None)


def _projected_boxes(z, u, v, eps):
    """Image-plane boxes ``(4, c, n)`` (umin, umax, vmin, vmax) of the parts of polygons in front of
    the eye plane ``z >= eps``; ``z, u, v (c, n, K)``, ``eps (c, n)``. Boxes of polygons entirely
    behind are empty (min = +inf). Vertices with z < eps are replaced by the edge crossings with
    z = eps (projected coordinates far out, which the face clamp then limits)."""
    ep = eps[..., None]
    front = z >= ep
    zn, un, vn = np.roll(z, -1, axis=2), np.roll(u, -1, axis=2), np.roll(v, -1, axis=2)
    cross = front != (zn >= ep)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(cross, (ep - z) / np.where(cross, zn - z, 1.0), 0.0)
        uc = (u + w * (un - u)) / ep
        vc = (v + w * (vn - v)) / ep
        uf = np.where(front, u / np.where(front, z, 1.0), np.nan)
        vf = np.where(front, v / np.where(front, z, 1.0), np.nan)
    uc = np.where(cross, uc, np.nan)
    vc = np.where(cross, vc, np.nan)
    uu = np.concatenate([uf, uc], axis=2)
    vv = np.concatenate([vf, vc], axis=2)
    any_ = np.isfinite(uu).any(axis=2)
    big = np.inf
    umin = np.where(any_, np.nanmin(np.where(np.isnan(uu), big, uu), axis=2), big)
    umax = np.where(any_, np.nanmax(np.where(np.isnan(uu), -big, uu), axis=2), -big)
    vmin = np.where(any_, np.nanmin(np.where(np.isnan(vv), big, vv), axis=2), big)
    vmax = np.where(any_, np.nanmax(np.where(np.isnan(vv), -big, vv), axis=2), -big)
    return np.stack([umin, umax, vmin, vmax])
