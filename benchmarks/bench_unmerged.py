"""A scene whose polygons do not merge (issue 10 part 2): a UV sphere facing inward, receivers inside
facing the centre (radiance 0.5 everywhere: H = π/2 exactly).

Every face of a sphere is in its own plane, so every face is a merged face (occluder) of its own. Inside a
convex sphere nothing hides anything, so the exact answer should be cheap; the level-1 culling
(:func:`.visibility.coverage`) used to build dense (face instances × volumes) tables per chunk, i.e.
receivers × n_o² (2,048 faces: 5.6 GB peak for 64 points; 8,192 faces: out of memory on 24 GB). It now
takes its pairs from the scene's sparse lists (:class:`.culling.VolumePairs`).

Each face count runs in a fresh subprocess (peak RSS is per process): the preparation, then the
irradiance with the sparse pairs, then (up to ``--dense-max`` faces) with the dense ones as before
(``visibility.DENSE_COVERAGE``), interleaved in one process for the time ratio; the peak RSS after
each step (monotone: the sparse run comes first) and max |ΔH| between the two.

    OMP_NUM_THREADS=1 python benchmarks/bench_unmerged.py [--faces 512,2048,8192] [--points 32] [--dense-max 2048]
        [--outside]   (receivers at 3 r facing an outward sphere: front faces hide back faces)

Measured 2026-12-02 00:22-00:33 UTC, load average 14 on 2 cores (absolute times ~5x a quiet machine's;
the old/new ratio is side by side in one process), 32 points:

     faces  prep s  prep RSS  ms/pt new  RSS new  ms/pt old  RSS old  old/new  max|dH|  |H-pi/2|
       512     0.9       71M       10.5      71M       52.6     224M     5.0x        0   1.6e-15
      2048    21.6      146M       31.9     146M     1998.3    2850M    62.7x        0   3.3e-15
      8192   375.9      792M      350.1     792M   (out of memory on 24 GB)                5.1e-15

``--outside`` (00:46-00:51 UTC, load 10-12; 8 and 4 points): front faces hide back faces, so level 1
has ~n_o²/4 real pairs per receiver (tested a block at a time now) and the clipping is real work:

       512     1.6       71M      186.1      71M      323.9     101M     1.7x        0   1.5e-03
      2048    21.3      146M     1646.4     146M     3342.9     492M     2.0x        0   4.0e-04

The preparation is still O(n_o²) in time and memory for such a scene (the pair tables are dense
relations there: every face is beyond every other face's plane), now as bits and uint16 lists; the
per-point cost is O(n_o) per receiver (shadow volumes, clear tiles, the hierarchy's roots).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np
from _common import ROOT

from hemisphere_local_pass.scenes import uv_sphere


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def one(faces: int, points: int, tables: bool, outside: bool = False) -> dict:
    from hemisphere_local_pass.core import Scene, culling, irradiance
    from hemisphere_local_pass.core.chunk import prepare_scene

    culling.PER_PAIR_DEPTH_FROM = None if tables else 0
    nu = int(round(np.sqrt(2 * faces)))
    v, p = uv_sphere(nu, nu // 2)
    if not outside:
        p = [f[::-1] for f in p]              # facing inward, as a room: the receivers see the fronts
    sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
    t = time.perf_counter()
    occ = prepare_scene(sc)
    out = {"faces": sc.n_polygons, "merged": int(len(occ.counts)), "prep_s": time.perf_counter() - t,
           "prep_rss_mb": rss_mb(), "points": points, "per_pair": occ.depth is not None}
    d = np.random.default_rng(1).normal(size=(points, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts, nrm = (3.0 if outside else 0.9) * d, -d
    t = time.perf_counter()
    h = irradiance(sc, pts, nrm, workers=1)
    out["ms"] = (time.perf_counter() - t) / points * 1e3
    out["rss_mb"] = rss_mb()
    out["H"] = h.tolist()
    # inside, closed, radiance 0.5: H = pi/2; outside, facing the centre at 3 r: H ~ pi/2 (1/3)^2 (a round
    # sphere's; the faceted one is a little smaller)
    out["H_err"] = float(np.abs(h - 0.5 * np.pi / (9.0 if outside else 1.0)).max())
    return out


def run(faces, points, tables, outside):
    cmd = [sys.executable, __file__, "--one", str(faces), "--points", str(points)] + (
        ["--tables"] if tables else []) + (["--outside"] if outside else [])
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if r.returncode:
        return {"error": (r.stderr.strip().splitlines() or ["?"])[-1]}
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--faces", default="512,2048,8192,32768")
    ap.add_argument("--points", type=int, default=32)
    ap.add_argument("--old-max", type=int, default=8192, help="largest face count also run with the tables")
    ap.add_argument("--outside", action="store_true", help="receivers outside the sphere, facing it (at 3 r)")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--tables", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one, a.points, a.tables, a.outside)))
        return
    print(f"load average {open('/proc/loadavg').read().split()[:3]}; receivers {'outside' if a.outside else 'inside'}")
    print(f"{'faces':>6} {'prep s old':>10} {'prep s new':>10} {'old/new':>7} {'prepRSS old':>11} {'prepRSS new':>11} "
          f"{'ms/pt old':>9} {'ms/pt new':>9} {'RSS new':>8} {'max|dH|':>8} {'|H-ref|':>8}")
    for f in (int(x) for x in a.faces.split(",")):
        new = run(f, a.points, False, a.outside)
        old = run(f, a.points, True, a.outside) if f <= a.old_max else None
        if "error" in new:
            print(f"{f:>6} failed: {new['error']}")
            continue
        if old is None or "error" in old:
            why = "-" if old is None else "failed"
            print(f"{new['faces']:>6} {why:>10} {new['prep_s']:10.2f} {'-':>7} {'-':>11} {new['prep_rss_mb']:10.0f}M "
                  f"{'-':>9} {new['ms']:9.1f} {new['rss_mb']:7.0f}M {'-':>8} {new['H_err']:8.1e}", flush=True)
            continue
        dh = float(np.abs(np.array(new["H"]) - np.array(old["H"])).max())
        print(f"{new['faces']:>6} {old['prep_s']:10.2f} {new['prep_s']:10.2f} {old['prep_s'] / new['prep_s']:6.1f}x "
              f"{old['prep_rss_mb']:10.0f}M {new['prep_rss_mb']:10.0f}M {old['ms']:9.1f} {new['ms']:9.1f} "
              f"{new['rss_mb']:7.0f}M {dh:8.1e} {new['H_err']:8.1e}", flush=True)


if __name__ == "__main__":
    main()
