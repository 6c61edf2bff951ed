"""The exact hemispherical projection (Stürzlinger, "Exact Projections onto the Hemisphere").

Pure numpy: importing this package needs nothing but numpy (no bpy, no mathutils).

    from hemisphere_local_pass.core import Scene, form_factors, irradiance, radiance, project_point
"""

from .inspection import Projection, project_point
from .local_pass import Cancelled, form_factors, irradiance, prepare_scene, radiance
from .scene import Scene

__all__ = ["Cancelled", "Projection", "Scene", "form_factors", "irradiance", "prepare_scene", "project_point",
           "radiance"]
