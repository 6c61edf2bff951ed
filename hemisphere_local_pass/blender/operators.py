"""Operators: the UI entry point of the local pass (one short call into ``job.run_local_pass``)."""

import time

import bpy

from .props import job_arguments

__all__ = ["HLP_OT_render_local_pass", "job_arguments"]


class _Progress:
    """``progress(done, total)`` for the job: the window manager's progress cursor when a window exists."""

    def __init__(self, context):
        self.wm = context.window_manager if context.window is not None else None
        self.started = False

    def __call__(self, done, total):
        if self.wm is None or total <= 0:
            return
        if not self.started:
            self.wm.progress_begin(0, total)
            self.started = True
        self.wm.progress_update(done)

    def end(self):
        if self.started:
            self.wm.progress_end()
            self.started = False


class HLP_OT_render_local_pass(bpy.types.Operator):
    """Compute the exact local pass (radiance and irradiance) from the radiosity attribute"""

    bl_idname = "hlp.render_local_pass"
    bl_label = "Render Local Pass"
    bl_options = {'REGISTER'}

    overwrite: bpy.props.BoolProperty(
        name="Overwrite",
        description=("Replace existing output files this extension wrote (default: Output Properties > Output > "
                     "Overwrite); other files are never replaced"),
        options={'SKIP_SAVE'},
    )

    @classmethod
    def poll(cls, context):
        return context.scene is not None and hasattr(context.scene, "hlp_settings")

    def execute(self, context):
        from ..core import Cancelled
        from . import job

        scene = context.scene
        kwargs = job_arguments(scene, scene.hlp_settings)
        if self.properties.is_property_set("overwrite"):
            kwargs["overwrite"] = self.overwrite
        progress = _Progress(context)
        start = time.perf_counter()
        try:
            result = job.run_local_pass(progress=progress, **kwargs)
        except (Cancelled, KeyboardInterrupt):
            self.report({'WARNING'}, "Local pass cancelled; finished chunks are kept in the checkpoint")
            return {'CANCELLED'}
        except (ValueError, OSError, RuntimeError) as ex:
            self.report({'ERROR'}, str(ex))
            return {'CANCELLED'}
        finally:
            progress.end()
        seconds = time.perf_counter() - start
        for message in getattr(result, "refused", ()):
            self.report({'WARNING'}, f"Not written: {message}")
        summary = getattr(result, "summary", None)
        self.report({'INFO'}, summary() if callable(summary) else f"Local pass done in {seconds:.1f} s")
        return {'FINISHED'}

    # the window's entry: timer-driven chunks, progress in the status bar, Esc (blender/modal.py)
    def invoke(self, context, event):
        from . import modal

        return modal.start(self, context, job_arguments(context.scene, context.scene.hlp_settings))

    def modal(self, context, event):
        from . import modal

        return modal.tick(self, context, event)

    def cancel(self, context):
        from . import modal

        modal.cancel(self, context)
