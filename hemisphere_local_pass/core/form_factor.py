"""Point-to-polygon form factors by Lambert's contour integral (paper eq. 4).

    F = 1/(2π) Σ_edges N · Γ_e,   Γ_e = unit(a × b) · γ_e,   γ_e = atan2(|a × b|, a · b)

with ``a, b`` the edge's end points relative to the receiver P (Baum, Rushmeier & Winget 1989). The
formula only needs directions from P, so it holds for the spherical fragments of the exact projection
(sec. 2.5) as well as for whole polygons. ``atan2(|a×b|, a·b)`` keeps full relative precision for tiny
or distant polygons, where ``acos(a·b)`` loses half the digits; and ``γ/|a×b|`` is evaluated as one
quotient so that it tends smoothly to ``1/(a·b)`` as the edge shrinks.
"""

from __future__ import annotations

import numpy as np

from .tolerances import PLANE_EPS

__all__ = ["contour_integral", "directions"]

_INV_2PI = 1.0 / (2.0 * np.pi)


def directions(verts: np.ndarray, inf: np.ndarray | None) -> np.ndarray:
    """Effective vertex vectors ``(F, K, 3)`` for the contour integral.

    A vertex at the receiver itself (real part zero within tolerance) only exists in a one-sided limit;
    its direction is its first-order part ``inf`` (see :mod:`.clipping`). Only directions matter to eq. 4.
    """
    if inf is None:
        return verts
    length = np.linalg.norm(verts, axis=2)                                   # (F, K)
    scale = length.max(axis=1, keepdims=True)
    at_p = length <= PLANE_EPS * scale
    if not at_p.any():
        return verts
    return np.where(at_p[..., None], inf * scale[..., None], verts)


def contour_integral(verts: np.ndarray, normal: np.ndarray, inf: np.ndarray | None = None) -> np.ndarray:
    """Signed form factor ``(F,)`` of padded polygons ``verts (F, K, 3)`` (receiver-local).

    ``normal`` is the receiver's unit normal, ``(F, 3)`` or ``(3,)``. The sign is positive when the
    vertices run counter-clockwise about the direction from the receiver to the polygon (i.e. the
    receiver is behind the polygon's right-handed normal); callers multiply by the orientation.
    Padding slots (repeated last vertex) give zero-length edges, which contribute exactly zero.
    The polygon must lie in the receiver's closed upper hemisphere (clip it first).
    """
    a = directions(verts, inf)
    b = np.roll(a, -1, axis=1)
    c = np.cross(a, b)                                                        # (F, K, 3)
    s = np.linalg.norm(c, axis=2)                                             # |a×b|
    d = np.einsum("fkc,fkc->fk", a, b)                                        # a·b
    gamma = np.arctan2(s, d)
    nz = s > 0.0
    ratio = np.divide(gamma, s, out=np.zeros_like(s), where=nz)               # γ/|a×b|
    if normal.ndim == 1:
        proj = c @ normal
    else:
        proj = np.einsum("fkc,fc->fk", c, normal)
    return _INV_2PI * (proj * ratio).sum(axis=1)
