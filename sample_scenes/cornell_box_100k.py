"""The Cornell box with 106,312 polygons, for the performance work, solved on its own polygons by the first pass.

    blender -b --python sample_scenes/cornell_box_100k.py -- out.blend [--subdivisions 120] [--clusters 500]
        [--tolerance 1e-2] [--order 1]
    python sample_scenes/cornell_box_100k.py out.blend ...    # a venv with the bpy module

The flat first pass (every polygon shoots for itself) needs a few sweeps of n shots of n-polygon point
evaluations: ~4·10⁵ × 0.1 s here. This scene takes the clustered route
(``first_pass.ClusteredSolver``, docs/first-pass.md "Large scenes"): the 644 light polygons shoot their
emission themselves (the centroid rule, ``--order 1``: they are 1/120 of the box), the reflected light is
shot from about ``--clusters`` clusters of coplanar polygons of one material (642 for 500), one exact
point evaluation per cluster shot, until the unshot power is below ``--tolerance`` (1e-2) of the emitted.
Every one of the 106,312 polygons receives and carries its own radiance (FACE-domain ``radiosity``,
written by ``solve_first_pass`` like the operator and the ``solve`` command). ``--subdivisions 4
--clusters 20`` builds a small version (tests).
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import _common as c  # noqa: E402
import cornell_box  # noqa: E402

#: the sample's first-pass settings (docs/first-pass.md gives their time, memory and error)
CLUSTERS, TOLERANCE, ORDER = 500, 1e-2, 1


def build(subdivisions: int = 120, *, clusters: int = CLUSTERS, resolution: int = 64, tolerance=None, order=None,
          quiet=False):
    return cornell_box.build(subdivisions, resolution=resolution, block_detail=1.05, quiet=quiet,
                             tolerance=TOLERANCE if tolerance is None else tolerance,
                             order=ORDER if order is None else order, clusters=clusters)


def main(argv):
    ap = c.parser("cornell_box_100k.py", "Build the 106,312-polygon Cornell box sample .blend (clustered first pass)")
    ap.add_argument("--subdivisions", type=int, default=120)
    ap.add_argument("--clusters", type=int, default=CLUSTERS,
                    help="shooting clusters of the reflected light (0: every polygon shoots; days at 10^5)")
    args = ap.parse_args(argv)
    build(args.subdivisions, clusters=args.clusters, resolution=args.resolution, tolerance=args.tolerance,
          order=args.order)
    c.save("cornell_box_100k", args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main(c.script_argv()))
