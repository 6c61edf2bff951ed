"""Scene settings of the local pass: ``bpy.types.Scene.hlp_settings`` (:class:`HLP_PG_settings`).

The panel (``panels.py``) shows them, the operators (``operators.py``, ``modal.py``) pass them to
``job.run_local_pass`` (:func:`job_arguments`); the command line (``blender -c hemisphere_local_pass
render``) has the same options as flags.
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

MODE_ITEMS = (
    ('PIXELS', "Pixels", "Render the active camera's view to an image and a multi-channel OpenEXR file"),
    ('VERTICES', "Vertices", "Write hlp_radiance and hlp_irradiance colour attributes on the selected meshes"),
)

MISSING_ITEMS = (
    ('ERROR', "Error", "Stop with an error naming the first object without the radiosity attribute"),
    ('BLACK', "Black Occluder", "Treat objects without the radiosity attribute as black occluders (counted)"),
)


def colour_attribute_names(self, context, edit_text=""):
    """Search list of the radiosity field: the colour (and vector) attributes the scene's meshes have,
    with the meshes that have them."""
    from .attribute_search import colour_attributes

    return colour_attributes(context.scene if context is not None else None, edit_text)


class HLP_PG_settings(bpy.types.PropertyGroup):
    """Settings of the exact local pass for this scene"""

    attribute: StringProperty(
        name="Radiosity Attribute",
        description=(
            "Mesh attribute holding the first pass's radiance (linear RGB; FACE domain: constant per "
            "polygon, POINT or CORNER domain: linearly varying)"
        ),
        default="radiosity",
        **({"search": colour_attribute_names} if bpy.app.version >= (3, 3, 0) else {}),
    )
    reflectivity_attribute: StringProperty(
        name="Reflectivity Attribute",
        description="Mesh attribute holding the receiver's reflectivity; else the material's base colour",
        default="reflectivity",
    )
    emission_attribute: StringProperty(
        name="Emission Attribute",
        description="Mesh attribute holding the receiver's emission; else the material's emission",
        default="emission",
    )
    mode: EnumProperty(
        name="Mode",
        description="Where the local pass is evaluated",
        items=MODE_ITEMS,
        default='PIXELS',
    )
    missing_attribute: EnumProperty(
        name="Missing Attribute",
        description="What to do with a mesh that has no radiosity attribute",
        items=MISSING_ITEMS,
        default='ERROR',
    )
    samples: IntProperty(
        name="Samples",
        description="Supersampling: k×k camera rays per pixel (pixels mode)",
        default=1,
        min=1,
        soft_max=8,
        max=64,
    )
    tolerance: FloatProperty(
        name="Tolerance",
        description=(
            "Largest error of the irradiance relative to its mean (e.g. 0.001); 0 is exact. Pixels: the adaptive "
            "pass interpolates between error-bounded samples. Vertices: the error-bounded far field; its bound is "
            "written to the attribute '<Irradiance Attribute>_bound'"
        ),
        default=0.0,
        min=0.0,
        soft_max=0.1,
        precision=4,
        step=0.01,
    )
    output_path: StringProperty(
        name="Output",
        description="Multi-channel OpenEXR file written in pixels mode (// is relative to the .blend file)",
        default="//local_pass.exr",
        subtype='FILE_PATH',
    )
    radiance_attribute: StringProperty(
        name="Radiance Attribute",
        description=("Colour attribute that receives the radiance L = E + rho/pi H (vertices mode); an existing "
                     "attribute of that name is replaced only if this extension made it"),
        default="hlp_radiance",
    )
    irradiance_attribute: StringProperty(
        name="Irradiance Attribute",
        description=("Colour attribute that receives the irradiance H (vertices mode); an existing attribute of "
                     "that name is replaced only if this extension made it"),
        default="hlp_irradiance",
    )
    workers: IntProperty(
        name="Workers",
        description=(
            "Worker processes computing the local pass (0: every core Blender may use; 1: Blender's own "
            "process only). The result is the same for any number"
        ),
        default=0,
        min=0,
        soft_max=64,
        max=1024,
    )
    double_sided: BoolProperty(
        name="Double Sided",
        description="Polygons emit their radiosity from both sides (else only from the front, the normal side)",
        default=False,
    )


def job_arguments(scene, settings: "HLP_PG_settings") -> dict:
    """Keyword arguments of ``job.run_local_pass`` taken from the scene settings."""
    output = settings.output_path or None  # '//' is resolved by the job (an error for an unsaved file)
    return {
        "scene": scene,
        "mode": settings.mode.lower(),
        "attribute": settings.attribute,
        "reflectivity_attribute": settings.reflectivity_attribute,
        "emission_attribute": settings.emission_attribute,
        "missing": settings.missing_attribute.lower(),
        "samples": settings.samples,
        "output": output if settings.mode == 'PIXELS' else None,
        "double_sided": settings.double_sided,
        "overwrite": scene.render.use_overwrite,  # Output Properties > Output > Overwrite, as Blender's renders
        "workers": settings.workers,
        "tolerance": getattr(settings, "tolerance", 0.0),
    }
