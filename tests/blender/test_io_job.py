"""The job end to end through the installed extension: pixels and vertices on the Cornell box against
the core on the same points, a closed form, tiles, interruption + resume, the command line."""

import importlib
import importlib.util
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from sample_loader import sample_module  # noqa: E402

TOL = 1e-9




@pytest.fixture
def hlp(extension, scene):
    base = extension.__name__
    return {
        "job": importlib.import_module(base + ".blender.job"),
        "outputs": importlib.import_module(base + ".blender.outputs"),
        "camera": importlib.import_module(base + ".blender.camera"),
        "core": importlib.import_module(base + ".core"),
        "raycast": importlib.import_module(base + ".core.raycast"),
    }


def first_pass_values(box):
    """Deterministic, non-trivial per-polygon radiosity (independent of the radiosity solver)."""
    rng = np.random.default_rng(3)
    return box.emission + 0.05 + 0.3 * rng.random((box.n_polygons, 3))


def build_box(domain="FACE", subdivisions=2, resolution=10):
    mod = sample_module()
    from hemisphere_local_pass.scenes.cornell_box import cornell_box

    values = first_pass_values(cornell_box(subdivisions))
    scene, box, values = mod.build(subdivisions, resolution=resolution, domain=domain, reset=False, radiosity=values)
    return scene, box, values


def object_polygon_to_box(report, box):
    """Map (object index, polygon index) of the job to the box's polygon ids."""
    names = np.array(box.names)
    table = {}
    for oi, obname in enumerate(report.objects):
        part = next(p for p in dict.fromkeys(box.names) if p.title().replace(" ", "") == obname)
        table[oi] = np.flatnonzero(names == part)
    return table


def f32(x):
    """Rounded to float32, as Blender stores coordinates, attributes and material colours."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)


def material_values(box):
    """(rho, E) per box polygon as the sample scene's materials store them (colour x strength)."""
    strength = box.emission.max(axis=1, keepdims=True)
    colour = np.divide(box.emission, strength, out=np.zeros_like(box.emission), where=strength > 0)
    return f32(box.reflectivity), f32(colour) * f32(strength)


def independent_scene(hlp, box, values, domain):
    """The core Scene built straight from the box arrays (float32-rounded like Blender's data)."""
    core = hlp["core"]
    verts = f32(box.vertices)
    if domain == "FACE":
        return core.Scene.from_polygons(verts, box.polygons, f32(values))
    # POINT: per part, the mean of the adjacent polygons' values at each vertex
    names = np.array(box.names)
    corner = []
    for i, poly in enumerate(box.polygons):
        same = np.flatnonzero(names == names[i])
        for v in poly:
            users = [j for j in same if v in box.polygons[j]]
            corner.append(values[users].mean(axis=0))
    return core.Scene.from_polygons(verts, box.polygons, corner_radiance=f32(corner))


@pytest.mark.parametrize("domain", ["FACE", "POINT"])
def test_pixels_match_core_on_the_same_points(hlp, tmp_path, domain):
    scene, box, values = build_box(domain)
    out = str(tmp_path / "box.exr")
    rep = hlp["job"].run_local_pass(output=out)
    assert rep.points == 100 and rep.max_form_factor_error < 1e-9 and not rep.black_occluders
    assert out in rep.outputs and str(tmp_path / "box.png") in rep.outputs
    res = rep.result
    # independent evaluation: the same camera rays against the box built from its own arrays
    cam = hlp["camera"]
    params = cam.camera_params(scene)
    px, py, sx, sy = cam.pixel_samples(cam.pixel_window(params))
    o, d, t0, t1 = cam.camera_rays(params, sx, sy)
    ref = independent_scene(hlp, box, values, domain)
    hits = hlp["raycast"].cast_rays(ref, o, d, t_min=t0, t_max=t1)
    assert hits.hit.all()
    table = object_polygon_to_box(rep, box)
    oi = res["object_index"].reshape(-1).astype(int)
    pi = res["polygon_index"].reshape(-1).astype(int)
    ours = np.array([table[a][b] for a, b in zip(oi, pi, strict=True)])
    same = ours == hits.source
    assert same.mean() > 0.9, "the two scenes disagree on which polygon most pixels see"
    n = np.where(hits.front[:, None], ref.poly_normals[hits.polygon], -ref.poly_normals[hits.polygon])
    p = hits.point
    rho, emit = material_values(box)
    lit = hlp["core"].radiance(ref, p[same], n[same], rho[hits.source[same]], emit[hits.source[same]])
    h = hlp["core"].irradiance(ref, p[same], n[same])
    np.testing.assert_allclose(res["radiance"].reshape(-1, 3)[same], lit, rtol=0, atol=TOL)
    np.testing.assert_allclose(res["irradiance"].reshape(-1, 3)[same], h, rtol=0, atol=TOL)
    np.testing.assert_allclose(res["depth"].reshape(-1)[same], hits.t[same], rtol=1e-12)
    # the EXR holds the same numbers (float32), Blender reads it, and the image datablock too
    layers, size, window, _ = hlp["outputs"].read_exr(out)
    assert size == (10, 10) and window == (0, 0, 10, 10)
    for key in ("radiance", "irradiance", "form_factor_sum", "depth", "object_index", "polygon_index", "alpha"):
        np.testing.assert_allclose(layers[key], res[key], rtol=1e-6, atol=1e-12, err_msg=key)
    img = bpy.data.images.load(out)
    px_b = np.empty(len(img.pixels), dtype=np.float32)
    img.pixels.foreach_get(px_b)
    np.testing.assert_allclose(px_b.reshape(10, 10, 4)[..., :3], res["radiance"], rtol=1e-6)
    local = bpy.data.images["Local Pass"]
    assert tuple(local.size) == (10, 10) and local.is_float
    png = bpy.data.images.load(str(tmp_path / "box.png"))
    assert tuple(png.size) == (10, 10)


def test_closed_form_parallel_square_emitter(hlp, tmp_path):
    """A receiver below the centre of a square emitter: H = L0 F with Lambert's closed form."""
    s = bpy.context.scene
    lamp = bpy.data.meshes.new("Lamp")
    a, c = 0.75, 1.0  # half side, height (exact in float32, as Blender stores them)
    lamp.from_pydata([(-a, -a, c), (-a, a, c), (a, a, c), (a, -a, c)], [], [(0, 1, 2, 3)])  # faces -z
    at = lamp.attributes.new("radiosity", "FLOAT_COLOR", "FACE")
    l0 = np.array([2.0, 1.0, 0.5])
    at.data.foreach_set("color", np.array([*l0, 1.0], dtype=np.float32))
    floor = bpy.data.meshes.new("Floor")
    floor.from_pydata([(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [], [(0, 1, 2, 3)])
    fa = floor.attributes.new("radiosity", "FLOAT_COLOR", "FACE")
    fa.data.foreach_set("color", np.zeros(4, dtype=np.float32))
    for me in (lamp, floor):
        s.collection.objects.link(bpy.data.objects.new(me.name, me))
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 0.5
    cam.location = (0, 0, 0.5)  # looks down -z between the two
    s.collection.objects.link(cam)
    s.camera = cam
    s.render.resolution_x = s.render.resolution_y = 4
    rep = hlp["job"].run_local_pass(output=None)
    res = rep.result
    xs = (np.arange(4) + 0.5) / 4 * 0.5 - 0.25
    x, y = np.meshgrid(xs, xs)  # row 0 at the bottom = smallest y

    def corner_ff(w, h):  # point below a corner of a parallel w x h rectangle at height c
        A, B = w / c, h / c
        return (A / np.sqrt(1 + A * A) * np.arctan(B / np.sqrt(1 + A * A))
                + B / np.sqrt(1 + B * B) * np.arctan(A / np.sqrt(1 + B * B))) / (2 * np.pi)

    ff = sum(corner_ff(a + sx * x, a + sy * y) for sx in (1, -1) for sy in (1, -1))
    np.testing.assert_allclose(res["form_factor_sum"], ff, rtol=1e-12)
    # H = c sum L F: c = pi for the physical irradiance of eq. 1 (what Cycles computes, see
    # test_cycles_agreement), 1 while the core takes eq. 3 literally; L = E + rho/pi H either way
    c = res["irradiance"][0, 0, 0] / (ff[0, 0] * l0[0])
    assert c == pytest.approx(1.0, rel=1e-12) or c == pytest.approx(np.pi, rel=1e-12), c
    np.testing.assert_allclose(res["irradiance"], c * ff[..., None] * l0, rtol=1e-12)
    np.testing.assert_allclose(res["radiance"], 0.8 / np.pi * res["irradiance"], rtol=1e-12)  # default rho
    np.testing.assert_allclose(res["depth"], 0.5, rtol=1e-12)
    assert rep.max_form_factor_error == pytest.approx(np.abs(ff - 1).max(), rel=1e-12)


def test_region_border_samples(hlp, tmp_path):
    scene, box, values = build_box(resolution=12)
    job = hlp["job"]
    full = job.run_local_pass(output=None, image=False).result
    sub = job.run_local_pass(output=None, region=(2, 3, 7, 5), image=False).result
    np.testing.assert_array_equal(sub["radiance"], full["radiance"][3:5, 2:7])
    scene.render.use_border = True
    scene.render.border_min_x, scene.render.border_max_x = 0.5, 1.0
    scene.render.border_min_y, scene.render.border_max_y = 0.0, 0.25
    rep = job.run_local_pass(output=str(tmp_path / "b.exr"), preview=False)
    assert rep.window == (6, 0, 12, 3) and rep.points == 18
    np.testing.assert_array_equal(rep.result["radiance"], full["radiance"][0:3, 6:12])
    _, size, window, _ = hlp["outputs"].read_exr(str(tmp_path / "b.exr"))
    assert size == (12, 12) and window == (6, 0, 12, 3)
    rep2 = job.run_local_pass(output=None, region=(0, 0, 2, 2), samples=3, image=False)
    assert rep2.points == 36
    assert rep2.result["radiance"].shape == (2, 2, 3)
    for key in ("depth", "object_index", "polygon_index"):  # from the centre sample of the 3 x 3
        np.testing.assert_array_equal(rep2.result[key], full[key][:2, :2], err_msg=key)
    assert not np.array_equal(rep2.result["radiance"], full["radiance"][:2, :2])  # an average of 9


def test_vertices_one_sided_limit_and_core_agreement(hlp):
    scene, box, values = build_box(subdivisions=2)
    floor, back = bpy.data.objects["Floor"], bpy.data.objects["BackWall"]
    for ob in scene.objects:
        ob.select_set(ob in (floor, back))
    rep = hlp["job"].run_local_pass(mode="vertices")
    assert sorted(rep.result) == ["BackWall", "Floor"]
    me = floor.data
    assert me.attributes["hlp_radiance"].domain == "CORNER"  # flat faces
    assert me.attributes["hlp_irradiance"].data_type == "FLOAT_COLOR"
    got = np.empty(len(me.loops) * 4, dtype=np.float32)
    me.attributes["hlp_irradiance"].data.foreach_get("color", got)
    got = got.reshape(-1, 4)[:, :3]
    # the core at the same corners with the documented limit direction (towards the face centroid)
    core = hlp["core"]
    ref = independent_scene(hlp, box, values, "FACE")
    co = np.array([v.co for v in me.vertices], dtype=np.float64)
    pts, nrm, lim = [], [], []
    for poly in me.polygons:
        cen = co[list(poly.vertices)].mean(axis=0)
        for v in poly.vertices:
            pts.append(co[v])
            nrm.append(poly.normal)
            u = cen - co[v]
            lim.append(u / np.linalg.norm(u))
    pts, nrm, lim = np.array(pts), np.array(nrm, dtype=np.float64), np.array(lim)
    h = core.irradiance(ref, pts, nrm, limit_directions=lim)
    np.testing.assert_allclose(rep.result["Floor"][2], h, rtol=0, atol=TOL)
    np.testing.assert_allclose(got, h, rtol=1e-6)
    # a floor vertex at the foot of the back wall: the value just inside the face, not the edge's
    corner = int(np.flatnonzero(np.abs(pts[:, 1] - pts[:, 1].max()) < 1e-9)[0])
    inside = core.irradiance(ref, pts[corner:corner + 1] + 1e-7 * lim[corner], nrm[corner:corner + 1])
    np.testing.assert_allclose(h[corner], inside[0], rtol=1e-4)
    exact = core.irradiance(ref, pts[corner:corner + 1], nrm[corner:corner + 1])
    assert not np.allclose(exact[0], h[corner], rtol=1e-3), "the edge value should differ from the limit"
    # radiance attribute: E + rho / pi H with the floor's material
    rad = np.empty(len(me.loops) * 4, dtype=np.float32)
    me.attributes["hlp_radiance"].data.foreach_get("color", rad)
    np.testing.assert_allclose(rad.reshape(-1, 4)[:, :3], np.asarray(box.reflectivity[0]) / np.pi * h, rtol=1e-5)


def test_vertices_smooth_point_domain_and_edit_mode_selection(hlp):
    scene, box, values = build_box(subdivisions=2)
    floor = bpy.data.objects["Floor"]
    for p in floor.data.polygons:
        p.use_smooth = True
    for ob in scene.objects:
        ob.select_set(ob == floor)
    bpy.context.view_layer.objects.active = floor
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="DESELECT")
    bpy.ops.object.mode_set(mode="OBJECT")
    floor.data.vertices[0].select = True
    floor.data.vertices[2].select = True
    bpy.ops.object.mode_set(mode="EDIT")
    rep = hlp["job"].run_local_pass(mode="vertices")
    assert bpy.context.object.mode == "EDIT"  # restored
    bpy.ops.object.mode_set(mode="OBJECT")
    attr = floor.data.attributes["hlp_irradiance"]
    assert attr.domain == "POINT"
    vals = np.empty(len(attr.data) * 4, dtype=np.float32)
    attr.data.foreach_get("color", vals)
    vals = vals.reshape(-1, 4)
    assert rep.points == 2
    assert (vals[[0, 2], 3] == 1).all() and (vals[[1, 3, 4], :] == 0).all()  # others untouched (new attribute)
    np.testing.assert_allclose(vals[[0, 2], :3], rep.result["Floor"][2][[0, 2]], rtol=1e-6)
    assert (vals[[0, 2], :3] > 0).all()


def test_vertex_targets_never_overwrite_user_attributes(hlp):
    scene, box, values = build_box(subdivisions=1)
    floor = bpy.data.objects["Floor"]
    for ob in scene.objects:
        ob.select_set(ob == floor)
    user = floor.data.attributes.new("hlp_radiance", "FLOAT_COLOR", "POINT")
    user.data.foreach_set("color", np.full(len(user.data) * 4, 0.25, dtype=np.float32))
    other = floor.data.attributes.new("my_paint", "FLOAT_COLOR", "CORNER")
    with pytest.raises(ValueError, match="already has a user attribute 'hlp_radiance'"):
        hlp["job"].run_local_pass(mode="vertices")
    kept = np.empty(len(user.data) * 4, dtype=np.float32)
    floor.data.attributes["hlp_radiance"].data.foreach_get("color", kept)
    assert (kept == 0.25).all()
    with pytest.raises(ValueError, match="also an input"):
        hlp["job"].run_local_pass(mode="vertices", radiance_attribute="radiosity")
    rep = hlp["job"].run_local_pass(mode="vertices", radiance_attribute="hlp_radiance")  # named: allowed
    assert rep.points > 0 and floor.data.attributes["hlp_radiance"].domain == "CORNER"
    assert "my_paint" in floor.data.attributes and other.name == "my_paint"
    hlp["job"].run_local_pass(mode="vertices", radiance_attribute="hlp_radiance")  # ours now: rerun works
    hlp["job"].run_local_pass(mode="vertices", radiance_attribute="lit")
    assert "lit" in floor.data.attributes


def test_missing_and_black_occluders_in_report(hlp):
    build_box(subdivisions=1, resolution=4)
    bare = bpy.data.objects.new("Bare", bpy.data.meshes.new("Bare"))
    bare.data.from_pydata([(0.4, 0.4, 0.4), (0.6, 0.4, 0.4), (0.6, 0.6, 0.4)], [], [(0, 1, 2)])
    bpy.context.scene.collection.objects.link(bare)
    with pytest.raises(ValueError, match="'Bare' has no attribute 'radiosity'"):
        hlp["job"].run_local_pass()
    rep = hlp["job"].run_local_pass(missing="black")
    assert rep.black_occluders == ["Bare"]
    assert "1 black occluder" in rep.summary()


def test_no_camera_and_unwritable_output(hlp, tmp_path):
    build_box(subdivisions=1, resolution=4)
    with pytest.raises(ValueError, match="does not exist"):
        hlp["job"].run_local_pass(output=str(tmp_path / "missing_dir" / "x.exr"))
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ValueError, match="cannot write"):
        hlp["job"].run_local_pass(output=str(blocker / "x.exr"))
    bpy.context.scene.camera = None
    bpy.data.objects.remove(bpy.data.objects["Camera"])
    with pytest.raises(ValueError, match="has no camera"):
        hlp["job"].run_local_pass(output=str(tmp_path / "x.exr"))


def _raise_after(n, exc):
    calls = {"n": 0}

    def progress(done, total):
        calls["n"] += 1
        if calls["n"] >= n:
            raise exc

    return progress


def test_interrupted_run_resumes_to_the_same_file(hlp, tmp_path, monkeypatch):
    build_box(resolution=24)
    job = hlp["job"]
    # several chunks on a small image
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".receiver_chunks.MIN_CHUNK", 16)
    ref_path = str(tmp_path / "ref.exr")
    job.run_local_pass(output=ref_path, preview=False)
    out = str(tmp_path / "run.exr")
    with pytest.raises(KeyboardInterrupt):
        job.run_local_pass(output=out, preview=False, progress=_raise_after(9, KeyboardInterrupt()))
    ck = out + ".checkpoint.npz"
    assert os.path.isfile(ck) and not os.path.exists(out)
    with np.load(ck) as z:
        assert 0 < z["done"].sum() < len(z["done"])
    cancelled = {"n": 0}

    def cancel():
        cancelled["n"] += 1
        return cancelled["n"] > 3

    core = hlp["core"]
    with pytest.raises(core.Cancelled):  # a second interruption, via cancel(), keeps its progress too
        job.run_local_pass(output=out, preview=False, resume=True, cancel=cancel)
    rep = job.run_local_pass(output=out, preview=False, resume=True)
    assert rep.resumed_points > 0 and not os.path.exists(ck)
    with open(ref_path, "rb") as a, open(out, "rb") as b:
        assert a.read() == b.read(), "the resumed file differs from the uninterrupted one"
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".")], "temporary files left behind"


def test_tiles_merge_to_the_full_image(hlp, tmp_path):
    build_box(resolution=10)
    job = hlp["job"]
    full = str(tmp_path / "full.exr")
    job.run_local_pass(output=full, preview=False)
    tiles = []
    for i in (1, 2, 3):
        t = str(tmp_path / f"tile{i}.exr")
        rep = job.run_local_pass(output=t, tile=f"{i}/3", preview=False)
        tiles.append(t)
        assert rep.window[3] - rep.window[1] in (3, 4)
    merged = str(tmp_path / "merged.exr")
    hlp["outputs"].merge_exr(tiles[::-1], merged)
    a, b = hlp["outputs"].read_exr(full), hlp["outputs"].read_exr(merged)
    assert a[1:3] == b[1:3]
    for k in a[0]:
        np.testing.assert_array_equal(a[0][k], b[0][k], err_msg=k)
    with pytest.raises(ValueError, match="gap"):
        hlp["outputs"].merge_exr([tiles[0], tiles[2]], merged)
    with pytest.raises(ValueError, match="overlap"):
        hlp["outputs"].merge_exr([tiles[0], tiles[0]], merged)
    with pytest.raises(ValueError, match="tile"):
        job.run_local_pass(output=full, tile="4/3")


def test_cli_render_merge_errors_and_ctrl_c(hlp, tmp_path, capsys, monkeypatch):
    build_box(resolution=8)
    job = hlp["job"]
    out = str(tmp_path / "cli.exr")
    assert job.cli_main(["render", "--output", out, "--region", "0", "0", "8", "4", "--samples", "1"]) == 0
    captured = capsys.readouterr()
    assert "points/s" in captured.err and "%" in captured.err and "ETA" in captured.err
    assert "max |sum F - 1|" in captured.out
    t1, t2 = str(tmp_path / "t1.exr"), str(tmp_path / "t2.exr")
    assert job.cli_main(["render", "-o", t1, "--tile", "1/2", "-q", "--no-preview"]) == 0
    assert job.cli_main(["render", "-o", t2, "--tile", "2/2", "-q", "--no-preview"]) == 0
    assert job.cli_main(["merge", t1, t2, "--output", str(tmp_path / "m.exr")]) == 0
    capsys.readouterr()
    assert job.cli_main(["render", "-o", str(tmp_path / "nodir" / "x.exr")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hemisphere_local_pass: error:") and "does not exist" in err[0]
    assert job.cli_main(["render", "-o", out, "--attribute", "nope", "--overwrite"]) == 1
    assert "has no attribute 'nope'" in capsys.readouterr().err
    # Ctrl-C during the run: exit 130, checkpoint kept, --resume finishes with the same file
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".receiver_chunks.MIN_CHUNK", 8)
    ref = str(tmp_path / "ref.exr")
    assert job.cli_main(["render", "-o", ref, "-q", "--no-preview"]) == 0
    real = importlib.import_module(job.__name__.rsplit(".", 1)[0] + ".stderr_lines").StderrProgress

    class Interrupting(real):
        def __call__(self, done, total):
            if done >= 24:
                raise KeyboardInterrupt
            super().__call__(done, total)

    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".cli.StderrProgress", Interrupting)
    run = str(tmp_path / "run.exr")
    assert job.cli_main(["render", "-o", run, "--no-preview"]) == 130
    assert "--resume" in capsys.readouterr().err and os.path.isfile(run + ".checkpoint.npz")
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".cli.StderrProgress", real)
    assert job.cli_main(["render", "-o", run, "--no-preview", "--resume", "-q"]) == 0
    with open(ref, "rb") as a, open(run, "rb") as b:
        assert a.read() == b.read()


def test_cli_vertices_saves_a_blend(hlp, tmp_path, capsys):
    scene, box, values = build_box(subdivisions=1)
    for ob in scene.objects:
        ob.select_set(ob.name == "Floor")
    job = hlp["job"]
    assert job.cli_main(["render", "--mode", "vertices", "-o", str(tmp_path / "x.exr"), "-q"]) == 1
    assert ".blend" in capsys.readouterr().err
    out = str(tmp_path / "baked.blend")
    assert job.cli_main(["render", "--mode", "vertices", "-o", out, "-q"]) == 0
    assert sorted(os.listdir(tmp_path)) == ["baked.blend"]
    bpy.ops.wm.open_mainfile(filepath=out)
    attrs = bpy.data.objects["Floor"].data.attributes
    assert attrs["hlp_radiance"].domain == "CORNER" and "hlp_irradiance" in attrs
    assert "hlp_radiance" not in bpy.data.objects["Ceiling"].data.attributes
    assert "hlp_irradiance_bound" not in attrs  # exact: no bound attribute
    # with a tolerance: the far field, its bound saved and the summary saying so
    capsys.readouterr()
    out2 = str(tmp_path / "baked_far.blend")
    assert job.cli_main(["render", "--mode", "vertices", "--objects", "Floor", "--tolerance", "1e-3", "-o", out2]) == 0
    assert "far field: error bound <= " in capsys.readouterr().out
    bpy.ops.wm.open_mainfile(filepath=out2)
    assert bpy.data.objects["Floor"].data.attributes["hlp_irradiance_bound"].domain == "CORNER"


@pytest.mark.parametrize("double_sided", [False, True])
def test_back_of_an_emitter_emits_only_when_double_sided(hlp, double_sided):
    """A square emitter facing away from the receivers: seen from behind it occludes (sum F > 0) and
    emits only with double_sided; both evaluation paths (one core call or two) agree with the core."""
    s = bpy.context.scene
    lamp = bpy.data.meshes.new("Lamp")
    lamp.from_pydata([(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)], [], [(0, 1, 2, 3)])  # faces +z
    lamp.attributes.new("radiosity", "FLOAT_COLOR", "FACE").data.foreach_set(
        "color", np.array([1.0, 2.0, 3.0, 1.0], dtype=np.float32))
    floor = bpy.data.meshes.new("Floor")
    floor.from_pydata([(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [], [(0, 1, 2, 3)])
    floor.attributes.new("radiosity", "FLOAT_COLOR", "POINT")  # zeros, linear: exercises the other path
    for me in (lamp, floor):
        s.collection.objects.link(bpy.data.objects.new(me.name, me))
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 0.5
    cam.location = (0, 0, 0.5)
    s.collection.objects.link(cam)
    s.camera = cam
    s.render.resolution_x = s.render.resolution_y = 2
    job = hlp["job"]
    res = job.run_local_pass(output=None, double_sided=double_sided).result
    floor.attributes.remove(floor.attributes["radiosity"])
    floor.attributes.new("radiosity", "FLOAT_COLOR", "FACE")  # constant: the one-call path
    res_c = job.run_local_pass(output=None, double_sided=double_sided).result
    assert (res["form_factor_sum"] > 0.1).all()
    np.testing.assert_allclose(res_c["form_factor_sum"], res["form_factor_sum"], rtol=1e-12)
    np.testing.assert_allclose(res_c["irradiance"], res["irradiance"], rtol=1e-12, atol=1e-15)
    if double_sided:
        assert (res["irradiance"] > 0).all()
    else:
        np.testing.assert_array_equal(res["irradiance"], 0.0)


def read_colours(mesh, name):
    got = np.empty(len(mesh.attributes[name].data) * 4, dtype=np.float32)
    mesh.attributes[name].data.foreach_get("color", got)
    return got.reshape(-1, 4)[:, :3].astype(np.float64)


def test_vertices_with_a_tolerance_run_the_bounded_far_field(hlp):
    """Vertices mode with a tolerance: the core's far field, its bound written next to H and within the
    tolerance, the measured error within the bound; an exact rerun zeroes our bound; a user's attribute of
    that name is refused, not overwritten."""
    from hemisphere_local_pass.scenes.cornell_box import cornell_box

    box = cornell_box(4)
    names = np.array(box.names)
    values = np.zeros((box.n_polygons, 3))
    rng = np.random.default_rng(5)
    for part in dict.fromkeys(box.names):  # one radiance per wall: whole walls become far-field proxies
        values[names == part] = 0.05 + 0.5 * rng.random(3)
    values += box.emission
    scene, box, values = sample_module().build(4, resolution=10, reset=False, radiosity=values)
    floor = bpy.data.objects["Floor"]
    for ob in scene.objects:
        ob.select_set(ob is floor)
    job = hlp["job"]
    rep = job.run_local_pass(mode="vertices", tolerance=1e-3)
    h = rep.result["Floor"][2]
    bound = read_colours(floor.data, "hlp_irradiance_bound")
    assert "Floor:hlp_irradiance_bound" in rep.outputs and "far field: error bound" in rep.summary()
    assert np.isnan(rep.max_form_factor_error)
    assert 0 < rep.error_estimate <= rep.tolerance and rep.tolerance == pytest.approx(1e-3 * h.mean(), rel=0.5)
    assert bound.shape == h.shape
    exact = job.run_local_pass(mode="vertices")  # the same corners, exact
    h0 = exact.result["Floor"][2]
    err = np.abs(h - h0)
    assert bound.max() > 0 and err.max() > 0, "the far field should have left something out here"
    assert (err <= bound.astype(np.float32).astype(np.float64) * (1 + 1e-6) + 1e-12).all(), err.max()
    assert exact.error_estimate is None and exact.max_form_factor_error < 1e-9
    assert (read_colours(floor.data, "hlp_irradiance_bound") == 0).all()  # ours, rewritten: exact now
    # a user's own attribute of that name: an exact run leaves it alone, a tolerance run refuses
    floor.data.attributes.remove(floor.data.attributes["hlp_irradiance_bound"])
    floor.data["hlp_owned_attributes"] = [n for n in floor.data["hlp_owned_attributes"] if n != "hlp_irradiance_bound"]
    mine = floor.data.attributes.new("hlp_irradiance_bound", "FLOAT_COLOR", "CORNER")
    mine.data.foreach_set("color", np.full(len(mine.data) * 4, 0.25, dtype=np.float32))
    job.run_local_pass(mode="vertices")
    assert (read_colours(floor.data, "hlp_irradiance_bound") == 0.25).all()
    with pytest.raises(ValueError, match="object 'Floor' already has a user attribute 'hlp_irradiance_bound'"):
        job.run_local_pass(mode="vertices", tolerance=1e-3)
    assert (read_colours(floor.data, "hlp_irradiance_bound") == 0.25).all()
