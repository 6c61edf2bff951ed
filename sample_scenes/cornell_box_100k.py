"""The Cornell box with 106,312 polygons, for the performance work, solved on its own polygons by the first pass.

    blender -b --python sample_scenes/cornell_box_100k.py -- out.blend [--subdivisions 120] [--clusters 300]
        [--tolerance 1e-2] [--order 1] [--in-blender]
    python sample_scenes/cornell_box_100k.py out.blend ...    # a venv with the bpy module

The flat first pass (every polygon shoots for itself) needs a few sweeps of n shots of n-polygon point
evaluations: ~4·10⁵ × 0.1 s here. This scene takes the clustered route (``first_pass.ClusteredSolver``,
docs/first-pass.md "Large scenes"): the 644 light polygons shoot their emission themselves (the centroid
rule, ``--order 1``: they are 1/120 of the box), the reflected light is shot from about ``--clusters``
clusters of coplanar polygons of one material (406 for 300), one exact point evaluation per cluster shot,
until the unshot power is below ``--tolerance`` (1e-2) of the emitted. Every one of the 106,312 polygons
receives and carries its own radiance.

By default the solver runs on the numeric box (``scenes.cornell_box``, float64 coordinates) — the same
polygons, in the same order, as the meshes built here — and the result is written as the FACE-domain
``radiosity`` attribute, marked as this extension's. ``--in-blender`` solves the built scene through
``blender.first_pass.solve_first_pass`` instead (the operator's and the ``solve`` command's path): the
same solver, but on Blender's float32 vertex coordinates, with which the core's visibility is far slower
here (the rotated blocks' subdivided faces are no longer exactly planar: 8× per point at 9,468 polygons,
more than 50× at 106,312; docs/first-pass.md). ``--subdivisions 4 --clusters 20`` builds a small version
(tests).
"""

from __future__ import annotations

import os
import resource
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import _common as c  # noqa: E402
import cornell_box  # noqa: E402

#: the sample's first-pass settings (docs/first-pass.md gives their time, memory and error)
CLUSTERS, TOLERANCE, ORDER = 300, 1e-2, 1


def solved_radiance(subdivisions: int, clusters: int, tolerance: float, order: int, quiet: bool = False):
    """(n, 3) radiance of ``scenes.cornell_box(subdivisions, block_detail=1.05)``'s polygons, by the first pass."""
    c.import_package()
    from hemisphere_local_pass.blender.first_pass import SolverProgressLines
    from hemisphere_local_pass.first_pass import solve_radiosity
    from hemisphere_local_pass.scenes import cornell_box as numeric_box

    t0 = time.perf_counter()
    box = numeric_box(subdivisions, block_detail=1.05)
    result = solve_radiosity(box.scene(), box.reflectivity, box.emission, tolerance=tolerance, order=order,
                             clusters=clusters or None, progress=None if quiet else SolverProgressLines(interval=5.0))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: kB
    print(f"cornell_box_100k: {result.summary()}; with the scene {time.perf_counter() - t0:.0f} s, peak RSS so far "
          f"{rss:.0f} MB", file=sys.stderr)
    if not result.converged:
        raise RuntimeError("cornell_box_100k: the first pass did not converge")
    return result.radiance


def build(subdivisions: int = 120, *, clusters: int = CLUSTERS, resolution: int = 64, tolerance=None, order=None,
          quiet=False, in_blender=False):
    import bpy

    tolerance = TOLERANCE if tolerance is None else tolerance
    order = ORDER if order is None else order
    if in_blender:
        return cornell_box.build(subdivisions, resolution=resolution, block_detail=1.05, quiet=quiet,
                                 tolerance=tolerance, order=order, clusters=clusters)
    values = solved_radiance(subdivisions, clusters, tolerance, order, quiet=quiet)
    out = cornell_box.build(subdivisions, resolution=resolution, block_detail=1.05, radiosity=values)
    for mesh in bpy.data.meshes:  # written by this extension's first pass: ours to replace later
        mesh["hlp_owned_attributes"] = ["radiosity"]
    return out


def main(argv):
    ap = c.parser("cornell_box_100k.py", "Build the 106,312-polygon Cornell box sample .blend (clustered first pass)")
    ap.add_argument("--subdivisions", type=int, default=120)
    ap.add_argument("--clusters", type=int, default=CLUSTERS,
                    help="shooting clusters of the reflected light (0: every polygon shoots; days at 10^5)")
    ap.add_argument("--in-blender", action="store_true",
                    help="solve the built scene through solve_first_pass (float32 coordinates: far slower)")
    args = ap.parse_args(argv)
    build(args.subdivisions, clusters=args.clusters, resolution=args.resolution, tolerance=args.tolerance,
          order=args.order, in_blender=args.in_blender)
    c.save("cornell_box_100k", args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main(c.script_argv()))
