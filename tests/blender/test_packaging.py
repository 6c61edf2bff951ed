"""The extension as a user gets it: manifest, built zip, install, enable, register/unregister, CLI."""

import glob
import os
import subprocess
import sys
import types
import zipfile

import addon_utils
import bpy
import pytest
import tomllib
from conftest import MODULE, PKG_ID, ROOT, blender_platform


def manifest() -> dict:
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        return tomllib.load(fh)


def version_tuple(text: str) -> tuple:
    return tuple(int(p) for p in text.split("."))


def test_manifest_fields():
    m = manifest()
    assert m["schema_version"] == "1.0.0"
    assert m["id"] == PKG_ID
    assert m["type"] == "add-on"
    assert m["license"] == ["SPDX:GPL-3.0-or-later"]
    assert m["blender_version_min"] == "4.2.0"
    assert m["permissions"]["files"] == "Read radiosity scenes and write EXR images"
    assert m["wheels"] == [], "the repository's manifest lists no wheels; the build fills the staged copy"
    assert blender_platform() in m["platforms"]
    from hemisphere_local_pass import bl_info

    assert ".".join(map(str, bl_info["version"])) == m["version"], "bl_info and the manifest disagree"


def test_this_blender_satisfies_version_min():
    assert bpy.app.version >= version_tuple(manifest()["blender_version_min"])


def test_manifest_validates_with_this_blenders_tool(build_script, built_zip):
    tool = build_script.blender_ext_tool(sys.executable)
    result = subprocess.run([sys.executable, tool, "validate", built_zip], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_built_zip_contents(built_zip):
    with zipfile.ZipFile(built_zip) as zf:
        names = set(zf.namelist())
        staged = tomllib.loads(zf.read("blender_manifest.toml").decode())
    for required in ("__init__.py", "blender/__init__.py", "blender/registration.py", "core/__init__.py"):
        assert required in names, f"{required} missing from {os.path.basename(built_zip)}"
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]
    wheels = [n for n in names if n.endswith(".whl")]
    assert not [w for w in wheels if os.path.basename(w).lower().startswith("numpy")], "numpy must never be bundled"
    tags = {os.path.basename(w).split("-")[2] for w in wheels}
    assert {"cp311", "cp313"} <= tags, wheels
    assert sorted(w.lstrip("./") for w in staged["wheels"]) == sorted(wheels)
    assert staged["platforms"] == [blender_platform()]


def test_installed_into_isolated_user_dir(extension, user_dir):
    path = os.path.realpath(extension.__file__)
    assert path.startswith(os.path.realpath(os.path.join(user_dir, "extensions", "user_default", PKG_ID)))
    assert addon_utils.check(MODULE) == (True, True)


def test_bundled_openexr_wheel_is_extracted_and_importable(extension, user_dir):
    site = os.path.join(
        user_dir, "extensions", ".local", "lib", "python{}.{}".format(*sys.version_info[:2]), "site-packages"
    )
    assert glob.glob(os.path.join(site, "OpenEXR*")), f"no OpenEXR in {site}"
    assert site in sys.path
    # In a clean interpreter, with only the extracted wheel added, OpenEXR must load from there.
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]); import OpenEXR, os; "
        "assert os.path.realpath(OpenEXR.__file__).startswith(os.path.realpath(sys.argv[1])), OpenEXR.__file__"
    )
    result = subprocess.run([sys.executable, "-s", "-c", code, site], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_operator_panel_and_settings_exist(scene):
    assert hasattr(bpy.types, "HLP_OT_render_local_pass")
    assert hasattr(bpy.types, "HLP_PT_local_pass")
    assert bpy.types.HLP_PT_local_pass.bl_context == "render"
    assert bpy.ops.hlp.render_local_pass.idname() == "HLP_OT_render_local_pass"
    settings = scene.hlp_settings
    assert settings.attribute == "radiosity"
    assert settings.reflectivity_attribute == "reflectivity"
    assert settings.emission_attribute == "emission"
    assert settings.mode == 'PIXELS'
    assert settings.missing_attribute == 'ERROR'
    assert settings.samples == 1
    assert settings.double_sided is False
    assert settings.output_path.endswith(".exr")
    settings.mode = 'VERTICES'
    settings.missing_attribute = 'BLACK'
    with pytest.raises(TypeError):
        settings.mode = 'NOPE'


def test_operator_tooltip_is_the_docstring(extension):
    op = bpy.types.HLP_OT_render_local_pass
    assert bpy.ops.hlp.render_local_pass.get_rna_type().description == op.__doc__.strip()


def _registered(capfd) -> bool:
    """Whether the ``hemisphere_local_pass`` CLI command is registered (a duplicate registration warns)."""
    capfd.readouterr()
    handle = bpy.utils.register_cli_command("hemisphere_local_pass", lambda argv: 0)
    bpy.utils.unregister_cli_command(handle)
    captured = capfd.readouterr()
    return "duplicate command" in captured.err + captured.out


def _assert_registered(module, state: bool):
    assert hasattr(bpy.types.Scene, "hlp_settings") is state
    assert hasattr(bpy.types, "HLP_OT_render_local_pass") is state
    assert hasattr(bpy.types, "HLP_PT_local_pass") is state
    for cls in module.blender.registration.classes:
        assert cls.is_registered is state, cls


def test_cli_command_registered(extension, capfd):
    assert _registered(capfd)


def test_register_unregister_twice(extension, capfd):
    module = extension
    try:
        for _ in range(2):
            module.unregister()
            _assert_registered(sys.modules[MODULE], False)
            assert not _registered(capfd)
            module.register()
            _assert_registered(sys.modules[MODULE], True)
            assert _registered(capfd)
        for _ in range(2):
            addon_utils.disable(MODULE, default_set=True)
            _assert_registered(sys.modules[MODULE], False)
            addon_utils.enable(MODULE, default_set=True)
            _assert_registered(sys.modules[MODULE], True)
            assert addon_utils.check(MODULE) == (True, True)
    finally:
        if not hasattr(bpy.types.Scene, "hlp_settings"):
            addon_utils.enable(MODULE, default_set=True)
    assert _registered(capfd)


def test_cli_handler_help_and_errors(extension, capsys):
    cli = sys.modules[MODULE + ".blender.cli"]
    assert cli.handler([]) == 0
    assert "blender --command hemisphere_local_pass" in capsys.readouterr().out
    assert cli.handler(["--help"]) == 0
    assert cli.handler(["--version"]) == 0
    assert capsys.readouterr().out.strip().endswith(manifest()["version"])
    assert cli.handler(["frobnicate"]) == 2
    assert "expected a sub-command" in capsys.readouterr().err


def test_cli_delegates_to_job(extension, capsys):
    cli = sys.modules[MODULE + ".blender.cli"]
    code = cli.handler(["render", "--help"])
    out = capsys.readouterr().out
    assert code == 0
    assert "--output" in out


def test_operator_error_is_reported(scene, tmp_path):
    """An empty scene cannot be rendered: the operator reports one clear error (RuntimeError in background)."""
    scene.hlp_settings.output_path = str(tmp_path / "never.exr")
    with pytest.raises(RuntimeError) as info:
        bpy.ops.hlp.render_local_pass()
    message = str(info.value)
    assert message.strip(), "the error must carry a message"
    assert "Traceback" not in message, f"the operator crashed instead of reporting: {message}"
    assert not (tmp_path / "never.exr").exists()


def test_panel_draws(scene):
    """The panel's draw() runs against real settings (through a stand-in layout)."""

    class Layout:
        def __init__(self):
            self.props = []
            self.operators = []
            self.use_property_split = False
            self.use_property_decorate = True

        def column(self, **_kw):
            return self

        def prop(self, data, name, **_kw):
            assert hasattr(data, name), name
            self.props.append(name)

        def operator(self, idname, **_kw):
            self.operators.append(idname)

    class Context:
        pass

    context = Context()
    context.scene = scene
    panel_cls = bpy.types.HLP_PT_local_pass
    assert panel_cls.poll(context)
    layout = Layout()
    panel_cls.draw(types.SimpleNamespace(layout=layout), context)  # draw() only uses self.layout
    assert "attribute" in layout.props and "mode" in layout.props and "output_path" in layout.props
    assert layout.operators == ["hlp.render_local_pass", "hlp.bake_vertex_colours"]


def test_import_does_not_import_bpy(tmp_path):
    """Plain Python: importing the package (and its core) must not import bpy."""
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]); import hemisphere_local_pass as h; "
        "assert 'bpy' not in sys.modules, 'bpy imported'; "
        "assert callable(h.register) and callable(h.unregister); print(h.bl_info['name'])"
    )
    result = subprocess.run([sys.executable, "-c", code, ROOT], capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "Hemisphere Local Pass" in result.stdout


def _closed_box_scene(scene, attribute: str):
    """A unit cube seen from inside (normals inward), FACE-domain radiance ``attribute``, camera inside."""
    import numpy as np

    verts = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    # faces wound so that the normals point into the box
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    mesh = bpy.data.meshes.new("Box")
    mesh.from_pydata(verts, [], faces)
    mesh.flip_normals()
    mesh.update()
    attr = mesh.attributes.new(attribute, 'FLOAT_COLOR', 'FACE')
    values = np.zeros((len(faces), 4), dtype=np.float32)
    values[:, :3] = 0.5
    values[0, :3] = 4.0  # one bright wall
    values[:, 3] = 1.0
    attr.data.foreach_set("color", values.ravel())
    ob = bpy.data.objects.new("Box", mesh)
    scene.collection.objects.link(ob)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = (0.0, 0.0, 0.0)
    cam.rotation_euler = (1.5707963, 0.0, 0.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.resolution_x = scene.render.resolution_y = 4
    scene.render.resolution_percentage = 100
    return ob


def test_operator_runs_the_job_with_the_scene_settings(scene, tmp_path):
    """The operator passes the panel's settings to the job: custom attribute name, EXR path, vertices."""
    box = _closed_box_scene(scene, "my_radiosity")
    settings = scene.hlp_settings
    settings.attribute = "my_radiosity"
    settings.output_path = str(tmp_path / "box.exr")
    assert bpy.ops.hlp.render_local_pass() == {'FINISHED'}
    assert (tmp_path / "box.exr").exists()
    assert "Local Pass" in bpy.data.images

    settings.mode = 'VERTICES'
    bpy.context.view_layer.objects.active = box
    box.select_set(True)
    assert bpy.ops.hlp.render_local_pass() == {'FINISHED'}
    names = {a.name for a in box.data.attributes}
    assert {"hlp_radiance", "hlp_irradiance"} <= names, names

    settings.attribute = "no_such_attribute"
    with pytest.raises(RuntimeError, match="no_such_attribute"):
        bpy.ops.hlp.render_local_pass()
