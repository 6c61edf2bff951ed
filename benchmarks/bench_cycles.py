"""Cycles against the exact local pass (issue 3): time to reach 1 % and 0.1 % RMS error on a 256² image.

Runs in a Python with the ``bpy`` module (Blender 4.2 LTS as a module)::

    source scripts/envs.sh; source scripts/bpy_envs.sh
    OMP_NUM_THREADS=1 "$(bpy_python 4.2)" benchmarks/bench_cycles.py [--scenes small] [--size 256]

The Cycles scene is built from ``scenes.cornell_box`` with the first-pass radiance L of every polygon
(``benchmarks/_common.py``). Every polygon gets its own material, the local-pass equivalent with constant
colours: a Diffuse BSDF of colour ρ added to an Emission of colour E for camera rays and L for all other
rays (a Mix Shader on Light Path "Is Camera Ray"),
with max bounces 0: a pixel is ``E + ρ Σ_i F_i L_i`` — the exact method's ``E + ρ/π H`` (eq. 5, the
core's ``radiance``, with ``H = π Σ L F`` its ``irradiance``). No clamping, no denoising, no adaptive
sampling, black world, Standard view transform, Gaussian pixel filter of width 0.01 (samples at the pixel
centres, where the exact image is evaluated), 2 CPU threads. The front wall closes the box but is
invisible to camera rays.

``--materials buckets`` builds the same image in expectation with few materials, for boxes where a
material per polygon cannot be built (bpy 4.2: ~187,588 polygons; docs/bench_time_vs_error.md): the
emitters (E > 0) keep one each; the other polygons share one per reflectivity and radiance level (each
channel rounded to a power of :data:`BUCKET_RATIO`), reading ``L / level`` per channel from a face
attribute. Cycles' light sampling weighs each polygon by its material's estimate, which is then its own
L to within 2.5 % per channel (:func:`_bucket_material`).

Three light-sampling modes: Blender's defaults (light tree on), light tree off, and BSDF sampling only
(``emission_sampling = 'NONE'``). For each samples-per-pixel setting it prints the render time and the
RMS, max and mean (bias) error of the radiance image against the exact image (luminance, relative to the
mean), and interpolates (log-log) the time to reach 1 % and 0.1 % RMS error. Results go to
``docs/bench_cycles.md`` and ``docs/bench_cycles.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CACHE, ROOT, log, luminance, machine, solved_radiance  # noqa: E402

from hemisphere_local_pass.core import radiance  # noqa: E402
from hemisphere_local_pass.core.raycast import cast_rays  # noqa: E402
from hemisphere_local_pass.scenes import PAPER_SETTINGS, camera_rays, cornell_box  # noqa: E402

DOCS = ROOT / "docs"

#: Sub-pixel lens shift (in pixels) of both the Cycles camera and the exact image. The classic frame
#: is symmetric: the box's edges project onto the image diagonals, exactly through pixel centres, where
#: the exact value at the centre (a point on an edge) differs from the average Cycles takes over its
#: 0.01-pixel filter. A shift that is not a multiple of the pixel keeps every centre off those edges.
SHIFT_PX = (0.13, 0.07)


def shifted_camera_rays(box, size, shift=SHIFT_PX):
    """Camera rays through the pixel centres moved by ``shift`` pixels (default :data:`SHIFT_PX`, Blender's
    lens shift), started just inside the front wall like :func:`scenes.camera_rays`; ``(size², 3)`` each,
    top row first."""
    o, d = camera_rays(box, size)
    cam = box.camera
    fwd = cam["direction"] / np.linalg.norm(cam["direction"])
    right = np.cross(fwd, cam["up"])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    px = 2.0 * np.tan(0.5 * cam["fov"]) / size  # pixel size on the image plane at distance 1
    d = d / (d @ fwd)[:, None] + px * (shift[0] * right + shift[1] * up)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t0 = (1e-9 * box.size - cam["location"][1]) / d[:, 1]
    return cam["location"] + t0[:, None] * d, d


def exact_image(key, box, lum, size):
    """``(size, size, 3)`` exact radiance image ``E + ρ/π H`` (eq. 5; top row first) and its seconds; cached."""
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"exact_image_{key}_{box.n_polygons}_{size}_shift{SHIFT_PX[0]}_{SHIFT_PX[1]}.npz"
    if path.exists():
        z = np.load(path)
        return z["image"], float(z["seconds"])
    scene = box.scene(radiance=lum)
    o, d = shifted_camera_rays(box, size)
    t = time.perf_counter()
    h = cast_rays(scene, o, d)
    src = h.source
    pts, nrm = h.point, scene.poly_normals[h.polygon]
    img = np.zeros((len(o), 3))
    step = 1024
    for s in range(0, len(o), step):
        sl = slice(s, s + step)
        # eq. 5: E + ρ/π H (H = π Σ F L, so E + ρ Σ F L: what a diffuse BSDF of albedo ρ reflects)
        img[sl] = radiance(scene, pts[sl], nrm[sl], box.reflectivity[src[sl]], box.emission[src[sl]])
        log(f"[exact {key}] {min(s + step, len(o))}/{len(o)} points, {time.perf_counter() - t:.0f} s")
    seconds = time.perf_counter() - t
    np.savez(path, image=img.reshape(size, size, 3), seconds=seconds)
    return img.reshape(size, size, 3), seconds


#: ``materials="buckets"``: the ratio between neighbouring radiance levels of one channel
BUCKET_RATIO = 1.05


def _new_material(name):
    """A node material with no nodes: ``(material, node tree, its new Material Output node)``."""
    import bpy

    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    return mat, nt, nt.nodes.new("ShaderNodeOutputMaterial")


def _wire_local_pass(nt, out, bsdf, other_rays, camera_rays=None):
    """Link ``out``'s surface to ``bsdf + (Is Camera Ray ? camera_rays : other_rays)`` (emission shader outputs;
    ``camera_rays`` None: camera rays see no emission)."""
    add = nt.nodes.new("ShaderNodeAddShader")
    mix = nt.nodes.new("ShaderNodeMixShader")
    path = nt.nodes.new("ShaderNodeLightPath")
    nt.links.new(path.outputs["Is Camera Ray"], mix.inputs["Fac"])
    nt.links.new(other_rays, mix.inputs[1])
    if camera_rays is not None:
        nt.links.new(camera_rays, mix.inputs[2])
    nt.links.new(bsdf, add.inputs[0])
    nt.links.new(mix.outputs["Shader"], add.inputs[1])
    nt.links.new(add.outputs["Shader"], out.inputs["Surface"])


def _local_pass_template(name):
    """The local-pass material's nodes with constant colours (``rho``, ``L``, ``E``), to be copied per polygon."""
    template, nt, out = _new_material(name)
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.name = "rho"
    em_l = nt.nodes.new("ShaderNodeEmission")  # other rays: first-pass radiance L
    em_l.name = "L"
    em_e = nt.nodes.new("ShaderNodeEmission")  # camera rays: emission E
    em_e.name = "E"
    for em in (em_l, em_e):
        em.inputs["Strength"].default_value = 1.0
    _wire_local_pass(nt, out, diffuse.outputs["BSDF"], em_l.outputs["Emission"], em_e.outputs["Emission"])
    return template


def _bucket_material(name, rho, level):
    """A bucket's material: a Diffuse BSDF of constant colour ``rho`` (3,); for rays other than camera rays
    ``L = Σ_c level_c · a_c``, one Emission per channel c of colour ``level_c`` on channel c alone and strength
    ``a_c`` from the face attribute ``local_pass_a`` (``L / level``, per channel); camera rays see no emission
    (E = 0 here: emitters keep their own materials).

    Cycles estimates an Emission node with a linked strength as its colour (``Shader::estimate_emission``),
    so a polygon's estimate is ``level``, its own L within the square root of :data:`BUCKET_RATIO` in every
    channel: the light tree weighs it (``area · average(estimate)``) as the per-polygon recipe does, to that
    ratio. (One grey level per bucket of mean radiance instead, with the colour from the attribute, gave
    1.2× the RMS at 16 spp on the 175-polygon box, 64²; this gives the per-polygon recipe's.)
    """
    mat, nt, out = _new_material(name)
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (*rho, 1.0)
    if not np.any(np.asarray(level) > 0.0):
        nt.links.new(diffuse.outputs["BSDF"], out.inputs["Surface"])
        return mat
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = "local_pass_a"
    sep = nt.nodes.new("ShaderNodeSeparateColor")  # RGB mode: the channels as they are
    nt.links.new(attr.outputs["Color"], sep.inputs["Color"])
    emission = None
    for c, channel in enumerate(("Red", "Green", "Blue")):
        if level[c] <= 0.0:
            continue
        em = nt.nodes.new("ShaderNodeEmission")
        col = [0.0, 0.0, 0.0, 1.0]
        col[c] = float(level[c])
        em.inputs["Color"].default_value = col
        nt.links.new(sep.outputs[channel], em.inputs["Strength"])
        if emission is None:
            emission = em.outputs["Emission"]
        else:
            both = nt.nodes.new("ShaderNodeAddShader")
            nt.links.new(emission, both.inputs[0])
            nt.links.new(em.outputs["Emission"], both.inputs[1])
            emission = both.outputs["Shader"]
    _wire_local_pass(nt, out, diffuse.outputs["BSDF"], emission)  # camera rays: no emission
    return mat


def radiance_buckets(rho, lum, ratio=BUCKET_RATIO):
    """Buckets for ``materials="buckets"``: ``(rho (k, 3), level (k, 3), bucket (n,) int)``.

    Polygons share a bucket when their reflectivity ``rho (n, 3)`` is the same and each channel of their
    radiance ``lum (n, 3)`` rounds to the same ``level_c = ratio**round(log_ratio L_c)`` (0 where L_c = 0),
    so ``L_c / level_c`` lies in ``[ratio**-0.5, ratio**0.5]``.
    """
    lum = np.asarray(lum, dtype=np.float64)
    pos = lum > 0.0
    q = np.where(pos, np.round(np.log(np.where(pos, lum, 1.0)) / np.log(ratio)), -1e9)
    keys, bucket = np.unique(np.column_stack([np.asarray(rho, dtype=np.float64), q]), axis=0, return_inverse=True)
    level = np.where(keys[:, 3:] > -1e8, ratio ** keys[:, 3:], 0.0)
    return keys[:, :3], level, bucket.reshape(-1)


def build_blender_scene(box, lum, size, threads, materials="polygon"):
    """bpy scene of the local-pass equivalent (module docstring); ``(scene, materials)``.

    ``materials``: ``"polygon"``, one material per polygon with constant colours (the recipe of every
    table before 2026-12-07); ``"buckets"``, one material per polygon for the emitters (E > 0) and, for
    the others, one per reflectivity and radiance level (:func:`radiance_buckets`) reading ``L / level``
    from a face attribute (:func:`_bucket_material`): the same image in expectation, Cycles' light-sampling
    weights within the square root of :data:`BUCKET_RATIO` per channel of the per-polygon ones, and buildable
    at 187,588 polygons (per-polygon materials are not, in bpy 4.2: docs/bench_time_vs_error.md).
    """
    import bpy

    if materials not in ("polygon", "buckets"):
        raise ValueError(f"materials must be 'polygon' or 'buckets', got {materials!r}")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    front = np.array([nm == "front wall" for nm in box.names])
    # Constant colours where a polygon has its own material: Cycles estimates each mesh light's power from
    # constant emission inputs (a colour driven by an attribute counts as 1), and its light sampling (light
    # tree or not) is only as good as that estimate (buckets: see _bucket_material).
    # One template material with the nodes, copied for every such polygon (``use_nodes`` on a new material
    # costs time in the number of materials: 4·10^4 took a minute and 1.9·10^5 would take most of an hour; a
    # copy costs a fraction of it)
    template = _local_pass_template("local_pass_template")
    own = np.ones(box.n_polygons, bool) if materials == "polygon" else np.asarray(box.emission).max(axis=1) > 0
    slot_of = np.empty(box.n_polygons, dtype=np.int64)  # index into mats
    mats = []
    for i in np.flatnonzero(own):
        mat = template.copy()
        mat.name = f"local_pass_{i:07d}"  # names in order: each is inserted at the end of the sorted list
        nodes = mat.node_tree.nodes
        nodes["rho"].inputs["Color"].default_value = (*box.reflectivity[i], 1.0)
        nodes["L"].inputs["Color"].default_value = (*lum[i], 1.0)
        nodes["E"].inputs["Color"].default_value = (*box.emission[i], 1.0)
        slot_of[i] = len(mats)
        mats.append(mat)
    bpy.data.materials.remove(template)
    l_attr = np.zeros((box.n_polygons, 3))  # L / level per channel: the bucketed polygons' emission strengths
    if not own.all():
        rest = np.flatnonzero(~own)
        rhos, levels, bucket = radiance_buckets(box.reflectivity[rest], lum[rest])
        for b, (rho, level) in enumerate(zip(rhos, levels)):
            mats.append(_bucket_material(f"local_pass_bucket_{b:05d}", rho, level))
        slot_of[rest] = len(mats) - len(levels) + bucket
        lv = levels[bucket]
        l_attr[rest] = np.where(lv > 0, lum[rest] / np.where(lv > 0, lv, 1.0), 0.0)
        log(f"buckets: {own.sum()} emitter materials, {len(levels)} bucket materials for {len(rest)} polygons")

    for label, sel in (("room", ~front), ("front_wall", front)):
        idx = np.flatnonzero(sel)
        polys = [box.polygons[i] for i in idx]
        mesh = bpy.data.meshes.new(label)
        mesh.from_pydata([tuple(v) for v in box.vertices], [], polys)
        mesh.update()
        used, local = np.unique(slot_of[idx], return_inverse=True)
        for k in used:
            mesh.materials.append(mats[k])
        mesh.polygons.foreach_set("material_index", local.reshape(-1).astype(np.int32))
        if materials == "buckets":
            attr = mesh.attributes.new("local_pass_a", "FLOAT_COLOR", "FACE")
            rgba = np.ones((len(idx), 4), dtype=np.float32)
            rgba[:, :3] = l_attr[idx]
            attr.data.foreach_set("color", rgba.reshape(-1))
        mesh.update()
        obj = bpy.data.objects.new(label, mesh)
        scene.collection.objects.link(obj)
        if label == "front_wall":
            obj.visible_camera = False  # closes the box for light, the camera looks through it

    cam_data = bpy.data.cameras.new("camera")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = float(box.camera["fov"])
    cam_data.shift_x = SHIFT_PX[0] / size  # in image widths
    cam_data.shift_y = SHIFT_PX[1] / size
    cam_data.clip_start = 1e-3 * box.size
    cam_data.clip_end = 100.0 * box.size
    cam = bpy.data.objects.new("camera", cam_data)
    cam.location = tuple(box.camera["location"])
    cam.rotation_euler = (np.pi / 2, 0.0, 0.0)  # local -Z (view) -> +Y, local +Y (up) -> +Z
    scene.collection.objects.link(cam)
    scene.camera = cam

    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0, 0, 0, 1)
    scene.world = world

    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x = r.resolution_y = size
    r.resolution_percentage = 100
    r.threads_mode = "FIXED"
    r.threads = threads
    r.film_transparent = False
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    c = scene.cycles
    c.device = "CPU"
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = 0
    c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = c.volume_bounces = 0
    c.transparent_max_bounces = 0
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.pixel_filter_type = "GAUSSIAN"
    c.filter_width = 0.01
    c.seed = 0
    return scene, mats


def render(scene, mats, spp, mode, path):
    import bpy

    c = scene.cycles
    c.samples = int(spp)
    c.use_light_tree = mode != "light tree off"
    for mat in mats:
        mat.cycles.emission_sampling = "NONE" if mode == "BSDF sampling only" else "AUTO"
    scene.render.filepath = str(path)
    t = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    seconds = time.perf_counter() - t
    img = bpy.data.images.load(str(path), check_existing=False)
    px = np.empty(len(img.pixels), dtype=np.float32)
    img.pixels.foreach_get(px)
    w, h = img.size
    bpy.data.images.remove(img)
    rgb = px.reshape(h, w, 4)[::-1, :, :3].astype(np.float64)  # Blender's rows run bottom to top
    return rgb, seconds


def time_to(errors, seconds, target):
    """Log-log interpolated render time at which the RMS error reaches ``target`` (None if not reached)."""
    e, t = np.asarray(errors), np.asarray(seconds)
    for i in range(1, len(e)):
        if e[i] <= target < e[i - 1]:
            f = (np.log(target) - np.log(e[i - 1])) / (np.log(e[i]) - np.log(e[i - 1]))
            return float(np.exp(np.log(t[i - 1]) + f * (np.log(t[i]) - np.log(t[i - 1]))))
    if len(e) and e[0] <= target:
        return float(t[0])
    return None


def extrapolate(errors, seconds, target):
    """Time to reach ``target`` from a power-law fit ``rms = a t^b`` to the last three settings, with b."""
    e, t = np.log(np.asarray(errors[-3:])), np.log(np.asarray(seconds[-3:]))
    if len(e) < 2:
        return None, None
    b, a = np.polyfit(t, e, 1)
    if b >= 0:
        return None, float(b)
    return float(np.exp((np.log(target) - a) / b)), float(b)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="small")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", default="1,4,16,64,256,1024,4096")
    ap.add_argument("--modes", default="default,light tree off,BSDF sampling only")
    ap.add_argument("--max-seconds", type=float, default=600.0, help="stop a mode once a render takes longer")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--materials", choices=("polygon", "buckets"), default="polygon",
                    help="one material per polygon, or the bucketed recipe (build_blender_scene)")
    ap.add_argument("--out", default=str(DOCS / "bench_cycles"))
    args = ap.parse_args(argv)
    import bpy

    spps = [int(s) for s in args.spp.split(",")]
    report = {"machine": machine(), "blender": bpy.app.version_string, "scenes": []}
    md = [f"# Cycles against the exact local pass\n\nMachine: {machine()}; Blender {bpy.app.version_string} "
          f"(bpy module), {args.threads} render threads\n",
          f"Command: `OMP_NUM_THREADS=1 \"$(bpy_python 4.2)\" benchmarks/bench_cycles.py --scenes {args.scenes} "
          f"--size {args.size} --spp {args.spp} --materials {args.materials}`\n",
          "Errors: radiance image (E + ρH/π) against the exact image, luminance, relative to its mean; "
          "bias = mean error. Times are wall-clock render times (scene sync included).\n"]
    for key in args.scenes.split(","):
        box = cornell_box(**PAPER_SETTINGS[key])
        lum = solved_radiance(key, box)
        exact, t_exact = exact_image(key, box, lum, args.size)
        y_exact = luminance(exact)
        mean = float(y_exact.mean())
        log(f"[{key}] exact image {args.size}² in {t_exact:.1f} s (cached or computed)")
        t = time.perf_counter()
        scene, mats = build_blender_scene(box, lum, args.size, args.threads, materials=args.materials)
        build = time.perf_counter() - t
        log(f"[{key}] bpy scene ({args.materials} materials) built in {build:.1f} s")
        entry = {"scene": key, "polygons": box.n_polygons, "exact_seconds": t_exact, "modes": {},
                 "materials": args.materials, "build_seconds": build}
        md.append(f"## {box.n_polygons} polygons, {args.size}×{args.size}\n")
        md.append(f"Exact image: {t_exact:.1f} s ({t_exact / args.size**2 * 1e3:.3f} ms per pixel).\n")
        md.append("| mode | spp | seconds | RMS error | max error | bias |")
        md.append("|---|---|---|---|---|---|")
        with tempfile.TemporaryDirectory() as tmp:
            for mode in args.modes.split(","):
                rows = []
                for spp in spps:
                    img, sec = render(scene, mats, spp, mode, Path(tmp) / f"r_{spp}.exr")
                    d = luminance(img) - y_exact
                    row = {"spp": spp, "seconds": sec, "rms": float(np.sqrt(np.mean(d * d)) / mean),
                           "max": float(np.abs(d).max() / mean), "bias": float(d.mean() / mean)}
                    rows.append(row)
                    log(f"[{key}] {mode} {spp} spp: {sec:.1f} s, RMS {row['rms']:.3e}, bias {row['bias']:+.2e}")
                    md.append(f"| {mode} | {spp} | {sec:.1f} | {row['rms']:.3e} | {row['max']:.3e} | "
                              f"{row['bias']:+.2e} |")
                    if sec > args.max_seconds:
                        break
                t1 = time_to([r["rms"] for r in rows], [r["seconds"] for r in rows], 0.01)
                t01 = time_to([r["rms"] for r in rows], [r["seconds"] for r in rows], 0.001)
                errs, secs = [r["rms"] for r in rows], [r["seconds"] for r in rows]
                x1, slope = extrapolate(errs, secs, 0.01)
                x01, _ = extrapolate(errs, secs, 0.001)
                entry["modes"][mode] = {"rows": rows, "seconds_to_1pct": t1, "seconds_to_0.1pct": t01,
                                        "fit_slope": slope, "extrapolated_1pct": x1, "extrapolated_0.1pct": x01}
        md.append("")
        for mode, m in entry["modes"].items():
            t1, t01 = m["seconds_to_1pct"], m["seconds_to_0.1pct"]

            def fmt(measured, extrapolated):
                if measured is not None:
                    return f"{measured:.1f} s"
                return "not reached" if extrapolated is None else f"~{extrapolated:.0f} s (extrapolated)"

            slope = "?" if m["fit_slope"] is None else f"{m['fit_slope']:.2f}"
            md.append(f"* {mode}: 1 % RMS in {fmt(t1, m['extrapolated_1pct'])}, 0.1 % RMS in "
                      f"{fmt(t01, m['extrapolated_0.1pct'])}; RMS ∝ time^{slope} over the last settings "
                      f"(exact image: {t_exact:.1f} s).")
        md.append("")
        report["scenes"].append(entry)
    text = "\n".join(md)
    print(text)
    with open(args.out + ".md", "w", encoding="utf-8") as fh:
        fh.write(text + "\n")
    with open(args.out + ".json", "w", encoding="utf-8") as fh:
        json.dump(report, fh, indent=1)


if __name__ == "__main__":
    main()
