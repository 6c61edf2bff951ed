"""The Cornell box subdivided to 9,468 polygons (the paper's scene 2 has 9,504), solved directly.

    blender -b --python sample_scenes/cornell_box_9500.py -- out.blend [--subdivisions 35] [--resolution 64]
    python sample_scenes/cornell_box_9500.py out.blend ...   # a venv with the bpy module

The first pass solves all 9,468 patches by progressive refinement (O(n) memory, no n × n matrix) with
the centroid rule (``--order 1``) to an unshot fraction of 1e-2 by default: see docs/first-pass.md for the
time and memory (benchmarks/bench_first_pass.py); ``--clusters N`` takes the clustered route instead (the user
guide's picture: 10× fewer point evaluations). ``--subdivisions 3`` builds a small version (tests).
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import _common as c  # noqa: E402
import cornell_box  # noqa: E402


def build(subdivisions: int = 35, *, resolution: int = 64, tolerance=None, order=None, quiet=False, clusters=None):
    scene, box, values = cornell_box.build(subdivisions, resolution=resolution, block_detail=1.05,
                                           tolerance=1e-2 if tolerance is None else tolerance, quiet=quiet,
                                           order=1 if order is None else order, clusters=clusters)
    return scene, box, values


def main(argv):
    ap = c.parser("cornell_box_9500.py", "Build the 9,468-polygon Cornell box sample .blend")
    ap.add_argument("--subdivisions", type=int, default=35)
    ap.add_argument("--clusters", type=int, default=None,
                    help="reflected light from about this many clusters (default: every polygon shoots)")
    args = ap.parse_args(argv)
    build(args.subdivisions, resolution=args.resolution, tolerance=args.tolerance, order=args.order,
          clusters=args.clusters)
    c.save("cornell_box_9500", args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main(c.script_argv()))
