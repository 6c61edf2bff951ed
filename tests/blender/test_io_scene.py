"""Scene extraction: attributes, domains, materials, visibility, instances, modifiers, bad input."""

import importlib

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")


@pytest.fixture
def hlp(extension, scene):
    """The installed extension's blender layer modules, on a fresh empty scene."""
    base = extension.__name__ + ".blender."
    return {name: importlib.import_module(base + name) for name in ("scene_export", "job", "camera")}


def quad_mesh(name, z=0.0, size=1.0, flip=False, values=None, domain="FACE", dtype="FLOAT_COLOR", attr="radiosity"):
    """Two quads side by side in the plane z (normal +z, or -z when flipped) with an attribute."""
    s = size
    verts = [(0, 0, z), (s, 0, z), (s, s, z), (0, s, z), (2 * s, 0, z), (2 * s, s, z)]
    faces = [(0, 1, 2, 3), (1, 4, 5, 2)]
    if flip:
        faces = [tuple(reversed(f)) for f in faces]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.update()
    if values is not None:
        a = me.attributes.new(attr, dtype, domain)
        n = len(a.data)
        vals = np.broadcast_to(np.asarray(values, dtype=np.float64), (n, 3))
        if dtype == "FLOAT_VECTOR":
            a.data.foreach_set("vector", vals.astype(np.float32).reshape(-1))
        elif dtype == "FLOAT":
            a.data.foreach_set("value", vals[:, 0].astype(np.float32))
        else:
            rgba = np.concatenate([vals, np.ones((n, 1))], axis=1).astype(np.float32)
            a.data.foreach_set("color", rgba.reshape(-1))
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def export(hlp, **kw):
    bpy.context.view_layer.update()
    return hlp["scene_export"].export_scene(bpy.context.scene, **kw)


def test_face_domain_world_space_and_names(hlp):
    ob = quad_mesh("Floor", values=[(1.0, 0.5, 0.25), (2.0, 2.0, 2.0)])
    ob.location = (10.0, 0.0, 1.0)
    ex = export(hlp)
    sc = ex.scene
    assert ex.objects == ["Floor"] and not ex.linear
    assert sc.n_input == 2
    np.testing.assert_allclose(sc.poly_radiance, [(1.0, 0.5, 0.25), (2.0, 2.0, 2.0)], rtol=1e-7)
    assert sc.poly_vertices[..., 0].min() == pytest.approx(10.0) and sc.poly_vertices[..., 2].max() == 1.0
    np.testing.assert_allclose(sc.poly_normals, [(0, 0, 1), (0, 0, 1)], atol=1e-12)
    assert ex.polygon_name(1) == "Floor.polygon 1"
    assert sc.describe(1) == "polygon 1 (Floor.polygon 1)"
    np.testing.assert_allclose(ex.reflectivity, 0.8)  # no material: documented default
    np.testing.assert_allclose(ex.emission, 0.0)


@pytest.mark.parametrize("domain", ["POINT", "CORNER"])
def test_point_and_corner_domains_are_linear(hlp, domain):
    ob = quad_mesh("Floor", values=[(0.5, 0.5, 0.5)], domain=domain)
    a = ob.data.attributes["radiosity"]
    n = len(a.data)
    vals = np.linspace(0, 1, n * 4, dtype=np.float32)
    a.data.foreach_set("color", vals)
    ex = export(hlp)
    assert ex.linear and ex.scene.linear
    rgba = vals.reshape(n, 4)[:, :3]
    loops = np.array([v for p in ob.data.polygons for v in p.vertices])
    corner = rgba[loops] if domain == "POINT" else rgba
    # the first triangle of polygon 0 (fan from its first corner) carries corners 0, 1, 2
    np.testing.assert_allclose(ex.scene.corner_radiance[0], corner[[0, 1, 2]], rtol=1e-7)


def test_byte_color_is_read_as_linear_and_vectors_accepted(hlp):
    ob = quad_mesh("A", values=[(0.5, 0.5, 0.5)], dtype="BYTE_COLOR")
    quad_mesh("B", z=1.0, values=[(3.0, 4.0, 5.0)], dtype="FLOAT_VECTOR")
    a = ob.data.attributes["radiosity"]
    srgb = np.empty(8, dtype=np.float32)
    a.data.foreach_get("color_srgb", srgb)
    ex = export(hlp)
    # 0.5 linear is stored as the sRGB byte 188 (0.737); reading .color gives back ~0.5, not 0.737
    assert srgb[0] == pytest.approx(188 / 255, abs=1e-6)
    np.testing.assert_allclose(ex.scene.poly_radiance[:2], 0.5, atol=3e-3)
    np.testing.assert_allclose(ex.scene.poly_radiance[2:], [(3, 4, 5)] * 2)


def test_material_and_attribute_reflectivity_emission(hlp):
    ob = quad_mesh("Lamp", values=[(1, 1, 1)])
    mat = bpy.data.materials.new("M")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (0.2, 0.3, 0.4, 1.0)
    col = bsdf.inputs.get("Emission Color") or bsdf.inputs.get("Emission")
    col.default_value = (1.0, 0.5, 0.25, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 4.0
    ob.data.materials.append(mat)
    other = quad_mesh("Painted", z=2.0, values=[(0, 0, 0)])
    a = other.data.attributes.new("reflectivity", "FLOAT", "FACE")
    a.data.foreach_set("value", np.array([0.1, 0.9], dtype=np.float32))
    e = other.data.attributes.new("emission", "FLOAT_COLOR", "POINT")
    e.data.foreach_set("color", np.tile(np.array([2, 0, 0, 1], dtype=np.float32), 6))
    ex = export(hlp)
    np.testing.assert_allclose(ex.reflectivity[:2], [(0.2, 0.3, 0.4)] * 2, rtol=1e-6)
    np.testing.assert_allclose(ex.emission[:2], [(4.0, 2.0, 1.0)] * 2, rtol=1e-6)
    np.testing.assert_allclose(ex.reflectivity[2:], [(0.1,) * 3, (0.9,) * 3], rtol=1e-6)
    np.testing.assert_allclose(ex.emission[2:], [(2, 0, 0)] * 2)


def test_missing_attribute_error_or_black_occluder(hlp):
    quad_mesh("Lit", values=[(1, 1, 1)])
    quad_mesh("Bare", z=1.0)
    with pytest.raises(ValueError, match="object 'Bare' has no attribute 'radiosity'"):
        export(hlp)
    ex = export(hlp, missing="black")
    assert ex.black_occluders == ["Bare"]
    np.testing.assert_allclose(ex.scene.poly_radiance[2:], 0.0)
    assert ex.scene.n_input == 4  # still occludes


@pytest.mark.parametrize("dtype,domain,match", [
    ("INT", "FACE", "data type INT"),
    ("FLOAT", "FACE", "data type FLOAT"),
    ("FLOAT_COLOR", "EDGE", "EDGE domain"),
])
def test_wrong_type_or_domain(hlp, dtype, domain, match):
    ob = quad_mesh("Wall")
    ob.data.attributes.new("radiosity", dtype, domain)
    with pytest.raises(ValueError, match=f"object 'Wall': attribute 'radiosity'.*{match}"):
        export(hlp)


def test_nan_names_object_and_polygon(hlp):
    ob = quad_mesh("Wall", values=[(1, 1, 1), (np.nan, 0, 0)])
    with pytest.raises(ValueError, match="object 'Wall': attribute 'radiosity' has a non-finite value .* polygon 1"):
        export(hlp)
    ob.data.attributes.remove(ob.data.attributes["radiosity"])
    a = ob.data.attributes.new("radiosity", "FLOAT_COLOR", "POINT")
    vals = np.ones((6, 4), dtype=np.float32)
    vals[5, 1] = np.inf  # vertex 5 is used by polygon 1 only
    a.data.foreach_set("color", vals.reshape(-1))
    with pytest.raises(ValueError, match="non-finite value .* polygon 1"):
        export(hlp)


def test_empty_scene(hlp):
    with pytest.raises(ValueError, match="no render-visible geometry"):
        export(hlp)
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("Empty", None))
    light = bpy.data.objects.new("Light", bpy.data.lights.new("L", "POINT"))
    bpy.context.scene.collection.objects.link(light)
    with pytest.raises(ValueError, match="no render-visible geometry"):
        export(hlp)


def test_non_mesh_objects(hlp):
    quad_mesh("Floor", values=[(1, 1, 1)])
    text = bpy.data.objects.new("Label", bpy.data.curves.new("T", "FONT"))
    text.data.body = "Hi"
    text.location = (0, 0, 3)
    bpy.context.scene.collection.objects.link(text)
    for kind in ("CAMERA", "LIGHT", "EMPTY"):
        data = {"CAMERA": bpy.data.cameras.new("c"), "LIGHT": bpy.data.lights.new("l", "SUN"), "EMPTY": None}[kind]
        bpy.context.scene.collection.objects.link(bpy.data.objects.new(kind.title(), data))
    with pytest.raises(ValueError, match="object 'Label' has no attribute 'radiosity'"):
        export(hlp)
    ex = export(hlp, missing="black")
    assert ex.objects == ["Floor", "Label"]  # the text once (not also as its mesh instance); others ignored
    assert ex.black_occluders == ["Label"]
    assert ex.scene.n_input > 2
    assert np.all(ex.scene.poly_vertices[ex.scene.poly_source >= 2][..., 2] == pytest.approx(3.0))


def test_visibility_modifiers_instances_and_mirroring(hlp):
    base = quad_mesh("Base", values=[(1, 1, 1)])
    hidden = quad_mesh("HiddenFromRender", z=5.0, values=[(1, 1, 1)])
    hidden.hide_render = True
    eye = quad_mesh("HiddenInViewport", z=6.0, values=[(1, 1, 1)])
    eye.hide_viewport = True
    col = bpy.data.collections.new("NoRender")
    bpy.context.scene.collection.children.link(col)
    col.hide_render = True
    inner = quad_mesh("InNoRenderCollection", z=7.0, values=[(1, 1, 1)])
    bpy.context.scene.collection.objects.unlink(inner)
    col.objects.link(inner)
    arr = base.modifiers.new("Array", "ARRAY")
    arr.count = 3
    # a collection instance of a mirrored object
    src_col = bpy.data.collections.new("Src")
    mirrored = bpy.data.objects.new("Mirrored", bpy.data.meshes["Base"].copy())
    mirrored.scale = (-1.0, 1.0, 1.0)
    src_col.objects.link(mirrored)
    inst = bpy.data.objects.new("Inst", None)
    inst.instance_type = "COLLECTION"
    inst.instance_collection = src_col
    inst.location = (0, 0, 2)
    bpy.context.scene.collection.objects.link(inst)
    ex = export(hlp)
    names = ex.objects
    assert "HiddenFromRender" not in names and "InNoRenderCollection" not in names
    assert "HiddenInViewport" in names  # hidden in the viewport only: rendered, so exported
    assert eye.hide_viewport  # and the flag was restored
    assert "Mirrored (instance 0 of Inst)" in names
    i_base = names.index("Base")
    assert np.sum(ex.polygon_object == i_base) == 6  # array modifier applied
    i_m = names.index("Mirrored (instance 0 of Inst)")
    rows = np.flatnonzero(np.isin(ex.scene.poly_source, np.flatnonzero(ex.polygon_object == i_m)))
    np.testing.assert_allclose(ex.scene.poly_normals[rows], [(0, 0, 1)] * len(rows), atol=1e-12)
    assert ex.scene.poly_vertices[rows][..., 0].max() <= 0.0 and ex.scene.poly_vertices[rows][..., 2].min() == 2.0


def _material(name, rho):
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*rho, 1.0)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = False  # the viewport colour is rho (5.0+: the default Principled BSDF's base colour)
    else:
        bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
        bsdf.inputs["Base Color"].default_value = (*rho, 1.0)
    return mat


def test_collection_instances_keep_every_object(hlp):
    """Issue 14.13: a collection of three objects instanced four times (one mirrored) exports 12
    objects, each with its own geometry, radiosity and material (the iterator's temporary object is
    read inside the iteration, not after it)."""
    src = bpy.data.collections.new("Src")
    for k in range(3):
        ob = quad_mesh(f"Part{k}", z=float(k), values=[(k + 1.0, 0.0, 0.0)])
        bpy.context.scene.collection.objects.unlink(ob)
        src.objects.link(ob)
        ob.data.materials.append(_material(f"M{k}", (0.1 * (k + 1), 0.2, 0.3)))
    for j in range(4):
        inst = bpy.data.objects.new(f"Inst{j}", None)
        inst.instance_type = "COLLECTION"
        inst.instance_collection = src
        inst.location = (5.0 * j, 0.0, 0.0)
        if j == 2:
            inst.scale = (-1.0, 1.0, 1.0)
        bpy.context.scene.collection.objects.link(inst)
    ex = export(hlp)
    assert sorted(ex.objects) == sorted(f"Part{k} (instance 0 of Inst{j})" for j in range(4) for k in range(3))
    sc = ex.scene
    for j in range(4):
        for k in range(3):
            i = ex.objects.index(f"Part{k} (instance 0 of Inst{j})")
            inputs = np.flatnonzero(ex.polygon_object == i)
            assert len(inputs) == 2
            rows = np.flatnonzero(np.isin(sc.poly_source, inputs))
            v = sc.poly_vertices[rows]
            np.testing.assert_allclose(v[..., 2], float(k))  # this part's own geometry
            x = v[..., 0]
            if j == 2:  # mirrored: x in [-2, 0] + 10, the front side still +z
                assert x.min() == pytest.approx(10.0 - 2.0) and x.max() == pytest.approx(10.0)
            else:
                assert x.min() == pytest.approx(5.0 * j) and x.max() == pytest.approx(5.0 * j + 2.0)
            np.testing.assert_allclose(sc.poly_normals[rows], [(0, 0, 1)] * len(rows), atol=1e-12)
            np.testing.assert_allclose(sc.poly_radiance[rows], [(k + 1.0, 0, 0)] * len(rows))
            np.testing.assert_allclose(ex.reflectivity[inputs], [(0.1 * (k + 1), 0.2, 0.3)] * 2, rtol=1e-6)


def test_bad_vertex_coordinates_name_the_object_and_its_own_vertex(hlp):
    """Issue 14.8: an infinite (stored as 3.4e38), NaN or absurdly large coordinate is an error naming
    the object and the vertex's index in that object (not across the scene), with all three values."""
    quad_mesh("Floor", values=[(1, 1, 1)])  # six vertices before TallBlock's
    ob = quad_mesh("TallBlock", z=1.0, values=[(1, 1, 1)])
    ob.data.vertices[2].co = (float("inf"), 1.0, 1.0)
    assert ob.data.vertices[2].co.x == pytest.approx(3.4028234663852886e38)  # how Blender stores it
    with pytest.raises(ValueError, match=r"object 'TallBlock': vertex 2 has coordinates beyond 1e\+15 .*"
                                         r"\(3\.40282346\d*e\+38, 1\.0, 1\.0\)"):
        export(hlp)
    ob.data.vertices[2].co = (float("nan"), 1.0, 1.0)  # only x NaN: all three shown
    with pytest.raises(ValueError, match=r"object 'TallBlock': vertex 2 has non-finite coordinates: "
                                         r"\(nan, 1\.0, 1\.0\)"):
        export(hlp)
    ob.data.vertices[2].co = (1.0, 1.0, 1.0)
    ob.scale = (1e16, 1.0, 1.0)  # finite in the mesh, absurd in world space
    with pytest.raises(ValueError, match=r"object 'TallBlock': vertex 1 has coordinates beyond .* in world space "
                                         r"\(object space: \(1\.0, 0\.0, 1\.0\)\)"):
        export(hlp)
    ob.scale = (1.0, 1.0, 1.0)
    ob.data.vertices.add(1)  # a loose vertex is not rendered: it may be anything
    ob.data.vertices[6].co = (float("nan"), 0.0, 0.0)
    assert export(hlp).scene.n_input == 4


def ngon_mesh(name, domain="CORNER", concave=False, values=None):
    """One hexagon (or a concave L-shaped hexagon) in z = 0 with a non-affine attribute."""
    if concave:
        verts = [(0, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1, 0), (1, 2, 0), (0, 2, 0)]
    else:
        verts = [(np.cos(a), np.sin(a), 0.0) for a in np.arange(6) * np.pi / 3]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], [tuple(range(6))])
    me.update()
    a = me.attributes.new("radiosity", "FLOAT_COLOR", domain)
    n = len(a.data)
    vals = np.asarray(values if values is not None else [(0.0, 0, 0), (1, 1, 1), (0, 0, 0), (5, 5, 5),
                                                         (0, 0, 0), (1, 1, 1)][:n], dtype=np.float32)
    vals = np.broadcast_to(vals, (n, 3))
    a.data.foreach_set("color", np.concatenate([vals, np.ones((n, 1), np.float32)], axis=1).reshape(-1))
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def blender_triangles(ob):
    """Blender's loop triangles of the evaluated ``ob`` in world space: {sorted vertex triple}, and
    the corner (loop) indices of each."""
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.data
    if not len(me.loop_triangles) and hasattr(me, "calc_loop_triangles"):
        me.calc_loop_triangles()
    m = np.array(ev.matrix_world)
    co = np.array([tuple(v.co) for v in me.vertices]) @ m[:3, :3].T + m[:3, 3]
    loops = [tuple(t.loops) for t in me.loop_triangles]
    lv = np.array([lp.vertex_index for lp in me.loops])
    return {tuple(sorted(map(tuple, np.round(co[lv[list(t)]], 9)))) for t in loops}, loops


def exported_triangles(ex, obname):
    i = ex.objects.index(obname)
    rows = np.flatnonzero(np.isin(ex.scene.poly_source, np.flatnonzero(ex.polygon_object == i)))
    return rows, {tuple(sorted(map(tuple, np.round(v[:3], 9)))) for v in ex.scene.poly_vertices[rows]}


@pytest.mark.parametrize("domain", ["POINT", "CORNER"])
def test_linear_ngons_are_split_into_blenders_loop_triangles(hlp, domain):
    """Issue 14.14: POINT/CORNER radiosity on n-gons is interpolated over Blender's loop triangles
    (for a hexagon (5,0,1),(1,2,3),(3,4,5),(1,3,5), not the core's fan from corner 0), a concave
    n-gon included, a mirrored copy too; polygons are still named by the object's polygon index."""
    hexa = ngon_mesh("Hexagon", domain)
    ell = ngon_mesh("Ell", domain, concave=True)
    ell.location = (3.0, 0.0, 0.0)
    mirror = ngon_mesh("MirroredEll", domain, concave=True)
    mirror.location, mirror.scale = (8.0, 0.0, 0.0), (-1.0, 1.0, 1.0)
    ex = export(hlp)
    assert ex.linear
    for ob in (hexa, ell, mirror):
        want, loops = blender_triangles(ob)
        rows, got = exported_triangles(ex, ob.name)
        assert got == want, ob.name
        np.testing.assert_allclose(ex.scene.poly_normals[rows], [(0, 0, 1)] * len(rows), atol=1e-12)
        assert {ex.polygon_name(int(s)) for s in ex.scene.poly_source[rows]} == {f"{ob.name}.polygon 0"}
    _, loops = blender_triangles(hexa)
    assert sorted(loops) == sorted([(5, 0, 1), (1, 2, 3), (3, 4, 5), (1, 3, 5)])
    rows, _ = exported_triangles(ex, "Hexagon")
    corner = np.array([0.0, 1, 0, 5, 0, 1])
    got = {tuple(sorted(r)) for r in ex.scene.corner_radiance[rows][..., 0]}
    assert got == {tuple(sorted(corner[list(t)])) for t in loops}


def test_face_ngons_concave_split_like_blender_convex_whole(hlp):
    """FACE values: a planar convex n-gon stays one polygon; a concave one and a non-planar quad are
    split into Blender's loop triangles (for the quad a different diagonal than ear clipping's:
    a different surface)."""
    ngon_mesh("Hexagon", "FACE", values=[(1.0, 1.0, 1.0)])
    ell = ngon_mesh("Ell", "FACE", concave=True, values=[(2.0, 2.0, 2.0)])
    ell.location = (3.0, 0.0, 0.0)
    bent = quad_mesh("Bent", values=[(1.0, 1.0, 1.0)])
    bent.location = (0.0, 4.0, 0.0)
    bent.data.vertices[2].co.z = 0.3  # corner 2 of polygon 0 (and corner 3 of polygon 1) lifted
    ex = export(hlp)
    assert not ex.linear
    rows, _ = exported_triangles(ex, "Hexagon")
    assert len(rows) == 1 and ex.scene.poly_counts[rows[0]] == 6  # planar convex: one polygon
    for ob in (ell, bent):
        want, _ = blender_triangles(ob)
        rows, got = exported_triangles(ex, ob.name)
        assert got == want, ob.name
    assert ex.dropped_names() == []


def test_instanced_collections_follow_render_visibility(hlp):
    """Inside an instanced collection the render flags decide, as in a render: an object or child
    collection hidden in viewports only is instanced, one disabled in renders is not; the viewport
    flags are restored."""
    src = bpy.data.collections.new("Src")
    child_vp = bpy.data.collections.new("ChildHiddenInViewport")
    child_rn = bpy.data.collections.new("ChildNoRender")
    src.children.link(child_vp)
    src.children.link(child_rn)
    for k, (name, col) in enumerate([("Shown", src), ("ViewportOff", src), ("RenderOff", src),
                                     ("InChildVp", child_vp), ("InChildNoRender", child_rn)]):
        ob = quad_mesh(name, z=float(k), values=[(1, 1, 1)])
        bpy.context.scene.collection.objects.unlink(ob)
        col.objects.link(ob)
    src.objects["ViewportOff"].hide_viewport = True
    src.objects["RenderOff"].hide_render = True
    child_vp.hide_viewport = True
    child_rn.hide_render = True
    inst = bpy.data.objects.new("Inst", None)
    inst.instance_type = "COLLECTION"
    inst.instance_collection = src
    bpy.context.scene.collection.objects.link(inst)
    ex = export(hlp)
    assert sorted(ex.objects) == sorted(f"{n} (instance 0 of Inst)" for n in ("Shown", "ViewportOff", "InChildVp"))
    assert src.objects["ViewportOff"].hide_viewport and child_vp.hide_viewport and not child_rn.hide_viewport


def _block_mesh(name, n=4):
    """A unit cube without bottom, standing on z = 0, centred on the z axis, in n x n cells per face
    (outward quads)."""
    g = np.linspace(-0.5, 0.5, n + 1)
    z = np.linspace(0.0, 1.0, n + 1)
    index, faces = {}, []

    def vid(p):
        return index.setdefault(tuple(float(c) for c in p), len(index))

    for i in range(n):
        for j in range(n):
            faces.append([vid((g[i], g[j], 1.0)), vid((g[i + 1], g[j], 1.0)), vid((g[i + 1], g[j + 1], 1.0)),
                          vid((g[i], g[j + 1], 1.0))])
            for fix, sgn in ((0, -1), (0, 1), (1, -1), (1, 1)):
                a, b = (g[i], z[j]), (g[i + 1], z[j + 1])
                corner = [(a[0], a[1]), (b[0], a[1]), (b[0], b[1]), (a[0], b[1])]
                pts = [(sgn * 0.5, u, w) if fix == 0 else (u, sgn * 0.5, w) for u, w in corner]
                if (fix == 0) != (sgn > 0):
                    pts = pts[::-1]
                faces.append([vid(p) for p in pts])
    me = bpy.data.meshes.new(name)
    me.from_pydata(list(index), [], faces)
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def test_rotation_in_the_object_transform_keeps_faces_planar(hlp, extension):
    """Blender stores vertex coordinates as float32. A rotated, subdivided block whose rotation stays in
    the object's transform reaches the core with planar faces (float32 local coordinates turned into
    world space in float64): its cells merge into 5 faces and it is a convex solid. With the rotation
    applied to the mesh (float32 world coordinates) its faces fold and do not merge; the core then finds
    a polytope inside it instead (core/inner_solids.py)."""
    culling = importlib.import_module(extension.__name__ + ".core.culling")
    ob = _block_mesh("Block")
    ob.rotation_euler = (0.0, 0.0, 0.3)
    ob.location = (0.25, -0.5, 0.0)
    occ = culling.build_occluders(export(hlp, missing="black").scene)
    assert occ.n == 5 and occ.solids.n == 1 and not occ.solids.is_virtual().any()
    bpy.context.view_layer.update()
    ob.data.transform(ob.matrix_world)
    ob.matrix_world.identity()
    occ = culling.build_occluders(export(hlp, missing="black").scene)
    assert occ.n > 5 and occ.solids.is_virtual().sum() == 1
