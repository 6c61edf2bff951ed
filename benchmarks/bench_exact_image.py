"""Time of the exact 256² local-pass image with the current core (the figure the Cycles tables compare with).

``bench_cycles.py`` caches the exact image it measures Cycles against, with the seconds it took then.
This recomputes the same image (same scene, radiance, camera and lens shift) with the current core,
without Blender, prints its time and its largest difference from the cached image (both are exact, so
they must agree to rounding), and writes ``docs/bench_exact_image.md``::

    OMP_NUM_THREADS=1 python benchmarks/bench_exact_image.py [--scenes small,large] [--size 256]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CACHE, ROOT, machine, solved_radiance  # noqa: E402

from hemisphere_local_pass.scenes import PAPER_SETTINGS, cornell_box  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="small,large")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench_exact_image.md"), help="markdown copy ('' for none)")
    args = ap.parse_args(argv)
    lines = ["# The exact 256² image with the current core\n", f"Machine: {machine()}\n",
             f"Command: `OMP_NUM_THREADS=1 python benchmarks/bench_exact_image.py --scenes {args.scenes} "
             f"--size {args.size}`\n",
             "| scene | polygons | pixels | seconds | ms per pixel | cached image (bench_cycles) seconds "
             "| max abs difference / mean |",
             "|---|---|---|---|---|---|---|"]
    import bench_cycles  # noqa: E402  (imports bpy only when rendering)

    for key in args.scenes.split(","):
        box = cornell_box(**PAPER_SETTINGS[key])
        lum = solved_radiance(key, box)
        cached = None
        sx, sy = bench_cycles.SHIFT_PX
        name = f"exact_image_{key}_{box.n_polygons}_{args.size}_shift{sx}_{sy}.npz"
        if (CACHE / name).exists():
            z = np.load(CACHE / name)
            cached = (z["image"], float(z["seconds"]))
        with tempfile.TemporaryDirectory() as tmp:
            bench_cycles.CACHE = Path(tmp)               # compute afresh, leave the shared cache alone
            img, seconds = bench_cycles.exact_image(key, box, lum, args.size)
        n_px = args.size * args.size
        diff = "—" if cached is None else f"{np.abs(img - cached[0]).max() / np.abs(cached[0]).mean():.1e}"
        old = "—" if cached is None else f"{cached[1]:.1f}"
        lines.append(f"| {key} | {box.n_polygons} | {n_px} | {seconds:.1f} | {seconds / n_px * 1e3:.3f} | {old} "
                     f"| {diff} |")
        print(lines[-1], flush=True)
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n", encoding="utf-8")


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    main()
