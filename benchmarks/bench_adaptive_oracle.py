"""Where the adaptive pass's exact evaluations go, and how few a perfect error estimate would need.

Both parts run on the cached all-exact image of a benchmark Cornell box (``HLP_CACHE``,
``exact_H_<scene>_<n>_<size>.npz``, the cache of ``bench_time_vs_error.py``; computed here if absent),
so they cost no exact evaluations and their counts do not depend on the machine's load:

* **replay**: ``core.adaptive_irradiance`` itself, with its exact evaluator replaced by a look-up in the
  cached image (bit for bit the values it would compute), isotropic and anisotropic: exact evaluations
  per hit pixel, measured max error over the tolerance, the method's own largest estimate;
* **oracle**: the same quadtree (coarse cells of 16, uniform cells only, every non-uniform cell split
  down to single pixels) where a cell is accepted when the *true* largest error of its interpolant is
  within the tolerance: a lower bound for any error estimate with that interpolant (isotropic splits,
  no shadow test, no spot-check cost beyond the interpolant's own samples). ``floor`` accepts every
  uniform cell (only the surface breaks cost); ``bilin4`` the corners' bilinear interpolant; ``bilin9``
  the bilinear interpolant over the nine samples (the adaptive pass's); ``biquad9`` the tensor-product
  quadratic through them; with ``--world`` also ``wbilin4`` / ``wbilin9``, the same bilinear interpolants
  with each cell's coordinates taken on the surface (the pixel's hit point inside the quad of its corners'
  hit points), which reproduce a function affine on the plane exactly where image-space weights miss it
  under perspective; with ``--estimates`` the same quadtree deciding from the samples alone
  (:func:`estimate_quadtree`): the bilinear interpolant with the adaptive pass's estimate, and the
  biquadratic with ``max |biquad9 - bilin9|`` as its estimate;
* ``--neighbour``: the replay without and with the spot check extended one sample spacing beyond the cell
  (``neighbour_check``): exact evaluations per hit pixel, max error over the tolerance, pixels over it.

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_oracle.py --scene small --size 256
    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_oracle.py --scene large --size 128

* **control variates** (``--control``): the oracle interpolating only the residual ``R = H − C`` of a
  closed-form part ``C`` evaluated at *every* pixel, ``C = π Σ_i L_i F_i^unocc(P)`` the unoccluded
  irradiance (Lambert's form factor of each emitting polygon clipped to the receiver's tangent plane,
  front sides lit, :func:`unoccluded_irradiance`; checked here against ``core.irradiance`` on
  single-polygon scenes): ``all`` over every polygon; ``near k`` per coarse cell over the polygons within
  ``k`` cell diameters of the cell or whose plane crosses its bounding box (C constant per cell, so the
  residual has no seams); ``--visibility`` adds the per-polygon visibility ratios ``V_i = F_i /
  F_i^unocc`` interpolated (``H ≈ π Σ L_i F_i^unocc interp(V_i)``; needs ``core.form_factors`` at every
  pixel, small scene only). It also times ``C`` against the exact core side by side (workers=1, one
  process, random hit pixels): C is worth having only if (oracle exact fraction with C) + (C's cost per
  pixel / the exact core's) is below the oracle's exact fraction without it.

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_oracle.py --scene small --size 256 \
        --rel 1e-2,1e-3,1e-4 --control all,0.5,2 --visibility
    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_oracle.py --scene large --size 128 \
        --rel 1e-2,1e-3 --control all,0.5 --no-replay
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CACHE, log  # noqa: E402


def reference(key, size):
    """Scene, (points, normals, polygons) images and the all-exact H image (cached)."""
    from bench_time_vs_error import prepare

    from hemisphere_local_pass.core import irradiance

    box, lum, scene, (p, n, g), *_ = prepare(key, size)
    path = CACHE / f"exact_H_{key}_{box.n_polygons}_{size}.npz"
    if path.exists():
        return scene, p, n, g, np.load(path)["H"]
    t = time.perf_counter()
    H = np.zeros(p.shape)
    v = g >= 0
    H[v] = irradiance(scene, p[v], n[v])
    sec = time.perf_counter() - t
    log(f"[ref] {key} {size}²: {sec:.1f} s")
    np.savez(path, H=H, seconds=sec, command="bench_adaptive_oracle.py (core.irradiance at every hit pixel)")
    return scene, p, n, g, H


def replay(scene, p, n, g, H, tol, **kw):
    """``adaptive_irradiance`` with ``irradiance`` looked up in ``H``: (image, stats)."""
    import hemisphere_local_pass.core.adaptive as ad

    v = g >= 0
    where = {p[y, x].tobytes(): (y, x) for y, x in zip(*np.nonzero(v), strict=True)}

    def lookup(scene_, pts, nrm, **_):
        yx = np.array([where[q.tobytes()] for q in pts], dtype=np.int64).reshape(-1, 2)
        return H[yx[:, 0], yx[:, 1]]

    saved = ad.irradiance
    ad.irradiance = lookup
    try:
        return ad.adaptive_irradiance(scene, p, n, g, tolerance=tol, workers=1, **kw)
    finally:
        ad.irradiance = saved


def _interp(H, x0, x1, y0, y1, kind):
    """Interpolant of image ``H (h, w, c)`` over cell ``[x0, x1] × [y0, y1]`` from its 4 or 9 samples:
    ``(values (ny, nx, c), samples [(y, x)])``."""
    ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
    u = ((xs - x0) / (x1 - x0))[..., None]
    v = ((ys - y0) / (y1 - y0))[..., None]
    mx, my = (x0 + x1) // 2, (y0 + y1) // 2
    if kind in ("bilin4", "floor"):
        val = (1 - v) * ((1 - u) * H[y0, x0] + u * H[y0, x1]) + v * ((1 - u) * H[y1, x0] + u * H[y1, x1])
        return val, [(y0, x0), (y0, x1), (y1, x0), (y1, x1)]
    samples = [(y, x) for y in (y0, my, y1) for x in (x0, mx, x1)]
    if kind == "biquad9":
        um, vm = (mx - x0) / (x1 - x0), (my - y0) / (y1 - y0)

        def lagrange(t, m):  # quadratic Lagrange basis on the nodes 0, m, 1
            return [(t - m) * (t - 1) / m, t * (1 - t) / (m * (1 - m)), t * (t - m) / (1 - m)]

        lu, lv = lagrange(u, um), lagrange(v, vm)
        val = sum(lu[i] * lv[j] * H[y, x] for j, y in enumerate((y0, my, y1)) for i, x in enumerate((x0, mx, x1)))
        return val, samples
    val = np.empty(u.shape[:2] + H.shape[2:])   # bilin9: bilinear over the four sub-cells
    for xa, xb in ((x0, mx), (mx, x1)):
        for ya, yb in ((y0, my), (my, y1)):
            sl = (slice(ya - y0, yb - y0 + 1), slice(xa - x0, xb - x0 + 1))
            uu = ((xs[sl] - xa) / max(xb - xa, 1))[..., None]
            vv = ((ys[sl] - ya) / max(yb - ya, 1))[..., None]
            val[sl] = (1 - vv) * ((1 - uu) * H[ya, xa] + uu * H[ya, xb]) + vv * ((1 - uu) * H[yb, xa] + uu * H[yb, xb])
    return val, samples


def _world_st(P, a, b, c, d, normal, iterations=50):
    """Bilinear coordinates ``(s, t)`` (each ``(..., 1)``) of points ``P (..., 3)`` in the planar quad
    ``a (0, 0), b (1, 0), c (1, 1), d (0, 1)`` (world points of one plane, unit ``normal``): the inverse of
    ``x(s, t) = a + s (b - a) + t (d - a) + s t (a - b + c - d)`` in the plane's two dominant axes, by Newton
    from the centre (the quad of a pixel rectangle seen in perspective is convex, the map one to one)."""
    i, j = [k for k in range(3) if k != int(np.argmax(np.abs(normal)))]
    A = np.stack([a[[i, j]], b[[i, j]], c[[i, j]], d[[i, j]]])
    X = P[..., [i, j]]
    e, f, g = A[1] - A[0], A[3] - A[0], A[0] - A[1] + A[2] - A[3]
    s = np.full(X.shape[:-1], 0.5)
    t = s.copy()
    for _ in range(iterations):
        r = A[0] + s[..., None] * e + t[..., None] * f + (s * t)[..., None] * g - X
        j11, j12 = e[0] + t * g[0], f[0] + s * g[0]
        j21, j22 = e[1] + t * g[1], f[1] + s * g[1]
        det = j11 * j22 - j12 * j21
        ds = (j22 * r[..., 0] - j12 * r[..., 1]) / det
        dt = (j11 * r[..., 1] - j21 * r[..., 0]) / det
        s, t = s - ds, t - dt
        if max(np.abs(ds).max(), np.abs(dt).max()) < 1e-14:
            break
    return s[..., None], t[..., None]


def _world_interp(H, p, n, x0, x1, y0, y1, kind):
    """``_interp``'s ``bilin4`` / ``bilin9`` (``kind`` ``wbilin4`` / ``wbilin9``) with each (sub-)cell's
    bilinear coordinates taken on the surface rather than in the image: the pixel's hit point ``p`` mapped
    back into the quad of its corners' hit points, so that a function affine in world coordinates on the
    plane is reproduced exactly (image-space weights miss it under perspective)."""
    mx, my = (x0 + x1) // 2, (y0 + y1) // 2
    if kind == "wbilin4":
        blocks = [((x0, x1), (y0, y1))]
        samples = [(y0, x0), (y0, x1), (y1, x0), (y1, x1)]
    else:
        blocks = [((xa, xb), (ya, yb)) for xa, xb in ((x0, mx), (mx, x1)) for ya, yb in ((y0, my), (my, y1))]
        samples = [(y, x) for y in (y0, my, y1) for x in (x0, mx, x1)]
    val = np.empty((y1 - y0 + 1, x1 - x0 + 1) + H.shape[2:])
    for (xa, xb), (ya, yb) in blocks:
        sl = (slice(ya - y0, yb - y0 + 1), slice(xa - x0, xb - x0 + 1))
        s, t = _world_st(p[ya:yb + 1, xa:xb + 1], p[ya, xa], p[ya, xb], p[yb, xb], p[yb, xa], n[y0, x0])
        val[sl] = (1 - t) * ((1 - s) * H[ya, xa] + s * H[ya, xb]) + t * ((1 - s) * H[yb, xa] + s * H[yb, xb])
    return val, samples


def world_check(scene, p, n, g, coarse=16):
    """Largest miss of the image-space and the world-space ``bilin9`` on an affine function of the hit
    point, over the uniform coarse cells: ``(image, world, cells)``."""
    import hemisphere_local_pass.core.adaptive as ad

    plane = np.where(g >= 0, ad._input_planes(scene)[np.maximum(g, 0)], -1)
    F = p @ np.array([[0.3, -0.2, 0.5], [0.1, 0.7, -0.4], [0.2, 0.2, 0.2]]).T
    img = wld = 0.0
    cells = 0
    h, w = g.shape
    for y0 in range(0, h - coarse, coarse):
        for x0 in range(0, w - coarse, coarse):
            x1, y1 = x0 + coarse, y0 + coarse
            if plane[y0, x0] < 0 or (plane[y0:y1 + 1, x0:x1 + 1] != plane[y0, x0]).any():
                continue
            cells += 1
            ref = F[y0:y1 + 1, x0:x1 + 1]
            img = max(img, float(np.abs(_interp(F, x0, x1, y0, y1, "bilin9")[0] - ref).max() / np.ptp(ref)))
            world = _world_interp(F, p, n, x0, x1, y0, y1, "wbilin9")[0]
            wld = max(wld, float(np.abs(world - ref).max() / np.ptp(ref)))
    return img, wld, cells


def _breaks(scene, n, g):
    """The adaptive pass's surface breaks ``(brk_x (h, w-1), brk_y (h-1, w))`` of the hit images."""
    import hemisphere_local_pass.core.adaptive as ad

    return ad._surface_breaks(scene, n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-300), g)


def _quadtree(g, bx, by, coarse, visit):
    """The oracle's quadtree: coarse cells of ``coarse`` pixels, corners exact, isotropic splits down to single
    pixels. ``visit(x0, x1, y0, y1)`` is called on every uniform cell at least 2 pixels a side and returns the
    samples ``[(y, x)]`` of its interpolant when it accepts the cell, else None (split). Returns ``exact (h, w)``."""
    valid = g >= 0
    h, w = g.shape
    exact = np.zeros((h, w), bool)
    stack = [(x, min(x + coarse, w - 1), y, min(y + coarse, h - 1))
             for y in range(0, h - 1, coarse) for x in range(0, w - 1, coarse)]
    while stack:
        x0, x1, y0, y1 = stack.pop()
        for yy, xx in ((y0, x0), (y0, x1), (y1, x0), (y1, x1)):
            exact[yy, xx] = valid[yy, xx]
        if x1 - x0 <= 1 and y1 - y0 <= 1:
            continue
        uni = valid[y0, x0] and not bx[y0:y1 + 1, x0:x1].any() and not by[y0:y1, x0:x1 + 1].any()
        if uni and x1 - x0 >= 2 and y1 - y0 >= 2:
            samples = visit(x0, x1, y0, y1)
            if samples is not None:
                for yy, xx in samples:
                    exact[yy, xx] = True
                continue
        mx, my = (x0 + x1) // 2, (y0 + y1) // 2
        xs = [(x0, mx), (mx, x1)] if x1 - x0 >= 2 else [(x0, x1)]
        ys = [(y0, my), (my, y1)] if y1 - y0 >= 2 else [(y0, y1)]
        stack += [(a, b, c, d) for a, b in xs for c, d in ys]
    return exact


def oracle(scene, p, n, g, H, tol, kind, coarse=16, predict=None):
    """Exact evaluations per hit pixel of the quadtree that accepts a cell when its true error <= tol.

    ``predict(x0, x1, y0, y1) -> (values (ny, nx, 3), samples)`` replaces the interpolant of ``kind``
    (control variates: the cell's C plus its interpolated residual)."""
    if kind == "floor":
        def predict(x0, x1, y0, y1):
            return _interp(H, x0, x1, y0, y1, kind)
    elif predict is None and kind.startswith("w"):
        def predict(x0, x1, y0, y1):
            return _world_interp(H, p, n, x0, x1, y0, y1, kind)
    elif predict is None:
        def predict(x0, x1, y0, y1):
            return _interp(H, x0, x1, y0, y1, kind)

    def visit(x0, x1, y0, y1):
        val, samples = predict(x0, x1, y0, y1)
        return samples if kind == "floor" or np.abs(val - H[y0:y1 + 1, x0:x1 + 1]).max() <= tol else None

    exact = _quadtree(g, *_breaks(scene, n, g), coarse, visit)
    return exact.sum() / (g >= 0).sum()


def estimate_quadtree(scene, p, n, g, H, tol, mode, inner, edge_factor, coarse=16, ratios=None):
    """The oracle's quadtree (uniform cells, isotropic, no shadow test) deciding from the samples alone.

    A uniform cell of at least 2 pixels a side evaluates its nine samples; ``mode`` ``bilin`` interpolates with
    ``bilin9`` and estimates its error by ``d``, the corners' bilinear miss at the five checks (the adaptive
    pass's estimate); ``biquad`` interpolates with ``biquad9`` and estimates by ``max |biquad9 - bilin9|`` over
    the cell (no further samples). The cell is accepted when ``factor × estimate <= tol`` (``edge_factor`` for a
    cell touching a surface break or the border, ``inner`` otherwise). With ``inner = 0`` every cell is refined
    and ``ratios`` (a list) collects ``(true error / estimate, edge, true error)`` of every uniform cell at least
    4 pixels a side. Returns ``(exact evaluations per hit pixel, measured max error / tol)``."""
    import hemisphere_local_pass.core.adaptive as ad

    valid = g >= 0
    h, w = g.shape
    bx, by = _breaks(scene, n, g)
    tx, ty = ad._summed(bx), ad._summed(by)
    out = np.zeros_like(H)

    def visit(x0, x1, y0, y1):
        mx, my = (x0 + x1) // 2, (y0 + y1) // 2
        checks = ((y0, mx), (y1, mx), (my, x0), (my, x1), (my, mx))
        b9, samples = _interp(H, x0, x1, y0, y1, "bilin9")
        if mode == "bilin":
            b4, _ = _interp(H, x0, x1, y0, y1, "bilin4")
            val = b9
            est = max(float(np.abs(b4[yy - y0, xx - x0] - H[yy, xx]).max()) for yy, xx in checks)
        else:
            val, _ = _interp(H, x0, x1, y0, y1, "biquad9")
            est = float(np.abs(val - b9).max())
        at_edge = bool(ad._touches_break(tx, ty, *(np.array([v]) for v in (x0, x1, y0, y1)), w, h)[0])
        if ratios is not None and x1 - x0 >= 4:
            true = float(np.abs(val - H[y0:y1 + 1, x0:x1 + 1]).max())
            ratios.append((true / max(est, 1e-300), at_edge, true))
        if (edge_factor if at_edge else inner) * est <= tol:
            out[y0:y1 + 1, x0:x1 + 1] = val
            return samples
        # rejected: its checks are its children's corners, evaluated by the quadtree
        return None

    exact = _quadtree(g, bx, by, coarse, visit)
    img = np.where(exact[..., None] | ~valid[..., None], H, out)
    return exact.sum() / valid.sum(), float(np.abs(img - H).max()) / tol


# ------------------------------------------------------------------------------ control variates
def unoccluded_form_factors(ax, ay, az, nx, ny, nz):
    """Unoccluded form factors ``(F,)`` of convex polygons, the part above each receiver's tangent plane.

    ``ax, ay, az (K, F)``: the vertices relative to the receiver (padding repeats a vertex);
    ``nx, ny, nz (F,)``: the receiver's unit normal. Eq. 4 of the paper (Lambert's contour integral, the
    atan2 form) over the polygon clipped by the plane ``N · x = 0``: the clipped edges plus the closing
    edge along the horizon from the exit point to the entry point. Unsigned (one side at a time)."""
    hgt = ax * nx + ay * ny + az * nz                                     # (K, F) heights above the horizon
    up = hgt >= 0
    total = np.zeros(ax.shape[1])

    def terms(px, py, pz, qx, qy, qz, mx, my, mz):  # eq. 4's edge terms, component arrays (slot-major)
        cx, cy, cz = py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx
        s = np.sqrt(cx * cx + cy * cy + cz * cz)
        gamma = np.arctan2(s, px * qx + py * qy + pz * qz)
        return np.divide((cx * mx + cy * my + cz * mz) * gamma, s, out=np.zeros_like(s), where=s > 0)

    whole = up.all(axis=0)                                                # most pairs: no clip
    if whole.any():
        f = np.flatnonzero(whole)
        a = ax[:, f], ay[:, f], az[:, f]
        b = tuple(np.roll(c, -1, axis=0) for c in a)
        total[f] = terms(*a, *b, nx[f], ny[f], nz[f]).sum(axis=0)
    f = np.flatnonzero(~whole & up.any(axis=0))
    if len(f):
        m = nx[f], ny[f], nz[f]
        a = ax[:, f], ay[:, f], az[:, f]
        b = tuple(np.roll(c, -1, axis=0) for c in a)
        ha, ua = hgt[:, f], up[:, f]
        hb, ub = np.roll(ha, -1, axis=0), np.roll(ua, -1, axis=0)
        cross = ua != ub
        t = np.where(cross, ha / np.where(cross, ha - hb, 1.0), 0.0)
        x = tuple(ca + t * (cb - ca) for ca, cb in zip(a, b, strict=True))  # where an edge meets the horizon
        a2 = tuple(np.where(ua, ca, cx) for ca, cx in zip(a, x, strict=True))
        b2 = tuple(np.where(ub, cb, cx) for cb, cx in zip(b, x, strict=True))
        part = np.where(ua | ub, terms(*a2, *b2, *m), 0.0).sum(axis=0)
        # the closing edge along the horizon, from the exit point to the entry point
        cols = np.arange(len(f))
        ke, kn = (ua & ~ub).argmax(axis=0), (~ua & ub).argmax(axis=0)
        xe = tuple(c[ke, cols] for c in x)
        xn = tuple(c[kn, cols] for c in x)
        total[f] = part + terms(*xe, *xn, *m)
    return np.abs(total) / (2 * np.pi)


def unoccluded_irradiance(scene, points, normals, polys=None, *, per_polygon=False, chunk=1 << 19):
    """``C = π Σ_i L_i F_i^unocc`` at ``points, normals (m, 3)``, ``(m, 3)``: the emitting polygons among
    ``polys`` (default all), each lit from its front side, without occlusion. ``per_polygon``: the
    ``(m, n)`` form factors instead."""
    emits = (scene.poly_radiance != 0).any(axis=1)
    idx = np.flatnonzero(emits) if polys is None else np.asarray(polys)
    if per_polygon:
        idx = np.arange(scene.n_polygons)
    V = np.ascontiguousarray(scene.poly_vertices[idx].transpose(2, 1, 0))   # (3, K, n)
    pn, po, rad = scene.poly_normals[idx], scene.poly_offsets[idx], scene.poly_radiance[idx]
    centre, radius = scene.poly_centers[idx], scene.poly_radii[idx]
    nrm = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    m, k = len(points), len(idx)
    out = np.zeros((m, k) if per_polygon else (m, 3))
    if not k:
        return out
    step = max(1, chunk // k)
    for s in range(0, m, step):
        P, N = points[s:s + step], nrm[s:s + step]
        front = P @ pn.T - po > 0                                          # (q, k) the lit side
        above = np.einsum("qkc,qc->qk", centre[None] - P[:, None], N) + radius > 0
        qi, pi = np.nonzero(front & above)
        ff = unoccluded_form_factors(V[0][:, pi] - P[qi, 0], V[1][:, pi] - P[qi, 1], V[2][:, pi] - P[qi, 2],
                                     N[qi, 0], N[qi, 1], N[qi, 2])
        if per_polygon:
            out[s + qi, pi] = ff
            continue
        for c in range(3):
            out[s:s + step, c] = np.pi * np.bincount(qi, weights=ff * rad[pi, c], minlength=len(P))
    return out


def check_unoccluded(trials=20, seed=1):
    """Largest relative difference of :func:`unoccluded_irradiance` from ``core.irradiance`` for one
    random emitting parallelogram and random receivers and normals (clipping included)."""
    from hemisphere_local_pass.core import Scene, irradiance

    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(trials):
        c, a, b = rng.normal(size=(3, 3))
        s = Scene.from_polygons(np.array([c, c + a, c + a + b, c + b]), [[0, 1, 2, 3]],
                                radiance=rng.uniform(0.5, 2, size=(1, 3)))
        P, N = rng.normal(size=(200, 3)) * 2, rng.normal(size=(200, 3))
        ref = irradiance(s, P, N, workers=1)
        worst = max(worst, float(np.abs(unoccluded_irradiance(s, P, N) - ref).max() / ref.max()))
    return worst


def near_polygons(scene, pts, k):
    """Emitting polygons within ``k`` diameters of the bounding box of ``pts (q, 3)`` or whose plane
    crosses that box (the receivers' plane-crossing kinks)."""
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    ctr, half = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    near = np.linalg.norm(scene.poly_centers - ctr, axis=1) - scene.poly_radii - half < k * max(2 * half, 1e-9)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    side = corners @ scene.poly_normals.T - scene.poly_offsets                 # (8, n)
    eps = 1e-9 * float(np.abs(scene.poly_vertices).max())
    near |= (side.max(axis=0) > eps) & (side.min(axis=0) < -eps)
    return np.flatnonzero(near & (scene.poly_radiance != 0).any(axis=1))


def control_predictors(scene, p, n, g, H, key, size, controls, kind, coarse=16, visibility=None):
    """``{label: (predict, polygons in C per hit pixel)}`` for the oracle, one per control variate."""
    v = g >= 0
    h, w = g.shape
    out = {}
    for ctl in controls:
        if ctl == "all":
            path = CACHE / f"unocc_H_{key}_{scene.n_polygons}_{size}.npz"
            if path.exists():
                C = np.load(path)["C"]
            else:
                t = time.perf_counter()
                C = np.zeros_like(H)
                C[v] = unoccluded_irradiance(scene, p[v], n[v])
                np.savez(path, C=C, command="bench_adaptive_oracle.py --control all", seconds=time.perf_counter() - t)
            R = H - C

            def predict(x0, x1, y0, y1, R=R, C=C):
                val, smp = _interp(R, x0, x1, y0, y1, kind)
                return val + C[y0:y1 + 1, x0:x1 + 1], smp
            out["H − C (all)"] = (predict, float(((scene.poly_radiance != 0).any(axis=1)).sum()))
            continue
        k = float(ctl)
        cells, count = {}, [0, 0]

        def cell_c(X, Y, k=k, cells=cells, count=count):
            if (X, Y) not in cells:
                X1, Y1 = min(X + coarse, w - 1), min(Y + coarse, h - 1)
                blk = (slice(Y, Y1 + 1), slice(X, X1 + 1))
                vv = v[blk]
                C = np.zeros(vv.shape + (3,))
                if vv.any():
                    polys = near_polygons(scene, p[blk][vv], k)
                    C[vv] = unoccluded_irradiance(scene, p[blk][vv], n[blk][vv], polys)
                    count[0] += len(polys) * int(vv.sum())
                    count[1] += int(vv.sum())
                cells[X, Y] = C
            return cells[X, Y]

        def predict(x0, x1, y0, y1, cell_c=cell_c):
            X, Y = x0 // coarse * coarse, y0 // coarse * coarse
            C = cell_c(X, Y)[y0 - Y:y1 - Y + 1, x0 - X:x1 - X + 1]
            val, smp = _interp(H[y0:y1 + 1, x0:x1 + 1] - C, 0, x1 - x0, 0, y1 - y0, kind)
            return val + C, [(y0 + a, x0 + b) for a, b in smp]
        for Y in range(0, h - 1, coarse):  # every cell's C, for the polygon count
            for X in range(0, w - 1, coarse):
                cell_c(X, Y)
        out[f"H − C (near {k:g})"] = (predict, count[0] / max(count[1], 1))
    if visibility is not None:
        F, U = visibility                                   # (hit, n) occluded / unoccluded form factors
        nn = scene.n_polygons
        ratio = np.ones((h, w, nn), np.float32)
        unocc = np.zeros((h, w, nn), np.float32)
        ratio[v] = np.where(U > 0, F / np.where(U > 0, U, 1), 1.0)
        unocc[v] = U
        piL = np.pi * scene.poly_radiance

        def predict(x0, x1, y0, y1):
            val, smp = _interp(ratio, x0, x1, y0, y1, kind)
            return (unocc[y0:y1 + 1, x0:x1 + 1].astype(np.float64) * val) @ piL, smp
        out["V interpolated"] = (predict, float(nn))
    return out


def visibility_tables(scene, p, n, g, key, size):
    """Per hit pixel and polygon: occluded ``F`` (``core.form_factors``, lit side only) and unoccluded
    ``U``, float32, cached."""
    from hemisphere_local_pass.core import form_factors

    path = CACHE / f"visibility_{key}_{scene.n_polygons}_{size}.npz"
    if path.exists():
        z = np.load(path)
        return z["F"], z["U"]
    v = g >= 0
    U = unoccluded_irradiance(scene, p[v], n[v], per_polygon=True)
    F = np.where(U > 0, form_factors(scene, p[v], n[v], workers=1), 0.0)
    np.savez(path, F=F.astype(np.float32), U=U.astype(np.float32))
    return F.astype(np.float32), U.astype(np.float32)


def control_cost(scene, p, n, g, samples=400, seed=0):
    """Seconds per pixel of C (all polygons) and of the exact core, side by side (workers=1)."""
    from hemisphere_local_pass.core import irradiance

    v = g >= 0
    i = np.random.default_rng(seed).choice(int(v.sum()), min(samples, int(v.sum())), replace=False)
    P, N = p[v][i], n[v][i]
    irradiance(scene, P[:32], N[:32], workers=1)         # the scene's caches, outside the timing
    t_c = t_e = np.inf
    for _ in range(2):
        t = time.perf_counter()
        irradiance(scene, P, N, workers=1)
        t_e = min(t_e, time.perf_counter() - t)
        t = time.perf_counter()
        unoccluded_irradiance(scene, P, N)
        t_c = min(t_c, time.perf_counter() - t)
    return t_c / len(P), t_e / len(P)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="small")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--rel", default="1e-2,1e-3")
    ap.add_argument("--control", default="", help="control variates: 'all' and/or near-polygon factors k")
    ap.add_argument("--visibility", action="store_true", help="also the interpolated visibility ratios")
    ap.add_argument("--no-replay", action="store_true", help="skip the replay and the first table")
    ap.add_argument("--estimates", action="store_true",
                    help="also the quadtree deciding from the samples: bilinear with its estimate, biquadratic with "
                         "|biquad9 - bilin9|")
    ap.add_argument("--neighbour", action="store_true",
                    help="also the replay without and with the spot check extended beyond the cell (neighbour_check)")
    ap.add_argument("--world", action="store_true",
                    help="also the oracle of the bilinear interpolants in world coordinates (perspective-correct)")
    args = ap.parse_args(argv)
    scene, p, n, g, H = reference(args.scene, args.size)
    hit = g >= 0
    mean = float(H[hit].mean())
    rels = [float(r) for r in args.rel.split(",")]
    print(f"{args.scene} box ({scene.n_input} polygons), {args.size}²; exact evaluations per hit pixel\n")
    if not args.no_replay:
        print("| tol / mean H | isotropic (before) | anisotropic (now) | max error / tol (iso / aniso) "
              "| oracle floor | oracle bilin4 | oracle bilin9 | oracle biquad9 |")
        print("|---|---|---|---|---|---|---|---|")
        for rel in rels:
            tol = rel * mean
            row = []
            errs = []
            for aniso in (False, True):
                img, st = replay(scene, p, n, g, H, tol, anisotropic=aniso)
                row.append(f"{st.exact_fraction:.1%}")
                errs.append(f"{np.abs(img - H).max() / tol:.2f}")
            orc = [f"{oracle(scene, p, n, g, H, tol, k):.1%}" for k in ("floor", "bilin4", "bilin9", "biquad9")]
            print(f"| {rel:g} | {row[0]} | {row[1]} | {' / '.join(errs)} | " + " | ".join(orc) + " |", flush=True)
    if args.neighbour:
        print("\nthe replay without / with the spot check extended beyond the cell (neighbour_check; anisotropic):\n")
        print("| tol / mean H | exact, without | exact, with (now) | max error / tol, without | with | "
              "pixels over tol, without | with |")
        print("|---|---|---|---|---|---|---|")
        for rel in rels:
            tol = rel * mean
            fr, mx, over = [], [], []
            for on in (False, True):
                img, st = replay(scene, p, n, g, H, tol, neighbour_check=on)
                e = np.abs(img - H).max(axis=2) / tol
                fr.append(f"{st.exact_fraction:.1%}")
                mx.append(f"{e.max():.3f}")
                over.append(str(int((e > 1.0).sum())))
            print(f"| {rel:g} | {fr[0]} | {fr[1]} | {mx[0]} | {mx[1]} | {over[0]} | {over[1]} |", flush=True)
    if args.world:
        img, wld, cells = world_check(scene, p, n, g)
        print(f"\nan affine function of the hit point over {cells} uniform coarse cells, largest miss over its range: "
              f"image-space bilin9 {img:.2e}, world-space {wld:.2e}\n")
        print("| tol / mean H | oracle bilin4 | oracle wbilin4 | oracle bilin9 | oracle wbilin9 |")
        print("|---|---|---|---|---|")
        for rel in rels:
            tol = rel * mean
            cols = [f"{oracle(scene, p, n, g, H, tol, k):.1%}" for k in ("bilin4", "wbilin4", "bilin9", "wbilin9")]
            print(f"| {rel:g} | " + " | ".join(cols) + " |", flush=True)
    if args.estimates:
        print("\nquadtree deciding from the samples (uniform cells, isotropic, no shadow test): true error over the "
              "estimate, cells >= 4 px with a true error above 0.1 tol (inside / at a break or border), and exact "
              "evaluations per hit pixel (max error / tol) for factors inside / at breaks\n")
        configs = (("bilin", 2, 4), ("biquad", 1, 2), ("biquad", 2, 4), ("biquad", 7, 14))
        print("| tol / mean H | bilin9: true / d, max (p99) | biquad9: true / est, max (p99) | "
              + " | ".join(f"{m} {a}/{b}" for m, a, b in configs) + " |")
        print("|---|---|---|" + "---|" * len(configs))
        for rel in rels:
            tol = rel * mean
            cols = []
            for mode in ("bilin", "biquad"):
                rat = []
                estimate_quadtree(scene, p, n, g, H, tol, mode, 0.0, 0.0, ratios=rat)
                r = np.array([x[0] for x in rat])
                e = np.array([x[1] for x in rat])
                big = np.array([x[2] for x in rat]) > 0.1 * tol
                cols.append(" / ".join(f"{r[big & m].max():.2f} ({np.percentile(r[big & m], 99):.2f})"
                                       for m in (~e, e)))
            for mode, a, b in configs:
                frac, err = estimate_quadtree(scene, p, n, g, H, tol, mode, a, b)
                cols.append(f"{frac:.1%} ({err:.2f})")
            print(f"| {rel:g} | " + " | ".join(cols) + " |", flush=True)
    controls = [c for c in args.control.split(",") if c]
    if not controls and not args.visibility:
        return
    print(f"\nunoccluded C against core.irradiance, one polygon, random receivers: largest relative "
          f"difference {check_unoccluded():.1e}")
    t_c, t_e = control_cost(scene, p, n, g)
    print(f"cost per pixel (workers=1, side by side, load {' '.join(f'{x:.2f}' for x in os.getloadavg())}): "
          f"C over all {scene.n_polygons} polygons {t_c * 1e3:.3f} ms, exact core {t_e * 1e3:.3f} ms: "
          f"C costs {t_c / t_e:.2f} exact evaluations\n")
    vis = visibility_tables(scene, p, n, g, args.scene, args.size) if args.visibility else None
    for kind in ("bilin9", "biquad9"):
        preds = control_predictors(scene, p, n, g, H, args.scene, args.size, controls, kind, visibility=vis)
        print(f"oracle {kind}: exact evaluations per hit pixel (polygons in C per pixel)\n")
        print("| tol / mean H | H (no C) | " + " | ".join(f"{k} ({c:.0f})" for k, (_, c) in preds.items()) + " |")
        print("|---|---|" + "---|" * len(preds))
        for rel in rels:
            tol = rel * mean
            cols = [f"{oracle(scene, p, n, g, H, tol, kind):.1%}"]
            cols += [f"{oracle(scene, p, n, g, H, tol, kind, predict=f):.1%}" for f, _ in preds.values()]
            print(f"| {rel:g} | " + " | ".join(cols) + " |", flush=True)
        print()


if __name__ == "__main__":
    main()
