"""The first pass: diffuse radiosity on the scene's polygons (pure numpy, beside the core).

Progressive refinement (:mod:`.progressive`) with patch-to-patch form factors from several exact
point-to-polygon evaluations of the core per shooting patch (:mod:`.quadrature`); memory O(n). Its
per-polygon radiance is the FACE-domain ``radiosity`` attribute the local pass reads.

    from hemisphere_local_pass.first_pass import solve_radiosity
    result = solve_radiosity(scene, reflectivity, emission, tolerance=1e-3)
    result.radiance          # (n, 3) W sr^-1 m^-2
    print(result.summary())  # shots, unshot fraction, energy balance
    solve_radiosity(scene, reflectivity, emission, clusters=500)   # 10^5 polygons: reflected light from clusters
"""

from .clustered import ClusteredSolver
from .clusters import Clusters, make_clusters
from .progressive import (
    DEFAULT_TOLERANCE,
    FirstPassResult,
    ProgressiveSolver,
    SolveProgress,
    make_solver,
    shooter_form_factors,
    solve_radiosity,
)
from .quadrature import PatchQuadrature, patch_quadrature

__all__ = ["DEFAULT_TOLERANCE", "ClusteredSolver", "Clusters", "FirstPassResult", "PatchQuadrature",
           "ProgressiveSolver", "SolveProgress", "make_clusters", "make_solver", "patch_quadrature",
           "shooter_form_factors", "solve_radiosity"]
