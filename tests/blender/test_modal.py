"""The modal machinery (blender/modal.py) in the bpy module: a job advanced chunk by chunk gives the
same result as run_local_pass; closing it between chunks leaves the scene unchanged; the operators
run synchronously in background mode; the radiosity field's search lists the scene's colour
attributes. (Timers, Esc and the status bar need a window: tests/blender_exe/test_ui.py.)"""

import importlib
import importlib.util
import threading

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from sample_loader import sample_module  # noqa: E402


@pytest.fixture
def hlp(extension, scene):
    base = extension.__name__
    return {name: importlib.import_module(f"{base}.blender.{name}")
            for name in ("modal", "job", "operators", "attribute_search")}


def build_box(resolution=8):
    sample_module().build(2, resolution=resolution, reset=False)
    return bpy.context.scene


def mesh_state(scene):
    """Everything a bake could change: attribute names and the mesh's vertex coordinates."""
    state = {}
    for ob in scene.objects:
        if ob.type == "MESH":
            co = np.empty(len(ob.data.vertices) * 3)
            ob.data.vertices.foreach_get("co", co)
            state[ob.name] = (sorted(a.name for a in ob.data.attributes), co.tobytes())
    return state


def select_meshes(scene, names):
    for ob in scene.objects:
        ob.select_set(ob.name in names)
    bpy.context.view_layer.objects.active = bpy.data.objects[names[0]]


def test_steps_equal_run_local_pass_and_close_changes_nothing(hlp):
    scene = build_box(16)
    modal = hlp["modal"]
    kwargs = hlp["operators"].job_arguments(scene, scene.hlp_settings)
    kwargs.update(mode="pixels", output=None, image=False)
    run = modal.LocalPassRun(kwargs)
    ticks = 0
    done = []
    while not run.advance(budget=0.0):  # one step per tick: a chunk, or (workers) a poll of the pool
        ticks += 1
        assert 0 <= run.done <= run.total and run.total > 0
        assert "points/s" in run.text() and "ETA" in run.text()
        done.append(run.done)
    assert done == sorted(done) and len(set(done) - {0}) >= 2, "the job must come in several chunks"
    assert run.keeper.pool is None  # the run's workers ended with it
    direct = hlp["job"].run_local_pass(**kwargs)
    assert np.array_equal(run.report.result["radiance"], direct.result["radiance"])  # bitwise

    names = [ob.name for ob in scene.objects if ob.type == "MESH"][:2]
    select_meshes(scene, names)
    before = mesh_state(scene)
    kwargs.update(mode="vertices")
    run = modal.LocalPassRun(kwargs)
    assert not run.advance(budget=0.0)
    run.close()  # Esc between two chunks
    assert mesh_state(scene) == before and run.keeper.pool is None


def _adaptive_threads():
    return [t for t in threading.enumerate() if t.name == "hlp-adaptive" and t.is_alive()]


def test_adaptive_pass_yields_while_it_runs_and_esc_stops_it(hlp, monkeypatch):
    """The adaptive pass (tolerance > 0) is no longer one blocking call: its core calls run in a
    thread and the job yields a step every POLL_SECONDS meanwhile (the modal timer returns to
    Blender's event loop there), with the exact evaluations done so far; the result is the same bits
    however many steps it took; closing the generator mid-pass (Esc) stops and joins the thread and
    leaves nothing behind; cancel() stops it as well."""
    scene = build_box(16)
    base = hlp["modal"].__name__.rsplit(".", 1)[0]
    cancelled = importlib.import_module(base.rsplit(".", 1)[0] + ".core").Cancelled
    monkeypatch.setattr(base + ".adaptive_pixels.POLL_SECONDS", 0.002)
    kwargs = hlp["operators"].job_arguments(scene, scene.hlp_settings)
    kwargs.update(mode="pixels", output=None, image=False, tolerance=1e-3)
    run = hlp["modal"].LocalPassRun(kwargs)
    ticks, alive, done = 0, 0, []
    while not run.advance(budget=0.0):  # one step per tick
        ticks += 1
        alive += bool(_adaptive_threads())
        done.append(run.done)
        assert 0 <= run.done <= run.total and "points/s" in run.text()
    assert ticks >= 2 and alive >= 1, (ticks, alive)  # the event loop got control while the pass ran
    assert done == sorted(done) and run.report.exact_points > 0
    assert not _adaptive_threads()
    monkeypatch.undo()  # the default poll: fewer steps, the same bits
    direct = hlp["job"].run_local_pass(**kwargs)
    for key in ("irradiance", "radiance", "exact_sample", "error_estimate"):
        assert np.array_equal(run.report.result[key], direct.result[key]), key
    assert direct.exact_points == run.report.exact_points

    monkeypatch.setattr(base + ".adaptive_pixels.POLL_SECONDS", 0.002)
    kwargs.update(image=True)
    run = hlp["modal"].LocalPassRun(kwargs)
    assert not run.advance(budget=0.0) and _adaptive_threads()  # mid-pass
    run.close()  # Esc
    assert not _adaptive_threads() and bpy.data.images.get(hlp["job"].IMAGE_NAME) is None
    with pytest.raises(cancelled):
        hlp["job"].run_local_pass(cancel=lambda: True, **kwargs)
    assert not _adaptive_threads() and bpy.data.images.get(hlp["job"].IMAGE_NAME) is None
    calls = []

    def interrupted(done, total):  # Ctrl-C in the caller's thread while the pass runs
        calls.append(done)
        if len(calls) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        hlp["job"].run_local_pass(progress=interrupted, **kwargs)
    assert len(calls) == 2 and not _adaptive_threads()  # the thread was stopped and waited for


def test_bake_operator_background_is_synchronous(hlp):
    scene = build_box(4)
    names = [ob.name for ob in scene.objects if ob.type == "MESH"][:1]
    select_meshes(scene, names)
    assert bpy.ops.hlp.bake_vertex_colours('INVOKE_DEFAULT') == {'FINISHED'}
    mesh = bpy.data.objects[names[0]].data
    assert "hlp_radiance" in mesh.attributes and "hlp_irradiance" in mesh.attributes
    for ob in scene.objects:
        ob.select_set(False)
    assert not bpy.ops.hlp.bake_vertex_colours.poll()


def test_show_vertex_colours_makes_the_attribute_active(hlp):
    scene = build_box(4)
    names = [ob.name for ob in scene.objects if ob.type == "MESH"][:1]
    select_meshes(scene, names)
    assert bpy.ops.hlp.bake_vertex_colours() == {'FINISHED'}
    ob = bpy.data.objects[names[0]]
    hlp["modal"].show_vertex_colours(bpy.context, [ob], "hlp_radiance")
    assert ob.data.color_attributes.active_color.name == "hlp_radiance"


def test_attribute_search_lists_colour_attributes(hlp):
    scene = build_box(4)
    ob = next(o for o in scene.objects if o.type == "MESH")
    ob.data.attributes.new("my_radiance", "FLOAT_COLOR", "POINT")
    ob.data.attributes.new("weight", "FLOAT", "POINT")  # not a colour: not listed
    items = hlp["attribute_search"].colour_attributes(scene)
    names = [name for name, _desc in items]
    assert "radiosity" in names and "my_radiance" in names and "weight" not in names
    assert names == sorted(names)
    assert [n for n, _ in hlp["attribute_search"].colour_attributes(scene, "MY_")] == ["my_radiance"]
    assert ob.name in dict(items)["my_radiance"]
    props = importlib.import_module(hlp["modal"].__name__.rsplit(".", 1)[0] + ".props")
    assert props.colour_attribute_names(scene.hlp_settings, bpy.context, "") == items  # the field's search
