"""The form-factor inspector: a 3D-viewport overlay and an N-panel list of what one surface point sees.

*Inspect Form Factors* (``hlp.inspect_form_factors``, 3D Viewport > Sidebar > Local Pass) is a
modal tool: click a surface (the point snaps to the surface under the mouse: a ray through the
core scene, as the render's camera rays), drag to move it live; Esc or right-click leaves. At the
point the overlay draws the arrays of :func:`.inspector_geometry.inspect_point`: the hemisphere
with every visible fragment filled (source radiance or false colour by F) and outlined, the Nusselt
analog on the disc in the tangent plane, and the top contributing polygons outlined in the scene.
The sidebar lists object, polygon, F, L.F and share of H per polygon, with sum F, H and L. The
scene is exported once when the tool starts (restart it after editing the scene).

GPU code lives only in the draw callbacks: shaders are created lazily there (never in background
mode), with Blender 3.4's ``3D_*`` built-in shader names or 4.x/5.x's unprefixed ones, and every
GPU state changed is restored. The overlay and its state go away when the tool is left, when a file
is loaded (``load_pre``) and when the add-on is disabled.
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

__all__ = ["HLP_OT_inspect_form_factors", "HLP_PT_inspector", "State", "inspect_ray", "register", "unregister"]

#: Polygons shown in the sidebar list.
LIST_ROWS = 8


class State:
    """The inspector's one session (module level: draw callbacks have no operator)."""

    exported = None  # ExportedScene of the inspected scene
    scene_name = None
    inspection = None  # inspector_geometry.Inspection at the current point
    polygon = -1  # input polygon under the point
    handles: list = []  # (space type, handle, region type)
    batches = None  # (inspection id, batches) cache
    shaders: dict = {}

    @classmethod
    def clear(cls):
        for space, handle, _region in cls.handles:
            space.draw_handler_remove(handle, 'WINDOW')
        cls.handles = []
        cls.exported = None
        cls.scene_name = None
        cls.inspection = None
        cls.polygon = -1
        cls.batches = None
        _redraw_views()


def _redraw_views():
    wm = getattr(bpy.context, "window_manager", None)
    for window in (wm.windows if wm is not None else ()):
        for area in window.screen.areas:
            if area.type == 'VIEW_3D':
                area.tag_redraw()


# ------------------------------------------------------------------------------------ the picking
def export_for_inspection(context):
    """Export the scene once per inspection session (same settings as the job)."""
    from .scene_export import export_scene

    scene = context.scene
    s = scene.hlp_settings
    State.exported = export_scene(scene, view_layer=context.view_layer, attribute=s.attribute,
                                  reflectivity_attribute=s.reflectivity_attribute,
                                  emission_attribute=s.emission_attribute, missing=s.missing_attribute.lower(),
                                  double_sided=s.double_sided)
    State.scene_name = scene.name
    return State.exported


def inspect_ray(context, origin, direction, t_min=0.0):
    """Snap to the first surface along the ray past ``t_min`` (core ray cast on the exported scene;
    ``t_min`` in units of ``direction``: the view's near clip) and inspect there; returns the
    Inspection or None when the ray hits nothing. The receiver is set up as the
    render's pixels are: P put on the hit polygon's plane, the hemisphere facing the ray's origin."""
    import numpy as np

    from ..core.raycast import cast_rays
    from .inspector_geometry import inspect_point

    exported = State.exported
    scene = exported.scene
    o = np.asarray(origin, dtype=np.float64).reshape(1, 3)
    d = np.asarray(direction, dtype=np.float64).reshape(1, 3)
    hits = cast_rays(scene, o, d, t_min=float(t_min))
    if not hits.hit[0]:
        return None
    poly, src, front = int(hits.polygon[0]), int(hits.source[0]), bool(hits.front[0])
    nrm = scene.poly_normals[poly] if front else -scene.poly_normals[poly]
    p = hits.point[0]
    p = p - (scene.poly_normals[poly] @ p - scene.poly_offsets[poly]) * scene.poly_normals[poly]
    wm = context.window_manager
    emits = front or scene.double_sided
    State.inspection = inspect_point(
        scene, p, nrm, radius=wm.hlp_inspector_radius, reflectivity=exported.reflectivity[src],
        emission=exported.emission[src] * emits, labels=exported.polygon_name,
        colour_by=wm.hlp_inspector_colour, top=wm.hlp_inspector_top)
    State.polygon = src
    State.batches = None
    return State.inspection


def _region_ray(context, region, rv3d, xy):
    """The view ray through region pixel ``xy``: origin, unit direction, and the near clip as a ray
    parameter (what the viewport hides in front of the clip plane cannot be picked)."""
    import numpy as np
    from bpy_extras import view3d_utils

    origin = np.array(view3d_utils.region_2d_to_origin_3d(region, rv3d, xy))
    direction = np.array(view3d_utils.region_2d_to_vector_3d(region, rv3d, xy))
    direction /= np.linalg.norm(direction)
    if rv3d.view_perspective == 'CAMERA' and context.scene.camera is not None:
        clip = context.scene.camera.data.clip_start
    else:
        clip = context.space_data.clip_start if context.space_data is not None else 0.0
    forward = -np.array(rv3d.view_matrix.inverted().to_3x3().col[2])
    t_min = clip / max(float(direction @ forward), 1e-6) if rv3d.is_perspective else 0.0
    return origin, direction, t_min


# -------------------------------------------------------------------------------------- drawing
def _shader(kind: str):
    """Built-in shader ``kind`` ("SMOOTH_COLOR", "UNIFORM_COLOR", "POLYLINE_UNIFORM_COLOR"), created on
    first use inside a draw callback; 4.x/5.x names first, then Blender 3.4's ``3D_`` names."""
    import gpu

    if kind not in State.shaders:
        try:
            State.shaders[kind] = gpu.shader.from_builtin(kind)
        except (ValueError, SystemError, TypeError):
            State.shaders[kind] = gpu.shader.from_builtin("3D_" + kind)
    return State.shaders[kind]


def _batches(ins):
    """GPU batches of an Inspection's arrays (cached per inspection)."""
    from gpu_extras.batch import batch_for_shader

    if State.batches is not None and State.batches[0] is ins:
        return State.batches[1]
    smooth = _shader("SMOOTH_COLOR")
    line = _shader("POLYLINE_UNIFORM_COLOR")
    out = []
    if len(ins.hemisphere_tris):
        for pos, colour in ((ins.disc_tris, ins.disc_colours), (ins.hemisphere_tris, ins.hemisphere_colours)):
            out.append(("tris", smooth, batch_for_shader(smooth, 'TRIS', {"pos": pos, "color": colour}), None, None))
    for arr, colour, width, xray in ((ins.frame_lines, (1.0, 1.0, 1.0, 0.6), 1.0, False),
                                     (ins.hemisphere_lines, (0.0, 0.0, 0.0, 0.5), 1.0, False),
                                     (ins.disc_lines, (0.0, 0.0, 0.0, 0.5), 1.0, False),
                                     (ins.top_lines, (1.0, 0.55, 0.0, 1.0), 3.0, True)):
        if len(arr):
            out.append(("lines", line, batch_for_shader(line, 'LINES', {"pos": arr}), colour, (width, xray)))
    State.batches = (ins, out)
    return out


def draw_overlay():
    """POST_VIEW callback: turn the current Inspection's arrays into batches and draw them."""
    ins = State.inspection
    if ins is None or bpy.app.background:
        return
    import gpu

    region = bpy.context.region
    viewport = (region.width, region.height) if region is not None else (1, 1)
    gpu.state.blend_set('ALPHA')
    gpu.state.depth_mask_set(False)
    try:
        for kind, shader, batch, colour, extra in _batches(ins):
            if kind == "tris":
                gpu.state.depth_test_set('LESS_EQUAL')
                shader.bind()
                batch.draw(shader)
            else:
                width, xray = extra
                gpu.state.depth_test_set('NONE' if xray else 'LESS_EQUAL')
                shader.bind()
                shader.uniform_float("viewportSize", viewport)
                shader.uniform_float("lineWidth", width)
                shader.uniform_float("color", colour)
                batch.draw(shader)
    finally:  # leave the state as Blender's drawing expects it
        gpu.state.depth_test_set('NONE')
        gpu.state.depth_mask_set(True)
        gpu.state.blend_set('NONE')


def label_text(ins) -> str:
    """The overlay's line next to the point: sum F and H, H as the mean of its R, G, B channels
    (W/m², the quantity the sidebar's shares are taken of; not a luminance). ``ins``: an
    :class:`.inspector_geometry.Inspection`."""
    return f"ΣF = {ins.form_factor_sum:.6f}   H (mean of R, G, B) = {ins.irradiance.mean():.4g} W/m²"


def draw_label():
    """POST_PIXEL callback: :func:`label_text` next to the point."""
    ins = State.inspection
    if ins is None or bpy.app.background:
        return
    import blf
    from bpy_extras.view3d_utils import location_3d_to_region_2d

    xy = location_3d_to_region_2d(bpy.context.region, bpy.context.region_data, ins.point)
    if xy is None:
        return
    font = 0
    if bpy.app.version >= (4, 0, 0):
        blf.size(font, 13)
    else:  # 3.x: (fontid, size, dpi)
        blf.size(font, 13, 72)
    blf.color(font, 1.0, 1.0, 1.0, 1.0)
    blf.position(font, xy[0] + 12, xy[1] - 18, 0)
    blf.draw(font, label_text(ins))


def _add_handlers():
    if State.handles:
        return
    space = bpy.types.SpaceView3D
    State.handles = [(space, space.draw_handler_add(draw_overlay, (), 'WINDOW', 'POST_VIEW'), 'POST_VIEW'),
                     (space, space.draw_handler_add(draw_label, (), 'WINDOW', 'POST_PIXEL'), 'POST_PIXEL')]


# ------------------------------------------------------------------------------------ the tool
class HLP_OT_inspect_form_factors(bpy.types.Operator):
    """Click a surface to see its exact hemisphere projection and form factors; drag to move; Esc leaves"""

    bl_idname = "hlp.inspect_form_factors"
    bl_label = "Inspect Form Factors"

    @classmethod
    def poll(cls, context):
        return (not bpy.app.background and context.area is not None and context.area.type == 'VIEW_3D'
                and hasattr(context.scene, "hlp_settings"))

    def invoke(self, context, event):
        try:
            export_for_inspection(context)
        except ValueError as ex:
            self.report({'ERROR'}, str(ex))
            return {'CANCELLED'}
        self._area = context.area
        self._region = next(r for r in context.area.regions if r.type == 'WINDOW')
        self._rv3d = context.area.spaces.active.region_3d
        self._dragging = False
        _add_handlers()
        context.window_manager.modal_handler_add(self)
        context.workspace.status_text_set("Inspect Form Factors: click a surface, drag to move, "
                                          "Esc / right-click to leave")
        return {'RUNNING_MODAL'}

    def _local(self, event):
        r = self._region
        x, y = event.mouse_x - r.x, event.mouse_y - r.y
        return (x, y) if 0 <= x < r.width and 0 <= y < r.height else None

    def _pick(self, context, xy):
        origin, direction, t_min = _region_ray(context, self._region, self._rv3d, xy)
        if inspect_ray(context, origin, direction, t_min) is not None:
            _redraw_views()
            for area in context.screen.areas:  # the sidebar list
                area.tag_redraw()

    def modal(self, context, event):
        if event.type in {'ESC', 'RIGHTMOUSE'} and event.value == 'PRESS':
            self._finish(context)
            return {'FINISHED'}
        try:
            xy = self._local(event)
        except ReferenceError:  # the viewport was closed (area joined, screen changed)
            self._finish(context)
            return {'CANCELLED'}
        if event.type == 'LEFTMOUSE':
            if event.value == 'PRESS' and xy is not None:
                self._dragging = True
                self._pick(context, xy)
                return {'RUNNING_MODAL'}
            if event.value == 'RELEASE' and self._dragging:
                self._dragging = False
                return {'RUNNING_MODAL'}
        if event.type == 'MOUSEMOVE' and self._dragging and xy is not None:
            self._pick(context, xy)
            return {'RUNNING_MODAL'}
        return {'PASS_THROUGH'}  # navigation, the sidebar, menus

    def _finish(self, context):
        workspace = getattr(context, "workspace", None)
        if workspace is not None:
            workspace.status_text_set(None)
        State.clear()

    def cancel(self, context):
        self._finish(context)


class HLP_PT_inspector(bpy.types.Panel):
    """Form factors at the inspected point, per contributing polygon"""

    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "Local Pass"
    bl_label = "Form-Factor Inspector"

    @classmethod
    def poll(cls, context):
        return hasattr(context.scene, "hlp_settings")

    def draw(self, context):
        layout = self.layout
        wm = context.window_manager
        layout.operator(HLP_OT_inspect_form_factors.bl_idname, icon='LIGHT_HEMI')
        col = layout.column(align=True)
        col.prop(wm, "hlp_inspector_colour", text="")
        row = col.row(align=True)
        row.prop(wm, "hlp_inspector_radius")
        row.prop(wm, "hlp_inspector_top")
        ins = State.inspection
        if ins is None:
            layout.label(text="Click a surface with the tool active")
            return
        box = layout.box()
        col = box.column(align=True)
        col.label(text=f"ΣF = {ins.form_factor_sum:.9f}")
        col.label(text=f"{ins.fragments} fragments, {len(ins.rows)} polygons")
        col.label(text="% = share of H, largest first")
        col.label(text="H = " + "  ".join(f"{v:.4g}" for v in ins.irradiance))
        col.label(text="L = " + "  ".join(f"{v:.4g}" for v in ins.radiance))
        exported = State.exported
        # two lines per polygon: the sidebar's default width holds three numbers, not five columns
        col = layout.column(align=True)
        for row in ins.rows[:LIST_ROWS]:
            i = row.polygon
            sub = col.box().column(align=True)
            obj, index = exported.objects[int(exported.polygon_object[i])], int(exported.polygon_index[i])
            line = sub.split(factor=0.7)
            line.label(text=f"{obj}  polygon {index}")
            line.label(text=f"{100 * row.share:.1f}%")
            line = sub.row(align=True)
            line.label(text=f"F {row.form_factor:.5f}")
            line.label(text=f"L·F {row.radiance_ff.mean():.3g}")
        if len(ins.rows) > LIST_ROWS:
            layout.label(text=f"... {len(ins.rows) - LIST_ROWS} more polygons")


@persistent
def _on_load_pre(*_args):
    State.clear()


classes = (HLP_OT_inspect_form_factors, HLP_PT_inspector)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    wm = bpy.types.WindowManager
    wm.hlp_inspector_radius = bpy.props.FloatProperty(
        name="Radius", description="Radius of the drawn hemisphere", default=0.15, min=1e-4, soft_max=10.0,
        subtype='DISTANCE', update=lambda self, ctx: _refresh())
    wm.hlp_inspector_top = bpy.props.IntProperty(
        name="Top", description="Contributing polygons outlined in the scene", default=5, min=0, max=50,
        update=lambda self, ctx: _refresh())
    wm.hlp_inspector_colour = bpy.props.EnumProperty(
        name="Colour", description="Fill colour of the fragments",
        items=(('RADIANCE', "Radiance", "The source polygon's radiosity"),
               ('FORM_FACTOR', "Form Factor", "False colour by the fragment's form factor")),
        update=lambda self, ctx: _refresh())
    if _on_load_pre not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_on_load_pre)


def _refresh():
    """A display setting changed: rebuild the arrays at the same point."""
    ins = State.inspection
    if ins is None or State.exported is None:
        return
    inspect_ray(bpy.context, ins.point + ins.normal * 1e-3 * max(ins.radius, 1e-3), -ins.normal)
    _redraw_views()


def unregister():
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)
    State.clear()
    State.shaders = {}
    for name in ("hlp_inspector_radius", "hlp_inspector_top", "hlp_inspector_colour"):
        if hasattr(bpy.types.WindowManager, name):
            delattr(bpy.types.WindowManager, name)
    for cls in reversed(classes):
        if getattr(cls, "is_registered", True):
            bpy.utils.unregister_class(cls)
