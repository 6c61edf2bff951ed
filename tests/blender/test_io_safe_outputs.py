"""Nothing a user made is lost (issue 14): output permissions, the overwrite rule, symlinks, unsaved
files, tile previews, real reasons for unwritable places, names the user sees, vertex-mode UX."""

import importlib
import os
import shlex
import shutil
import stat
import subprocess
import sys
import tempfile

import numpy as np
import pytest
from test_io_job import build_box

bpy = pytest.importorskip("bpy")


@pytest.fixture
def hlp(extension, scene):
    base = extension.__name__
    mods = {name: importlib.import_module(f"{base}.blender.{name}") for name in ("job", "outputs")}
    mods["base"] = base
    return mods


def output_paths(hlp):
    return importlib.import_module(hlp["base"] + ".blender.output_paths")


def read(path):
    with open(path, "rb") as fh:
        return fh.read()


def mode_of(path):
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


# --------------------------------------------------------------------------- 1. permissions
def test_outputs_get_ordinary_permissions(hlp, tmp_path, umask_022, monkeypatch):
    build_box(subdivisions=1, resolution=24)
    job = hlp["job"]
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".receiver_chunks.MIN_CHUNK", 16)
    out = str(tmp_path / "a.exr")
    seen = {}

    def progress(done, total):  # the checkpoint exists between chunks
        ck = out + ".checkpoint.npz"
        if os.path.exists(ck):
            seen["checkpoint"] = mode_of(ck)

    job.run_local_pass(output=out, progress=progress)
    assert mode_of(out) == 0o644 and mode_of(str(tmp_path / "a.png")) == 0o644  # 0666 & ~022, as open() gives
    assert seen["checkpoint"] == 0o644
    os.chmod(out, 0o664)  # a replaced file keeps its mode
    os.chmod(str(tmp_path / "a.png"), 0o640)
    job.run_local_pass(output=out, overwrite=True)
    assert mode_of(out) == 0o664 and mode_of(str(tmp_path / "a.png")) == 0o640
    os.umask(0o077)
    blend = str(tmp_path / "b.blend")
    for ob in bpy.context.scene.objects:
        ob.select_set(ob.name == "Floor")
    assert job.cli_main(["render", "--mode", "vertices", "-o", blend, "-q"]) == 0
    assert mode_of(blend) == 0o600  # the umask is honoured too


# ------------------------------------------------------------------------ 2. the overwrite rule
def test_existing_files_are_replaced_only_when_ours_and_asked(hlp, tmp_path):
    build_box(subdivisions=1, resolution=4)
    job = hlp["job"]
    blend = tmp_path / "scene_copy.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    original = read(blend)
    for flag in (False, True):  # a .blend is never replaced, not even with overwrite
        with pytest.raises(ValueError, match=r"scene_copy.blend' exists and is a .blend file.*never replaced"):
            job.run_local_pass(output=str(blend), overwrite=flag)
    assert read(blend) == original
    foreign = tmp_path / "precious.exr"  # an EXR of another program (no hlp_software header)
    hlp["outputs"]._write_plain_exr(str(foreign), {"R": np.zeros((1, 1), np.float32)}, (0, 0, 0, 0), (0, 0, 0, 0), {})
    foreign_bytes = read(foreign)
    with pytest.raises(ValueError, match="OpenEXR image not written by hemisphere_local_pass"):
        job.run_local_pass(output=str(foreign), overwrite=True)
    assert read(foreign) == foreign_bytes and not (tmp_path / "precious.png").exists()
    # our own EXR: refused without overwrite, replaced with it
    out = str(tmp_path / "ours.exr")
    rep = job.run_local_pass(output=out)
    assert rep.outputs == [out, str(tmp_path / "ours.png")] and rep.refused == []
    op = output_paths(hlp)
    assert op.is_ours(out, "exr") and op.is_ours(str(tmp_path / "ours.png"), "png")
    with pytest.raises(ValueError, match="exists.*--overwrite"):
        job.run_local_pass(output=out)
    # the preview next to it is a name the user never gave: a foreign PNG there is refused, by path
    png = tmp_path / "ours.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n not ours")
    rep = job.run_local_pass(output=out, overwrite=True)
    assert rep.outputs == [out] and len(rep.refused) == 1 and str(png) in rep.refused[0]
    assert read(png) == b"\x89PNG\r\n\x1a\n not ours"
    # devices are never replaced
    with pytest.raises(ValueError, match="character device"):
        op.check_new_or_ours("/dev/null", "exr", overwrite=True, what="output image")


def test_symlinks_are_written_through(hlp, tmp_path):
    build_box(subdivisions=1, resolution=4)
    (tmp_path / "renders").mkdir()
    target = tmp_path / "renders" / "frame.exr"
    link = tmp_path / "latest.exr"
    link.symlink_to(target)  # dangling until the first run
    rep = hlp["job"].run_local_pass(output=str(link))
    assert link.is_symlink() and target.is_file() and str(target) in rep.outputs
    assert (tmp_path / "renders" / "frame.png").is_file()  # the preview goes next to the file written
    hlp["job"].run_local_pass(output=str(link), overwrite=True)
    assert link.is_symlink() and os.readlink(link) == str(target)


def test_cli_reports_written_and_refused_and_blend_rules(hlp, tmp_path, capsys):
    scene, box, values = build_box(subdivisions=1, resolution=4)
    job = hlp["job"]
    out = str(tmp_path / "o.exr")
    png = tmp_path / "o.png"
    png.write_text("my notes")
    assert job.cli_main(["render", "-o", out, "-q"]) == 0
    cap = capsys.readouterr()
    assert f"wrote {out}" in cap.out and f"not written: preview '{png}' exists" in cap.err
    assert job.cli_main(["render", "-o", out, "-q"]) == 1
    assert "--overwrite" in capsys.readouterr().err
    assert job.cli_main(["render", "-o", out, "-q", "--overwrite"]) == 0 and png.read_text() == "my notes"
    # vertices mode: never the open file, an existing .blend only with --overwrite (old kept as .blend1)
    src = str(tmp_path / "input.blend")
    bpy.ops.wm.save_as_mainfile(filepath=src)
    bpy.data.objects["Floor"].select_set(True)
    before = read(src)
    assert job.cli_main(["render", "--mode", "vertices", "-o", src, "-q", "--overwrite"]) == 1
    assert "is the open .blend file" in capsys.readouterr().err and read(src) == before
    baked = str(tmp_path / "baked.blend")
    assert job.cli_main(["render", "--mode", "vertices", "-o", baked, "-q"]) == 0
    first = read(baked)
    assert job.cli_main(["render", "--mode", "vertices", "-o", baked, "-q"]) == 1
    assert "pass --overwrite" in capsys.readouterr().err and read(baked) == first
    assert job.cli_main(["render", "--mode", "vertices", "-o", baked, "-q", "--overwrite"]) == 0
    assert read(baked + "1") == first
    notes = tmp_path / "notes.blend"
    notes.write_text("not a blend")
    assert job.cli_main(["render", "--mode", "vertices", "-o", str(notes), "-q", "--overwrite"]) == 1
    assert "not a .blend file" in capsys.readouterr().err and notes.read_text() == "not a blend"


def test_checkpoint_of_an_interrupted_run_is_kept(hlp, tmp_path, monkeypatch):
    build_box(subdivisions=1, resolution=24)
    job = hlp["job"]
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".receiver_chunks.MIN_CHUNK", 16)
    out = str(tmp_path / "c.exr")

    def stop(done, total):
        if done >= 64:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        job.run_local_pass(output=out, progress=stop)
    ck = out + ".checkpoint.npz"
    kept = read(ck)
    with pytest.raises(ValueError, match="interrupted run exists: pass --resume"):
        job.run_local_pass(output=out)  # a rerun without --resume does not throw the work away
    assert read(ck) == kept
    assert job.run_local_pass(output=out, resume=True).resumed_points > 0


# ------------------------------------------------------------------------ 3. unsaved + relative
def test_relative_output_of_an_unsaved_file_is_refused(hlp, tmp_path, monkeypatch, capfd):
    build_box(subdivisions=1, resolution=4)
    monkeypatch.chdir(tmp_path)
    settings = bpy.context.scene.hlp_settings
    assert settings.output_path == "//local_pass.exr" and not bpy.data.filepath
    with pytest.raises(RuntimeError, match=r"relative to the \.blend file.*not been saved"):
        bpy.ops.hlp.render_local_pass()
    assert os.listdir(tmp_path) == []  # nothing written into the working directory
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "saved.blend"))
    (tmp_path / "local_pass.png").write_text("a user's file")
    capfd.readouterr()
    assert bpy.ops.hlp.render_local_pass() == {'FINISHED'}
    assert (tmp_path / "local_pass.exr").is_file() and (tmp_path / "local_pass.png").read_text() == "a user's file"
    assert f"Not written: preview '{tmp_path / 'local_pass.png'}' exists" in capfd.readouterr().out
    with pytest.raises(RuntimeError, match="exists"):  # the operator property overrides Output > Overwrite
        bpy.ops.hlp.render_local_pass(overwrite=False)
    bpy.context.scene.render.use_overwrite = False
    with pytest.raises(RuntimeError, match="exists"):
        bpy.ops.hlp.render_local_pass()
    assert bpy.ops.hlp.render_local_pass(overwrite=True) == {'FINISHED'}


# ---------------------------------------------------------------------- 4. tile and merge previews
def test_tiles_write_no_preview_and_merge_writes_the_whole_one(hlp, tmp_path, capsys):
    build_box(subdivisions=1, resolution=6)
    job = hlp["job"]
    full = str(tmp_path / "full.exr")
    job.run_local_pass(output=full)
    tiles = [str(tmp_path / f"t{i}.exr") for i in (1, 2)]
    for i, t in enumerate(tiles, 1):
        assert job.cli_main(["render", "-o", t, "--tile", f"{i}/2", "-q"]) == 0
    assert sorted(os.listdir(tmp_path)) == ["full.exr", "full.png", "t1.exr", "t2.exr"]
    merged = str(tmp_path / "m.exr")
    assert job.cli_main(["merge", *tiles, "-o", merged]) == 0
    out = capsys.readouterr().out
    assert f"wrote {tmp_path / 'm.png'}" in out
    a = bpy.data.images.load(str(tmp_path / "full.png"))
    b = bpy.data.images.load(str(tmp_path / "m.png"))
    pa, pb = np.empty(len(a.pixels), np.float32), np.empty(len(b.pixels), np.float32)
    a.pixels.foreach_get(pa)
    b.pixels.foreach_get(pb)
    np.testing.assert_array_equal(pa, pb)
    assert job.cli_main(["merge", *tiles, "-o", merged]) == 1  # exists: --overwrite
    assert job.cli_main(["merge", *tiles, "-o", merged, "--overwrite"]) == 0


# ---------------------------------------------------------------------- 9. real reasons
def test_unwritable_places_give_their_real_reason(hlp, tmp_path):
    job = hlp["job"]
    build_box(subdivisions=1, resolution=4)
    with pytest.raises(ValueError, match="'/proc' is a proc file system") as info:
        job.run_local_pass(output="/proc/x.exr")
    assert "No such file" not in str(info.value)
    with pytest.raises(ValueError, match="'/sys' is a sysfs file system"):
        job.run_local_pass(output="/sys/x.exr")
    base = tempfile.mkdtemp(prefix="hlp-perm-")  # a directory nobody may enter ...
    try:
        os.chmod(base, 0o755)
        locked = os.path.join(base, "locked")  # ... holding one nobody may write in
        os.mkdir(locked, 0o555)
        os.chmod(locked, 0o555)
        closed = os.path.join(base, "closed")
        os.mkdir(closed, 0o700)
        code = ("import sys, os, errno, pwd, stat, tempfile, zipfile; sys.path.insert(0, sys.argv[1])\n"
                # output_paths too before setuid: a checkout nobody may read (a 0700 mktemp clone, as CI's)
                # cannot import it afterwards
                "from hemisphere_local_pass.blender import outputs as o, output_paths  # noqa: F401\n"
                "if os.getuid() == 0: os.setgid(65534); os.setuid(65534)\n"  # root writes anywhere: be nobody
                "for p in sys.argv[2:]:\n"
                "    try: o.check_writable(p)\n"
                "    except ValueError as e: print(e)")
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        res = subprocess.run([sys.executable, "-c", code, root, os.path.join(locked, "x.exr"),
                              os.path.join(closed, "sub", "x.exr")], capture_output=True, text=True)
        lines = res.stdout.splitlines()
        assert len(lines) == 2, res.stdout + res.stderr
        assert "permission denied: no write permission in the directory" in lines[0] and "dr-xr-xr-x" in lines[0]
        assert f"permission denied: the directory '{closed}' cannot be entered" in lines[1], lines[1]
    finally:
        shutil.rmtree(base, ignore_errors=True)
    (tmp_path / "f").write_text("")
    with pytest.raises(ValueError, match="f' is not a directory"):
        job.run_local_pass(output=str(tmp_path / "f" / "x.exr"))


def test_read_only_file_system_is_named(hlp, tmp_path):
    """A read-only mount (a private mount namespace where the machine allows it, as root in CI);
    otherwise the same message from the EROFS errno the kernel would give."""
    import errno

    op = output_paths(hlp)
    mnt = tmp_path / "ro"
    mnt.mkdir()
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    code = ("import sys; sys.path.insert(0, sys.argv[1])\n"
            "from hemisphere_local_pass.blender import output_paths as o\n"
            "try: o.check_writable(sys.argv[2])\nexcept ValueError as e: print(e)")
    args = " ".join(shlex.quote(a) for a in (sys.executable, "-c", code, root, str(mnt / "x.exr")))
    script = f"mount -t tmpfs -o ro none {shlex.quote(str(mnt))} && {args}"
    res = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True)
    if res.returncode == 0 and res.stdout.strip():
        assert f"the file system of '{mnt}' is read-only (mounted read-only at '{mnt}')" in res.stdout, res.stdout
    else:  # no mount namespaces here: the message for the errno a read-only file system gives
        msg = op.unwritable_reason(str(tmp_path), OSError(errno.EROFS, os.strerror(errno.EROFS)))
        assert msg.startswith(f"the file system of '{tmp_path}' is read-only"), msg


# ---------------------------------------------------------------------- 10. names the user sees
def test_messages_name_options_and_objects_as_the_user_sees_them(hlp, extension):
    build_box(subdivisions=1, resolution=4)
    bare = bpy.data.objects.new("Bare", bpy.data.meshes.new("Bare"))
    bare.data.from_pydata([(0.4, 0.4, 0.4), (0.6, 0.4, 0.4), (0.6, 0.6, 0.4)], [], [(0, 1, 2)])
    bpy.context.scene.collection.objects.link(bare)
    with pytest.raises(ValueError, match="Missing Attribute to Black Occluder.*--missing black"):
        hlp["job"].run_local_pass()
    bpy.data.objects.remove(bare)
    # the vertex-target conflict names the object (not its mesh) and a field the panel has
    short = bpy.data.objects["ShortBlock"]
    assert short.data.name != short.name
    short.data.attributes.new("hlp_radiance", "FLOAT_COLOR", "POINT")
    for ob in bpy.context.scene.objects:
        ob.select_set(ob == short)
    with pytest.raises(ValueError) as info:
        hlp["job"].run_local_pass(mode="vertices")
    msg = str(info.value)
    assert msg.startswith("object 'ShortBlock' already has a user attribute 'hlp_radiance'"), msg
    assert "Radiance Attribute in the panel" in msg and "--radiance-attribute" in msg
    settings = bpy.context.scene.hlp_settings
    settings.mode = 'VERTICES'
    panels = importlib.import_module(extension.__name__ + ".blender.panels")
    drawn = _panel_props(panels, bpy.context)
    assert "radiance_attribute" in drawn and "irradiance_attribute" in drawn
    settings.radiance_attribute = "lit"  # the field the message names is the one the job uses
    assert bpy.ops.hlp.render_local_pass() == {'FINISHED'}
    assert "lit" in short.data.attributes


def _panel_props(panels, context):
    import types

    names = []

    class Layout:
        use_property_split = use_property_decorate = False

        def column(self, **_kw):
            return self

        def prop(self, data, name, **_kw):
            assert hasattr(data, name), name
            names.append(name)

        def operator(self, *_a, **_kw):
            pass

    panels.HLP_PT_local_pass.draw(types.SimpleNamespace(layout=Layout()), context)
    return names


# ---------------------------------------------------------------------- 11. vertex mode UX
def test_vertex_bake_activates_radiance_and_objects_option(hlp, tmp_path, capsys):
    build_box(subdivisions=1, resolution=4)
    floor, back = bpy.data.objects["Floor"], bpy.data.objects["BackWall"]
    floor.data.attributes.new("Col", "FLOAT_COLOR", "POINT")
    floor.data.color_attributes.active_color = floor.data.color_attributes["Col"]
    for ob in bpy.context.scene.objects:
        ob.select_set(False)  # nothing selected: --objects chooses
    out = str(tmp_path / "v.blend")
    assert hlp["job"].cli_main(["render", "--mode", "vertices", "--objects", "Floor", "BackWall", "-o", out, "-q"]) == 0
    for ob in (floor, back):
        assert ob.data.color_attributes.active_color.name == "hlp_radiance", ob.name
    assert "hlp_radiance" not in bpy.data.objects["Ceiling"].data.attributes
    out = str(tmp_path / "v2.blend")
    assert hlp["job"].cli_main(["render", "--mode", "vertices", "--objects", "Nope", "-o", out, "-q"]) == 1
    assert "has no object 'Nope'" in capsys.readouterr().err
    assert hlp["job"].cli_main(["render", "--mode", "vertices", "--objects", "Camera", "-o", out, "-q"]) == 1
    assert "'Camera' is a camera, not a mesh" in capsys.readouterr().err


def test_edit_mode_with_nothing_selected_is_an_error(hlp):
    build_box(subdivisions=1, resolution=4)
    floor = bpy.data.objects["Floor"]
    for ob in bpy.context.scene.objects:
        ob.select_set(ob == floor)
    bpy.context.view_layer.objects.active = floor
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="DESELECT")
    with pytest.raises(ValueError, match="nothing selected: 'Floor' in Edit Mode"):
        hlp["job"].run_local_pass(mode="vertices")
    assert bpy.context.object.mode == "EDIT"
    bpy.ops.object.mode_set(mode="OBJECT")
    assert "hlp_radiance" not in floor.data.attributes  # nothing written


# ---------------------------------------------------------------------- 7. register twice
def test_register_twice_is_harmless(extension):
    extension.register()  # already enabled: no "already registered"
    assert hasattr(bpy.types, "HLP_OT_render_local_pass")
    extension.unregister()
    assert not hasattr(bpy.types, "HLP_OT_render_local_pass")
    extension.register()
    extension.register()
    assert bpy.types.HLP_OT_render_local_pass.is_registered


# ---------------------------------------------------------------------- 6. SIGINT in the bpy module
def test_first_sigint_stops_the_job_even_where_the_host_swallows_it(hlp, tmp_path, monkeypatch):
    """A host that ignores SIGINT (as Blender 3.4's break-event handler in effect does): for the
    job's duration SIGINT stops it anyway, the checkpoint is kept, and the host's handler is back
    afterwards (tier 3 sends a real SIGINT to Blender 3.4)."""
    import signal

    build_box(subdivisions=1, resolution=24)
    job = hlp["job"]
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".receiver_chunks.MIN_CHUNK", 16)
    out = str(tmp_path / "s.exr")

    def ctrl_c(done, total):
        if done >= 64:
            os.kill(os.getpid(), signal.SIGINT)

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with pytest.raises(KeyboardInterrupt):
            job.run_local_pass(output=out, progress=ctrl_c)
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)
    assert os.path.isfile(out + ".checkpoint.npz") and not os.path.exists(out)
