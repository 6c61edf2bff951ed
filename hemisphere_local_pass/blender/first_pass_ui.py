"""The first pass in the UI: settings, the ``hlp.solve_radiosity`` operator and its render-panel sub-panel.

The operator is one short call into :mod:`.first_pass`: in a window it runs modally (one solver step per
timer tick, progress and ETA in the status bar, Esc cancels with the scene unchanged); in background mode
and from scripts ``execute`` runs the same job synchronously.
"""

import time

import bpy
from bpy.props import FloatProperty, IntProperty

from .panels import HLP_RenderButtonsPanel

__all__ = ["HLP_OT_solve_radiosity", "HLP_PG_first_pass", "HLP_PT_first_pass", "classes"]

#: seconds of solver work per timer tick in the modal operator (the UI stays responsive)
TICK_SECONDS = 0.2


class HLP_PG_first_pass(bpy.types.PropertyGroup):
    """Settings of the first pass (radiosity solver) for this scene"""

    tolerance: FloatProperty(
        name="Tolerance",
        description="Stop when the unshot power is below this fraction of the emitted power",
        default=1e-3, min=1e-9, max=0.5, soft_min=1e-6, precision=6,
    )
    order: IntProperty(
        name="Quadrature Order",
        description="Points per shooting patch: 2 = 3-point rule on triangles, 2×2 Gauss on quads; "
                    "1 = one point at the centroid (faster, less accurate)",
        default=2, min=1, max=2,
    )
    clusters: IntProperty(
        name="Clusters",
        description="0: every polygon shoots its reflected light itself (exact patch rule, time ~ polygons²). "
                    "N > 0: reflected light is shot from about N clusters of coplanar polygons of one material, "
                    "one point each (large scenes; emitted light still from every polygon)",
        default=0, min=0, soft_max=5000,
    )


def _message(ex) -> str:
    return str(ex).strip().splitlines()[0] if str(ex).strip() else type(ex).__name__


class HLP_OT_solve_radiosity(bpy.types.Operator):
    """Solve the first pass (diffuse radiosity) and write the FACE-domain radiosity attribute on every exported mesh"""

    bl_idname = "hlp.solve_radiosity"
    bl_label = "Solve Radiosity"
    bl_options = {'REGISTER', 'UNDO'}

    _job = None
    _timer = None

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def execute(self, context):
        from ..core import Cancelled
        from .first_pass import SolverProgressLines, solve_first_pass

        try:  # without a window (background, scripts): progress lines on stderr
            report = solve_first_pass(context.scene, progress=SolverProgressLines(interval=5.0) if bpy.app.background
                                      else None)
        except (Cancelled, KeyboardInterrupt):
            self.report({'WARNING'}, "First pass cancelled; the scene is unchanged")
            return {'CANCELLED'}
        except (ValueError, OSError, RuntimeError) as ex:
            self.report({'ERROR'}, _message(ex))
            return {'CANCELLED'}
        self.report({'INFO'}, report.summary())
        return {'FINISHED'}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        from .first_pass import prepare

        try:
            self._job = prepare(context.scene)
        except (ValueError, OSError, RuntimeError) as ex:
            self.report({'ERROR'}, _message(ex))
            return {'CANCELLED'}
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 1000)
        context.workspace.status_text_set("First pass: starting (Esc to cancel)")
        return {'RUNNING_MODAL'}

    def _end(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        context.workspace.status_text_set(None)

    def modal(self, context, event):
        if event.type == 'ESC':
            self._end(context)
            self.report({'WARNING'}, "First pass cancelled; the scene is unchanged")
            return {'CANCELLED'}
        if event.type != 'TIMER':
            return {'PASS_THROUGH'}
        solver = self._job.solver
        try:
            t0 = time.perf_counter()
            while not solver.done and time.perf_counter() - t0 < TICK_SECONDS:
                if not solver.step():
                    break
            p = solver.progress()
            context.window_manager.progress_update(int(1000 * p.fraction_done))
            context.workspace.status_text_set(p.message() + " (Esc to cancel)")
            if not (solver.done or p.unshot_fraction == 0.0):
                return {'RUNNING_MODAL'}
            report = self._job.finish()
        except (ValueError, OSError, RuntimeError) as ex:
            self._end(context)
            self.report({'ERROR'}, _message(ex))
            return {'CANCELLED'}
        self._end(context)
        self.report({'INFO'}, report.summary())
        return {'FINISHED'}


class HLP_PT_first_pass(HLP_RenderButtonsPanel, bpy.types.Panel):
    """First pass: diffuse radiosity solved on the scene's polygons"""

    bl_label = "First Pass (Radiosity)"
    bl_parent_id = "HLP_PT_local_pass"

    @classmethod
    def poll(cls, context):
        return context.scene is not None and hasattr(context.scene, "hlp_first_pass")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        fp = context.scene.hlp_first_pass
        col = layout.column()
        col.prop(fp, "tolerance")
        col.prop(fp, "order")
        col.prop(fp, "clusters")
        layout.operator(HLP_OT_solve_radiosity.bl_idname, icon='LIGHT_SUN')


classes = (HLP_PG_first_pass, HLP_OT_solve_radiosity, HLP_PT_first_pass)
