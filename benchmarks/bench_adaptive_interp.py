"""Which interpolation lets the adaptive pass evaluate fewest pixels exactly (issue 11, sec. 2)?

Step 1 (``--reference``): the all-exact image H and the exact gradients dH/dP at every hit pixel of the
benchmark Cornell boxes (the scenes of ``bench_time_vs_error.py``), cached in ``HLP_CACHE``, and the
measured cost ratio gradient/irradiance (side by side on the same pixels, one process).
Step 2: the quadtree of ``core/adaptive.py`` (same coarse cells, the same forced surface and shadow
splits, the same spot checks) replayed on the cached values with different interpolants and estimates;
each variant's error is measured against the all-exact image. Cost = exact evaluations + ratio x
gradient evaluations.

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_interp.py --size 96
    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_interp.py --size 128 --scenes small

The replay reproduces ``adaptive_irradiance``'s exact count and max error bit for bit for the current
method (checked: 96² small box, 1e-2 and 1e-3). Figures and the reading in docs/adaptive.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CACHE, log  # noqa: E402


def reference(key, size):
    from bench_time_vs_error import prepare

    from hemisphere_local_pass.core import irradiance, irradiance_gradient

    path = CACHE / f"interp_ref_{key}_{size}.npz"
    box, lum, scene, (p, n, g), *_ = prepare(key, size)
    if path.exists():
        d = np.load(path)
        return scene, (p, n, g), d["H"], d["G"], float(d["ratio"])
    valid = g >= 0
    t = time.perf_counter()
    Hv = irradiance(scene, p[valid], n[valid])
    te = time.perf_counter() - t
    t = time.perf_counter()
    Gv = irradiance_gradient(scene, p[valid], n[valid])
    tg = time.perf_counter() - t
    H = np.zeros(p.shape)
    G = np.zeros(p.shape + (3,))
    H[valid], G[valid] = Hv, Gv
    ratio = tg / te
    log(f"[ref] {key} {size}²: exact {te:.1f} s, gradient {tg:.1f} s, ratio {ratio:.2f}")
    np.savez(path, H=H, G=G, ratio=ratio)
    return scene, (p, n, g), H, G, ratio



def replay(scene, inputs, H_ref, G_ref, tol, variant, inner, edge, grad_min=0, coarse=16):
    """The quadtree of ``adaptive_irradiance`` on cached exact values. ``variant``: "bilinear" (the
    current method), "hermite" (first-order Taylor from the four exact corners with their gradients,
    blended bilinearly, plus the biquadratic correction through the five spot checks; the estimate is
    the Taylor blend's largest miss at the spot checks) — for cells of at least ``grad_min`` pixels a
    side, bilinear below. Returns (H, exact mask, gradient mask, per-cell (true error, raw d, edge))."""
    from hemisphere_local_pass.core import adaptive as ad

    p, n, g = inputs
    h, w = g.shape
    valid = g >= 0
    H = np.zeros((h, w, 3))
    exact = np.zeros((h, w), bool)
    grad = np.zeros((h, w), bool)

    def evaluate(ys, xs):
        ok = valid[ys, xs]
        exact[ys[ok], xs[ok]] = True
        H[ys[ok], xs[ok]] = H_ref[ys[ok], xs[ok]]

    def gradients(ys, xs):
        ok = valid[ys, xs]
        grad[ys[ok], xs[ok]] = True

    unit = n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-300)
    tx, ty = (ad._summed(b) for b in ad._surface_breaks(scene, unit, g))

    def uniform(x0, x1, y0, y1):
        return ad._uniform(valid, tx, ty, x0, x1, y0, y1)

    lights = [lg for lg in ad.light_groups(scene) if np.pi * lg["radiance"] > tol]
    bvh = ad.build_bvh(scene) if lights else None
    eps = 1e-9 * float(np.abs(scene.poly_vertices).max())

    def nodes(size):
        v = np.unique(np.concatenate([np.arange(0, size, coarse), [size - 1]]))
        return v[:-1], v[1:]

    X0, Y0 = np.meshgrid(*[nodes(w)[0], nodes(h)[0]])
    X1, Y1 = np.meshgrid(*[nodes(w)[1], nodes(h)[1]])
    cells = [a.reshape(-1) for a in (X0, X1, Y0, Y1)]
    out = np.zeros((h, w, 3))
    done = np.zeros((h, w), bool)
    cellrec = []

    def taylor(ys, xs, cy, cx, wts):
        """(k, 3) first-order Taylor blend at pixels (ys, xs) from corners (cy, cx) (k, 4), weights (k, 4)."""
        d = p[ys, xs][:, None, :] - p[cy, cx]                          # (k, 4, 3)
        t = H[cy, cx] + np.einsum("kjca,kja->kjc", G_ref[cy, cx], d)     # (k, 4, 3)
        return (wts[..., None] * t).sum(axis=1)

    def interp(x0, x1, y0, y1, mx, my, ys, xs, use_h):
        """Interpolant of the accepted cells at pixels (one cell index per pixel via arrays)."""
        u = (xs - x0) / np.maximum(x1 - x0, 1)
        v = (ys - y0) / np.maximum(y1 - y0, 1)
        wts = np.stack([(1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v], axis=1)
        cy = np.stack([y0, y0, y1, y1], axis=1)
        cx = np.stack([x0, x1, x0, x1], axis=1)
        base = np.where(use_h[:, None], taylor(ys, xs, cy, cx, wts) if use_h.any() else 0.0,
                        (wts[..., None] * H[cy, cx]).sum(axis=1))
        return base, wts, u, v

    while len(cells[0]):
        x0, x1, y0, y1 = cells
        evaluate(np.concatenate([y0, y0, y1, y1]), np.concatenate([x0, x1, x0, x1]))
        small = (x1 - x0 <= 1) & (y1 - y0 <= 1)
        mx, my = (x0 + x1) // 2, (y0 + y1) // 2
        ok = ~small & uniform(x0, x1, y0, y1)
        split = ~small & ~ok
        if lights and ok.any():
            i = np.flatnonzero(ok)
            quads = np.stack([p[y0[i], x0[i]], p[y0[i], x1[i]], p[y1[i], x1[i]], p[y1[i], x0[i]]], axis=1)
            sh = ad._shadow_cells(scene, bvh, lights, quads, unit[y0[i], x0[i]], eps)
            ok[i[sh]] = False
            split[i[sh]] = True
        i = np.flatnonzero(ok)
        if len(i):
            size = np.maximum(x1 - x0, y1 - y0)[i]
            use_h = np.full(len(i), variant == "hermite") & (size >= grad_min)
            hi = i[use_h]
            gradients(np.concatenate([y0[hi], y0[hi], y1[hi], y1[hi]]),
                      np.concatenate([x0[hi], x1[hi], x0[hi], x1[hi]]))
            cx = np.stack([mx[i], mx[i], x0[i], x1[i], mx[i]], axis=1)
            cy = np.stack([y0[i], y1[i], my[i], my[i], my[i]], axis=1)
            evaluate(cy.reshape(-1), cx.reshape(-1))
            x0r, x1r, y0r, y1r = (np.repeat(a[i], 5) for a in (x0, x1, y0, y1))
            base, _, _, _ = interp(x0r, x1r, y0r, y1r, None, None, cy.reshape(-1),
                                   cx.reshape(-1), np.repeat(use_h, 5))
            res = (H[cy, cx] - base.reshape(-1, 5, 3))                   # (c, 5, 3)
            d = np.abs(res).max(axis=(1, 2))
            e = ad._touches_break(tx, ty, x0[i], x1[i], y0[i], y1[i], w, h)
            est = d * np.where(e, edge, inner)
            good = est <= tol
            split[i[~good]] = True
            a = np.flatnonzero(good)
            # fill the accepted cells: base + biquadratic correction through the spot-check residuals
            # (hermite), or bilinear over the four sub-cells (bilinear: the current method)
            for k in a:
                c = i[k]
                ys, xs = np.mgrid[y0[c]:y1[c] + 1, x0[c]:x1[c] + 1]
                ys, xs = ys.reshape(-1), xs.reshape(-1)
                m = len(ys)
                if use_h[k] or variant == "biquadratic":
                    b, _, u, v = interp(np.full(m, x0[c]), np.full(m, x1[c]), np.full(m, y0[c]), np.full(m, y1[c]),
                                        None, None, ys, xs, np.full(m, bool(use_h[k])))
                    # quadratic Lagrange in u with nodes 0, .5, 1 (mid node weight 4u(1-u)); corner residual 0
                    lu0, lu1, lu2 = 2 * (u - .5) * (u - 1), 4 * u * (1 - u), 2 * u * (u - .5)
                    lv0, lv1, lv2 = 2 * (v - .5) * (v - 1), 4 * v * (1 - v), 2 * v * (v - .5)
                    r = res[k]  # order: (mx,y0), (mx,y1), (x0,my), (x1,my), (mx,my)
                    corr = ((lu1 * lv0)[:, None] * r[0] + (lu1 * lv2)[:, None] * r[1] + (lu0 * lv1)[:, None] * r[2]
                            + (lu2 * lv1)[:, None] * r[3] + (lu1 * lv1)[:, None] * r[4])
                    val = b + corr
                else:
                    val = np.empty((m, 3))
                    for xa, xb, ya, yb in ((x0[c], mx[c], y0[c], my[c]), (mx[c], x1[c], y0[c], my[c]),
                                           (x0[c], mx[c], my[c], y1[c]), (mx[c], x1[c], my[c], y1[c])):
                        sel = (xs >= xa) & (xs <= xb) & (ys >= ya) & (ys <= yb)
                        uu = ((xs[sel] - xa) / max(xb - xa, 1))[:, None]
                        vv = ((ys[sel] - ya) / max(yb - ya, 1))[:, None]
                        val[sel] = ((1 - vv) * ((1 - uu) * H[ya, xa] + uu * H[ya, xb])
                                    + vv * ((1 - uu) * H[yb, xa] + uu * H[yb, xb]))
                out[ys, xs] = val
                done[ys, xs] = True
                tru = np.abs(val - H_ref[ys, xs])[valid[ys, xs]].max(initial=0.0)
                cellrec.append((tru, d[k], bool(e[k])))
        s = np.flatnonzero(split)
        kids = [[], [], [], []]
        for xa, xb, ya, yb, need in ((x0, mx, y0, my, ""), (mx, x1, y0, my, "x"), (x0, mx, my, y1, "y"),
                                     (mx, x1, my, y1, "xy")):
            m = np.ones(len(s), bool)
            if "x" in need:
                m &= x1[s] - x0[s] >= 2
            if "y" in need:
                m &= y1[s] - y0[s] >= 2
            sel = s[m]
            for lst, arr in zip(kids, (xa[sel], np.where(x1[sel] - x0[sel] >= 2, xb[sel], x1[sel]), ya[sel],
                                       np.where(y1[sel] - y0[sel] >= 2, yb[sel], y1[sel])), strict=True):
                lst.append(arr)
        cells = [np.concatenate(k) for k in kids]
    # later (smaller) accepted cells never overlap earlier ones except on shared exact samples
    final = np.where(exact[..., None], H_ref, out)
    final[~valid] = 0.0
    return final, exact, grad, np.array(cellrec).reshape(-1, 3)


VARIANTS = {  # name: (variant, inner factor, edge factor, gradients only for cells >= this side)
    "bilinear 2/4 (current)": ("bilinear", 2.0, 4.0, 0),
    "biquadratic 1/2": ("biquadratic", 1.0, 2.0, 0),
    "hermite 2/4": ("hermite", 2.0, 4.0, 0),
    "hermite 1/2": ("hermite", 1.0, 2.0, 0),
    "hermite 2/4, cells >= 8": ("hermite", 2.0, 4.0, 8),
}


def compare(keys, size, tols, variants):
    rows = []
    for key in keys:
        scene, inputs, H_ref, G_ref, ratio = reference(key, size)
        hit = inputs[2] >= 0
        mean = float(H_ref[hit].mean())
        for rel in tols:
            for name, (var, fi, fe, gmin) in variants.items():
                t = time.perf_counter()
                Hs, ex, gr, rec = replay(scene, inputs, H_ref, G_ref, rel * mean, var, fi, fe, gmin)
                err = float(np.abs(Hs - H_ref)[hit].max()) / (rel * mean)
                ne, ng = int(ex.sum()), int(gr.sum())
                ri = rec[~rec[:, 2].astype(bool)]
                re_ = rec[rec[:, 2].astype(bool)]
                q = lambda r: float((r[:, 0] / np.maximum(r[:, 1], 1e-300)).max()) if len(r) else 0.0  # noqa: E731
                rows.append((key, rel, name, ne / hit.sum(), ng / hit.sum(), (ne + ratio * ng) / hit.sum(), err,
                             q(ri), q(re_)))
                log(f"{key:5s} {rel:.0e} {name:28s} exact {ne / hit.sum():6.1%} grad {ng / hit.sum():6.1%} "
                    f"cost {(ne + ratio * ng) / hit.sum():6.1%} (ratio {ratio:.2f}) max err/tol {err:5.2f} "
                    f"true/d inner {q(ri):.2f} edge {q(re_):.2f}  [{time.perf_counter() - t:.1f} s]")
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--scenes", default="small,large")
    a = ap.parse_args()
    compare(a.scenes.split(","), a.size, [1e-2, 1e-3], VARIANTS)
