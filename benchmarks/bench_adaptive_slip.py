"""How often a hard shadow line slips between the adaptive pass's samples, with and without its shadow test.

The thin-occluder scene of ``tests/core/test_adaptive.py`` (a small bright light, five bars 0.003 wide
outside the camera's view casting penumbra lines about one pixel wide on the floor) is rendered with
the bars moved by ``n`` random offsets. For each offset and tolerance (relative to the mean H) it
counts images whose largest error exceeds the tolerance and the pixels that do, once with the
geometric shadow test switched off (``light_ratio=inf``: spot checks only) and once with it::

    OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_slip.py [--n 12] [--size 48]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "core"))

import test_adaptive as T  # noqa: E402

from hemisphere_local_pass.core import adaptive_irradiance  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--size", type=int, default=48)
    ap.add_argument("--rel", default="1e-2,1e-3")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(11)
    offsets = rng.uniform(0.0, 0.031, args.n)
    rels = [float(r) for r in args.rel.split(",")]
    stats = {(rel, mode): [0, 0, 0.0, 0] for rel in rels for mode in ("spot checks only", "with shadow test")}
    for off in offsets:
        scene, o, d = T.thin_occluders(offset=off, size=args.size)
        p, n, g = T.image_inputs(scene, o, d, args.size)
        ref = T.exact_image(scene, p, n, g)
        for rel in rels:
            tol = rel * ref[g >= 0].mean()
            for mode, ratio in (("spot checks only", np.inf), ("with shadow test", 4.0)):
                img, st = adaptive_irradiance(scene, p, n, g, tolerance=tol, light_ratio=ratio)
                err = np.abs(img - ref).max(axis=2)
                s = stats[rel, mode]
                s[0] += int(err.max() > tol)
                s[1] += int((err > tol).sum())
                s[2] = max(s[2], float(err.max() / tol))
                s[3] += st.exact_points
    lines = [f"Thin occluders, {args.size}², {args.n} random bar offsets "
             f"(command: `OMP_NUM_THREADS=1 .venv/core/bin/python benchmarks/bench_adaptive_slip.py --n {args.n} "
             f"--size {args.size}`)\n",
             "| tolerance / mean H | mode | images over tolerance | pixels over tolerance | worst error / tolerance "
             "| exact evaluations per image |", "|---|---|---|---|---|---|"]
    for (rel, mode), (bad, px, worst, ex) in stats.items():
        lines.append(f"| {rel:g} | {mode} | {bad} of {args.n} | {px} | {worst:.2f} | {ex / args.n:.0f} "
                     f"of {args.size**2} |")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
