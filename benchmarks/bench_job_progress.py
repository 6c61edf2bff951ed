"""When does the batch job say something? The sample Cornell box plus a flat N x N-face plane on its
floor (issue 14.16: 448 x 448 = 200,704 faces), rendered through ``job.cli_main`` for a few pixels;
prints every progress line with the seconds since the job started.

Run with a bpy module (it builds the scene itself)::

    .venv/bpy-4.2/bin/python benchmarks/bench_job_progress.py [--faces 448] [--pixels 2]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class _Stamped:
    """stderr with the seconds since ``t0`` in front of every line."""

    def __init__(self, t0):
        self.t0 = t0

    def write(self, text):
        for line in text.splitlines():
            if line.strip():
                sys.__stderr__.write(f"[{time.perf_counter() - self.t0:6.1f} s] {line}\n")

    def flush(self):
        sys.__stderr__.flush()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--faces", type=int, default=448, help="faces per side of the plane (448: 200,704 faces)")
    parser.add_argument("--pixels", type=int, default=2, help="a square region of this many pixels per side")
    args = parser.parse_args(argv)
    import bpy

    spec = importlib.util.spec_from_file_location("hlp_sample", ROOT / "sample_scenes" / "cornell_box.py")
    sample = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sample)
    sc, _, _ = sample.build(4, resolution=16)
    n = args.faces
    g = np.linspace(0.25, 0.75, n + 1)
    verts = [(x, y, 0.001) for y in g for x in g]
    faces = [(j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)
             for j in range(n) for i in range(n)]
    me = bpy.data.meshes.new("Plane")
    me.from_pydata(verts, [], faces)
    a = me.attributes.new("radiosity", "FLOAT_COLOR", "FACE")
    a.data.foreach_set("color", np.tile(np.array([0.1, 0.1, 0.1, 1], np.float32), len(faces)))
    sc.collection.objects.link(bpy.data.objects.new("Plane", me))
    bpy.context.view_layer.update()
    print(f"scene: sample box + a {len(faces)}-face plane; region {args.pixels} x {args.pixels} px", flush=True)
    from hemisphere_local_pass.blender import job

    t0 = time.perf_counter()
    sys.stderr = _Stamped(t0)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            rc = job.cli_main(["render", "-o", str(Path(tmp) / "p.exr"), "--no-preview",
                               "--region", "0", "0", str(args.pixels), str(args.pixels)])
    finally:
        sys.stderr = sys.__stderr__
    print(f"exit {rc} after {time.perf_counter() - t0:.1f} s", flush=True)
    return rc


if __name__ == "__main__":
    sys.exit(main())
