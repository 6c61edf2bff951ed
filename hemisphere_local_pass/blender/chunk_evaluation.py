"""One chunk of receivers through the core: H (m, 3), sum F (m,) and the bound on H's error (m, 3),
and the scene's preparation as a stage of its own before the first chunk.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import numpy as np

from .job_report import stage

__all__ = ["constant_planes", "evaluate_chunk", "prepare"]


def prepare(exported, points, normals, limit, progress, cancel):
    """Build the core's per-scene structures (merged occluders, depth tables, tiles, solids, tile edges,
    the hierarchy: :func:`core.prepare_scene`, cached on the scene) as a stage of its own, each of its
    steps named as it ends, so the job says what it is doing before the first chunk (results are the
    same bit for bit: the first core call would build the same structures)."""
    from ..core import prepare_scene
    from ..core.chunk import PREPARATION_STAGES

    sc = exported.scene
    stage(progress, f"preparing the scene for the exact projection ({sc.n_polygons} convex polygons)")

    def step(done, total):
        stage(progress, f"preparing the scene: {PREPARATION_STAGES[done - 1]} ready ({done}/{total})")

    prepare_scene(sc, progress=step, cancel=cancel)


def evaluate_chunk(exported, points, normals, limit, progress, cancel, executor=None, tolerance=0.0):
    """``(H (m, 3), sum F (m,), error bound (m, 3))`` at the receivers (W m^-2; bound 0: exact).

    ``tolerance > 0`` (absolute, W m^-2 per channel): one ``core.irradiance`` call with the
    error-bounded far field (:mod:`..core.far_field`; exact where the scene has linear radiance), the
    bound it used per receiver and channel, and sum F not computed (NaN): the form factors would cost
    what the exact irradiance costs.

    In general two core calls: ``core.irradiance`` (front sides emit, linear radiance integrated
    exactly) and ``core.form_factors``. When the radiance is constant, no receiver has a limit
    direction and every input polygon is one convex polygon, one ``form_factors`` call gives both:
    a plane's front side is visible exactly from the points in front of it, so
    ``H = c * sum_i [P in front of polygon i] F_i L_i`` — eq. 3, with ``c`` the core's own ratio
    ``irradiance / sum F`` measured on a probe (so the result follows the core's convention).
    """
    from ..core import form_factors, irradiance

    scene = exported.scene
    # the job's own pool (or this process): the core starts no pool per call
    kw = {"limit_directions": limit, "cancel": cancel, "workers": 1, "executor": executor}
    exact = np.zeros((len(points), 3))
    if tolerance > 0:
        h, stats = irradiance(scene, points, normals, tolerance=tolerance, return_stats=True, **kw)
        return h, np.full(len(points), np.nan), stats.error_bound
    fast = constant_planes(exported) if limit is None else None
    if fast is not None:
        normals_in, offsets_in, radiance_in = fast
        ff = form_factors(scene, points, normals, **kw)  # (m, n_input)
        if not scene.double_sided:
            side = points @ normals_in.T - offsets_in  # (m, n_input) signed distances
            ff_lit = np.where(side > 0.0, ff, 0.0)
        else:
            ff_lit = ff
        # einsum's own loops (not BLAS): each row's sum is independent of the chunk's other rows
        h = np.einsum("mn,nc->mc", ff_lit, radiance_in, optimize=False)
        return np.pi * h, ff.sum(axis=1), exact  # the core's irradiance is eq. 1: H = pi sum L F
    h = irradiance(scene, points, normals, **kw)
    if progress is not None:
        progress(1, 2)
    ff = form_factors(scene, points, normals, **kw)  # (m, n_input)
    return h, ff.sum(axis=1), exact


def constant_planes(exported):
    """``(normals (n_in, 3), offsets (n_in,), radiance (n_in, 3))`` per input polygon when the scene
    has constant radiance and no input polygon was split; else None. Cached on the export."""
    cached = getattr(exported, "_hlp_planes", False)
    if cached is not False:
        return cached
    scene = exported.scene
    result = None
    if not scene.linear and np.bincount(scene.poly_source, minlength=scene.n_input).max(initial=0) <= 1:
        n_in = scene.n_input
        normals_in = np.zeros((n_in, 3))
        offsets_in = np.full(n_in, np.inf)  # dropped polygons: never in front (and F = 0)
        radiance_in = np.zeros((n_in, 3))
        normals_in[scene.poly_source] = scene.poly_normals
        offsets_in[scene.poly_source] = scene.poly_offsets
        radiance_in[scene.poly_source] = scene.poly_radiance
        result = (normals_in, offsets_in, radiance_in)
    exported._hlp_planes = result
    return result
