"""A closed UV sphere: the scene whose polygons do not merge (every face has a plane of its own)."""

from __future__ import annotations

import numpy as np

__all__ = ["uv_sphere"]


def uv_sphere(nu: int, nv: int, r: float = 1.0):
    """A closed UV sphere of ``nu × nv`` faces (triangles at the poles), faces outward.

    Returns ``(vertices (nu·(nv+1), 3) float64, polygons)``: a list of vertex-index lists (quads, and
    triangles in the first and last rings), for :meth:`..core.Scene.from_polygons`. Radius ``r`` (m).
    """
    th = np.linspace(0, np.pi, nv + 1)
    ph = np.linspace(0, 2 * np.pi, nu + 1)[:-1]
    t, p = np.meshgrid(th, ph, indexing="ij")
    v = r * np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    polys = []
    for i in range(nv):
        for j in range(nu):
            a, b = i * nu + j, i * nu + (j + 1) % nu
            c, d = (i + 1) * nu + (j + 1) % nu, (i + 1) * nu + j
            polys.append([a, d, c] if i == 0 else [a, d, b] if i == nv - 1 else [a, d, c, b])
    return v, polys
