"""Time of the exact 256² local-pass image with the current core (the figure the Cycles tables compare with).

``bench_cycles.py`` caches the exact image it measures Cycles against, with the seconds it took then.
This recomputes the same image (same scene, radiance, camera and lens shift) with the current core,
without Blender, prints its time and its largest difference from the cached image (both are exact, so
they must agree to rounding), and writes ``docs/bench_exact_image.md``::

    OMP_NUM_THREADS=1 python benchmarks/bench_exact_image.py [--scenes small,large] [--size 256]

``--workers 1,2`` instead times the whole image in one ``radiance`` call per worker count, the counts
interleaved ``--repeat`` times (side by side, so they share the machine's load), checks that every run
gives the same bits and prints the speedup of each count over the first (issue 11: the all-exact image
on 2 workers against 1), into ``docs/bench_exact_image_workers.md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
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
    ap.add_argument("--workers", default="", help="e.g. 1,2: time the image on these worker counts instead")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args(argv)
    if args.workers:
        return _workers(args)
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


def _workers(args):
    """The whole exact image on each worker count, interleaved; speedups of medians; bit-identity."""
    import bench_cycles  # noqa: E402

    from hemisphere_local_pass.core import radiance
    from hemisphere_local_pass.core.parallel import WorkerPool
    from hemisphere_local_pass.core.raycast import cast_rays

    counts = [int(w) for w in args.workers.split(",")]
    lines = ["# The exact image on 1 and more workers (one run, side by side)\n", f"Machine: {machine()}; "
             f"load average at start {'/'.join(f'{x:.1f}' for x in os.getloadavg())}\n",
             f"Command: `OMP_NUM_THREADS=1 python benchmarks/bench_exact_image.py --scenes {args.scenes} "
             f"--size {args.size} --workers {args.workers} --repeat {args.repeat}`\n",
             "Each run: one `radiance` call over every pixel's camera-ray hit (rays cast once, outside the "
             "timing); a kept pool per worker count > 1 (its start-up excluded); the scene prepared once "
             "before the first run. Seconds: median (fastest) of the repeats.\n",
             "| scene | polygons | pixels | " + " | ".join(f"{w} worker{'s' * (w > 1)} s" for w in counts)
             + " | " + " | ".join(f"speedup {w}/{counts[0]}" for w in counts[1:]) + " | same bits |",
             "|---|---|---|" + "---|" * (2 * len(counts) - 1) + "---|"]
    for key in args.scenes.split(","):
        box = cornell_box(**PAPER_SETTINGS[key])
        lum = solved_radiance(key, box)
        scene = box.scene(radiance=lum)
        o, d = bench_cycles.shifted_camera_rays(box, args.size)
        h = cast_rays(scene, o, d)
        src = h.source
        pts, nrm = h.point, scene.poly_normals[h.polygon]
        rho, emi = box.reflectivity[src], box.emission[src]
        radiance(scene, pts[:8], nrm[:8], rho[:8], emi[:8], workers=1)  # preparation, outside the timing
        pools = {w: WorkerPool(w) for w in counts if w > 1}
        times = {w: [] for w in counts}
        images = {}
        try:
            for _ in range(args.repeat):
                for w in counts:
                    t = time.perf_counter()
                    img = radiance(scene, pts, nrm, rho, emi, workers=1, executor=pools.get(w))
                    times[w].append(time.perf_counter() - t)
                    print(f"[{key}] {w} workers: {times[w][-1]:.2f} s", flush=True)
                    images.setdefault(w, img)
                    same = np.array_equal(img, images[counts[0]])
                    images[w] = img if same else images[w]
                    if not same:
                        images["differs"] = True
        finally:
            for pool in pools.values():
                pool.shutdown()
        med = {w: float(np.median(times[w])) for w in counts}
        lines.append(f"| {key} | {box.n_polygons} | {len(o)} | "
                     + " | ".join(f"{med[w]:.2f} ({min(times[w]):.2f})" for w in counts) + " | "
                     + " | ".join(f"{med[counts[0]] / med[w]:.2f}×" for w in counts[1:])
                     + f" | {'no' if images.get('differs') else 'yes'} |")
        print(lines[-1], flush=True)
    lines.append(f"\nLoad average at the end {'/'.join(f'{x:.1f}' for x in os.getloadavg())}.")
    out = ROOT / "docs" / "bench_exact_image_workers.md" if args.out else None
    if out:
        out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    main()
