"""How the exact local pass scales with the polygon count (issue 10): visible and hidden geometry.

Two series of scenes, all closed Cornell boxes with receivers at camera-visible surface points:

* **visible**: the box subdivided more and more finely (every polygon can be seen from somewhere;
  constant radiance per part: the light's emission plus 0.1 × reflectivity elsewhere, no first pass);
* **hidden**: the 175-polygon box plus a subdivided plane of h quads (radiance 0.5) *outside* it,
  invisible from every receiver: behind the back wall (h = 10^4, 10^5, 10^6) and the issue's case, a
  300 × 300 plane below the floor (extending 0.5 beyond the box on every side).

For each scene: the preparation (``core.prepare_scene``: merged faces, depth tables, tiles, solids,
tile edges, hierarchy), the irradiance per point and the form factors per point, and the peak memory
(tracemalloc, which sees numpy's allocations) of the preparation and of one irradiance call. For the
hidden series the per-point times are also given as a ratio to the bare 175-polygon box, measured
interleaved in the same process (this shared VM drifts by ±30 % over minutes: the ratios travel,
the absolute times less so).

With ``--baseline REV`` the same is measured for the core at git revision REV (exported to a
temporary directory and imported side by side) on the scenes up to ``--baseline-max`` polygons.

With ``--tolerance T`` (default 1e-4; 0: off) the new code is also timed with ``irradiance(...,
tolerance=T × mean H)`` (the error-bounded far field, :mod:`hemisphere_local_pass.core.far_field`; mean
H of the exact result per channel), in one process (``workers=1``, interleaved with the exact call on
the same points) and on every core (a kept ``WorkerPool`` as ``executor``, on ``--worker-points`` points:
a call with fewer than 4 chunks of 192 points would stay in one process); the largest measured error
and the largest returned bound are given as fractions of the tolerance, and the first call's extra
preparation (the proxy scene) apart.

    OMP_NUM_THREADS=1 python benchmarks/bench_scaling.py [--points 256] [--visible 5,20,35,80,160]
        [--hidden 10000,100000,1000000] [--below 300] [--under 448] [--baseline aa9e604] [--baseline-max 100000]
        [--tolerance 1e-4] [--worker-points 1024] [--out docs/bench_scaling]

Writes ``docs/bench_scaling.md``, ``.json`` and ``.png`` (log-log: time against polygons); an existing
markdown file keeps what follows its :data:`KEEP_MARKER` line (hand-written measurements and readings).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
from _common import ROOT, keep_marker, log, machine, with_kept_sections

from hemisphere_local_pass.core.raycast import build_bvh, cast_rays
from hemisphere_local_pass.scenes import camera_rays, cornell_box

DOCS = ROOT / "docs"


#: radiance of the visible boxes: "constant" (per part) or "smooth" (see :func:`smooth_radiance`)
RADIANCE = "constant"


def box_arrays(subdivisions: int, radiance: str | None = None):
    """``(vertices (V, 3), quads (n, 4), radiance (n, 3), box)`` of a closed Cornell box."""
    box = cornell_box(subdivisions, block_detail=1.05 if subdivisions > 5 else 1.0)
    verts, quads = np.asarray(box.vertices), np.array(box.polygons, dtype=np.int64)
    if (radiance or RADIANCE) == "smooth":
        return verts, quads, smooth_radiance(verts, quads, box), box
    rad = box.emission + 0.1 * box.reflectivity * (box.emission.sum(axis=1) == 0)[:, None]
    return verts, quads, rad, box


def smooth_radiance(verts, quads, box) -> np.ndarray:
    """A radiosity-like radiance, smooth over every wall and different on every polygon, with hard shadows:
    ``L_i = E_i + ρ_i/π (E_direct(c_i) + E_ambient)`` at the polygon centroid ``c_i``, ``E_direct`` from
    the light as one small source at its centre (``L_e A cosθ_i cosθ_l / (r² + a²)``, ``a²`` its area /
    4, zero where a shadow ray from ``c_i`` to the light's centre hits something) and ``E_ambient``
    0.03 (1 + 0.8 u_z + 0.8 (u_x² + u_y²)) times the light's ``π L_e``, ``u = c_i / size − ½`` (the
    reflected light a first pass adds; no wall has constant radiance). What a
    user's first pass gives varies like this (smoothly, shadows aside); the real solver
    (:mod:`hemisphere_local_pass.first_pass`) takes ~15 min at 10^5 polygons on this machine."""
    from hemisphere_local_pass.core import Scene

    n = len(quads)
    scene = Scene.from_arrays(verts, quads.ravel(), np.arange(n, dtype=np.int64) * 4, np.full(n, 4, dtype=np.int64),
                              np.zeros((n, 3)))
    c = verts[quads].mean(axis=1)
    nrm = scene.poly_normals
    light = np.flatnonzero(box.emission.sum(axis=1) > 0)
    area = np.linalg.norm(np.cross(verts[quads[:, 2]] - verts[quads[:, 0]], verts[quads[:, 3]] - verts[quads[:, 1]]),
                          axis=1) * 0.5
    a_l = area[light].sum()
    x_l = (c[light] * area[light, None]).sum(axis=0) / a_l
    n_l = nrm[light[0]]
    le = box.emission[light[0]]
    d = x_l - c
    r2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-30)
    cos_i = np.maximum(np.einsum("ij,ij->i", nrm, d), 0.0) / np.sqrt(r2)
    cos_l = np.maximum(-np.einsum("ij,ij->i", n_l[None, :] * np.ones((n, 1)), d), 0.0) / np.sqrt(r2)
    e_dir = le[None, :] * (a_l * cos_i * cos_l / (r2 + 0.25 * a_l))[:, None]
    lit = (cos_i > 0) & (cos_l > 0)
    idx = np.flatnonzero(lit)
    o = c[idx] + 1e-7 * nrm[idx]
    hits = cast_rays(scene, o, x_l + 1e-6 * n_l - o, t_max=1.0 - 1e-7, bvh=build_bvh(scene))
    vis = np.zeros(n, dtype=bool)
    vis[idx] = ~hits.hit
    # reflected light: smaller than the direct light on the floor, growing towards the ceiling
    u = c / box.size - 0.5
    e_amb = 0.03 * np.pi * le[None, :] * (1.0 + 0.8 * u[:, 2:3] + 0.8 * (u[:, :2] ** 2).sum(axis=1, keepdims=True))
    rad = box.emission + box.reflectivity / np.pi * (np.where(vis[:, None], e_dir, 0.0) + e_amb)
    rad[light] = box.emission[light]
    return rad


def grid(nx: int, origin, du, dv):
    """An ``nx × nx`` grid of quads spanning ``origin + [0, 1] du + [0, 1] dv``: ``(vertices, quads)``."""
    s = np.linspace(0.0, 1.0, nx + 1)
    u, v = np.meshgrid(s, s, indexing="ij")
    verts = np.asarray(origin) + u.reshape(-1, 1) * np.asarray(du) + v.reshape(-1, 1) * np.asarray(dv)
    i, j = np.meshgrid(np.arange(nx), np.arange(nx), indexing="ij")
    a = (i * (nx + 1) + j).ravel()
    return verts, np.stack([a, a + nx + 1, a + nx + 2, a + 1], axis=1)


def hidden_plane(where: str, h: int):
    """A plane of about ``h`` quads outside the unit box: ``"behind"`` the back wall (y = 1.05, facing
    the box), ``"below"`` the floor (z = -0.1, 2 × 2, facing up) or ``"under"`` it (z = -1e-3: a ground
    plane a user put under the box, issue 14 point 16)."""
    nx = int(round(np.sqrt(h)))
    if where == "behind":
        return grid(nx, (-0.25, 1.05, -0.25), (0.0, 0.0, 1.5), (1.5, 0.0, 0.0))
    z = -0.1 if where == "below" else -1e-3
    return grid(nx, (-0.5, -0.5, z), (2.0, 0.0, 0.0), (0.0, 2.0, 0.0))


def scene_of(core, verts, quads, rad):
    n = len(quads)
    loops = quads.ravel()
    start = np.arange(n, dtype=np.int64) * 4
    total = np.full(n, 4, dtype=np.int64)
    return core.Scene.from_arrays(verts, loops, start, total, rad)


def receivers(box, scene_core, m: int, seed: int = 0):
    """Camera-visible points of the box (jittered pixel centres; no point exactly on an edge)."""
    side = int(np.ceil(np.sqrt(m)))
    o, d = camera_rays(box, side)
    rng = np.random.default_rng(seed)
    d = d + rng.uniform(-0.3, 0.3, d.shape) / side
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    h = cast_rays(scene_core, o, d, bvh=build_bvh(scene_core))
    keep = np.flatnonzero(h.hit)[:m]
    return h.point[keep], scene_core.poly_normals[h.polygon[keep]]


def load_baseline(rev: str):
    """The core at git revision ``rev``, imported as a separate package."""
    tmp = Path(tempfile.mkdtemp(prefix="hlp_baseline_"))
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "hemisphere_local_pass"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tmp)], input=archive, check=True)
    (tmp / "hemisphere_local_pass").rename(tmp / "hlp_baseline")
    sys.path.insert(0, str(tmp))
    return importlib.import_module("hlp_baseline.core")


def prepare(core, scene):
    """Seconds of the scene preparation (the baseline has no ``prepare_scene``: its first call)."""
    t = time.perf_counter()
    if hasattr(core, "prepare_scene"):
        core.prepare_scene(scene)
    else:
        core.irradiance(scene, np.array([[0.5, 0.5, 1e-3]]), np.array([[0.0, 0.0, 1.0]]))
    return time.perf_counter() - t


def _call(fn, **kw):
    """``fn`` with keyword arguments bound (for :func:`per_point`)."""
    return lambda *a: fn(*a, **kw)


def per_point(fn, *args, repeat=3):
    """Fastest of ``repeat`` calls, seconds per point, and the last result."""
    best, out = np.inf, None
    m = len(args[1])
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn(*args)
        best = min(best, (time.perf_counter() - t) / m)
    return best, out


def peak_mb(fn, *args):
    tracemalloc.start()
    tracemalloc.reset_peak()
    fn(*args)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=256)
    ap.add_argument("--ff-points", type=int, default=32, help="receivers for the form factors (output m × n)")
    ap.add_argument("--visible", default="5,20,35,80,160", help="subdivisions of the visible series")
    ap.add_argument("--hidden", default="10000,100000,1000000", help="quads behind the back wall")
    ap.add_argument("--below", type=int, default=300, help="grid side of the plane below the floor (0: none)")
    ap.add_argument("--under", type=int, default=448, help="grid side of the ground plane under the box (0: none)")
    ap.add_argument("--baseline", default="", help="git revision to measure side by side")
    ap.add_argument("--baseline-max", type=int, default=100000, help="largest scene for the baseline")
    ap.add_argument("--baseline-visible-max", type=int, default=10000,
                    help="largest visible scene for the baseline (its preparation grows faster than n log n)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--tolerance", type=float, default=1e-4,
                    help="far-field tolerance relative to the mean irradiance (0: exact only)")
    ap.add_argument("--worker-points", type=int, default=1024, help="receivers of the all-workers timing")
    ap.add_argument("--ratio-pair", default="35,160",
                    help="two visible subdivisions timed interleaved, exact and with the tolerance ('' for none)")
    ap.add_argument("--ratio-radiance", default="",
                    help="radiances of the ratio pair, e.g. constant,smooth (default: --radiance)")
    ap.add_argument("--radiance", choices=("constant", "smooth"), default="constant",
                    help="radiance of the visible boxes: constant per part, or smooth_radiance (varies per polygon)")
    ap.add_argument("--out", default=str(DOCS / "bench_scaling"), help="output prefix ('' for none)")
    args = ap.parse_args(argv)
    global RADIANCE
    RADIANCE = args.radiance
    core = importlib.import_module("hemisphere_local_pass.core")
    base = load_baseline(args.baseline) if args.baseline else None

    v0, q0, r0, box0 = box_arrays(5)
    cases = [("visible", int(s), box_arrays(int(s))) for s in args.visible.split(",") if s]
    for h in (int(x) for x in args.hidden.split(",") if x):
        pv, pq = hidden_plane("behind", h)
        cases.append(("hidden behind wall", len(pq), (np.concatenate([v0, pv]), np.concatenate([q0, pq + len(v0)]),
                                                      np.concatenate([r0, np.full((len(pq), 3), 0.5)]), box0)))
    for where, side in (("below", args.below), ("under", args.under)):
        if side:
            pv, pq = hidden_plane(where, side**2)
            cases.append((f"hidden {where} floor", len(pq), (np.concatenate([v0, pv]),
                                                             np.concatenate([q0, pq + len(v0)]),
                                                             np.concatenate([r0, np.full((len(pq), 3), 0.5)]), box0)))
    bare = {"new": scene_of(core, v0, q0, r0)}
    if base is not None:
        bare["baseline"] = scene_of(base, v0, q0, r0)
    for label, mod in (("new", core), ("baseline", base)):
        if mod is not None:
            prepare(mod, bare[label])
    results = []
    from hemisphere_local_pass.core.parallel import WorkerPool

    pool = WorkerPool() if args.tolerance > 0 else None
    for series, param, (verts, quads, rad, box) in cases:
        n = len(quads)
        for label, mod in (("new", core), ("baseline", base)):
            if mod is None or (label == "baseline" and (n > args.baseline_max or (
                    series == "visible" and n > args.baseline_visible_max))):
                continue
            log(f"[{series} {param}] {n} polygons, {label}")
            scene = scene_of(mod, verts, quads, rad)
            p, nrm = receivers(box, scene_of(core, verts, quads, rad) if label == "baseline" else scene, args.points)
            tracemalloc.start()
            t_prep = prepare(mod, scene)
            prep_mb = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
            log(f"  preparation {t_prep:.2f} s, peak {prep_mb:.0f} MB")
            # interleaved with the bare box, so that the ratio shares the machine's phase
            t_irr, t_box, t_one, t_tol = [], [], [], []
            tol = None
            exact = None
            tol_extra = {}
            if label == "new" and args.tolerance > 0:
                exact = mod.irradiance(scene, p, nrm, workers=1)
                tol = args.tolerance * exact.mean(axis=0)
                t = time.perf_counter()
                mod.irradiance(scene, p[:1], nrm[:1], workers=1, tolerance=tol)   # builds the proxy scene
                tol_extra["prep_tol_s"] = time.perf_counter() - t
            for _ in range(args.repeat):
                t_irr.append(per_point(mod.irradiance, scene, p, nrm, repeat=1)[0])
                t_box.append(per_point(mod.irradiance, bare[label], p, nrm, repeat=1)[0]
                             if series != "visible" else np.nan)
                if tol is not None:
                    t_one.append(per_point(_call(mod.irradiance, workers=1), scene, p, nrm, repeat=1)[0])
                    t_tol.append(per_point(_call(mod.irradiance, workers=1, tolerance=tol), scene, p, nrm,
                                           repeat=1)[0])
            if tol is not None:
                h_tol, st = mod.irradiance(scene, p, nrm, workers=1, tolerance=tol, return_stats=True)
                err = np.abs(h_tol - exact)
                assert (err <= st.error_bound).all(), "measured error above the returned bound"
                pw, nw = receivers(box, scene, args.worker_points, seed=1)
                # a kept pool of every core (the scene reaches each worker once, on the first call)
                t_all = per_point(_call(mod.irradiance, tolerance=tol, executor=pool), scene, pw, nw,
                                  repeat=args.repeat + 1)[0]
                tol_extra.update({"exact_1w_ms": 1e3 * min(t_one), "tol_1w_ms": 1e3 * min(t_tol),
                                  "tol_all_ms": 1e3 * t_all, "err_over_tol": float((err / tol).max()),
                                  "bound_over_tol": float((st.error_bound / tol).max()),
                                  "edges_summed": float(st.edges_summed.mean()),
                                  "clear_nodes": float(st.clear_nodes.mean()),
                                  "linear": float(st.linear_proxies.mean())})
            mf = min(args.ff_points, len(p))
            t_ff = per_point(mod.form_factors, scene, p[:mf], nrm[:mf], repeat=args.repeat)[0] if n <= 200_000 \
                else np.nan
            mem = peak_mb(mod.irradiance, scene, p, nrm)
            row = {"series": series, "param": param, "polygons": n, "code": label, "points": len(p),
                   "prep_s": t_prep, "irradiance_ms": 1e3 * min(t_irr), "form_factors_ms": 1e3 * t_ff,
                   "box_ms": 1e3 * np.nanmin(t_box) if series != "visible" else None,
                   "ratio_to_box": (min(t_irr) / np.nanmin(t_box)) if series != "visible" else None,
                   "peak_irradiance_mb": mem, "peak_prep_mb": prep_mb, **tol_extra}
            log(f"  {row}")
            results.append(row)
            del scene
    if pool is not None:
        pool.shutdown()
    lines = ["# Scaling of the exact local pass with the polygon count (issue 10)\n",
             f"Machine: {machine()}\n",
             f"Load average at the end: {os.getloadavg()[0]:.1f} (1 min) on {os.cpu_count()} cores.\n",
             f"Command: `OMP_NUM_THREADS=1 python benchmarks/bench_scaling.py --points {args.points} "
             f"--visible {args.visible} --hidden {args.hidden} --below {args.below} --under {args.under} "
             f"--repeat {args.repeat} --tolerance {args.tolerance:g} --worker-points {args.worker_points} "
             f"--ratio-pair {args.ratio_pair or chr(39) * 2}"
             + (f" --radiance {args.radiance}" if args.radiance != "constant" else "")
             + (f" --ratio-radiance {args.ratio_radiance}" if args.ratio_radiance else "")
             + (f" --out {args.out}" if args.out != str(DOCS / "bench_scaling") else "")
             + (f" --baseline {args.baseline} --baseline-max {args.baseline_max} --baseline-visible-max "
                f"{args.baseline_visible_max}" if args.baseline else "") + "`\n",
             f"Per-point times: fastest of {args.repeat} runs; irradiance over {args.points} camera-visible points, "
             f"form factors over {args.ff_points} (— above 200,000 polygons: the (m, n) output). *ratio*: "
             "irradiance per point over that of the bare 175-polygon box (same code, same points), interleaved in "
             "the same process. "
             "Peak memory: tracemalloc peaks (numpy arrays included) of the preparation (timed under tracemalloc) "
             "and of one irradiance call, beyond what the scene already holds.\n",
             "| series | polygons | code | preparation s | irradiance ms/pt | ratio to the box | "
             "form factors ms/pt | peak MB (preparation) | peak MB (irradiance) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        ratio = "" if r["ratio_to_box"] is None else f"{r['ratio_to_box']:.2f}"
        ff = "—" if not np.isfinite(r["form_factors_ms"]) else f"{r['form_factors_ms']:.2f}"
        lines.append(f"| {r['series']} | {r['polygons']:,} | {r['code']} | {r['prep_s']:.2f} | "
                     f"{r['irradiance_ms']:.3f} | {ratio} | {ff} | {r['peak_prep_mb']:.0f} | "
                     f"{r['peak_irradiance_mb']:.0f} |")
    tol_rows = [r for r in results if "tol_1w_ms" in r]
    if tol_rows:
        lines += ["", f"### Tolerance {args.tolerance:g} of the mean irradiance (error-bounded far field)\n",
                  "Per-point irradiance, ms: *exact* and *tolerance* in one process (`workers=1`, fastest of "
                  f"{args.repeat}, interleaved on the same points), *tolerance, all workers* on "
                  f"{args.worker_points} other points (a kept `core.parallel.WorkerPool` of every core as `executor`, "
                  "fastest call after the first, which ships the scene). *error / tol* and *bound / tol*: the "
                  "largest measured |H_tol − H_exact| and the largest returned bound per receiver and channel, "
                  "over the tolerance. *extra prep*: the first tolerance call's proxy scene.\n",
                  "| series | polygons | exact ms/pt | tolerance ms/pt | speed-up | tolerance, all workers ms/pt | "
                  "error / tol | bound / tol | edges summed /pt | clear nodes /pt | linear proxies /pt | "
                  "extra prep s |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in tol_rows:
            lines.append(f"| {r['series']} | {r['polygons']:,} | {r['exact_1w_ms']:.3f} | {r['tol_1w_ms']:.3f} | "
                         f"{r['exact_1w_ms'] / r['tol_1w_ms']:.1f}× | {r['tol_all_ms']:.3f} | "
                         f"{r['err_over_tol']:.1e} | {r['bound_over_tol']:.2f} | {r['edges_summed']:.0f} | "
                         f"{r['clear_nodes']:.0f} | {r.get('linear', 0):.0f} | {r['prep_tol_s']:.2f} |")
        vis = sorted((r for r in tol_rows if r["series"] == "visible"), key=lambda r: r["polygons"])
        ref = [r for r in vis if 5000 <= r["polygons"] <= 20000]
        if vis and ref:
            big, mid = vis[-1], ref[0]
            lines += ["", f"Largest visible box ({big['polygons']:,} polygons) with the tolerance over the "
                      f"{mid['polygons']:,}-polygon box: {big['tol_1w_ms'] / mid['tol_1w_ms']:.1f}× (both with the "
                      f"tolerance), {big['tol_1w_ms'] / mid['exact_1w_ms']:.1f}× (that box exact); exact over "
                      f"exact: {big['exact_1w_ms'] / mid['exact_1w_ms']:.1f}×."]
    if args.ratio_pair and args.tolerance > 0:
        lines += ratio_pair(core, [int(x) for x in args.ratio_pair.split(",")], args)
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out + ".md").write_text(with_kept_sections(text, Path(args.out + ".md")))
        Path(args.out + ".json").write_text(json.dumps(results, indent=1))
        plot(results, args.out + ".png")
        log(f"wrote {args.out}.md, .json, .png")


#: the line of a written ``--out`` markdown file from which on the rest is hand-written (see
#: :func:`_common.with_kept_sections`)
KEEP_MARKER = keep_marker("bench_scaling.py")


def ratio_pair(core, subdivisions, args):
    """The goal of issue 10 part 4 measured side by side: two visible boxes, exact and with the tolerance,
    for every radiance of ``--ratio-radiance``, all calls interleaved in one process (``workers=1``);
    returns markdown lines."""
    kinds = [k for k in args.ratio_radiance.split(",") if k] or [args.radiance]
    cases = []
    for kind in kinds:
        for sub in subdivisions:
            verts, quads, rad, box = box_arrays(sub, kind)
            scene = scene_of(core, verts, quads, rad)
            p, nrm = receivers(box, scene, args.points)
            core.prepare_scene(scene)
            exact = core.irradiance(scene, p, nrm, workers=1)
            tol = args.tolerance * exact.mean(axis=0)
            t = time.perf_counter()
            h, st = core.irradiance(scene, p, nrm, workers=1, tolerance=tol, return_stats=True)   # proxies, once
            extra = time.perf_counter() - t
            err = np.abs(h - exact)
            assert (err <= st.error_bound).all(), "measured error above the returned bound"
            info = {"err": float((err / tol).max()), "bound": float((st.error_bound / tol).max()),
                    "linear": float(st.linear_proxies.mean()), "edges": float(st.edges_summed.mean()),
                    "nodes": float(st.clear_nodes.mean()), "extra": extra}
            cases.append((kind, scene, p, nrm, tol, info))
    best = {}
    reps = max(args.repeat, 3)
    for _ in range(reps):
        for i, (_, scene, p, nrm, tol, _) in enumerate(cases):
            for kind, kw in (("exact", {}), ("tol", {"tolerance": tol})):
                t = per_point(_call(core.irradiance, workers=1, **kw), scene, p, nrm, repeat=1)[0]
                best[i, kind] = min(best.get((i, kind), np.inf), t)
    ms = {k: 1e3 * v for k, v in best.items()}
    log(f"ratio pairs: {ms}")
    lines = ["", f"### Side by side: {subdivisions[0]} and {subdivisions[1]} subdivisions, radiance "
             f"{', '.join(kinds)} (interleaved, one process, fastest of {reps}, {args.points} points each)\n",
             "*linear / edges / nodes*: per point, the linear proxies taken, the welded edges summed and the clear "
             "nodes; *first call*: the first call with the tolerance (proxy scene, node fits and the calls' own "
             "work).\n",
             "| radiance | polygons | exact ms/pt | tolerance ms/pt | error / tol | bound / tol | linear | edges | "
             "nodes | first call s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for i, (kind, scene, _, _, _, info) in enumerate(cases):
        lines.append(f"| {kind} | {scene.n_polygons:,} | {ms[i, 'exact']:.3f} | {ms[i, 'tol']:.3f} | "
                     f"{info['err']:.1e} | {info['bound']:.2f} | {info['linear']:.0f} | {info['edges']:.0f} | "
                     f"{info['nodes']:.0f} | {info['extra']:.1f} |")
    lines.append("")
    for j, kind in enumerate(kinds):
        a, b = 2 * j, 2 * j + 1
        na, nb = cases[a][1].n_polygons, cases[b][1].n_polygons
        lines.append(f"{kind}: {nb:,} with the tolerance / {na:,} with the tolerance: "
                     f"**{ms[b, 'tol'] / ms[a, 'tol']:.1f}×**; / {na:,} exact: "
                     f"**{ms[b, 'tol'] / ms[a, 'exact']:.1f}×**; exact / exact: "
                     f"{ms[b, 'exact'] / ms[a, 'exact']:.1f}×.")
    return lines


def plot(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for code, style in (("new", "-o"), ("baseline", "--s")):
        for series, colour in (("visible", "C0"), ("hidden behind wall", "C1"), ("hidden below floor", "C2"),
                               ("hidden under floor", "C3")):
            rs = sorted((r for r in results if r["code"] == code and r["series"] == series),
                        key=lambda r: r["polygons"])
            if not rs:
                continue
            x = [r["polygons"] for r in rs]
            lab = f"{series} ({code})"
            axes[0].plot(x, [r["irradiance_ms"] for r in rs], style, color=colour, label=lab)
            axes[1].plot(x, [r["prep_s"] for r in rs], style, color=colour, label=lab)
    axes[0].set_ylabel("irradiance, ms per point")
    axes[1].set_ylabel("scene preparation, s")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("polygons")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
