"""A scene whose polygons do not merge (issue 10 part 2): a UV sphere facing inward, receivers inside
facing the centre (radiance 0.5 everywhere: H = π/2 exactly).

Every face of a sphere is in its own plane, so every face is a merged face (occluder) of its own, and
the depth relations between them are dense (every face is beyond every other face's plane). *old*:
the (polygon × merged face) tables and the VolumePairs lists (``culling.PER_PAIR_DEPTH_FROM = None``,
O(n_o²) time and memory); *new*: the relations per pair (:mod:`.depth_pairs`, the default from 4,096
merged faces on; forced here at every size). Each (face count, old/new) runs in a fresh subprocess
(peak RSS is per process): the preparation, then the irradiance at ``--points`` receivers; max |ΔH|
between old and new (0: bit-identical).

    OMP_NUM_THREADS=1 python benchmarks/bench_unmerged.py [--faces 512,2048,8192,32768] [--points 32]
        [--old-max 8192] [--outside]   (receivers at 3 r facing an outward sphere: front faces hide back faces)

Figures and what is left: docs/bench_unmerged.md (8,192 faces: 35.9 s / 792 MB -> 2.7 s / 122 MB to
prepare; 32,768: 23 s / 187 MB).
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
    t, cpu = time.perf_counter(), time.process_time()
    occ = prepare_scene(sc)
    # process CPU time besides the wall clock: one thread, so it is the wall time without the other jobs
    out = {"faces": sc.n_polygons, "merged": int(len(occ.counts)), "prep_s": time.perf_counter() - t,
           "prep_cpu_s": time.process_time() - cpu,
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
          f"{'ms/pt old':>9} {'ms/pt new':>9} {'RSS new':>8} {'max|dH|':>8} {'|H-ref|':>8} "
          f"{'cpu old':>7} {'cpu new':>7}")
    for f in (int(x) for x in a.faces.split(",")):
        new = run(f, a.points, False, a.outside)
        old = run(f, a.points, True, a.outside) if f <= a.old_max else None
        if "error" in new:
            print(f"{f:>6} failed: {new['error']}")
            continue
        if old is None or "error" in old:
            why = "-" if old is None else "failed"
            print(f"{new['faces']:>6} {why:>10} {new['prep_s']:10.2f} {'-':>7} {'-':>11} {new['prep_rss_mb']:10.0f}M "
                  f"{'-':>9} {new['ms']:9.1f} {new['rss_mb']:7.0f}M {'-':>8} {new['H_err']:8.1e} {'-':>7} "
                  f"{new['prep_cpu_s']:7.2f}", flush=True)
            continue
        dh = float(np.abs(np.array(new["H"]) - np.array(old["H"])).max())
        print(f"{new['faces']:>6} {old['prep_s']:10.2f} {new['prep_s']:10.2f} {old['prep_s'] / new['prep_s']:6.1f}x "
              f"{old['prep_rss_mb']:10.0f}M {new['prep_rss_mb']:10.0f}M {old['ms']:9.1f} {new['ms']:9.1f} "
              f"{new['rss_mb']:7.0f}M {dh:8.1e} {new['H_err']:8.1e} "
              f"{old['prep_cpu_s']:7.2f} {new['prep_cpu_s']:7.2f}", flush=True)


if __name__ == "__main__":
    main()
