"""Long jobs without freezing the window: the operators' modal machinery.

Only the main thread touches ``bpy``. :class:`LocalPassRun` holds one
:func:`.job.local_pass_steps` generator; a window-manager timer advances it chunk by chunk for at
most ``TICK_BUDGET`` seconds per tick, so Blender redraws (and handles Esc) between chunks. The
status bar shows a progress bar (``UILayout.progress`` on 4.0+, a percentage slider on 3.4) and
"12,288 / 65,536 points, 3,100 points/s, ETA 17 s"; Esc closes the generator between two chunks,
before the job has written anything, so the scene stays exactly as it was. In background mode
(``blender -b``, the bpy module) timers never fire and ``invoke`` runs the job synchronously.

With workers the job yields at every poll of its pool (``core.parallel.POLL_SECONDS``), not only when a
chunk ends, so a tick returns to the event loop within ~``TICK_BUDGET`` even while chunks compute; the
run's workers are ``WORKER_NICE`` below Blender (the window's drawing, which is CPU work with software
OpenGL, and its Esc handling come first) and end with the run.

When a job finishes, its result is made visible: pixels open in an Image Editor, vertex colours
become the active colour attribute with the 3D viewports in Attribute colour mode.
"""

from __future__ import annotations

import math
import time

import bpy

__all__ = ["HLP_OT_bake_vertex_colours", "LocalPassRun", "register", "unregister"]

#: Seconds of work per timer tick (whole chunks: a tick ends after the chunk that crosses it).
TICK_BUDGET = 0.1
#: Timer interval (s).
TICK_INTERVAL = 0.02
#: Nice value added to the run's worker processes.
WORKER_NICE = 10

#: Events a running job lets through to the viewports (navigation only: the scene must not change
#: under the job, as Blender's own render jobs lock the interface).
_NAVIGATION = {'MIDDLEMOUSE', 'WHEELUPMOUSE', 'WHEELDOWNMOUSE', 'TRACKPADPAN', 'TRACKPADZOOM', 'MOUSEMOVE',
               'INBETWEEN_MOUSEMOVE', 'NDOF_MOTION'}

#: The runs in progress (the status bar draws the first).
_running: list = []


class LocalPassRun:
    """One job advanced step by step: ``local_pass_steps(**kwargs)``.

    Attributes:
        done, total: receivers evaluated / to evaluate (0 / 0 until the first chunk ends).
        report: the :class:`.job.JobReport` once finished.
    """

    def __init__(self, kwargs: dict):
        from ..core.parallel import PoolKeeper
        from .job import local_pass_steps

        self.keeper = PoolKeeper()  # the run's one worker pool, started by its first chunks
        self.steps = local_pass_steps(**kwargs)
        self.mode = kwargs.get("mode", "pixels")
        self.done = 0
        self.total = 0
        self.start = time.perf_counter()
        self.report = None

    def advance(self, budget: float = TICK_BUDGET) -> bool:
        """Run chunks for about ``budget`` seconds; True when the job has finished (errors propagate)."""
        end = time.perf_counter() + budget
        while True:
            try:
                with self.keeper.scope(nice=WORKER_NICE):
                    step = next(self.steps)
            except StopIteration as stop:
                self.report = stop.value
                self.done = self.total = getattr(self.report, "points", self.total)
                self.keeper.close()
                return True
            except BaseException:
                self.keeper.close()
                raise
            self.done, self.total = step.done, step.total
            if time.perf_counter() >= end:
                return False

    def close(self):
        """Stop between two chunks: nothing of the job has been written; the workers are killed at once
        (reaped in the background: Esc does not wait for them)."""
        self.steps.close()
        self.keeper.close(wait=False)

    @property
    def fraction(self) -> float:
        return self.done / self.total if self.total else 0.0

    def text(self) -> str:
        """"12,288 / 65,536 points, 3,100 points/s, ETA 17 s"."""
        elapsed = time.perf_counter() - self.start
        if not self.total:
            return "Local pass: preparing (scene export, camera rays) ..."
        rate = self.done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else math.nan
        eta_s = f"{eta:,.0f} s" if math.isfinite(eta) else "?"
        return f"Local pass: {self.done:,} / {self.total:,} points, {rate:,.0f} points/s, ETA {eta_s} (Esc cancels)"


def draw_status(self, context):
    """``STATUSBAR_HT_header`` prepend: the progress of the running job."""
    if not _running:
        return
    run = _running[0]
    row = self.layout.row(align=True)
    if hasattr(row, "progress"):  # Blender 4.0+
        row.progress(factor=run.fraction, type='BAR', text=f"Local pass {100 * run.fraction:.0f} %")
    else:
        sub = row.row()
        sub.ui_units_x = 8
        sub.prop(context.window_manager, "hlp_progress", text="Local pass", slider=True)


def _redraw_all(context):
    wm = context.window_manager
    for window in wm.windows:
        for area in window.screen.areas:
            area.tag_redraw()


def _set_status(context, text):
    """The status bar's text (None: back to the key map hints); redraws the status bar."""
    workspace = getattr(context, "workspace", None)
    if workspace is not None:
        workspace.status_text_set(text)


# --------------------------------------------------------------------------- the visible result
def show_image(context, name: str):
    """Show the image ``name`` in an Image Editor: an open one, else a new window (as F12 does)."""
    img = bpy.data.images.get(name)
    if img is None or context.window_manager is None:
        return
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == 'IMAGE_EDITOR':
                area.spaces.active.image = img
                area.tag_redraw()
                return
    before = set(context.window_manager.windows)
    try:
        bpy.ops.render.view_show('INVOKE_DEFAULT')
    except RuntimeError:
        return
    for window in context.window_manager.windows:
        if window in before:
            continue
        for area in window.screen.areas:
            if area.type == 'IMAGE_EDITOR':
                area.spaces.active.image = img


def show_vertex_colours(context, objects, name: str):
    """Make ``name`` the active (and rendered) colour attribute of the objects' meshes and switch the
    3D viewports to Solid shading in Attribute colour mode."""
    for ob in objects:
        mesh = getattr(ob, "data", None)
        colours = getattr(mesh, "color_attributes", None)
        if colours is None or name not in colours:
            continue
        attr = colours[name]
        if hasattr(colours, "active_color"):
            colours.active_color = attr
        if hasattr(colours, "active_color_name"):
            colours.active_color_name = name
        if hasattr(colours, "render_color_index"):
            colours.render_color_index = list(colours).index(attr)
    wm = context.window_manager
    for window in (wm.windows if wm is not None else ()):
        for area in window.screen.areas:
            if area.type != 'VIEW_3D':
                continue
            shading = area.spaces.active.shading
            if shading.type == 'WIREFRAME':
                shading.type = 'SOLID'
            if shading.type == 'SOLID':
                shading.color_type = 'VERTEX'
            area.tag_redraw()


def finish(operator, context, report):
    """Report line and visible result of a finished job."""
    from .job import IMAGE_NAME

    operator.report({'INFO'}, report.summary())
    if bpy.app.background:
        return
    if report.mode == "pixels":
        show_image(context, IMAGE_NAME)
    else:
        names = {entry.split(":", 1)[0] for entry in report.outputs if ":" in entry}
        target = next((entry.split(":", 1)[1] for entry in report.outputs if ":" in entry), "hlp_radiance")
        show_vertex_colours(context, [bpy.data.objects[n] for n in names if n in bpy.data.objects], target)


# ------------------------------------------------------------------------------ the operator part
def run_sync(operator, context, kwargs) -> set:
    """``execute()``: the whole job now (background mode, scripts)."""
    from ..core import Cancelled
    from .job import run_local_pass

    try:
        report = run_local_pass(**kwargs)
    except Cancelled:
        operator.report({'WARNING'}, "Local pass cancelled")
        return {'CANCELLED'}
    except (ValueError, OSError, RuntimeError) as ex:
        operator.report({'ERROR'}, str(ex))
        return {'CANCELLED'}
    finish(operator, context, report)
    return {'FINISHED'}


def start(operator, context, kwargs) -> set:
    """``invoke()``: start the timer-driven job (synchronous in background mode)."""
    if bpy.app.background or context.window is None:
        return run_sync(operator, context, kwargs)
    if _running:
        operator.report({'WARNING'}, "A local pass is already running")
        return {'CANCELLED'}
    try:
        run = LocalPassRun(kwargs)
    except (ValueError, OSError, RuntimeError) as ex:
        operator.report({'ERROR'}, str(ex))
        return {'CANCELLED'}
    wm = context.window_manager
    operator._hlp_run = run
    operator._hlp_timer = wm.event_timer_add(TICK_INTERVAL, window=context.window)
    _running.append(run)
    wm.hlp_progress = 0.0
    wm.progress_begin(0, 1000)
    wm.modal_handler_add(operator)
    _set_status(context, run.text())
    return {'RUNNING_MODAL'}


def _stop(operator, context):
    run = getattr(operator, "_hlp_run", None)
    wm = context.window_manager
    if getattr(operator, "_hlp_timer", None) is not None:
        wm.event_timer_remove(operator._hlp_timer)
        operator._hlp_timer = None
    if run in _running:
        _running.remove(run)
    wm.progress_end()
    _set_status(context, None)
    _redraw_all(context)
    return run


def tick(operator, context, event) -> set:
    """``modal()``: one timer tick of work, or Esc."""
    from ..core import Cancelled

    run = operator._hlp_run
    if event.type == 'ESC' and event.value == 'PRESS':
        run.close()
        _stop(operator, context)
        operator.report({'WARNING'}, f"Local pass cancelled after {run.done:,} of {run.total:,} points; "
                                     "the scene is unchanged")
        return {'CANCELLED'}
    if event.type != 'TIMER':  # (Event has no .timer before 4.x: any timer tick does one slice)
        return {'PASS_THROUGH'} if event.type in _NAVIGATION else {'RUNNING_MODAL'}
    try:
        finished = run.advance()
    except Cancelled:
        _stop(operator, context)
        operator.report({'WARNING'}, "Local pass cancelled")
        return {'CANCELLED'}
    except Exception as ex:  # noqa: BLE001 - a modal handler must never be left running on an error
        _stop(operator, context)
        kind = "" if isinstance(ex, (ValueError, OSError, RuntimeError)) else f"{type(ex).__name__}: "
        operator.report({'ERROR'}, f"{kind}{ex}")
        return {'CANCELLED'}
    wm = context.window_manager
    wm.hlp_progress = 100.0 * run.fraction
    wm.progress_update(int(1000 * run.fraction))
    if finished:
        _stop(operator, context)
        finish(operator, context, run.report)
        return {'FINISHED'}
    _set_status(context, run.text())  # redraws the status bar only (not every editor: software GL is slow)
    return {'RUNNING_MODAL'}


def cancel(operator, context):
    """The window closed or the file changed under a running job: stop it, write nothing."""
    run = getattr(operator, "_hlp_run", None)
    if run is not None:
        run.close()
        _stop(operator, context)


class HLP_OT_bake_vertex_colours(bpy.types.Operator):
    """Bake the exact local pass into colour attributes of the selected meshes (Edit Mode: selected vertices)"""

    bl_idname = "hlp.bake_vertex_colours"
    bl_label = "Bake to Vertex Colours"
    bl_options = {'REGISTER'}

    @classmethod
    def poll(cls, context):
        if context.scene is None or not hasattr(context.scene, "hlp_settings"):
            return False
        objects = getattr(context, "selected_objects", None) or []
        if not any(ob.type == 'MESH' for ob in objects):
            if hasattr(cls, "poll_message_set"):
                cls.poll_message_set("Select the mesh objects to bake")
            return False
        return True

    def _kwargs(self, context):
        from .props import job_arguments

        kwargs = job_arguments(context.scene, context.scene.hlp_settings)
        kwargs.update(mode="vertices", output=None)
        return kwargs

    def execute(self, context):
        return run_sync(self, context, self._kwargs(context))

    def invoke(self, context, event):
        return start(self, context, self._kwargs(context))

    def modal(self, context, event):
        return tick(self, context, event)

    def cancel(self, context):
        cancel(self, context)


classes = (HLP_OT_bake_vertex_colours,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.WindowManager.hlp_progress = bpy.props.FloatProperty(
        name="Local Pass Progress", description="Progress of the running local pass", subtype='PERCENTAGE',
        min=0.0, max=100.0, precision=0, options={'SKIP_SAVE'})
    bpy.types.STATUSBAR_HT_header.prepend(draw_status)


def unregister():
    bpy.types.STATUSBAR_HT_header.remove(draw_status)
    if hasattr(bpy.types.WindowManager, "hlp_progress"):
        del bpy.types.WindowManager.hlp_progress
    _running.clear()
    for cls in reversed(classes):
        if getattr(cls, "is_registered", True):
            bpy.utils.unregister_class(cls)
