"""Properties Editor > Render > Hemisphere Local Pass (follows ``bl_ui/properties_render.py``)."""

import bpy

from .operators import HLP_OT_render_local_pass

__all__ = ["HLP_PT_local_pass"]


class HLP_RenderButtonsPanel:
    """Shared placement of the render-context panels (as ``RenderButtonsPanel`` in ``properties_render.py``)."""

    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "render"

    @classmethod
    def poll(cls, context):
        return context.scene is not None and hasattr(context.scene, "hlp_settings")


class HLP_PT_local_pass(HLP_RenderButtonsPanel, bpy.types.Panel):
    """Exact local pass of two-pass global illumination"""

    bl_label = "Hemisphere Local Pass"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):  # with the engine active its own panels show the settings (engine.py)
        return super().poll(context) and getattr(context, "engine", None) != "HEMISPHERE_LOCAL_PASS"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False

        settings = context.scene.hlp_settings

        col = layout.column()
        col.prop(settings, "mode")
        col.prop(settings, "attribute", text="Radiosity")  # short labels fit the default editor width
        col.prop(settings, "missing_attribute", text="Missing")
        col.prop(settings, "double_sided", text="Two-Sided")

        col = layout.column(heading="Receiver")
        col.prop(settings, "reflectivity_attribute", text="Albedo")
        col.prop(settings, "emission_attribute", text="Emission")

        if settings.mode == 'PIXELS':
            col = layout.column()
            col.prop(settings, "samples")
            col.prop(settings, "tolerance")
            col.prop(settings, "output_path")
            col.prop(context.scene.render, "use_overwrite", text="Overwrite")  # Blender's own Output > Overwrite
        else:
            col = layout.column(heading="Output")
            col.prop(settings, "radiance_attribute", text="Radiance Attribute")
            col.prop(settings, "irradiance_attribute", text="Irradiance Attribute")
            col.prop(settings, "tolerance")

        layout.prop(settings, "workers")
        layout.operator(HLP_OT_render_local_pass.bl_idname, icon='RENDER_STILL')
        layout.operator("hlp.bake_vertex_colours", icon='VPAINT_HLT')
