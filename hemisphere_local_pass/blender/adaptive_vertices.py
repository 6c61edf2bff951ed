"""The adaptive pass of vertices mode (``tolerance > 0``): H at the receivers by
``core.adaptive_vertex_irradiance``, exactly only where interpolation along a mesh's lattice (the vertices of a
subdivided wall, floor or block face) would err by more than the tolerance; receivers on no lattice exactly.

One core call, run in a thread of its own while the job keeps yielding (:mod:`.core_thread`).

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import numpy as np

from .core_thread import in_thread

__all__ = ["adaptive_vertices", "input_polygons"]


def input_polygons(exported, ob, corner_poly, domain, loop_vertices, n_receivers):
    """(n_receivers,) int: the exported scene's input polygon of each receiver of ``ob``'s original mesh (its
    corner's face; a vertex's first face in the POINT domain), -1 where unknown (the object is not exported,
    or its evaluated mesh has other faces than the original: modifiers). The core checks the planes
    itself (a receiver off its polygon's plane is on no lattice, evaluated exactly)."""
    out = np.full(n_receivers, -1, dtype=np.int64)
    if ob.name not in exported.objects:
        return out
    rows = np.flatnonzero(exported.polygon_object == exported.objects.index(ob.name))
    n_faces = int(corner_poly.max()) + 1 if len(corner_poly) else 0
    if len(rows) != n_faces:
        return out
    of_face = np.empty(n_faces, dtype=np.int64)
    of_face[exported.polygon_index[rows]] = rows
    if domain == "CORNER":
        return of_face[corner_poly]
    first = np.full(n_receivers, -1, dtype=np.int64)
    first[loop_vertices[::-1]] = np.arange(len(loop_vertices))[::-1]
    has = first >= 0
    out[has] = of_face[corner_poly[first[has]]]
    return out


def adaptive_vertices(exported, points, normals, limits, polygons, absolute, progress, cancel, report):
    """H (m, 3) and its error estimate (m,) (W m^-2, 0 where exact; a far-field sample's bound) by
    ``core.adaptive_vertex_irradiance`` with the absolute tolerance ``absolute`` (W m^-2 per channel).

    A generator (through :func:`.core_thread.in_thread`): yields ``JobStep(done, m)`` (``done``: core
    evaluations so far) and returns ``(H, error)``; cancel raises ``core.Cancelled``."""

    def work(state, stop, pool):
        from ..core.adaptive import FINAL_SHARE, SAMPLE_SHARE
        from ..core.adaptive_vertices import adaptive_vertex_irradiance

        def prog(done, _total):
            state["done"] = done

        on = {"workers": 1} if pool is None else {"executor": pool}  # the same bits either way
        # the samples from the far field with SAMPLE_SHARE of the tolerance, the final ones with FINAL_SHARE,
        # as in pixels mode (core.adaptive steps 5-6)
        return adaptive_vertex_irradiance(exported.scene, points, normals, polygons, limit_directions=limits,
                                          tolerance=absolute, progress=prog, cancel=stop, sample_share=SAMPLE_SHARE,
                                          final_share=FINAL_SHARE, **on)

    h, st = yield from in_thread(work, len(points), progress, cancel, report.workers)
    report.exact_points = st.exact_points
    report.error_estimate = st.error_estimate
    return h, st.receiver_error
