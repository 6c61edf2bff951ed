"""Structure prediction probe (issue 11; docs/adaptive.md, "Structure prediction").

At ``--pixels`` random hit pixels of a cached all-exact benchmark image (the cache of
``bench_adaptive_oracle.py``) whose four right-hand neighbours lie on the same input plane:

* ``core.fragment_structure`` against ``core.irradiance`` at the same pixels (CPU time, workers=1,
  one process): the extraction's cost in exact evaluations;
* the structures flagged ambiguous, and their H at P against the cached exact image (relative);
* the prediction ``evaluate_structure`` 1 and 4 pixels to the right, against the exact image (over the
  image's mean H): quantiles, and the fraction exact (< 1e-10).

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_structure_probe.py --scene small --size 128
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_adaptive_oracle import reference  # noqa: E402

STEPS = 4  # the farthest neighbour predicted, in pixels to the right


def same_plane_runs(scene, g):
    """(h, w - STEPS) bool: the pixel and its STEPS right-hand neighbours hit the same input plane."""
    from hemisphere_local_pass.core.adaptive import _input_planes

    hit = g >= 0
    plane = np.where(hit, _input_planes(scene)[np.maximum(g, 0)], -1)
    w = plane.shape[1]
    same = hit[:, :-STEPS].copy()
    for k in range(1, STEPS + 1):
        same &= plane[:, k:w - STEPS + k] == plane[:, :-STEPS]
    return same


def main(argv=None):
    from hemisphere_local_pass.core import irradiance
    from hemisphere_local_pass.core.fragment_structure import evaluate_structure, fragment_structure

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="small", help="small (175 polygons) or large (9,468)")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--pixels", type=int, default=300)
    args = ap.parse_args(argv)

    scene, p, n, g, H = reference(args.scene, args.size)
    ys, xs = np.nonzero(same_plane_runs(scene, g))
    pick = np.random.default_rng(1).choice(len(ys), args.pixels, replace=False)
    ys, xs = ys[pick], xs[pick]

    t = time.process_time()
    structures = fragment_structure(scene, p[ys, xs], n[ys, xs])
    t_extract = time.process_time() - t
    t = time.process_time()
    irradiance(scene, p[ys, xs], n[ys, xs], workers=1)
    t_exact = time.process_time() - t
    print(f"extraction {t_extract:.3f} s CPU, exact {t_exact:.3f} s CPU: {t_extract / t_exact:.1f} exact "
          f"evaluations per structure; edges per structure {np.mean([s.n_edges for s in structures]):.0f}")
    print(f"ambiguous {sum(s.ambiguous for s in structures)} of {len(structures)}",
          dict(Counter(r for s in structures for r in s.reasons)))

    mean = H[g >= 0].mean()
    at_p, step1, step_far = [], [], []
    for s, y, x in zip(structures, ys, xs):
        at_p.append(np.abs(s.H - H[y, x]).max() / max(H[y, x].max(), 1e-300))
        err = np.abs(evaluate_structure(s, p[y, x + 1:x + 1 + STEPS]) - H[y, x + 1:x + 1 + STEPS]).max(axis=1) / mean
        step1.append(err[0])
        step_far.append(err[-1])
    step1, step_far = np.array(step1), np.array(step_far)
    print(f"H at P: largest relative difference from the exact image {max(at_p):.2e}")
    print(f"prediction error / mean H, 1 / {STEPS} pixels away:")
    for q in (0.5, 0.9, 0.99, 1.0):
        print(f"  quantile {q:g}: {np.quantile(step1, q):.2e} / {np.quantile(step_far, q):.2e}")
    print(f"  exact (< 1e-10): {(step1 < 1e-10).mean():.0%} / {(step_far < 1e-10).mean():.0%}")


if __name__ == "__main__":
    main()
