"""An earlier commit's core against this checkout's with the far-field tolerance, side by side (issue 10).

The boxes of ``bench_scaling.py`` (``box_arrays``: constant or smooth radiance), the earlier commit's core
imported as a separate package (``bench_scaling.load_baseline``), both called on the same camera-visible
points with ``irradiance(..., tolerance=REL × mean H, workers=1)``, alternating which goes first run by
run (they share the machine's slow and fast phases: the per-run ratio is what travels). Times are CPU
seconds of this process (``time.process_time``).

Prints per box: each core's measured error and returned bound over the tolerance, the linear proxies,
edges summed and clear nodes per point, max |ΔH| between the cores, the fastest and median ms per point
and the median of the per-run ratios (this / base). ``--set module.NAME=value`` (repeatable) changes a
constant of this checkout's core first (e.g. ``far_field.LINEAR_EDGES=16``), to try a setting against the
commit that has the default.

    OMP_NUM_THREADS=1 python benchmarks/bench_ab_tolerance.py --base dc843e1 --subdivisions 35,160
        [--radiance smooth] [--tolerance 1e-4] [--points 64] [--repeat 7] [--set far_field.LINEAR_SHARE=0.95]
"""

from __future__ import annotations

import argparse
import ast
import importlib
import time

import numpy as np
from _common import machine
from bench_scaling import box_arrays, load_baseline, receivers, scene_of


def apply_settings(settings: list[str]) -> list[str]:
    """Set ``module.NAME=value`` constants of this checkout's core (value a Python literal, cast to the
    constant's type); returns what was set, for the report."""
    done = []
    for spec in settings:
        lhs, value = spec.split("=", 1)
        mod_name, name = lhs.rsplit(".", 1)
        mod = importlib.import_module(f"hemisphere_local_pass.core.{mod_name}")
        old = getattr(mod, name)
        setattr(mod, name, type(old)(ast.literal_eval(value)))
        done.append(f"{mod_name}.{name} = {getattr(mod, name)!r} (was {old!r})")
    return done


def prepare_case(core, verts, quads, rad, box, n_points: int, rel: float):
    """``(scene, points, normals, tol, H, stats)`` for one core: prepared, its exact H and its first
    tolerance call (proxy scene and node fits built) done before any timing."""
    scene = scene_of(core, verts, quads, rad)
    p, nrm = receivers(box, scene, n_points)
    core.prepare_scene(scene)
    exact = core.irradiance(scene, p, nrm, workers=1)
    tol = rel * exact.mean(axis=0)
    h, st = core.irradiance(scene, p, nrm, workers=1, tolerance=tol, return_stats=True)
    err = np.abs(h - exact)
    if not (err <= st.error_bound).all():
        raise AssertionError("measured error above the returned bound")
    info = {"err": float((err / tol).max()), "bound": float((st.error_bound / tol).max()),
            "linear": float(st.linear_proxies.mean()), "edges": float(st.edges_summed.mean()),
            "nodes": float(st.clear_nodes.mean())}
    return scene, p, nrm, tol, h, info


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the earlier commit (any git revision)")
    ap.add_argument("--subdivisions", default="35,160", help="boxes, as bench_scaling's subdivisions")
    ap.add_argument("--radiance", choices=("constant", "smooth"), default="smooth")
    ap.add_argument("--tolerance", type=float, default=1e-4, help="relative to the mean irradiance")
    ap.add_argument("--points", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--set", action="append", default=[], metavar="module.NAME=value",
                    help="a constant of this checkout's core (repeatable)")
    args = ap.parse_args(argv)
    import hemisphere_local_pass.core as this

    base = load_baseline(args.base)
    settings = apply_settings(args.set)
    print(f"Machine: {machine()}\n\nbase {args.base} against this checkout"
          + (f" with {'; '.join(settings)}" if settings else "")
          + f", radiance {args.radiance}, tolerance {args.tolerance:g} of the mean H, {args.points} points, "
          f"{args.repeat} alternating runs, CPU ms per point\n")
    print("| polygons | core | error / tol | bound / tol | linear | edges | nodes | fastest ms/pt | median ms/pt "
          "| this / base (median of runs) | max abs(ΔH) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for sub in (int(s) for s in args.subdivisions.split(",") if s):
        verts, quads, rad, box = box_arrays(sub, args.radiance)
        cases = {label: prepare_case(core, verts, quads, rad, box, args.points, args.tolerance)
                 for label, core in (("base", base), ("this", this))}
        cores = {"base": base, "this": this}
        times = {"base": [], "this": []}
        for r in range(args.repeat):
            for label in (("base", "this") if r % 2 == 0 else ("this", "base")):
                scene, p, nrm, tol, _, _ = cases[label]
                t = time.process_time()
                cores[label].irradiance(scene, p, nrm, workers=1, tolerance=tol)
                times[label].append(1e3 * (time.process_time() - t) / len(p))
        ratio = float(np.median(np.array(times["this"]) / np.array(times["base"])))
        h_base, h_this = cases["base"][4], cases["this"][4]
        diff = "bitwise" if np.array_equal(h_base, h_this) else f"{float(np.abs(h_base - h_this).max()):.2e}"
        for label in ("base", "this"):
            info, t = cases[label][5], times[label]
            last = label == "this"
            print(f"| {cases[label][0].n_polygons:,} | {label} | {info['err']:.4f} | {info['bound']:.4f} | "
                  f"{info['linear']:.1f} | {info['edges']:.1f} | {info['nodes']:.1f} | {min(t):.3f} | "
                  f"{float(np.median(t)):.3f} | {f'{ratio:.3f}' if last else ''} | {diff if last else ''} |",
                  flush=True)


if __name__ == "__main__":
    main()
