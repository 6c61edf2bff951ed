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

The second test does the same on a scene built for the data path (issue 14.15): collection instances
(one mirrored), Array / Mirror / Solidify modifiers, a child of a non-uniformly scaled parent
(sheared), n-gons with non-affine CORNER (float) and POINT (byte colour) values (one concave), BYTE
and FLOAT colours, an object hidden from render above everything and one hidden in the viewport only,
seen by an orthographic and by a shifted perspective camera; 32 x 24 pixels, 4 seeds x 256 spp
(about 20 s per camera, most of it the exact job's linear-radiance evaluation). Measured on bpy 4.2:
z sd 0.42-0.46, max |z| 1.6 (the variance is an upper bound); with main's export (instances lost) the
image is 48-51 % off (max |z| 17-43), with the core's own n-gon triangulation 25-29 % (bias z 30-47).
"""

import importlib
import importlib.util
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from sample_loader import sample_module  # noqa: E402

RESOLUTION = 48
SUBDIVISIONS = 4  # 172 polygons
SEEDS = 8
SAMPLES = 256  # per seed




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


# ------------------------------------------------------------------------------------------------
# The data path (issue 14.13-15): what Cycles renders of a scene with instances, modifiers, sheared
# parenting, n-gons with non-affine POINT/CORNER values, byte and float colours, objects hidden from
# render, seen by an orthographic and a shifted perspective camera, is what the job computes.

FEATURE_RES = (32, 24)
FEATURE_SEEDS = 4
FEATURE_SAMPLES = 256  # per seed


def _feature_mesh(name, verts, faces, values, *, domain="FACE", dtype="FLOAT_COLOR", rho=(0.6, 0.6, 0.6)):
    """A mesh object (flat shaded) with a ``radiosity`` attribute and a Cycles material of reflectivity
    rho (its viewport colour rho too, which is what the export reads from a node tree without a
    Principled BSDF); E = 0."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in verts], [], [tuple(f) for f in faces])
    me.update()
    attr = me.attributes.new("radiosity", dtype, domain)
    n = len(attr.data)
    vals = np.broadcast_to(np.asarray(values, dtype=np.float64).reshape(-1, 3), (n, 3)) \
        if np.asarray(values).size in (3, 3 * n) else None
    assert vals is not None, (name, np.shape(values), n)
    attr.data.foreach_set("color", np.concatenate([vals, np.ones((n, 1))], axis=1).astype(np.float32).reshape(-1))
    mat = cycles_material(name, list(rho), [0.0, 0.0, 0.0])
    mat.diffuse_color = (*rho, 1.0)
    me.materials.append(mat)
    return bpy.data.objects.new(name, me)


def _box(x0, y0, z0, x1, y1, z1):
    v = [(x, y, z) for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)]
    f = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    return v, f


def build_feature_scene():
    """Returns the scene; every object emits its ``radiosity`` (both sides, as Cycles' Emission does)."""
    sc = bpy.context.scene
    link = sc.collection.objects.link
    rng = np.random.default_rng(14)
    # floor 6 x 6 in 3 x 3 quads, back wall, left wall (FACE, float)
    g = np.linspace(-3, 3, 4)
    fv = [(x, y, 0.0) for y in g for x in g]
    ff = [(j * 4 + i, j * 4 + i + 1, j * 4 + i + 5, j * 4 + i + 4) for j in range(3) for i in range(3)]
    link(_feature_mesh("Floor", fv, ff, 0.1 + 0.3 * rng.random((9, 3)), rho=(0.7, 0.7, 0.7)))
    link(_feature_mesh("BackWall", [(-3, 3, 0), (3, 3, 0), (3, 3, 3), (-3, 3, 3)], [(0, 1, 2, 3)],
                       (0.3, 0.25, 0.2), rho=(0.5, 0.6, 0.7)))
    # n-gons: a hexagon overhead with non-affine CORNER values (float), a concave L-shaped hexagon on the
    # left with non-affine POINT values (byte colours)
    hexv = [(0.9 * np.cos(a), 0.9 * np.sin(a) + 0.5, 1.8) for a in np.arange(6) * np.pi / 3]
    hexc = np.array([(0.1, 0.1, 0.1), (3.0, 2.0, 1.0), (0.1, 0.1, 0.1), (4.0, 4.0, 4.0), (0.1, 0.1, 0.1),
                     (1.0, 2.0, 3.0)])
    link(_feature_mesh("Hexagon", hexv, [(0, 1, 2, 3, 4, 5)], hexc, domain="CORNER"))
    ell = [(-2.5, -1, 0.2), (-2.5, 1, 0.2), (-2.5, 1, 0.8), (-2.5, 0, 0.8), (-2.5, 0, 1.8), (-2.5, -1, 1.8)]
    ellv = np.array([(0.05, 0.05, 0.05), (0.9, 0.1, 0.1), (0.05, 0.05, 0.05), (1.0, 1.0, 1.0), (0.05, 0.05, 0.05),
                     (0.1, 0.1, 0.9)])
    link(_feature_mesh("Ell", ell, [(0, 1, 2, 3, 4, 5)], ellv, domain="POINT", dtype="BYTE_COLOR"))
    # a collection of two objects instanced three times, one instance mirrored
    props = bpy.data.collections.new("Props")
    v, f = _box(-0.2, -0.2, 0.0, 0.2, 0.2, 0.5)
    props.objects.link(_feature_mesh("PropBox", v, f, 0.2 + 0.6 * rng.random((6, 3)), rho=(0.8, 0.5, 0.3)))
    props.objects.link(_feature_mesh("PropFlag", [(0.2, 0, 0.5), (0.7, 0, 0.5), (0.7, 0.1, 0.9), (0.2, 0, 0.9)],
                                     [(0, 1, 2, 3)], (0.9, 0.3, 0.1), dtype="BYTE_COLOR"))
    for j, (loc, scale) in enumerate([((-1.2, -0.8, 0), (1, 1, 1)), ((0.9, -0.6, 0), (-1, 1, 1)),
                                      ((1.6, 1.2, 0), (1, 1, 1.5))]):
        inst = bpy.data.objects.new(f"PropsInstance{j}", None)
        inst.instance_type = "COLLECTION"
        inst.instance_collection = props
        inst.location, inst.scale, inst.rotation_euler = loc, scale, (0, 0, 0.4 * j)
        link(inst)
    # modifiers: Array (3 bars), Mirror (a wedge and its mirror image), Solidify (a thick tilted plate)
    v, f = _box(0, 0, 0, 0.15, 0.6, 0.3)
    bars = _feature_mesh("Bars", v, f, 0.3 + 0.5 * rng.random((6, 3)))
    bars.location = (-0.6, 1.6, 0)
    arr = bars.modifiers.new("Array", "ARRAY")
    arr.count, arr.relative_offset_displace = 3, (2.5, 0, 0)
    link(bars)
    wedge = _feature_mesh("Wedge", [(0.3, 0, 0), (0.8, 0, 0), (0.3, 0, 0.6), (0.3, 0.4, 0)],
                          [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)], 0.2 + 0.8 * rng.random((4, 3)))
    wedge.location = (0.2, -1.8, 0)
    wedge.modifiers.new("Mirror", "MIRROR")  # about the object's x axis
    link(wedge)
    plate = _feature_mesh("Plate", [(-0.5, -0.4, 0), (0.5, -0.4, 0), (0.5, 0.4, 0), (-0.5, 0.4, 0)], [(0, 1, 2, 3)],
                          (0.6, 0.9, 0.6))
    plate.location, plate.rotation_euler = (2.0, -1.4, 0.5), (0.6, 0.0, 0.3)
    sol = plate.modifiers.new("Solidify", "SOLIDIFY")
    sol.thickness = 0.12
    link(plate)
    # parenting with shear: a rotated child of a non-uniformly scaled parent
    parent = bpy.data.objects.new("ShearParent", None)
    parent.location, parent.scale = (-1.6, 1.0, 0.0), (1.0, 2.2, 1.0)
    link(parent)
    v, f = _box(-0.25, -0.25, 0, 0.25, 0.25, 0.6)
    child = _feature_mesh("ShearedBox", v, f, 0.2 + 0.7 * rng.random((6, 3)), rho=(0.4, 0.7, 0.5))
    child.parent, child.rotation_euler = parent, (0, 0, 0.7)
    link(child)
    # hidden from render: a big occluder over everything (a render does not see it, nor may we)
    link(_feature_mesh("HiddenFromRender", [(-3, -3, 1.2), (3, -3, 1.2), (3, 3, 1.2), (-3, 3, 1.2)],
                       [(0, 1, 2, 3)], (5.0, 5.0, 5.0)))
    sc.objects["HiddenFromRender"].hide_render = True
    sc.render.resolution_x, sc.render.resolution_y = FEATURE_RES
    sc.render.resolution_percentage = 100
    if sc.world is None:
        sc.world = bpy.data.worlds.new("World")
    bpy.context.view_layer.update()
    m = np.array(child.matrix_world)[:3, :3]
    assert abs(np.dot(m[:, 0], m[:, 1])) > 0.1, "the child's world matrix is sheared"
    return sc


def _feature_camera(sc, kind):
    data = bpy.data.cameras.new(kind)
    cam = bpy.data.objects.new(kind, data)
    sc.collection.objects.link(cam)
    if kind == "ortho":
        data.type, data.ortho_scale = "ORTHO", 6.5
        cam.location, cam.rotation_euler = (0.0, -5.0, 4.5), (0.85, 0.0, 0.0)
    else:
        data.lens, data.shift_x, data.shift_y = 26.0, 0.12, -0.08
        cam.location, cam.rotation_euler = (3.0, -3.6, 2.8), (0.92, 0.0, 0.62)
    data.clip_start, data.clip_end = 0.1, 100.0
    sc.camera = cam
    bpy.context.view_layer.update()


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["perspective-shifted", "ortho"])
def test_cycles_agrees_on_instances_modifiers_ngons_and_cameras(extension, scene, tmp_path, kind):
    """Issue 14.15. Statistical bound as in the box test: per pixel the exact variance of one BSDF
    sample, rho^2 (sum F L^2 - (sum F L)^2) (an upper bound for Cycles' stratified sampler; with
    linear radiance sum F (L^2 interpolated) >= the integral of L^2, so still an upper bound),
    over FEATURE_SEEDS x FEATURE_SAMPLES samples; on pixels whose 3 x 3 neighbourhood sees one
    object: max |z| < 6, few |z| > 4, no bias per channel beyond 5 sigma of the mean."""
    job = importlib.import_module(extension.__name__ + ".blender.job")
    core = importlib.import_module(extension.__name__ + ".core")
    export = importlib.import_module(extension.__name__ + ".blender.scene_export")
    cam = importlib.import_module(extension.__name__ + ".blender.camera")
    raycast = importlib.import_module(extension.__name__ + ".core.raycast")
    sc = build_feature_scene()
    sc.objects["Ell"].hide_set(True)  # hidden in the viewport only: rendered, so computed
    _feature_camera(sc, kind)
    rep = job.run_local_pass(output=str(tmp_path / "exact.exr"), preview=False, double_sided=True)
    res = rep.result
    names = set(rep.objects)
    assert "HiddenFromRender" not in names and "Ell" in names
    assert {f"{p} (instance 0 of PropsInstance{j})" for p in ("PropBox", "PropFlag") for j in range(3)} <= names
    setup_cycles(sc, FEATURE_SAMPLES)
    imgs = np.array([render(sc, str(tmp_path / f"cycles{s}.exr"), s) for s in range(FEATURE_SEEDS)])
    mean = imgs.mean(axis=0)
    seed_var = imgs.var(axis=0, ddof=1) * FEATURE_SAMPLES

    obj = res["object_index"]
    pad = np.pad(obj, 1, mode="edge")
    same = np.ones_like(obj, dtype=bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            same &= pad[1 + dy:1 + dy + obj.shape[0], 1 + dx:1 + dx + obj.shape[1]] == obj
    same &= obj >= 0

    # the noise scale from the exported scene (its radiance squared), at the job's own hit points
    ex = export.export_scene(sc, double_sided=True)
    n_poly = {name: int(np.sum(ex.polygon_object == i)) for i, name in enumerate(ex.objects)}
    assert (n_poly["Bars"], n_poly["Wedge"], n_poly["Plate"]) == (18, 8, 6)  # Array x3, Mirror x2, Solidify
    ref = ex.scene
    sq = core.Scene(ref.poly_vertices, ref.poly_counts, ref.poly_source, ref.poly_radiance ** 2, ref.n_input,
                    corner_radiance=None if ref.corner_radiance is None else ref.corner_radiance ** 2,
                    double_sided=True)
    params = cam.camera_params(sc)
    _, _, sx, sy = cam.pixel_samples(cam.pixel_window(params))
    o, d, t_lo, t_hi = cam.camera_rays(params, sx, sy)
    hits = raycast.cast_rays(ref, o, d, t_min=t_lo, t_max=t_hi)
    hit = hits.hit
    nrm = np.where(hits.front[:, None], ref.poly_normals[np.maximum(hits.polygon, 0)],
                   -ref.poly_normals[np.maximum(hits.polygon, 0)])
    h1 = res["irradiance"].reshape(-1, 3)[hit] / np.pi  # sum F L: the job's H (eq. 1: pi sum F L)
    on = np.flatnonzero(hit)
    judged = same.reshape(-1)[on]  # only the judged pixels need the (linear, slow) second sum
    h2 = np.zeros_like(h1)
    h2[judged] = core.irradiance(sq, hits.point[on[judged]], nrm[on[judged]]) / np.pi  # sum F L^2 (bound)
    rho = ex.reflectivity[hits.source[hit]]
    var = np.zeros((len(hit), 3))
    var[hit] = rho * rho * np.maximum(h2 - h1 * h1, 0.0)
    var = var.reshape(mean.shape)
    keep = same & (var.min(axis=-1) > 0)
    stderr = np.sqrt(var / (FEATURE_SEEDS * FEATURE_SAMPLES))
    exact = res["radiance"]
    z = (mean - exact) / np.where(stderr > 0, stderr, 1.0)
    zk = z[keep]
    bias = (mean - exact)[keep].sum(axis=0) / np.sqrt((stderr[keep] ** 2).sum(axis=0))
    var_ratio = seed_var[keep].mean() / var[keep].mean()
    rel = np.abs(mean - exact)[keep].sum() / np.abs(exact)[keep].sum()
    print(f"\n{kind}: {rep.points} px, {len(rep.objects)} objects; {keep.sum()} pixels away from edges; "
          f"z mean {zk.mean():+.3f} sd {zk.std():.3f} max |z| {np.abs(zk).max():.2f}, |z|>4: "
          f"{np.mean(np.abs(zk) > 4):.4f}; bias z {bias}; seed/theory variance {var_ratio:.3f}; "
          f"mean |Cycles - exact| / exact {rel:.4f}")
    seen = {rep.objects[int(i)] for i in np.unique(obj[keep])}
    print("objects judged:", sorted(seen))
    assert keep.sum() > 0.3 * keep.size
    # the bound is an upper bound (Cycles stratifies: measured 0.10-0.14 here); far below it would
    # mean the variance estimate, not Cycles, is off
    assert 0.03 < var_ratio < 1.3, "Cycles' noise across seeds does not match BSDF sampling"
    assert np.abs(zk).max() < 6
    assert np.mean(np.abs(zk) > 4) < 0.01
    assert np.all(np.abs(bias) < 5)
