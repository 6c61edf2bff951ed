"""The preparation of a closed ball (issue 10 part 2): a UV sphere with exact poles (one convex solid),
faces outward (receivers outside) or inward (receivers inside), prepared with the solids' support search
against every vertex (*dense*, ``depth_pairs.SUPPORT_TREE_FROM = None``: O(n × V)) and in the tree of
bounding spheres (*tree*, the default: O(n log V)). Each (face count, side, search) runs in a fresh
subprocess, dense and tree alternating; the process CPU time of :func:`.chunk.prepare_scene` (one
thread) and of ``solid_columns`` alone, and whether the solids' columns are bit-identical.

    OMP_NUM_THREADS=1 python benchmarks/bench_ball_prep.py [--faces 2048,8192,32768] [--dense-max 8192]

Figures: docs/bench_unmerged.md ("Receivers outside a big convex solid").
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import time

import numpy as np
from _common import ROOT

from hemisphere_local_pass.scenes import uv_sphere


def one(faces: int, inside: bool, dense: bool) -> dict:
    from hemisphere_local_pass.core import Scene, culling, depth_pairs
    from hemisphere_local_pass.core.chunk import prepare_scene

    culling.PER_PAIR_DEPTH_FROM = 0                   # the per-pair relations at every size
    if dense:
        depth_pairs.SUPPORT_TREE_FROM = None
    spent = [0.0]
    inner = culling.solid_columns

    def timed(*a, **k):
        t = time.process_time()
        try:
            return inner(*a, **k)
        finally:
            spent[0] += time.process_time() - t

    culling.solid_columns = timed
    nu = int(round(np.sqrt(2 * faces)))
    v, p = uv_sphere(nu, nu // 2)
    v = np.asarray(v, dtype=np.float64).copy()
    v[np.abs(v) < 1e-12] = 0.0                        # exact poles: a closed convex solid
    if inside:
        p = [f[::-1] for f in p]
    sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
    cpu = time.process_time()
    occ = prepare_scene(sc)
    cpu = time.process_time() - cpu
    d = occ.depth
    h = hashlib.sha256()
    for x in (d.solid_front_pos, d.solid_front_neg, d.solid_reach_pos, d.solid_reach_neg):
        h.update(np.ascontiguousarray(x).tobytes())
    return {"faces": sc.n_polygons, "prep_cpu_s": cpu, "columns_cpu_s": spent[0], "hash": h.hexdigest()[:16]}


def run(faces, inside, dense):
    cmd = [sys.executable, __file__, "--one", str(faces)] + (["--inside"] if inside else []) + (
        ["--dense"] if dense else [])
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if r.returncode:
        return {"error": (r.stderr.strip().splitlines() or ["?"])[-1]}
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--faces", default="2048,8192,32768")
    ap.add_argument("--dense-max", type=int, default=8192, help="largest face count also run dense")
    ap.add_argument("--sides", default="outside,inside")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--dense", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one, a.inside, a.dense)))
        return
    print(f"load average {open('/proc/loadavg').read().split()[:3]} (CPU seconds, one thread)")
    print(f"{'faces':>6} {'side':>7} {'prep dense':>10} {'prep tree':>9} {'ratio':>6} {'cols dense':>10} "
          f"{'cols tree':>9} {'ratio':>6} {'same':>5}")
    for f in (int(x) for x in a.faces.split(",")):
        for side in a.sides.split(","):
            inside = side == "inside"
            dn = run(f, inside, True) if f <= a.dense_max else None
            tr = run(f, inside, False)
            if "error" in tr or (dn is not None and "error" in dn):
                print(f"{f:>6} {side:>7} failed: {(tr if 'error' in tr else dn)['error']}")
                continue
            if dn is None:
                print(f"{tr['faces']:>6} {side:>7} {'-':>10} {tr['prep_cpu_s']:9.2f} {'-':>6} {'-':>10} "
                      f"{tr['columns_cpu_s']:9.2f} {'-':>6} {'-':>5}", flush=True)
                continue
            print(f"{tr['faces']:>6} {side:>7} {dn['prep_cpu_s']:10.2f} {tr['prep_cpu_s']:9.2f} "
                  f"{dn['prep_cpu_s'] / tr['prep_cpu_s']:5.1f}x {dn['columns_cpu_s']:10.2f} {tr['columns_cpu_s']:9.2f} "
                  f"{dn['columns_cpu_s'] / max(tr['columns_cpu_s'], 1e-9):5.1f}x "
                  f"{'yes' if dn['hash'] == tr['hash'] else 'NO':>5}", flush=True)


if __name__ == "__main__":
    main()
