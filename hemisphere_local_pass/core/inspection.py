"""What one receiver sees, for the inspector: its visible spherical polygons (sec. 2.2–2.5).

Sits on top of the visibility stage of :mod:`.chunk` (one receiver is a chunk of one), below nothing:
the batch drivers of :mod:`.local_pass` are not involved.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .chunk import visible_fragments_with_ff
from .receivers import idle_limits_dropped, prepare_receivers
from .scene import Scene

__all__ = ["Projection", "project_point"]


@dataclass
class Projection:
    """The exact hemispherical projection seen from one receiver point (for the inspector).

    Attributes:
        point, normal: (3,) the receiver.
        fragments: list of (k_i, 3) unit vectors: the visible spherical polygons, positively oriented
            about P (``v0 . (v1 × v2) > 0``: counter-clockwise seen from outside the sphere); edges are
            great-circle arcs between consecutive vertices.
        polygon: (F,) input polygon of each fragment.
        form_factor: (F,) form factor of each fragment (eq. 4).
        distance: list of (k_i,) distances from P to the fragment's vertices (paper's dist(v)).
        polygon_form_factors: (n_input,) visible form factor of every input polygon.
    """

    point: np.ndarray
    normal: np.ndarray
    fragments: list
    polygon: np.ndarray
    form_factor: np.ndarray
    distance: list
    polygon_form_factors: np.ndarray


def project_point(scene: Scene, point, normal, *, limit_direction=None, occluders=None) -> Projection:
    """Visible fragments of every polygon seen from one receiver point, with their form factors."""
    pts, nrm, lim = prepare_receivers(point, normal, limit_direction, single=True)
    lim = idle_limits_dropped(scene, pts, nrm, lim)  # as form_factors and irradiance do: the same values
    frags, ff = visible_fragments_with_ff(scene, pts, nrm, lim, occluders=occluders)
    fragments, dists = [], []
    for f in range(len(frags.counts)):
        k = frags.counts[f]
        v = frags.verts[f, :k]
        d = np.linalg.norm(v, axis=1)
        dirs = v / np.where(d > 0, d, 1.0)[:, None]
        if frags.inf is not None and (d == 0).any():
            iv = frags.inf[f, :k]
            dirs = np.where((d == 0)[:, None], iv / np.linalg.norm(iv, axis=1, keepdims=True), dirs)
        if frags.side[f] < 0:  # receiver in front: make every fragment positively oriented about P
            dirs, d = dirs[::-1], d[::-1]
        fragments.append(dirs)
        dists.append(d)
    source = scene.poly_source[frags.poly]
    per_poly = np.bincount(source, weights=ff, minlength=scene.n_input) if len(ff) else np.zeros(scene.n_input)
    return Projection(pts[0], nrm[0], fragments, source, ff, dists, per_poly)
