"""hemisphere_local_pass: the exact local pass of two-pass global illumination, for Blender.

Importing this package never imports bpy: the numeric core (``hemisphere_local_pass.core``) runs in
any Python with numpy. Blender-specific code is imported inside :func:`register`.
"""

bl_info = {
    "name": "Hemisphere Local Pass",
    "author": "hemisphere_local_pass developers",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Render > Hemisphere Local Pass",
    "description": "Exact hemispherical projection local pass from a radiosity solution",
    "category": "Render",
}


def __getattr__(name):
    """``hemisphere_local_pass.run_local_pass`` / ``solve_first_pass``: the batch jobs, imported (with bpy) on
    first use."""
    if name == "run_local_pass":
        from .blender.job import run_local_pass

        return run_local_pass
    if name == "solve_first_pass":
        from .blender.first_pass import solve_first_pass

        return solve_first_pass
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def register():
    from .blender import registration

    registration.register()


def unregister():
    from .blender import registration

    registration.unregister()
