"""Receivers outside a big convex solid (issue 10): per point time and traced peak memory.

A closed UV sphere (exact poles, so it is one convex solid; faces outward, radiance 0.5) and
``--points`` receivers at 3 r facing its centre. Per receiver the solid's volume has a plane per face
facing P plus one per silhouette edge (~1/3 of the faces). *apart*: the wide volume stored apart
(:class:`.visibility.ShadowVolumes` ``wide_*``, the default); *padded*: the same volumes with every
face volume padded to the solid's width, as before (the layout of ``test_wide_solids._padded``; the
pair tests then see one array); *dense*: apart, with the wide volume's pair tests over every plane
(``visibility.WIDE_GROUPS = False``) instead of through its bounding tree (``_PlaneTree``; from
``WIDE_TREE_MIN`` planes on). Alternating per receiver in one process; max |ΔH| apart/padded, and
whether apart and dense are bit for bit equal.

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_wide_solids.py [--faces 512,2048,8192]
        [--points 3] [--padded-max 8192]

Figures: docs/bench_unmerged.md.
"""

from __future__ import annotations

import argparse
import sys
import time
import tracemalloc

import numpy as np
from _common import ROOT

sys.path.insert(0, str(ROOT / "tests" / "core"))

from test_wide_solids import _padded  # noqa: E402

from hemisphere_local_pass.core import Scene, chunk, irradiance, visibility  # noqa: E402
from hemisphere_local_pass.core.chunk import prepare_scene  # noqa: E402
from hemisphere_local_pass.scenes import uv_sphere  # noqa: E402


def _padded_volumes(*a, **k):
    sv, table = visibility.shadow_volumes(*a, **k)
    return (_padded(sv)[0] if sv.wide_row is not None else sv), table


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--faces", default="512,2048,8192")
    ap.add_argument("--points", type=int, default=3)
    ap.add_argument("--padded-max", type=int, default=8192)
    a = ap.parse_args()
    print(f"load average {open('/proc/loadavg').read().split()[:3]}")
    print(f"{'faces':>6} {'prep s':>6} {'planes':>6} {'ms/pt apart':>11} {'ms/pt padded':>12} {'peak apart':>10} "
          f"{'peak padded':>11} {'max|dH|':>8} {'ms/pt dense':>11} {'dense/apart':>11} {'H same':>6}")
    for f in (int(x) for x in a.faces.split(",")):
        nu = int(round(np.sqrt(2 * f)))
        v, p = uv_sphere(nu, nu // 2)
        v = np.asarray(v, dtype=np.float64).copy()
        v[np.abs(v) < 1e-12] = 0.0
        sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
        t = time.perf_counter()
        occ = prepare_scene(sc)
        prep = time.perf_counter() - t
        d = np.random.default_rng(1).normal(size=(a.points, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        pts, nrm = 3.0 * d, -d
        sv, _ = visibility.shadow_volumes(occ, pts[:1], nrm[:1])
        planes = sv.n_planes
        irradiance(sc, pts[:1], nrm[:1], workers=1)                    # warm up
        modes = [("apart", visibility.shadow_volumes), ("dense", visibility.shadow_volumes)] + (
            [("padded", _padded_volumes)] if f <= a.padded_max else [])
        res = {m: [0.0, 0, []] for m, _ in modes}
        for i in range(a.points):
            for m, fn in modes:
                chunk.shadow_volumes = fn
                visibility.WIDE_GROUPS = m != "dense"
                tracemalloc.start()
                t = time.perf_counter()
                h = irradiance(sc, pts[i:i + 1], nrm[i:i + 1], workers=1)
                res[m][0] += time.perf_counter() - t
                res[m][1] = max(res[m][1], tracemalloc.get_traced_memory()[1])
                tracemalloc.stop()
                res[m][2].append(h)
        chunk.shadow_volumes = visibility.shadow_volumes
        visibility.WIDE_GROUPS = True
        ap_, pd, de = res["apart"], res.get("padded"), res["dense"]
        same = np.array_equal(np.array(ap_[2]), np.array(de[2]))
        dh = "-" if pd is None else f"{np.abs(np.array(ap_[2]) - np.array(pd[2])).max():.1e}"
        print(f"{sc.n_polygons:>6} {prep:6.2f} {planes:>6} {ap_[0] / a.points * 1e3:11.1f} "
              f"{'-' if pd is None else f'{pd[0] / a.points * 1e3:.1f}':>12} {ap_[1] / 1e6:9.1f}M "
              f"{'-' if pd is None else f'{pd[1] / 1e6:.1f}M':>11} {dh:>8} {de[0] / a.points * 1e3:11.1f} "
              f"{de[0] / ap_[0]:11.2f} {str(same):>6}", flush=True)


if __name__ == "__main__":
    main()
