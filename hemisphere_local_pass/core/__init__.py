"""The exact hemispherical projection (Stürzlinger, "Exact Projections onto the Hemisphere").

Pure numpy: importing this package needs nothing but numpy (no bpy, no mathutils).

    from hemisphere_local_pass.core import Scene, form_factors, irradiance, radiance, project_point
    from hemisphere_local_pass.core import irradiance_gradient, irradiance_normal_gradient
    from hemisphere_local_pass.core import adaptive_irradiance  # images: exact only where needed
    from hemisphere_local_pass.core import adaptive_vertex_irradiance  # vertex sets: the same on mesh lattices
"""

from .adaptive import AdaptiveStats, adaptive_irradiance
from .adaptive_vertices import VertexAdaptiveStats, adaptive_vertex_irradiance
from .gradient import irradiance_gradient, irradiance_normal_gradient
from .inspection import Projection, project_point
from .local_pass import Cancelled, form_factors, irradiance, prepare_scene, radiance
from .scene import Scene

__all__ = ["AdaptiveStats", "Cancelled", "Projection", "Scene", "VertexAdaptiveStats", "adaptive_irradiance",
           "adaptive_vertex_irradiance", "form_factors", "irradiance",
           "irradiance_gradient", "irradiance_normal_gradient", "prepare_scene", "project_point", "radiance"]
