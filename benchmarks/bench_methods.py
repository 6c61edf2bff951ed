"""Run time against error (issue 3): the exact method beside the hemicube, ray-traced form factors and
Monte Carlo, on Cornell boxes of 175 and 9,468 polygons (the paper's tables 5 and 6: 176 and 9,504).

For every method and setting, over the same camera-visible points: time per point, max and RMS error of
the per-point irradiance against the exact method (luminance, relative to the mean exact irradiance),
max |ΣF − 1| and the per-polygon form-factor error (max over all point/polygon entries, and the mean
over points of Σ_i |F_i − F_i,exact|). The exact method is checked against independent references: the
closed scene's ΣF = 1 and the highest-count Monte Carlo run (|H_exact − H_MC| in MC standard errors).

Writes ``docs/bench_methods.md`` (tables in the paper's format plus the full table), ``docs/bench_methods.json``
and ``docs/bench_methods.png`` (log-log time per point against RMS irradiance error, one curve per method,
the exact method as a point).

    OMP_NUM_THREADS=1 python benchmarks/bench_methods.py [--points 1024] [--scenes small,large] [--quick]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from _common import ROOT, case, log, luminance, machine, timed

from hemisphere_local_pass.baselines import hemicube, monte_carlo, raytraced_form_factors
from hemisphere_local_pass.core import form_factors, irradiance
from hemisphere_local_pass.core.raycast import build_bvh

DOCS = ROOT / "docs"


def errors(h, f, h_ref, f_ref):
    """Error figures of one run against the exact reference (dict)."""
    y, y_ref = luminance(h), luminance(h_ref)
    mean = float(np.mean(y_ref))
    d = y - y_ref
    out = {
        "irr_max": float(np.abs(d).max() / mean),
        "irr_rms": float(np.sqrt(np.mean(d * d)) / mean),
        "irr_bias": float(np.mean(d) / mean),
    }
    if f is not None:
        out["ff_sum_max"] = float(np.abs(f.sum(axis=1) - 1.0).max())
        out["ff_max"] = float(np.abs(f - f_ref).max())
        out["ff_l1"] = float(np.abs(f - f_ref).sum(axis=1).mean())
    return out


def run_scene(key, n_points, seed, settings, check_spp=16384):
    box, scene, p, n, _ = case(key, n_points, seed)
    m = len(p)
    log(f"[{key}] {box.n_polygons} polygons, {m} points")
    rows = []
    h_ref, t_h = timed(irradiance, scene, p, n)
    f_ref, t_f = timed(form_factors, scene, p, n)
    exact = {"method": "exact", "setting": "", "ms_per_point": t_h / m * 1e3, "ff_ms_per_point": t_f / m * 1e3,
             "ff_sum_max": float(np.abs(f_ref.sum(axis=1) - 1.0).max())}
    log(f"[{key}] exact {exact['ms_per_point']:.3f} ms/pt (form factors {exact['ff_ms_per_point']:.3f})")
    rows.append(exact)
    bvh = build_bvh(scene)
    runs = [("hemicube", f"{r}x{r}", lambda r=r: hemicube(scene, p, n, r, rng=seed)) for r in settings["hemicube"]]
    runs += [("raytraced FF", f"{r} rays/unit F",
              lambda r=r: raytraced_form_factors(scene, p, n, r, rng=seed, bvh=bvh)) for r in settings["raytraced"]]
    runs += [("Monte Carlo", f"{s} spp", lambda s=s: monte_carlo(scene, p, n, s, rng=seed, bvh=bvh))
             for s in settings["mc"]]
    for method, setting, fn in runs:
        res, t = timed(fn)
        row = {"method": method, "setting": setting, "ms_per_point": t / m * 1e3}
        row.update(errors(res.irradiance, res.form_factors, h_ref, f_ref))
        log(f"[{key}] {method} {setting}: {row['ms_per_point']:.3f} ms/pt, RMS {row['irr_rms']:.2e}")
        rows.append(row)
    if check_spp:  # the exact method against an independent reference: high-count Monte Carlo
        q = min(m, 128)
        res, _ = timed(monte_carlo, scene, p[:q], n[:q], check_spp, rng=seed + 1, bvh=bvh)
        se = luminance(res.stderr)
        ok = se > 0
        z = np.abs(luminance(h_ref[:q]) - luminance(res.irradiance))[ok] / se[ok]
        fq = f_ref[:q]
        zf = np.abs(res.form_factors - fq) / np.sqrt(np.maximum(fq * (1 - fq), 1e-30) / check_spp)
        normal = fq * check_spp >= 20  # the normal approximation of the binomial holds there
        exact["mc_check"] = {"setting": f"{check_spp} spp on {q} points", "z_max": float(z.max()),
                             "z_rms": float(np.sqrt(np.mean(z**2))), "within_3se": float(np.mean(z <= 3.0)),
                             "ff_z_max": float(zf[normal].max()), "ff_entries": int(normal.sum()),
                             # rays hitting a polygon the exact method finds invisible would be a visibility error
                             "hits_where_exact_zero": int(((res.form_factors > 0) & (fq == 0)).sum())}
        log(f"[{key}] exact vs MC: {exact['mc_check']}")
    return {"scene": key, "polygons": box.n_polygons, "points": m, "rows": rows}


def paper_table(sc):
    """The paper's table 5/6 layout: methods as columns."""
    rows = sc["rows"]
    cols = [f"{r['method']} {r['setting']}".strip() for r in rows]
    lines = [f"Scene with {sc['polygons']} polygons, {sc['points']} camera-visible points", "",
             "| Method | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]

    def fmt(v, spec):
        return "—" if v is None else format(v, spec)

    lines.append("| max FF sum | " + " | ".join(fmt(r.get("ff_sum_max"), ".2e") for r in rows) + " |")
    lines.append("| Time/pixel (s) | " + " | ".join(fmt(r["ms_per_point"] / 1e3, ".2e") for r in rows) + " |")
    lines.append("| RMS irradiance error | " + " | ".join(fmt(r.get("irr_rms", 0.0), ".2e") for r in rows) + " |")
    lines.append("| max irradiance error | " + " | ".join(fmt(r.get("irr_max", 0.0), ".2e") for r in rows) + " |")
    lines.append("| max per-polygon F error | " + " | ".join(fmt(r.get("ff_max", 0.0), ".2e") for r in rows) + " |")
    return "\n".join(lines)


def plot(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4.5), squeeze=False)
    for ax, sc in zip(axes[0], results, strict=True):
        by = {}
        for r in sc["rows"]:
            by.setdefault(r["method"], []).append(r)
        for method, rs in by.items():
            if method == "exact":
                # its error against the closed-scene reference (ΣF = 1); floored for the log axis
                err = max(rs[0]["ff_sum_max"], 1e-16)
                ax.plot([rs[0]["ms_per_point"]], [err], "k*", ms=14, label=f"exact (max |ΣF−1| = {err:.0e})")
                continue
            ax.plot([r["ms_per_point"] for r in rs], [max(r["irr_rms"], 1e-16) for r in rs], "o-", label=method)
            for r in rs:
                ax.annotate(r["setting"].split()[0], (r["ms_per_point"], max(r["irr_rms"], 1e-16)), fontsize=7,
                            textcoords="offset points", xytext=(3, 3))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time per point (ms)")
        ax.set_ylabel("RMS irradiance error (relative to mean)")
        ax.set_title(f"Cornell box, {sc['polygons']} polygons, {sc['points']} points")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(machine(), fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=1024)
    ap.add_argument("--scenes", default="small,large")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="fewer settings (smoke test)")
    ap.add_argument("--out", default=str(DOCS / "bench_methods"), help="output path prefix (.md, .json, .png)")
    args = ap.parse_args(argv)
    settings = {"hemicube": [50, 100, 200], "raytraced": [4, 16, 64], "mc": [64, 256, 1024, 4096]}
    if args.quick:
        settings = {"hemicube": [50], "raytraced": [4], "mc": [64, 256]}
    check = 2048 if args.quick else 16384
    results = [run_scene(k, args.points, args.seed, settings, check) for k in args.scenes.split(",")]
    md = [f"# Run time against error: exact method and baselines\n\nMachine: {machine()}\n",
          f"Command: `OMP_NUM_THREADS=1 python benchmarks/bench_methods.py --points {args.points} "
          f"--scenes {args.scenes}`\n",
          "Errors are relative to the mean exact irradiance (luminance); time is wall-clock per point, single "
          "process. The exact method's own error is checked against the closed scene's ΣF = 1 and against "
          "the highest-count Monte Carlo run.\n"]
    for sc in results:
        md.append(paper_table(sc) + "\n")
        ex = sc["rows"][0]
        if "mc_check" in ex:
            c = ex["mc_check"]
            md.append(f"Exact vs Monte Carlo {c['setting']}: max |ΔH|/stderr {c['z_max']:.2f}, RMS {c['z_rms']:.2f}, "
                      f"{100 * c['within_3se']:.1f} % of points within 3 standard errors; per-polygon form factors "
                      f"within {c['ff_z_max']:.2f} binomial standard deviations (the {c['ff_entries']} entries "
                      f"with F·N ≥ 20); {c['hits_where_exact_zero']} MC hits on polygons the exact method "
                      f"finds invisible.\n")
        md.append("| method | setting | ms/point | RMS irr. err | max irr. err | bias | max abs(ΣF−1) | max abs(ΔF) "
                  "| mean Σ abs(ΔF) |")
        md.append("|---|---|---|---|---|---|---|---|---|")
        for r in sc["rows"]:
            md.append(f"| {r['method']} | {r['setting']} | {r['ms_per_point']:.3f} | {r.get('irr_rms', 0):.2e} | "
                      f"{r.get('irr_max', 0):.2e} | {r.get('irr_bias', 0):+.1e} | {r.get('ff_sum_max', 0):.2e} | "
                      f"{r.get('ff_max', 0):.2e} | {r.get('ff_l1', 0):.2e} |")
        md.append("")
    text = "\n".join(md)
    print(text)
    prefix = args.out
    with open(prefix + ".md", "w", encoding="utf-8") as fh:
        fh.write(text + "\n")
    with open(prefix + ".json", "w", encoding="utf-8") as fh:
        json.dump({"machine": machine(), "results": results}, fh, indent=1)
    plot(results, prefix + ".png")
    log(f"wrote {prefix}.md, .json, .png")


if __name__ == "__main__":
    main()
