"""The Cornell box with 104,400 polygons, for the performance work: a coarse first pass gathered at every patch.

    blender -b --python sample_scenes/cornell_box_100k.py -- out.blend [--subdivisions 120] [--coarse 5]
    python sample_scenes/cornell_box_100k.py out.blend ...    # a venv with the bpy module

Progressive refinement on 10^5 patches costs ~n shots of n-polygon point evaluations (days here), so this
scene takes the two-level route: the first pass solves the same box at ``--coarse`` subdivisions (175
polygons; ``first_pass.solve_radiosity``), and every fine patch gets ``E + ρ/π H`` gathered at its centre
from that solution with the exact core (``scenes.radiosity.gathered_radiance``: one exact evaluation per
patch, occlusion included). The attribute is FACE-domain ``radiosity`` as everywhere, marked as this
extension's (the ``solve`` command may replace it). ``--subdivisions 4`` builds a small version (tests).
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import _common as c  # noqa: E402
import cornell_box  # noqa: E402


def gathered_solution(subdivisions: int, coarse: int, tolerance: float = 1e-3, quiet: bool = False):
    """(n, 3) radiance of ``cornell_box(subdivisions)``'s patches from the solved ``cornell_box(coarse)``."""
    c.import_package()
    from hemisphere_local_pass.first_pass import solve_radiosity
    from hemisphere_local_pass.scenes import cornell_box as numeric_box
    from hemisphere_local_pass.scenes.radiosity import gathered_radiance

    t0 = time.perf_counter()
    small = numeric_box(coarse)
    result = solve_radiosity(small.scene(), small.reflectivity, small.emission, tolerance=tolerance)
    fine = numeric_box(subdivisions, block_detail=1.05)
    solved = small.scene(radiance=result.radiance)

    def progress(done, total):
        if not quiet and (done == total or done % 16384 < 256):
            print(f"cornell_box_100k: gathered {done}/{total} patches", file=sys.stderr, flush=True)

    values = np.empty((fine.n_polygons, 3))
    centres, normals = fine.centroids(), fine.normals()
    step = 4096
    for s in range(0, fine.n_polygons, step):
        e = min(s + step, fine.n_polygons)
        values[s:e] = gathered_radiance(solved, centres[s:e], normals[s:e], fine.reflectivity[s:e],
                                        fine.emission[s:e])
        progress(e, fine.n_polygons)
    if not quiet:
        print(f"cornell_box_100k: coarse {result.summary()}; {fine.n_polygons} patches gathered in "
              f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return values


def build(subdivisions: int = 120, *, coarse: int = 5, resolution: int = 64, quiet=False):
    import bpy

    values = gathered_solution(subdivisions, coarse, quiet=quiet)
    scene, box, values = cornell_box.build(subdivisions, resolution=resolution, block_detail=1.05, radiosity=values)
    for mesh in bpy.data.meshes:  # written by this extension's sample: ours to replace later
        mesh["hlp_owned_attributes"] = ["radiosity"]
    return scene, box, values


def main(argv):
    ap = c.parser("cornell_box_100k.py", "Build the 104,400-polygon Cornell box sample .blend")
    ap.add_argument("--subdivisions", type=int, default=120)
    ap.add_argument("--coarse", type=int, default=5)
    args = ap.parse_args(argv)
    build(args.subdivisions, coarse=args.coarse, resolution=args.resolution)
    c.save("cornell_box_100k", args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main(c.script_argv()))
