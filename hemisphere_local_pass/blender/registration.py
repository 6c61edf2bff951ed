"""Registration of the Blender layer: property group, operator, panel and the CLI command.

``register()`` registers ``classes`` in order, attaches ``Scene.hlp_settings`` and, where Blender has
it (4.2+), ``bpy.utils.register_cli_command``; ``unregister()`` undoes all of it in reverse. Both are
safe to call repeatedly (register/unregister/register/unregister), and ``register()`` twice in a row
is harmless.
"""

import bpy

from . import cli, engine, first_pass_ui, inspector, modal, operators, panels, props

__all__ = ["classes", "register", "unregister"]

classes = (
    props.HLP_PG_settings,
    operators.HLP_OT_render_local_pass,
    panels.HLP_PT_local_pass,
    *first_pass_ui.classes,
)

#: Modules with their own ``register()`` / ``unregister()`` (after ``classes``, undone before them).
modules = (engine, modal, inspector)

#: Handle returned by ``bpy.utils.register_cli_command`` (None when not registered / Blender < 4.2).
_cli_handle = None


def register():
    """Register everything; harmless when already registered (an add-on enabled with ``--addons`` and
    a script calling ``register()`` again: each class is registered once)."""
    global _cli_handle
    for cls in classes:
        if not cls.is_registered:
            bpy.utils.register_class(cls)
    bpy.types.Scene.hlp_settings = bpy.props.PointerProperty(type=props.HLP_PG_settings)
    bpy.types.Scene.hlp_first_pass = bpy.props.PointerProperty(type=first_pass_ui.HLP_PG_first_pass)
    for module in modules:
        if not all(cls.is_registered for cls in module.classes):  # registered already: draw hooks too
            module.register()
    if hasattr(bpy.utils, "register_cli_command") and _cli_handle is None:
        _cli_handle = bpy.utils.register_cli_command(cli.COMMAND, cli.handler)


def unregister():
    global _cli_handle
    if _cli_handle is not None:
        bpy.utils.unregister_cli_command(_cli_handle)
        _cli_handle = None
    for module in reversed(modules):
        module.unregister()
    if hasattr(bpy.types.Scene, "hlp_settings"):
        del bpy.types.Scene.hlp_settings
    if hasattr(bpy.types.Scene, "hlp_first_pass"):
        del bpy.types.Scene.hlp_first_pass
    for cls in reversed(classes):
        if getattr(cls, "is_registered", True):
            bpy.utils.unregister_class(cls)
