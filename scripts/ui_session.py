"""Drive Blender's real window (under Xvfb) through the local pass's UI and take screenshots.

Run inside Blender with a window (``scripts/ui_screenshots.sh`` for the docs, ``tests/blender_exe/
test_ui.py`` for the checks)::

    xvfb-run -a -s "-screen 0 1280x800x24" blender --factory-startup scene.blend \
        --window-geometry 0 0 1280 800 --python scripts/ui_session.py -- --out DIR [--result FILE.json]

Steps (a generator advanced by ``bpy.app.timers``; input events come from ``xdotool``, as a user's):

1. the Render tab with the engine active (its panels), and with EEVEE (the one-line entry at the top);
2. *Render Local Pass* as a modal job: a screenshot mid-run (status-bar progress), progress and
   redraw counts at two times, the finished image in the Image Editor;
3. *Bake to Vertex Colours* cancelled with Esc mid-run: the scene unchanged; F12 with the engine
   and Esc mid-render: the render stops early and keeps its finished bands;
4. the inspector: click (xdotool) on the known floor point ``TARGET``; the snapped point, the list
   against ``core.project_point`` / ``core.irradiance``, the overlay's pixels around the point's
   projection (screenshot difference); a drag moves it; Esc leaves and the overlay is gone;
5. *Bake to Vertex Colours* on the floor, to the end: the result is the active colour attribute and
   the viewport is in Attribute colour mode.

Writes ``DIR/ui_*.png`` and a JSON summary (``--result``), then quits. Any failure is in the JSON
(``ok: false``, ``error``).
"""

import argparse
import json
import os
import subprocess
import sys
import time
import traceback

import bpy

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

import hemisphere_local_pass as hlp  # noqa: E402

#: A floor point of the sample Cornell box (unit cube, z up) that the camera sees.
TARGET = (0.3, 0.25, 0.0)


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    parser = argparse.ArgumentParser(prog="ui_session.py")
    parser.add_argument("--out", required=True)
    parser.add_argument("--result", default=None)
    parser.add_argument("--resolution", type=int, default=64, help="render size of the modal job (longer = easier "
                        "to catch mid-run)")
    return parser.parse_args(argv)


ARGS = parse_args()
os.makedirs(ARGS.out, exist_ok=True)
RESULT = {"ok": False, "steps": []}
COUNTS = {"status": 0, "view3d": 0, "inspector_panel": 0}


def log(step, **data):
    RESULT["steps"].append(step)
    RESULT[step] = data
    print(f"ui_session: {step} {data}", flush=True)


def finish(ok, error=None):
    RESULT["ok"] = ok
    if error:
        RESULT["error"] = error
        print(error, flush=True)
    if ARGS.result:
        with open(ARGS.result, "w") as fh:
            json.dump(RESULT, fh, indent=1, default=str)
    if ok:
        # Blender's exit code is G.is_break, which any Esc key press sets (here: cancelling the bake,
        # leaving the inspector); starting a render clears it. A 2 x 2 frame of the engine does that.
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 2
        scene.render.engine = 'HEMISPHERE_LOCAL_PASS'
        bpy.ops.render.render()
    bpy.ops.wm.quit_blender()


def window():
    return bpy.context.window_manager.windows[0]


def area_of(kind):
    return next((a for a in window().screen.areas if a.type == kind), None)


def shot(name):
    path = os.path.join(ARGS.out, name)
    with bpy.context.temp_override(window=window()):
        bpy.ops.screen.screenshot(filepath=path)
    return path


def xdotool(*args):
    """Real X input (XTEST), as a user's; its messages are kept off Blender's stderr."""
    done = subprocess.run(["xdotool", *[str(a) for a in args]], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"xdotool {' '.join(map(str, args))}: {done.stderr.strip()}")


def to_screen(wx, wy):
    """Window coordinates (Blender: from the bottom left) -> X screen coordinates (from the top left)."""
    win = window()
    return int(win.x + wx), int(win.y + win.height - 1 - wy)


def pixels(path):
    import numpy as np

    img = bpy.data.images.load(path)
    w, h = img.size
    arr = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(arr)
    bpy.data.images.remove(img)
    return arr.reshape(h, w, 4)


def mesh_state(scene):
    import numpy as np

    out = {}
    for ob in scene.objects:
        if ob.type == "MESH":
            co = np.empty(len(ob.data.vertices) * 3)
            ob.data.vertices.foreach_get("co", co)
            out[ob.name] = [sorted(a.name for a in ob.data.attributes), hash(co.tobytes())]
    return out


def esc_panel(scene, cells):
    """A horizontal ``cells x cells``-quad panel of zero radiosity floating mid-room, linked to ``scene``."""
    from sample_scenes._common import grid, mesh_object

    # the unit box; z = 0.8 is above both blocks, below the light; normal +z (e1 x e2)
    verts, faces = grid((0.3, 0.3, 0.8), (0.4, 0.0, 0.0), (0.0, 0.4, 0.0), cells, cells)
    ob = mesh_object("HLP_esc_panel", verts, faces, collection=scene.collection)
    attr = ob.data.attributes.new(scene.hlp_settings.attribute, 'FLOAT_COLOR', 'FACE')
    attr.data.foreach_set("color", [0.0] * (4 * len(faces)))
    return ob


def alive(pid) -> bool:
    """Whether process ``pid`` exists and is not a zombie (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def wait(predicate, timeout, step=0.1):
    """Yield until predicate() (or the timeout); returns via StopIteration whether it came true."""
    end = time.time() + timeout
    while not predicate():
        if time.time() > end:
            return False
        yield step
    return True


def settled(seconds=1.5, timeout=40.0):
    """Yield until the 3D viewport has not redrawn for ``seconds`` (returns the time waited).

    With software OpenGL under load a viewport redraw takes 1-2 s, and after a change (the engine, the
    resolution, the selection) Blender redraws it once per anti-aliasing sample (8 by default); its main
    thread reads key events only between redraws, so an Esc pressed then waits for them (Blender's, not
    the job's: docs/blender-ui.md). A user pressing Esc on a render looks at a settled window."""
    start = time.perf_counter()
    seen, changed = COUNTS["view3d"], start
    while time.perf_counter() - start < timeout:
        if COUNTS["view3d"] != seen:
            seen, changed = COUNTS["view3d"], time.perf_counter()
        elif time.perf_counter() - changed >= seconds:
            break
        yield 0.05
    return time.perf_counter() - start


def session():
    import numpy as np

    from hemisphere_local_pass.blender import inspector, modal
    from hemisphere_local_pass.core import irradiance, project_point

    scene = bpy.context.scene
    win = window()
    # count redraws: the status bar's progress and the 3D viewport
    _status = modal.draw_status

    def counted_status(self, context):
        COUNTS["status"] += 1
        _status(self, context)

    bpy.types.STATUSBAR_HT_header.remove(modal.draw_status)
    bpy.types.STATUSBAR_HT_header.prepend(counted_status)
    counter = bpy.types.SpaceView3D.draw_handler_add(lambda: COUNTS.__setitem__("view3d", COUNTS["view3d"] + 1), (),
                                                     'WINDOW', 'POST_PIXEL')
    _panel_draw = inspector.HLP_PT_inspector.draw

    def panel_draw(self, context):
        COUNTS["inspector_panel"] += 1
        _panel_draw(self, context)

    inspector.HLP_PT_inspector.draw = panel_draw

    props = area_of('PROPERTIES')
    props.spaces.active.context = 'RENDER'
    timeline = area_of('DOPESHEET_EDITOR') or area_of('TIMELINE')
    if timeline is not None:
        timeline.type = 'IMAGE_EDITOR'  # where the finished image is shown
    view = area_of('VIEW_3D')
    space = view.spaces.active
    space.region_3d.view_perspective = 'CAMERA'
    space.show_region_ui = True
    space.shading.type = 'SOLID'
    scene.render.resolution_x = scene.render.resolution_y = ARGS.resolution
    scene.hlp_settings.output_path = ""  # the image only, no files
    yield 1.0

    # 1. panels
    scene.render.engine = 'HEMISPHERE_LOCAL_PASS'
    yield 0.5
    shot("ui_engine_panels.png")
    scene.render.engine = 'BLENDER_EEVEE'
    yield 0.5
    shot("ui_other_engine.png")
    log("panels")

    # 2. the modal job; 3x3 rays per pixel so that it runs long enough to be seen mid-run (on an idle machine
    # with the hierarchy and 2 workers the 16x16 job ends in 0.4 s, before a 0.05 s poll sees 20 %)
    scene.hlp_settings.samples = 3
    with bpy.context.temp_override(window=win, area=props, region=next(r for r in props.regions if r.type == 'WINDOW')):
        started = bpy.ops.hlp.render_local_pass('INVOKE_DEFAULT')
    t0 = time.time()
    ok = yield from wait(lambda: modal._running and modal._running[0].fraction > 0.2, 120, 0.05)
    if not ok:
        raise RuntimeError(f"the modal job never reached 20 % (started: {started})")
    run = modal._running[0]
    first = {"fraction": run.fraction, "status": COUNTS["status"], "view3d": COUNTS["view3d"], "t": time.time() - t0}
    yield 0.05
    shot("ui_progress.png")
    yield 0.5
    second = {"fraction": run.fraction, "status": COUNTS["status"], "view3d": COUNTS["view3d"], "t": time.time() - t0,
              "text": run.text()}
    ok = yield from wait(lambda: not modal._running, 300, 0.2)
    editor = area_of('IMAGE_EDITOR')
    shown = editor.spaces.active.image.name if editor is not None and editor.spaces.active.image else None
    yield 0.5
    shot("ui_result.png")
    scene.hlp_settings.samples = 1
    log("modal", started=list(started), first=first, second=second, finished=ok, shown=shown,
        summary=run.report.summary() if run.report else None, seconds=time.time() - t0)

    # 3. Esc cancels a bake. The box's 208 receivers (face corners) take ~0.1 s with 2 workers, which can
    # end before the first 0.05 s poll (CI, 2026-12-02: done_at_esc == total); a 64 x 64-quad panel
    # floating mid-room (16,384 more corners: 100 chunks of 166) makes the bake last seconds, so Esc lands
    # mid-run (one or two chunks of 166 done at the key press in runs here). The panel is removed after this stage.
    panel = esc_panel(scene, cells=64)
    for ob in scene.objects:
        ob.select_set(ob.type == 'MESH')
    before = mesh_state(scene)
    settle_bake = yield from settled()
    with bpy.context.temp_override(window=win, area=props, region=next(r for r in props.regions if r.type == 'WINDOW')):
        bpy.ops.hlp.bake_vertex_colours('INVOKE_DEFAULT')
    ok = yield from wait(lambda: modal._running and modal._running[0].done > 0, 120, 0.05)
    done_at_esc = modal._running[0].done if modal._running else None
    total = modal._running[0].total if modal._running else None
    pool = modal._running[0].keeper.pool if modal._running else None
    bake_pids = pool.pids if pool is not None else []
    cx, cy = to_screen(view.x + view.width // 2, view.y + view.height // 2)
    xdotool("mousemove", cx, cy)
    t_esc = time.perf_counter()
    xdotool("key", "Escape")
    cancelled = yield from wait(lambda: not modal._running, 10, 0.02)
    t_cancelled = time.perf_counter()
    yield from wait(lambda: not any(alive(pid) for pid in bake_pids), 5, 0.1)  # reaped in the background
    # latency: Esc pressed -> the modal run had stopped (its operator returned CANCELLED)
    log("esc", running_before=ok, done_at_esc=done_at_esc, total=total, cancelled=cancelled,
        unchanged=mesh_state(scene) == before, latency=t_cancelled - t_esc, settle=settle_bake, workers=len(bake_pids),
        workers_left=[pid for pid in bake_pids if alive(pid)])
    mesh = panel.data
    bpy.data.objects.remove(panel)
    bpy.data.meshes.remove(mesh)

    # 3b. F12 with the engine, Esc mid-render: test_break() stops it, the finished bands stay
    from hemisphere_local_pass.blender import engine

    bpy.context.preferences.view.render_display_type = 'NONE'  # keep the layout (no render window)
    scene.render.engine = 'HEMISPHERE_LOCAL_PASS'
    scene.render.resolution_x = scene.render.resolution_y = 3 * ARGS.resolution
    engine.BAND_PIXELS = 4 * ARGS.resolution * 3  # 4 rows per band: several partial results
    settle = yield from settled()
    engine.status.clear()
    with bpy.context.temp_override(window=win, area=view):
        bpy.ops.render.render('INVOKE_DEFAULT')
    ok = yield from wait(lambda: engine.status.get("bands", 0) >= 1, 120, 0.05)  # a finished band to keep
    xdotool("mousemove", cx, cy)
    t_esc = time.perf_counter()
    xdotool("key", "Escape")
    t_sent = time.perf_counter()  # xdotool has returned: the key event is in the X server
    ticks = []  # this main-thread timer's ticks: gaps show whether the main thread (and the GIL) was free

    def job_gone():
        ticks.append(time.perf_counter())
        return not bpy.app.is_job_running('RENDER')

    stopped = yield from wait(job_gone, 60, 0.02)
    gaps = np.diff([t_sent] + ticks)
    pids = [pid for pool in engine.status.get("worker_pids", []) for pid in pool]
    yield from wait(lambda: not any(alive(pid) for pid in pids), 5, 0.1)
    # latency: Esc pressed -> the job had stopped for it (engine.status["cancelled_at"]);
    # break_seen: -> test_break() first True (Blender delivering Esc); stop: test_break's first True ->
    # the render result ended (ours); job_seen: -> this main-thread timer saw the render job gone
    nan = float("nan")
    st = engine.status
    log("f12_esc", started=ok, stopped=stopped, job_seen=time.perf_counter() - t_esc, xdotool=t_sent - t_esc,
        latency=st.get("cancelled_at", nan) - t_esc, break_seen=(st.get("break_at") or nan) - t_esc,
        stop=st.get("ended_at", nan) - (st.get("break_at") or nan), timer_ticks=len(ticks),
        timer_max_gap=float(gaps.max()) if len(gaps) else nan, settle=settle,
        workers_left=[pid for pid in pids if alive(pid)], **st)
    scene.render.engine = 'BLENDER_EEVEE'
    scene.render.resolution_x = scene.render.resolution_y = ARGS.resolution

    # 4. the inspector at a known point
    for ob in scene.objects:
        ob.select_set(False)
    from bpy_extras.view3d_utils import location_3d_to_region_2d

    region = next(r for r in view.regions if r.type == 'WINDOW')
    xy = location_3d_to_region_2d(region, space.region_3d, TARGET)
    sx, sy = to_screen(region.x + xy[0], region.y + xy[1])
    xdotool("mousemove", sx, sy)
    yield 0.5
    ui = next(r for r in view.regions if r.type == 'UI')
    if hasattr(ui, "active_panel_category"):  # Blender 4.1+
        ui.active_panel_category = "Local Pass"
    else:  # 3.4: click the sidebar's "Local Pass" tab (the third tab of the factory sidebar, right edge)
        tx, ty = to_screen(ui.x + ui.width - 10, ui.y + ui.height - 130)
        xdotool("mousemove", tx, ty)
        xdotool("click", 1)
        yield 0.5
        xdotool("mousemove", sx, sy)
    # widen the sidebar as a user would: drag its left edge 160 px to the left
    ex, ey = to_screen(ui.x + 2, ui.y + ui.height // 2)
    xdotool("mousemove", ex, ey)
    xdotool("mousedown", 1)
    for step in range(1, 9):
        xdotool("mousemove", ex - 20 * step, ey)
        yield 0.05
    xdotool("mouseup", 1)
    yield 0.5
    xdotool("mousemove", sx, sy)
    yield 0.5
    before_png = shot("ui_before_inspect.png")
    with bpy.context.temp_override(window=win, area=view, region=region):
        bpy.ops.hlp.inspect_form_factors('INVOKE_DEFAULT')
    yield 0.3
    xdotool("click", 1)
    ok = yield from wait(lambda: inspector.State.inspection is not None, 30, 0.1)
    if not ok:
        raise RuntimeError("the click did not inspect a point")
    panel_draws = COUNTS["inspector_panel"]
    yield 1.0
    after_png = shot("ui_inspector.png")
    ins = inspector.State.inspection
    exported = inspector.State.exported
    proj = project_point(exported.scene, ins.point, ins.normal)
    h = irradiance(exported.scene, ins.point[None], ins.normal[None])[0]
    rows_ok = all(r.form_factor == proj.polygon_form_factors[r.polygon] for r in ins.rows)
    a, b = pixels(before_png), pixels(after_png)
    wx, wy = region.x + xy[0], region.y + xy[1]  # window coordinates of the point's projection
    changed = np.abs(a[..., :3] - b[..., :3]).max(axis=2) > 0.02  # (H, W), row 0 at the bottom
    ys, xs = np.nonzero(changed[region.y:region.y + region.height, region.x:region.x + region.width - 400])
    near = int(np.sum(np.hypot(xs + region.x - wx, ys + region.y - wy) < 40))
    log("inspector", target=list(TARGET), point=ins.point.tolist(), normal=ins.normal.tolist(),
        snapped_error=float(np.linalg.norm(ins.point - np.array(TARGET))), rows=len(ins.rows), rows_equal_core=rows_ok,
        form_factor_sum=ins.form_factor_sum, core_form_factor_sum=float(np.sum(proj.form_factor)),
        irradiance=ins.irradiance.tolist(), core_irradiance=h.tolist(), panel_draws=COUNTS["inspector_panel"],
        panel_draws_at_click=panel_draws, changed_pixels_near_point=near, changed_pixels=int(changed.sum()),
        point_pixel=[float(wx), float(wy)],
        changed_centroid=[float(xs.mean() + region.x), float(ys.mean() + region.y)] if len(xs) else None)
    # drag: the point follows the mouse live (press, move in steps, release)
    xdotool("mousedown", 1)
    for step in range(1, 5):
        xdotool("mousemove", sx + 8 * step, sy)
        yield 0.2
    xdotool("mouseup", 1)
    yield 0.5
    moved = inspector.State.inspection
    log("inspector_drag", moved=float(np.linalg.norm(moved.point - ins.point)), on_floor=bool(moved.point[2] == 0.0),
        towards_x=bool(moved.point[0] > ins.point[0]))
    ins = moved
    bpy.context.window_manager.hlp_inspector_colour = 'FORM_FACTOR'  # re-inspects at the same point
    yield 1.0
    shot("ui_inspector_form_factor.png")
    recoloured = inspector.State.inspection
    log("inspector_recoloured", same_point=bool(np.allclose(recoloured.point, ins.point, atol=1e-9)),
        same_sum=recoloured.form_factor_sum == ins.form_factor_sum)
    xdotool("key", "Escape")
    left = yield from wait(lambda: inspector.State.inspection is None, 10, 0.1)
    log("inspector_left", cleared=left, handlers=len(inspector.State.handles))

    # 5. a finished bake is made visible: active colour attribute, viewport in Attribute colour mode
    floor = bpy.data.objects["Floor"]
    for ob in scene.objects:
        ob.select_set(ob is floor)
    bpy.context.view_layer.objects.active = floor
    with bpy.context.temp_override(window=win, area=props, region=next(r for r in props.regions if r.type == 'WINDOW')):
        bpy.ops.hlp.bake_vertex_colours('INVOKE_DEFAULT')
    baked = yield from wait(lambda: not modal._running, 120, 0.1)
    yield 0.5
    shot("ui_baked.png")
    active = floor.data.color_attributes.active_color
    log("bake", finished=baked, active=active.name if active is not None else None,
        color_type=space.shading.color_type, shading=space.shading.type,
        attributes=sorted(a.name for a in floor.data.attributes if a.name.startswith("hlp_")))
    bpy.types.SpaceView3D.draw_handler_remove(counter, 'WINDOW')


def main():
    hlp.register()
    steps = session()

    def tick():
        try:
            return next(steps)
        except StopIteration:
            finish(True)
        except Exception:
            finish(False, traceback.format_exc())
        return None

    bpy.app.timers.register(tick, first_interval=1.0)


main()
