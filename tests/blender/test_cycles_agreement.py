"""The exact local pass against Cycles on the same Cornell box (48 x 48 pixels).

Cycles settings that make a pixel equal the local pass ``E + rho/pi H`` (issue 2): each polygon's
shader is a Diffuse BSDF of rho added to an Emission that is E for camera rays and the radiosity
attribute L for every other ray (Light Path "Is Camera Ray"); max bounces 0, so a camera ray's
diffuse bounce sees the neighbours' L and nothing else; emission sampling off (BSDF sampling only,
unbiased: each sample contributes rho * L(omega)); no clamping, no denoising, black world, Standard
view transform, a Gaussian pixel filter of width 0.01 (a pixel is its centre, like our ray).

K renders with independent seeds give a per-pixel mean. Its noise: with BSDF-only sampling one
sample of a pixel is ``E + rho L(omega)``, omega cosine-distributed, so its variance is exactly
``rho^2 (sum_i F_i L_i^2 - (sum_i F_i L_i)^2)`` (visible form factors F_i from the core); the
per-pixel variance across the seeds is checked against it (the seeds are independent and Cycles'
stratified sampler is no noisier than that), and the z-scores of the exact image use it (an upper
bound: stratification only lowers the noise), because a per-pixel estimate from a few seeds is
useless where a bright, small source (the light) is hit by a handful of samples. Away from
geometric edges (pixels whose 3 x 3 neighbourhood sees one object) the z-scores must look like
noise: none beyond 6, few beyond 4, no overall bias.
"""

import importlib
import importlib.util
import os
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RESOLUTION = 48
SUBDIVISIONS = 4  # 172 polygons
SEEDS = 8
SAMPLES = 256  # per seed


def sample_module():
    spec = importlib.util.spec_from_file_location("hlp_sample_cornell_box_cycles",
                                                  os.path.join(ROOT, "sample_scenes", "cornell_box.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def cycles_material(name, rho, emit):
    """Diffuse(rho) + (Is Camera Ray ? Emission(E) : Emission(attribute radiosity))."""
    m = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):  # 5.0+: always node-based
        m.use_nodes = True
    nt = m.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "radiosity"
    attr.attribute_type = "GEOMETRY"
    path = nt.nodes.new("ShaderNodeLightPath")
    em_l = nt.nodes.new("ShaderNodeEmission")
    em_l.inputs["Strength"].default_value = 1.0
    nt.links.new(attr.outputs["Color"], em_l.inputs["Color"])
    em_e = nt.nodes.new("ShaderNodeEmission")
    em_e.inputs["Strength"].default_value = 1.0
    em_e.inputs["Color"].default_value = (*emit, 1.0)
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(path.outputs["Is Camera Ray"], mix.inputs[0])
    nt.links.new(em_l.outputs[0], mix.inputs[1])
    nt.links.new(em_e.outputs[0], mix.inputs[2])
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (*rho, 1.0)
    diffuse.inputs["Roughness"].default_value = 0.0
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(diffuse.outputs[0], add.inputs[0])
    nt.links.new(mix.outputs[0], add.inputs[1])
    nt.links.new(add.outputs[0], out.inputs["Surface"])
    if hasattr(m.cycles, "emission_sampling"):  # 4.0+
        m.cycles.emission_sampling = "NONE"
    else:  # 3.x
        m.cycles.sample_as_light = False
    return m


def setup_cycles(scene, samples):
    r = scene.render
    r.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = samples
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = 0
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.pixel_filter_type = "GAUSSIAN"
    c.filter_width = 0.01
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    world = scene.world
    world.color = (0.0, 0.0, 0.0)
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = False
    else:  # always node-based: a black background
        for node in world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
                node.inputs["Strength"].default_value = 0.0
    r.threads_mode = "FIXED"
    r.threads = 2
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"


def render(scene, path, seed):
    """One Cycles render -> (H, W, 3) float64, row 0 at the bottom."""
    import OpenEXR

    scene.cycles.seed = seed
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    ch = OpenEXR.File(path, separate_channels=True).channels()
    return np.stack([np.asarray(ch[k].pixels) for k in ("R", "G", "B")], axis=-1)[::-1].astype(np.float64)


def core_irradiance_factor(core):
    """H / (L F) of the core for a closed-form case: pi if ``irradiance`` is the physical integral
    of eq. 1 (W m^-2), 1 if it is eq. 3's sum of L F taken literally."""
    a = 1.0
    sc = core.Scene.from_polygons(np.array([(-a, -a, 1), (-a, a, 1), (a, a, 1), (a, -a, 1)], float),
                                  [[0, 1, 2, 3]], np.ones((1, 3)))
    p, n = np.zeros((1, 3)), np.array([(0.0, 0.0, 1.0)])
    return float(core.irradiance(sc, p, n)[0, 0] / core.form_factors(sc, p, n).sum())


@pytest.mark.slow
def test_cycles_agrees_with_the_exact_local_pass(extension, scene, tmp_path):
    job = importlib.import_module(extension.__name__ + ".blender.job")
    core = importlib.import_module(extension.__name__ + ".core")
    mod = sample_module()
    from hemisphere_local_pass.scenes.cornell_box import cornell_box

    box0 = cornell_box(SUBDIVISIONS)
    values = box0.emission + 0.05 + 0.3 * np.random.default_rng(3).random((box0.n_polygons, 3))
    sc, box, values = mod.build(SUBDIVISIONS, resolution=RESOLUTION, reset=False, radiosity=values)
    t0 = time.perf_counter()
    rep = job.run_local_pass(output=str(tmp_path / "exact.exr"), preview=False)
    t_exact = time.perf_counter() - t0
    res = rep.result
    names = np.array(box.names)
    for part in dict.fromkeys(box.names):
        ob = bpy.data.objects[part.title().replace(" ", "")]
        i = int(np.flatnonzero(names == part)[0])
        rho = [float(v) for v in np.float32(box.reflectivity[i])]
        emit = [float(v) for v in np.float32(box.emission[i])]
        ob.data.materials.clear()
        ob.data.materials.append(cycles_material(part, rho, emit))
    setup_cycles(sc, SAMPLES)
    t0 = time.perf_counter()
    imgs = np.array([render(sc, str(tmp_path / f"cycles{s}.exr"), s) for s in range(SEEDS)])
    t_cycles = time.perf_counter() - t0
    mean = imgs.mean(axis=0)
    seed_var = imgs.var(axis=0, ddof=1) * SAMPLES  # per-sample variance seen across the seeds

    # pixels away from geometric edges: the 3 x 3 neighbourhood sees a single object
    obj = res["object_index"]
    pad = np.pad(obj, 1, mode="edge")
    same = np.ones_like(obj, dtype=bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            same &= pad[1 + dy:1 + dy + obj.shape[0], 1 + dx:1 + dx + obj.shape[1]] == obj

    # per-sample variance of BSDF sampling at the same points (independent scene from the box arrays)
    cam = importlib.import_module(extension.__name__ + ".blender.camera")
    raycast = importlib.import_module(extension.__name__ + ".core.raycast")
    params = cam.camera_params(sc)
    _, _, sx, sy = cam.pixel_samples(cam.pixel_window(params))
    o, d, t_lo, t_hi = cam.camera_rays(params, sx, sy)
    verts = np.float32(box.vertices).astype(np.float64)
    lin = np.float32(values).astype(np.float64)
    sq = core.Scene.from_polygons(verts, box.polygons, lin * lin)
    ref = core.Scene.from_polygons(verts, box.polygons, lin)
    hits = raycast.cast_rays(ref, o, d, t_min=t_lo, t_max=t_hi)
    nrm = np.where(hits.front[:, None], ref.poly_normals[hits.polygon], -ref.poly_normals[hits.polygon])
    factor = core_irradiance_factor(core)
    h1 = core.irradiance(ref, hits.point, nrm) / factor  # sum F L
    h2 = core.irradiance(sq, hits.point, nrm) / factor  # sum F L^2
    rho = np.float32(box.reflectivity[hits.source]).astype(np.float64)
    var = (rho * rho * np.maximum(h2 - h1 * h1, 0.0)).reshape(mean.shape)
    keep = same & (var.min(axis=-1) > 0)
    var_ratio = seed_var[keep].mean() / var[keep].mean()  # < 1: Cycles' samples are stratified
    stderr = np.sqrt(var / (SEEDS * SAMPLES))  # independent samples: an upper bound for Cycles' noise

    # the physically exact pixel: E + rho/pi H with H the integral of eq. 1 = pi sum L F
    emission = _emission_image(rep, box)
    reflected = res["radiance"] - emission
    exact_physical = emission + reflected * (np.pi / factor)
    z = (mean - exact_physical) / np.where(stderr > 0, stderr, 1.0)
    zk = z[keep]
    bias = (mean - exact_physical)[keep].sum(axis=0) / np.sqrt((stderr[keep] ** 2).sum(axis=0))
    print(f"\nexact {rep.points} px in {t_exact:.1f} s; Cycles {SEEDS} x {SAMPLES} spp in {t_cycles:.1f} s; "
          f"{keep.sum()} pixels away from edges; z: mean {zk.mean():+.3f} sd {zk.std():.3f} "
          f"max |z| {np.abs(zk).max():.2f}, |z|>4: {np.mean(np.abs(zk) > 4):.4f}; bias z per channel {bias}; "
          f"seed/theory variance {var_ratio:.3f}; core H/(L F) = {factor:.6f}")
    worst = np.unravel_index(np.argmax(np.where(keep[..., None], np.abs(z), 0)), z.shape)
    print(f"worst pixel (row, col, channel) {worst}: object {rep.objects[int(obj[worst[:2]])]}, "
          f"polygon {int(res['polygon_index'][worst[:2]])}, exact {exact_physical[worst[:2]]}, "
          f"Cycles {mean[worst[:2]]} +- {stderr[worst[:2]]}, seeds {imgs[(slice(None),) + worst[:2]][:, worst[2]]}")
    assert keep.sum() > 0.6 * keep.size
    assert 0.3 < var_ratio < 1.3, "Cycles' noise across seeds does not match BSDF sampling"
    assert np.abs(zk).max() < 6
    assert np.mean(np.abs(zk) > 4) < 0.01
    assert abs(zk.mean()) < 0.1 and 0.4 < zk.std() < 1.2
    assert np.all(np.abs(bias) < 5)
    # the core's H is the physical irradiance of eq. 1, pi sum(L F), so eq. 5 gives what Cycles renders
    assert np.isclose(factor, np.pi, rtol=1e-9), f"core.irradiance / sum(L F) = {factor}, want pi"
    np.testing.assert_allclose(exact_physical, res["radiance"], rtol=1e-12)


def _emission_image(rep, box):
    """E of the hit polygon per pixel (the camera-ray emission), from the job's object/polygon maps."""
    names = np.array(box.names)
    parts = list(dict.fromkeys(box.names))
    emit_of_object = []
    for obname in rep.objects:
        part = next(p for p in parts if p.title().replace(" ", "") == obname)
        emit_of_object.append(np.float32(box.emission[np.flatnonzero(names == part)[0]]).astype(np.float64))
    obj = rep.result["object_index"].astype(int)
    return np.where(obj[..., None] >= 0, np.array(emit_of_object)[np.maximum(obj, 0)], 0.0)
