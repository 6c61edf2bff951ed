"""The render engine through the installed extension: ``bpy.ops.render.render(write_still=True)``
writes through Blender's output settings; the passes equal ``run_local_pass`` on the same scene (float32
render buffers: 1e-6 relative); border and resolution % are honoured; registering twice leaves nothing
behind."""

import importlib
import importlib.util
import os
import sys
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import MODULE  # noqa: E402
from sample_loader import sample_module  # noqa: E402

ENGINE_ID = "HEMISPHERE_LOCAL_PASS"
EXTRA_PASSES = ("Depth", "Irradiance", "Form Factor Sum", "Error Estimate", "Exact Samples", "IndexOB")




@pytest.fixture
def hlp(extension, scene):
    base = extension.__name__
    return {name: importlib.import_module(f"{base}.blender.{name}") for name in ("engine", "job", "outputs")}


def build_box(resolution=12):
    scene, _box, _values = sample_module().build(2, resolution=resolution, reset=False)
    return bpy.context.scene


def read_multilayer(path) -> dict:
    """{"Layer.Pass.C": (H, W) top row first} of a multilayer EXR: with the OpenEXR package (the
    extension's wheel; Blender 5 writes multi-part files), else our reader (single-part, uncompressed)."""
    try:
        import OpenEXR
    except ImportError:
        from hemisphere_local_pass.blender.outputs import _read_plain_exr

        return _read_plain_exr(path)[0]
    out = {}
    with OpenEXR.File(path, separate_channels=True) as f:
        for part in f.parts:
            prefix = part.name() if callable(getattr(part, "name", None)) else getattr(part, "name", "")
            for name, channel in part.channels.items():
                full = name if name.count(".") >= 2 or not prefix else f"{prefix}.{name}"
                out[full] = np.array(channel.pixels)
    return out


def render_exr(scene, path):
    """Render with the engine into an uncompressed 32-bit multilayer EXR -> {channel: (H, W) row 0 at the bottom}."""
    scene.render.engine = ENGINE_ID
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):  # Blender 5.0+: multilayer is a media type
        settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.exr_codec = "NONE"
    settings.color_depth = "32"
    scene.render.filepath = str(path)
    scene.render.use_file_extension = False
    assert bpy.ops.render.render(write_still=True) == {'FINISHED'}
    assert os.path.isfile(path), "write_still wrote nothing"
    chans = read_multilayer(str(path))
    layer = scene.view_layers[0].name
    return {name[len(layer) + 1:]: c[::-1].astype(np.float64) for name, c in chans.items()}


def close(a, b, rel=1e-6):
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    assert a.shape == b.shape, (a.shape, b.shape)
    err = np.abs(a - b) / np.maximum(1.0, np.abs(b))
    assert err.max(initial=0.0) <= rel, f"max relative difference {err.max():.3e}"


def engine_available() -> bool:
    """Whether Properties > Render > Render Engine offers the engine (a dynamic enum: try to set it)."""
    r = bpy.context.scene.render
    old = r.engine
    try:
        r.engine = ENGINE_ID
    except TypeError:
        return False
    r.engine = old
    return True


def test_engine_is_listed(hlp):
    assert engine_available()
    cls = hlp["engine"].HLP_RenderEngine
    assert cls.is_registered and cls.bl_idname == ENGINE_ID and cls.bl_label == "Hemisphere Local Pass"
    assert cls.bl_use_postprocess and not cls.bl_use_preview


def test_render_equals_run_local_pass(hlp, tmp_path, monkeypatch):
    scene = build_box(12)
    ob = bpy.data.objects[sorted(o.name for o in scene.objects if o.type == "MESH")[0]]
    ob.pass_index = 7
    monkeypatch.setattr(hlp["engine"], "BAND_PIXELS", 40)  # 3 rows per band: several partial results
    passes = render_exr(scene, tmp_path / "frame.exr")
    status = hlp["engine"].status
    assert status["n_bands"] == 4 and status["bands"] == 4 and not status["cancelled"], status
    assert status["done"] == status["total"] == 144, status
    for name in EXTRA_PASSES:
        assert any(c.startswith(name + ".") for c in passes), (name, sorted(passes))
    report = hlp["job"].run_local_pass(scene, output=None, image=False)
    lay = report.result
    close(np.stack([passes[f"Combined.{c}"] for c in "RGB"], -1), lay["radiance"])
    close(passes["Combined.A"], np.ones_like(lay["alpha"]))  # an opaque film
    close(np.stack([passes[f"Irradiance.{c}"] for c in "RGB"], -1), lay["irradiance"])
    close(passes["Form Factor Sum.X"], lay["form_factor_sum"])
    close(passes["Depth.Z"], lay["depth"])
    assert (passes["Error Estimate.X"] == 0).all()  # the exact job
    assert (passes["Exact Samples.X"] == (lay["alpha"] > 0)).all()
    objects = np.array(report.objects)
    hit = lay["object_index"] >= 0
    names = np.where(hit, objects[np.maximum(lay["object_index"], 0).astype(int)], "")
    expect = np.where(names == ob.name, 7.0, 0.0)
    assert (passes["IndexOB.X"] == expect).all()
    assert (expect == 7).any()


def test_border_and_resolution_percentage(hlp, tmp_path):
    scene = build_box(20)
    r = scene.render
    r.resolution_percentage = 50  # 10 x 10 pixels
    r.use_border, r.use_crop_to_border = True, True
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = 0.2, 0.7, 0.3, 0.9
    passes = render_exr(scene, tmp_path / "border.exr")
    window = (2, 3, 7, 9)  # Blender's border rectangle of the 10 x 10 image
    assert passes["Combined.R"].shape == (window[3] - window[1], window[2] - window[0])
    report = hlp["job"].run_local_pass(scene, output=None, image=False, region=window)
    close(np.stack([passes[f"Combined.{c}"] for c in "RGB"], -1), report.result["radiance"])


def test_png_through_output_settings_and_bad_input(hlp, tmp_path):
    scene = build_box(8)
    scene.render.engine = ENGINE_ID
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(tmp_path / "frame_")
    assert bpy.ops.render.render(write_still=True) == {'FINISHED'}
    assert os.path.isfile(tmp_path / "frame_.png")
    img = bpy.data.images.load(str(tmp_path / "frame_.png"))
    assert tuple(img.size) == (8, 8)
    # an object without the radiosity attribute: the render reports the object, writes no image
    bpy.ops.mesh.primitive_plane_add(size=0.1, location=(0.5, 0.5, 0.5))
    scene.render.filepath = str(tmp_path / "bad_")
    with pytest.raises(RuntimeError, match="Plane"):
        bpy.ops.render.render(write_still=True)


def ours_appended() -> list:
    """Draw functions of the extension still prepended/appended to Blender's headers and panels."""
    found = []
    for cls in (bpy.types.STATUSBAR_HT_header, bpy.types.RENDER_PT_context):
        for fn in cls._dyn_ui_initialize():
            if getattr(fn, "__module__", "").startswith(MODULE):
                found.append(f"{cls.__name__}: {fn.__name__}")
    return found


def test_register_unregister_twice_leaves_no_engine(extension):
    module = extension
    try:
        for _ in range(2):
            module.unregister()
            assert not engine_available()
            assert not sys.modules[MODULE + ".blender.engine"].HLP_RenderEngine.is_registered
            assert not ours_appended(), "a draw function of the extension is still appended"
            assert not hasattr(bpy.types.WindowManager, "hlp_progress")
            for panel in (bpy.types.RENDER_PT_color_management,):
                assert ENGINE_ID not in panel.COMPAT_ENGINES
            module.register()
            assert engine_available()
            assert sorted(ours_appended()) == ["RENDER_PT_context: draw_render_context",
                                               "STATUSBAR_HT_header: draw_status"]
    finally:
        if not hasattr(bpy.types.Scene, "hlp_settings"):
            sys.modules[MODULE].register()


def test_bands_cover_the_window_once(hlp):
    engine = hlp["engine"]
    for window, band in (((0, 0, 7, 5), 14), ((2, 3, 12, 13), 4096), ((0, 0, 3, 9), 1)):
        bands = engine.band_windows(window, band)
        assert bands[0][3] == window[3] and bands[-1][1] == window[1]  # from the top row down
        rows = [y for b in bands for y in range(b[1], b[3])]
        assert sorted(rows) == list(range(window[1], window[3])) and len(rows) == len(set(rows))
        assert all(b[0] == window[0] and b[2] == window[2] for b in bands)
        assert all((b[3] - b[1]) * (window[2] - window[0]) <= max(band, window[2] - window[0]) for b in bands)


def test_esc_stops_within_a_second_and_keeps_the_bands(hlp, monkeypatch):
    """test_break() turning True mid-render (Esc) ends the render in under a second, measured from the
    first True to the end of the result, with the worker pool of the default settings; finished bands stay."""

    scene = build_box(48)
    scene.render.engine = ENGINE_ID
    engine = hlp["engine"]
    monkeypatch.setattr(engine, "BAND_PIXELS", 48 * 12)  # 4 bands
    calls = {"n": 0, "t0": None}

    def test_break(_engine):
        calls["n"] += 1
        if engine.status.get("bands", 0) < 1:
            return False
        if calls["t0"] is None:  # the second band starts
            calls["t0"] = time.perf_counter()
        return time.perf_counter() - calls["t0"] > 0.15  # Esc inside the second band

    monkeypatch.setattr(engine, "_break_requested", test_break)
    bpy.ops.render.render()
    status = engine.status
    assert status["cancelled"] and status["break_at"] is not None, status
    assert 1 <= status["bands"] < status["n_bands"], status
    latency = status["ended_at"] - status["break_at"]
    print(f"stop latency {latency:.3f} s")
    assert latency < 1.0, status


def _alive(pid) -> bool:
    """Whether process ``pid`` exists and is not a zombie (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_one_worker_pool_for_every_band_and_frame_and_none_left(hlp, tmp_path):
    """An animation of 2 frames x 4 bands on the default workers: one pool (the same processes) computes
    every band of both frames; when the render job ends no worker process is left."""
    scene = build_box(48)
    scene.render.engine = ENGINE_ID
    engine = hlp["engine"]
    old_band = engine.BAND_PIXELS
    engine.BAND_PIXELS = 48 * 12  # 4 bands of 576 points: each on the workers
    scene.frame_start, scene.frame_end = 1, 2
    scene.render.filepath = str(tmp_path / "frame_")
    scene.render.image_settings.file_format = "PNG"
    frames = []

    def post(*_args):
        frames.append(dict(engine.status))

    bpy.app.handlers.render_post.append(post)
    try:
        assert bpy.ops.render.render(animation=True) == {'FINISHED'}
    finally:
        bpy.app.handlers.render_post.remove(post)
        engine.BAND_PIXELS = old_band
    assert len(frames) == 2 and all(f["bands"] == f["n_bands"] == 4 for f in frames), frames
    pools = [tuple(p) for f in frames for p in f["worker_pids"]]
    assert len(set(pools)) == 1 and len(pools[0]) >= 1, pools  # one pool, reused by every band and frame
    assert engine._KEEPER.pool is None  # shut down at render_complete
    deadline = time.monotonic() + 5
    while any(_alive(pid) for pid in pools[0]) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(pid) for pid in pools[0]), pools
    assert (tmp_path / "frame_0001.png").is_file() and (tmp_path / "frame_0002.png").is_file()
