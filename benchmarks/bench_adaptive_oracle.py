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
  quadratic through them.

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_oracle.py --scene small --size 256
    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_oracle.py --scene large --size 128
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
    val = np.empty(u.shape[:2] + (3,))   # bilin9: bilinear over the four sub-cells
    for xa, xb in ((x0, mx), (mx, x1)):
        for ya, yb in ((y0, my), (my, y1)):
            sl = (slice(ya - y0, yb - y0 + 1), slice(xa - x0, xb - x0 + 1))
            uu = ((xs[sl] - xa) / max(xb - xa, 1))[..., None]
            vv = ((ys[sl] - ya) / max(yb - ya, 1))[..., None]
            val[sl] = (1 - vv) * ((1 - uu) * H[ya, xa] + uu * H[ya, xb]) + vv * ((1 - uu) * H[yb, xa] + uu * H[yb, xb])
    return val, samples


def oracle(scene, p, n, g, H, tol, kind, coarse=16):
    """Exact evaluations per hit pixel of the quadtree that accepts a cell when its true error <= tol."""
    import hemisphere_local_pass.core.adaptive as ad

    valid = g >= 0
    plane = np.where(valid, ad._input_planes(scene)[np.maximum(g, 0)], -1)
    unit = n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-300)
    cj = np.cos(ad.NORMAL_JUMP)
    bx = ~(valid[:, :-1] & valid[:, 1:] & (plane[:, :-1] == plane[:, 1:])
           & (np.einsum("hwc,hwc->hw", unit[:, :-1], unit[:, 1:]) >= cj))
    by = ~(valid[:-1] & valid[1:] & (plane[:-1] == plane[1:])
           & (np.einsum("hwc,hwc->hw", unit[:-1], unit[1:]) >= cj))
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
            val, samples = _interp(H, x0, x1, y0, y1, kind)
            if kind == "floor" or np.abs(val - H[y0:y1 + 1, x0:x1 + 1]).max() <= tol:
                for yy, xx in samples:
                    exact[yy, xx] = True
                continue
        mx, my = (x0 + x1) // 2, (y0 + y1) // 2
        xs = [(x0, mx), (mx, x1)] if x1 - x0 >= 2 else [(x0, x1)]
        ys = [(y0, my), (my, y1)] if y1 - y0 >= 2 else [(y0, y1)]
        stack += [(a, b, c, d) for a, b in xs for c, d in ys]
    return exact.sum() / valid.sum()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="small")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--rel", default="1e-2,1e-3")
    args = ap.parse_args(argv)
    scene, p, n, g, H = reference(args.scene, args.size)
    hit = g >= 0
    mean = float(H[hit].mean())
    print(f"{args.scene} box ({scene.n_input} polygons), {args.size}²; exact evaluations per hit pixel\n")
    print("| tol / mean H | isotropic (before) | anisotropic (now) | max error / tol (iso / aniso) "
          "| oracle floor | oracle bilin4 | oracle bilin9 | oracle biquad9 |")
    print("|---|---|---|---|---|---|---|---|")
    for rel in (float(r) for r in args.rel.split(",")):
        tol = rel * mean
        row = []
        errs = []
        for aniso in (False, True):
            img, st = replay(scene, p, n, g, H, tol, anisotropic=aniso)
            row.append(f"{st.exact_fraction:.1%}")
            errs.append(f"{np.abs(img - H).max() / tol:.2f}")
        orc = [f"{oracle(scene, p, n, g, H, tol, k):.1%}" for k in ("floor", "bilin4", "bilin9", "biquad9")]
        print(f"| {rel:g} | {row[0]} | {row[1]} | {' / '.join(errs)} | " + " | ".join(orc) + " |", flush=True)


if __name__ == "__main__":
    main()
