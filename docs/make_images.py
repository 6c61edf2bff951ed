"""Regenerate the user guide's pictures: every sample's local pass beside Cycles at equal time.

    bash scripts/make_docs_images.sh [--samples cornell_box,numerical_traps,...] [--resolution N]

(every sample by default, each at its own resolution unless ``--resolution`` is given: the Cornell box at
96², the others at 48² — their exact point evaluations cost 0.01–0.2 s each here; ~1 h in all on the
shared 2-core machine).

(runs this file in the bpy 4.2 venv). For each sample: build and solve it with its own script
(sample_scenes/NAME.py), render the exact local pass (the batch job, pixels mode), then Cycles with the
scene's own materials (full path tracing, default bounces, Standard view transform) with its time limit
set to the local pass's time, and write ``docs/guide/NAME.png`` (local pass left, Cycles right) and the
table in ``docs/guide/images.md``.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
GUIDE = os.path.join(ROOT, "docs", "guide")
DEFAULT = "cornell_box,numerical_traps,furnished_room,cornell_box_9500,cornell_box_100k"
#: resolution of each sample's picture when --resolution is not given
RESOLUTION = {"cornell_box": 96, "numerical_traps": 48, "furnished_room": 48, "cornell_box_9500": 48,
              "cornell_box_100k": 32}
#: samples whose local pass is computed by the core on the numeric box's float64 coordinates by default
#: (on Blender's float32 copy the core's visibility is > 50x slower per point at 10^5 polygons)
NUMERIC = {"cornell_box_100k"}
#: the build arguments of each sample's picture (the 9,468-polygon box with the clustered first pass, as the
#: flat one takes ~10-45 min here; docs/first-pass.md)
ARGS = {"cornell_box": ["--subdivisions", "4"], "cornell_box_9500": ["--clusters", "300"], "furnished_room": [],
        "numerical_traps": [], "cornell_box_100k": []}


def load(name):
    spec = importlib.util.spec_from_file_location(f"sample_{name}", os.path.join(ROOT, "sample_scenes", f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def pixels(path):
    import bpy

    img = bpy.data.images.load(path)
    w, h = img.size
    px = np.empty(4 * w * h, dtype=np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)


def save_png(path, rgba):
    import bpy

    h, w = rgba.shape[:2]
    img = bpy.data.images.new(".guide", w, h, alpha=False)
    img.pixels.foreach_set(rgba.astype(np.float32).reshape(-1))
    img.filepath_raw = path
    img.file_format = "PNG"
    img.save()
    bpy.data.images.remove(img)


def numeric_local_pass(name, resolution):
    """The exact local pass of a Cornell-box sample by the core on the numeric box (float64 coordinates), with
    the radiosity attribute of the open .blend; ``(rgba (h, w, 4) bottom row first, seconds, points)``."""
    import bpy

    from hemisphere_local_pass.core import radiance
    from hemisphere_local_pass.core.raycast import build_bvh, cast_rays
    from hemisphere_local_pass.scenes import camera_rays, cornell_box

    settings = {"cornell_box": dict(subdivisions=4), "cornell_box_9500": dict(subdivisions=35, block_detail=1.05),
                "cornell_box_100k": dict(subdivisions=120, block_detail=1.05)}[name]
    t0 = time.perf_counter()
    box = cornell_box(**settings)
    names = np.array(box.names)
    lum = np.zeros((box.n_polygons, 3))
    for part in dict.fromkeys(box.names):  # the attribute in the box's polygon order (cornell_box.build)
        mesh = bpy.data.objects[part.title().replace(" ", "")].data
        got = np.empty(4 * len(mesh.polygons), dtype=np.float32)
        mesh.attributes["radiosity"].data.foreach_get("color", got)
        lum[names == part] = got.reshape(-1, 4)[:, :3]
    scene = box.scene(radiance=lum)
    o, d = camera_rays(box, resolution)
    hits = cast_rays(scene, o, d, bvh=build_bvh(scene))
    hit = np.flatnonzero(hits.hit)
    src = hits.source[hit]
    out = np.zeros((resolution * resolution, 3))
    out[hit] = radiance(scene, hits.point[hit], scene.poly_normals[hits.polygon[hit]], box.reflectivity[src],
                        box.emission[src])
    seconds = time.perf_counter() - t0
    lin = np.clip(out, 0.0, 1.0)
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)  # Standard view transform
    rgba = np.concatenate([srgb, np.ones((len(srgb), 1))], axis=1).reshape(resolution, resolution, 4)
    return rgba[::-1].copy(), seconds, len(hit)


def one(name, resolution, tmp, blend=None, numeric=False):
    import bpy

    from hemisphere_local_pass.blender import job

    t0 = time.perf_counter()
    if blend:  # built before (its build time is in its own log)
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(blend))
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = resolution
    else:
        load(name).main([os.path.join(tmp, f"{name}.blend"), "--resolution", str(resolution), *ARGS[name]])
    solve_s = float("nan") if blend else time.perf_counter() - t0
    scene = bpy.context.scene
    if numeric:
        left, local_s, points = numeric_local_pass(name, resolution)
    else:
        exr = os.path.join(tmp, f"{name}.exr")
        report = job.run_local_pass(scene, output=exr, mode="pixels", samples=1)
        local_s, points = report.seconds, report.points
        left = pixels(next(p for p in report.outputs if p.endswith(".png")))
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1 << 16
    scene.cycles.use_denoising = False
    scene.cycles.time_limit = max(local_s, 1.0)
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = os.path.join(tmp, f"{name}_cycles.png")
    t1 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    cycles_s = time.perf_counter() - t1
    right = pixels(scene.render.filepath)
    gap = np.ones((left.shape[0], 4, 4), dtype=np.float32)
    os.makedirs(GUIDE, exist_ok=True)
    save_png(os.path.join(GUIDE, f"{name}.png"), np.concatenate([left, gap, right], axis=1))
    return dict(name=name, solve=solve_s, local=local_s, cycles=cycles_s, points=points, resolution=resolution,
                blend=blend, numeric=numeric)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", default=DEFAULT)
    ap.add_argument("--resolution", type=int, default=None, help="square image size (default: per sample)")
    ap.add_argument("--blend", default=None, help="one sample: open this .blend (built before) instead of building it")
    ap.add_argument("--numeric", action="store_true",
                    help="Cornell boxes: the local pass by the core on the numeric box's float64 coordinates (the "
                         "Blender job's float32 ones make the core's visibility far slower at 10^5 polygons)")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.samples.split(","):
            rows.append(one(name, args.resolution or RESOLUTION.get(name, 96), tmp, args.blend,
                            args.numeric or name in NUMERIC))
            print(rows[-1], flush=True)
    table = os.path.join(GUIDE, "images.md")
    old = {}
    if os.path.isfile(table):  # keep the rows of samples not redone in this run
        for line in open(table).read().splitlines():
            if line.startswith("| ") and not line.startswith("| sample") and "`" in line:
                old[line.split("|")[1].strip()] = line
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    for r in rows:
        cmd = f"`bash scripts/make_docs_images.sh --samples {r['name']} --resolution {r['resolution']}`"
        if r["blend"]:
            cmd = cmd[:-1] + f" --blend {os.path.relpath(r['blend'], ROOT)}`"
        if r["numeric"]:
            cmd += " (local pass by the core on float64 coordinates)"
        if ARGS[r["name"]] and not r["blend"]:
            cmd += f" (builds with `{' '.join(ARGS[r['name']])}`)"
        built = "built before" if r["blend"] else f"{r['solve']:.0f} s"
        old[r["name"]] = (f"| {r['name']} | {built} | {r['local']:.0f} s ({r['points']} points) | "
                          f"{r['cycles']:.0f} s | {cmd} ({stamp}) | ![{r['name']}]({r['name']}.png) |")
    lines = ["Left: the exact local pass; right: Cycles path tracing of the scene's own materials with its time limit "
             "set to the local pass's time (2 shared cores, other jobs running). Each row gives the command that "
             "regenerates it.",
             "", "| sample | build + first pass | local pass | Cycles (time limit) | command | picture |",
             "|---|---|---|---|---|---|"]
    lines += [old[k] for k in sorted(old)]
    with open(table, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]))
