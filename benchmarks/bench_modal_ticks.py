"""How long does the modal operator hold Blender's main thread per timer tick? The sample Cornell box
rendered by ``modal.LocalPassRun`` one step per tick (``advance(budget=0)``, as the timer does with
its 0.1 s budget, minus the budget); prints the number of ticks, the first tick (scene export and
camera rays, on the main thread by design) and the longest tick after it, then the time Esc
(``close()``) takes to stop a running job. ``--tolerance`` > 0 is the adaptive pass, whose core calls
run in a thread while the job yields every ``adaptive_pixels.POLL_SECONDS``.

Run with a bpy module (it builds the scene itself)::

    .venv/bpy-4.2/bin/python benchmarks/bench_modal_ticks.py [--resolution 64] [--tolerance 1e-2]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=64, help="image side in pixels")
    parser.add_argument("--tolerance", type=float, default=1e-2, help="0: the exact job")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args(argv)

    import bpy

    bpy.ops.wm.read_homefile(use_factory_startup=True, use_empty=True)
    import hemisphere_local_pass as hlp

    hlp.register()
    spec = importlib.util.spec_from_file_location("hlp_box", ROOT / "sample_scenes" / "cornell_box.py")
    box = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(box)
    box.build(2, resolution=args.resolution, reset=False)
    from hemisphere_local_pass.blender import modal, props

    scene = bpy.context.scene
    kwargs = props.job_arguments(scene, scene.hlp_settings)
    kwargs.update(mode="pixels", output=None, image=False, tolerance=args.tolerance, workers=args.workers)

    run = modal.LocalPassRun(kwargs)
    ticks = []
    start = time.perf_counter()
    while True:
        t = time.perf_counter()
        finished = run.advance(budget=0.0)
        ticks.append(time.perf_counter() - t)
        if finished:
            break
    total = time.perf_counter() - start
    rest = max(ticks[1:], default=0.0)
    print(f"{args.resolution}x{args.resolution}, tolerance {args.tolerance:g}, workers {args.workers}: "
          f"{len(ticks)} ticks in {total:.2f} s; first tick (export, camera rays) {ticks[0]:.3f} s, "
          f"longest after it {rest:.3f} s; {run.report.summary()}")

    run = modal.LocalPassRun(kwargs)
    for _ in range(10):
        if run.advance(budget=0.0):
            break
    t = time.perf_counter()
    run.close()
    print(f"Esc after 10 ticks ({run.done} of {run.total} points): stopped in {time.perf_counter() - t:.3f} s")


if __name__ == "__main__":
    main()
