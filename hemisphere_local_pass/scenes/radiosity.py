"""Compatibility wrapper of the first pass, and the dense centre-to-polygon reference (pure numpy).

:func:`radiosity` solves with :mod:`hemisphere_local_pass.first_pass` (progressive refinement, O(n)
memory, patch-to-patch factors from several exact point-to-polygon evaluations per shooter) unless a
``form_factor_matrix`` is given; then it iterates on that matrix as before (a reference for small scenes,
used by tests and benchmarks). The dense path:

Every polygon i is represented by its centre ``c_i`` and normal ``n_i``; ``F[i, j]`` is the exact
visible form factor from that point to polygon j (the core's :func:`~..core.form_factors`, which
accounts for occlusion). The radiance of the polygons then solves

    L_i = E_i + ρ_i Σ_j F[i, j] L_j                         (per RGB channel)

— the radiosity equation in radiance form (B = π L): a diffuse surface of reflectivity ρ lit by
irradiance ``H = π Σ_j F_ij L_j`` (the core's :func:`~..core.irradiance`) reflects radiance
``ρ/π H = ρ Σ_j F_ij L_j`` (eq. 5). Solved by Jacobi iterations
(the spectral radius of ``ρ F`` is at most ``max ρ < 1``, so they converge geometrically; the error
after k sweeps is below ``max ρ^k`` times the first correction).

Point-to-polygon factors at the centre approximate the patch-to-patch factors of classical
radiosity; the result is the *coarse* solution the local pass refines.
"""

from __future__ import annotations

import numpy as np

__all__ = ["centroid_form_factors", "gathered_radiance", "radiosity"]


def centroid_form_factors(scene, centroids: np.ndarray, normals: np.ndarray, *, dtype=np.float32, progress=None):
    """``F (n, n_input)`` visible form factors from every patch centre, stored as ``dtype``.

    ``centroids, normals (n, 3)``. Factors of polygons seen from their back side are set to 0: light
    leaves the front side only (as in the core's :func:`~..core.irradiance`), so a patch hidden under a
    block, which sees only the block's back faces, receives nothing. Memory: ``n * n_input * itemsize``
    (361 MB for 9,504 polygons in float32); computed by the core in chunks of 256 receivers.
    """
    from ..core import form_factors

    n = len(centroids)
    out = np.empty((n, scene.n_input), dtype=dtype)
    step = 256
    for s in range(0, n, step):
        e = min(s + step, n)
        f = form_factors(scene, centroids[s:e], normals[s:e])  # (c, n_input)
        # side of every convex polygon's plane each centre lies on; an input polygon counts as seen
        # from the front when its (first) convex piece is
        side = centroids[s:e] @ scene.poly_normals.T - scene.poly_offsets  # (c, n_convex)
        front = np.zeros((e - s, scene.n_input), dtype=bool)
        front[:, scene.poly_source] = side > 0.0
        out[s:e] = np.where(front, f, 0.0)
        if progress is not None:
            progress(e, n)
    return out


def radiosity(
    vertices,
    polygons,
    reflectivity,
    emission,
    *,
    form_factor_matrix: np.ndarray | None = None,
    iterations: int = 200,
    tol: float = 1e-10,
    progress=None,
    tolerance: float | None = None,
) -> np.ndarray:
    """Per-polygon radiance ``L (n, 3)`` (W sr^-1 m^-2) of a diffuse polygonal scene.

    Args:
        vertices: (V, 3) float coordinates; polygons: n index lists (planar; each is one patch).
        reflectivity: (n, 3) or (n,) diffuse reflectivity ρ in [0, 1).
        emission: (n, 3) or (n,) emitted radiance E of the front side.
        form_factor_matrix: optional precomputed ``(n, n)`` centre-to-polygon form factors (e.g. from
            :func:`centroid_form_factors`), solved by Jacobi sweeps; when omitted the first pass
            (:func:`hemisphere_local_pass.first_pass.solve_radiosity`) solves without any matrix.
        iterations: maximum Jacobi sweeps (matrix only); stops early when the largest change is below
            ``tol`` times the largest radiance.
        progress: ``progress(done, total)``: form-factor rows (matrix), or per mille of the first pass's
            logarithmic progress.
        tolerance: the first pass's stopping tolerance (unshot / emitted power; default
            ``first_pass.DEFAULT_TOLERANCE``).

    Returns:
        (n, 3) float64 radiance L_i = E_i + ρ_i Σ_j F_ij L_j (the first pass, pass it to the local pass as
        the scene's polygon radiance).
    """
    verts = np.asarray(vertices, dtype=np.float64)
    n = len(polygons)
    rho = np.broadcast_to(np.asarray(reflectivity, dtype=np.float64).reshape(n, -1), (n, 3))
    emit = np.broadcast_to(np.asarray(emission, dtype=np.float64).reshape(n, -1), (n, 3))
    if (rho < 0).any() or (rho >= 1).any():
        raise ValueError("reflectivity must lie in [0, 1)")
    if form_factor_matrix is None:
        from ..core import Scene
        from ..first_pass import DEFAULT_TOLERANCE, solve_radiosity

        scene = Scene.from_polygons(verts, polygons)
        if scene.dropped:
            i = next(iter(scene.dropped))
            raise ValueError(f"polygon {i} is degenerate ({scene.dropped[i]})")
        report = None if progress is None else (lambda p: progress(int(1000 * p.fraction_done), 1000))
        result = solve_radiosity(scene, rho, emit, tolerance=DEFAULT_TOLERANCE if tolerance is None else tolerance,
                                 progress=report)
        return result.radiance
    f = form_factor_matrix
    if f.shape != (n, n):
        raise ValueError(f"form_factor_matrix must have shape ({n}, {n}), got {f.shape}")
    radiance = emit.copy()
    for _ in range(iterations):  # Jacobi: L <- E + ρ F L
        new = emit + rho * (f @ radiance.astype(f.dtype)).astype(np.float64)
        change = np.abs(new - radiance).max()
        radiance = new
        if change <= tol * max(float(np.abs(radiance).max()), 1e-300):
            break
    return radiance


def gathered_radiance(coarse_scene, points: np.ndarray, normals: np.ndarray, reflectivity, emission) -> np.ndarray:
    """Radiance ``(m, 3)`` of receivers lit by a solved coarse scene: ``E + ρ Σ_j F_j L_j`` (one gather).

    For large scenes whose full form-factor matrix is too costly: solve :func:`radiosity` on a coarse
    subdivision of the same surfaces, build ``coarse_scene`` with that solution as its polygon radiance
    (``double_sided=False``: polygons radiate from their front side), and gather it at the fine patches'
    centres ``points, normals (m, 3)``. ``reflectivity, emission`` broadcast to ``(m, 3)``. The core's
    :func:`~..core.irradiance` is ``H = π Σ_j F_j L_j`` (eq. 1), so this is eq. 5, ``E + ρ/π H``;
    cost ~ one exact local-pass evaluation per point.
    """
    from ..core import irradiance

    m = len(points)
    h = np.empty((m, 3))
    step = 256
    for s in range(0, m, step):
        h[s:s + step] = irradiance(coarse_scene, points[s:s + step], normals[s:s + step])
    rho = np.broadcast_to(np.asarray(reflectivity, dtype=np.float64).reshape(m, -1), (m, 3))
    emit = np.broadcast_to(np.asarray(emission, dtype=np.float64).reshape(m, -1), (m, 3))
    return emit + rho / np.pi * h
