"""What the form-factor inspector shows at one receiver point, as plain arrays (pure numpy, no bpy,
no gpu: tested without a GPU; ``inspector.py`` only turns these arrays into GPU batches).

At a point P with normal N the core's exact projection (``core.project_point``) gives the visible
fragments: spherical polygons (unit directions, great-circle edges) with their form factors (eq. 4).
The inspector draws

* the hemisphere of radius ``r`` over P with every fragment filled (the source polygon's radiance,
  or a false colour by its form factor) and outlined;
* the Nusselt analog: every fragment projected orthogonally onto the unit disc in the tangent
  plane (scaled by ``r``); its area divided by pi r^2 is the fragment's form factor (Nusselt 1928;
  the paper's eq. 4 integrates exactly this);
* the outlines of the top contributing input polygons in the scene;

and lists per contributing input polygon F, L.F and its share of H (eq. 3: H = pi sum_i L_i F_i
over the polygons whose emitting side P sees), with sum F, H and L = E + rho/pi H (eq. 5).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Inspection", "Row", "arc_points", "false_colour", "inspect_point", "nusselt_area", "tangent_basis"]

#: Segments per great-circle edge of a drawn fragment.
ARC_SEGMENTS = 16
#: Fraction of r by which the drawn hemisphere / disc are lifted off the surface (no z-fighting).
LIFT = 1e-3


@dataclass
class Row:
    """One contributing input polygon (the N-panel list)."""

    polygon: int  # input polygon index of the core scene
    label: str  # "Object, polygon j"
    form_factor: float  # F_i, visible form factor (eq. 4 summed over the polygon's fragments)
    radiance_ff: np.ndarray  # (3,) L_i F_i of the emitting side P sees (0 when P sees its back)
    share: float  # L_i F_i / sum_j L_j F_j, mean over RGB channels with a non-zero sum


@dataclass
class Inspection:
    """Everything drawn and listed at one receiver point (world space, metres).

    Attributes:
        point, normal: (3,) receiver; radius: r of the drawn hemisphere.
        rows: input polygons with F > 0, largest share of H first (then largest F).
        form_factor_sum: sum F over every fragment; irradiance: (3,) H from ``core.irradiance``;
            radiance: (3,) L = E + rho / pi H (eq. 5); fragments: number of visible fragments.
        hemisphere_tris / hemisphere_colours: (3T, 3) / (3T, 4) float32 filled fragments.
        hemisphere_lines: (2S, 3) float32 fragment outlines (line segments).
        disc_tris / disc_colours / disc_lines: the same for the Nusselt analog.
        frame_lines: (2S, 3) the hemisphere's equator and two meridians, the disc's rim.
        top_lines: (2S, 3) outlines of the top ``top`` input polygons in the scene.
        nusselt_areas: (F,) area of each projected fragment / (pi r^2) (= its form factor).
    """

    point: np.ndarray
    normal: np.ndarray
    radius: float
    rows: list = field(default_factory=list)
    form_factor_sum: float = 0.0
    irradiance: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radiance: np.ndarray = field(default_factory=lambda: np.zeros(3))
    fragments: int = 0
    hemisphere_tris: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    hemisphere_colours: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))
    hemisphere_lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    disc_tris: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    disc_colours: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))
    disc_lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    frame_lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    top_lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    nusselt_areas: np.ndarray = field(default_factory=lambda: np.zeros(0))


def tangent_basis(normal) -> tuple:
    """Unit tangents ``(t, b)`` with ``t x b = n`` (Frisvad-style, branch on the larger component)."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(helper, n)
    t /= np.linalg.norm(t)
    return t, np.cross(n, t)


def arc_points(dirs: np.ndarray, segments: int = ARC_SEGMENTS) -> np.ndarray:
    """The closed boundary of a spherical polygon ``dirs (k, 3)`` (unit vectors, great-circle edges)
    sampled with ``segments`` points per edge -> ``(k * segments, 3)`` unit vectors (first vertex of
    every edge included, the closing vertex not repeated). Points are slerped, so they lie on the arcs."""
    a = np.asarray(dirs, dtype=np.float64)
    b = np.roll(a, -1, axis=0)
    t = np.arange(segments) / segments  # (s,)
    cos = np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)
    sin = np.linalg.norm(np.cross(a, b), axis=1)
    omega = np.arctan2(sin, cos)[:, None]  # (k, 1) arc angle, atan2 form: exact for tiny arcs
    safe = np.where(sin > 1e-12, sin, 1.0)[:, None]
    wa = np.where(sin[:, None] > 1e-12, np.sin((1.0 - t) * omega) / safe, 1.0 - t)  # (k, s)
    wb = np.where(sin[:, None] > 1e-12, np.sin(t * omega) / safe, t)
    pts = wa[:, :, None] * a[:, None, :] + wb[:, :, None] * b[:, None, :]  # (k, s, 3)
    pts /= np.linalg.norm(pts, axis=2, keepdims=True)
    return pts.reshape(-1, 3)


def nusselt_area(boundary: np.ndarray, normal) -> float:
    """Area of the orthogonal projection onto the tangent plane of a closed loop of unit vectors
    ``boundary (m, 3)`` (shoelace formula in the plane's basis); |area| / pi is the form factor."""
    t, b = tangent_basis(normal)
    x, y = boundary @ t, boundary @ b
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)))


def false_colour(value: np.ndarray) -> np.ndarray:
    """``value`` in [0, 1] -> (n, 3) RGB on a blue-green-yellow ramp (perceptually ordered)."""
    stops = np.array([[0.27, 0.00, 0.33], [0.23, 0.32, 0.55], [0.13, 0.57, 0.55], [0.37, 0.79, 0.38],
                      [0.99, 0.91, 0.14]])
    v = np.clip(np.asarray(value, dtype=np.float64), 0.0, 1.0) * (len(stops) - 1)
    i = np.minimum(v.astype(int), len(stops) - 2)
    f = (v - i)[..., None]
    return stops[i] * (1 - f) + stops[i + 1] * f


def _display(rgb: np.ndarray) -> np.ndarray:
    """Linear radiance (n, 3) -> display RGB in [0, 1]: exposed so the median fragment is mid-grey,
    Reinhard's x / (1 + x) for the bright emitters, sRGB-ish gamma."""
    lum = rgb.mean(axis=1) if rgb.size else np.zeros(0)
    mid = float(np.median(lum[lum > 0])) if (lum > 0).any() else 0.0
    if mid <= 0:
        return np.zeros_like(rgb)
    x = np.maximum(rgb, 0.0) / mid
    return (x / (1.0 + x)) ** (1 / 2.2)


def inspect_point(scene, point, normal, *, radius: float, reflectivity=(0.8, 0.8, 0.8), emission=(0.0, 0.0, 0.0),
                  labels=None, colour_by: str = "RADIANCE", top: int = 5, alpha: float = 0.75) -> Inspection:
    """The inspector's arrays at ``point`` (3,) with ``normal`` (3,) in the core ``scene``.

    Args:
        radius: r of the drawn hemisphere (m).
        reflectivity, emission: (3,) rho and E of the receiving surface (for L, eq. 5).
        labels: ``labels(i) -> str`` naming input polygon i (default "polygon i").
        colour_by: "RADIANCE" (the source polygon's radiance) or "FORM_FACTOR" (false colour by F
            relative to the largest fragment).
        top: how many input polygons (the first rows: the largest shares of H) to outline in the scene.
    """
    from ..core import irradiance, project_point

    p = np.asarray(point, dtype=np.float64).reshape(3)
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    n = n / np.linalg.norm(n)
    proj = project_point(scene, p, n)
    h = irradiance(scene, p[None], n[None])[0]
    rho = np.asarray(reflectivity, dtype=np.float64).reshape(3)
    emit = np.asarray(emission, dtype=np.float64).reshape(3)
    out = Inspection(point=p, normal=n, radius=float(radius), form_factor_sum=float(np.sum(proj.form_factor)),
                     irradiance=h, radiance=emit + rho / np.pi * h, fragments=len(proj.fragments))

    # radiance each input polygon sends towards P: the side P sees must emit (eq. 3)
    n_in = scene.n_input
    lin_rad = np.zeros((n_in, 3))
    lit = np.zeros(n_in, dtype=bool)
    rad = scene.corner_radiance.mean(axis=1) if scene.corner_radiance is not None else scene.poly_radiance
    lin_rad[scene.poly_source] = rad
    front = scene.poly_normals @ p - scene.poly_offsets > 0.0
    lit[scene.poly_source] = front | bool(scene.double_sided)
    ff = proj.polygon_form_factors
    lf = np.where(lit[:, None], lin_rad * ff[:, None], 0.0)  # (n_in, 3)
    total = lf.sum(axis=0)
    shares = np.where(total > 0, lf / np.where(total > 0, total, 1.0), 0.0)
    chans = total > 0
    share = shares[:, chans].mean(axis=1) if chans.any() else np.zeros(n_in)  # (n_in,)
    order = np.lexsort((-ff, -share))  # largest share of H first, then largest F
    name = labels if labels is not None else (lambda i: f"polygon {i}")
    for i in order[ff[order] > 0]:
        out.rows.append(Row(int(i), name(int(i)), float(ff[i]), lf[i].copy(), float(share[i])))

    # geometry: hemisphere fragments, Nusselt disc, outlines
    r = float(radius)
    t, b = tangent_basis(n)
    lift = LIFT * r * n
    if colour_by == "FORM_FACTOR":
        peak = float(proj.form_factor.max()) if len(proj.form_factor) else 1.0
        colours = false_colour(proj.form_factor / (peak if peak > 0 else 1.0))
    else:
        colours = _display(lin_rad[proj.polygon]) if len(proj.polygon) else np.zeros((0, 3))
    h_tris, h_cols, h_lines, d_tris, d_lines, areas = [], [], [], [], [], []
    for f, dirs in enumerate(proj.fragments):
        loop = arc_points(dirs)  # (m, 3) unit vectors on the fragment's boundary
        centre = loop.mean(axis=0)
        centre /= np.linalg.norm(centre)
        nxt = np.roll(loop, -1, axis=0)
        fan = np.stack([np.broadcast_to(centre, loop.shape), loop, nxt], axis=1).reshape(-1, 3)  # (3m, 3)
        h_tris.append(p + lift + r * fan)
        h_cols.append(np.broadcast_to(np.append(colours[f], alpha), (len(fan), 4)))
        h_lines.append(p + lift + r * np.stack([loop, nxt], axis=1).reshape(-1, 3))
        flat = fan - np.outer(fan @ n, n)  # orthogonal projection onto the tangent plane
        d_tris.append(p + lift + r * flat)
        flat_loop = loop - np.outer(loop @ n, n)
        d_lines.append(p + 2 * lift + r * np.stack([flat_loop, np.roll(flat_loop, -1, axis=0)], axis=1).reshape(-1, 3))
        areas.append(nusselt_area(loop, n) / np.pi)
    if h_tris:
        out.hemisphere_tris = np.concatenate(h_tris).astype(np.float32)
        out.hemisphere_colours = np.concatenate(h_cols).astype(np.float32)
        out.hemisphere_lines = np.concatenate(h_lines).astype(np.float32)
        out.disc_tris = np.concatenate(d_tris).astype(np.float32)
        out.disc_colours = np.concatenate(h_cols).astype(np.float32)
        out.disc_colours[:, 3] = 1.0
        out.disc_lines = np.concatenate(d_lines).astype(np.float32)
    out.nusselt_areas = np.array(areas)

    # frame: equator (= the disc's rim) and two meridians
    ang = np.linspace(0.0, 2 * np.pi, 65)
    ring = np.cos(ang)[:, None] * t + np.sin(ang)[:, None] * b
    half = np.linspace(0.0, np.pi, 33)
    meridians = [np.cos(half)[:, None] * axis + np.sin(half)[:, None] * n for axis in (t, b)]
    segs = [np.stack([c[:-1], c[1:]], axis=1).reshape(-1, 3) for c in [ring] + meridians]
    out.frame_lines = (p + lift + r * np.concatenate(segs)).astype(np.float32)

    # the top polygons' outlines in the scene (every convex piece of each)
    lines = []
    for row in out.rows[:top]:
        for piece in np.flatnonzero(scene.poly_source == row.polygon):
            k = int(scene.poly_counts[piece])
            v = scene.poly_vertices[piece, :k]
            lines.append(np.stack([v, np.roll(v, -1, axis=0)], axis=1).reshape(-1, 3))
    if lines:
        out.top_lines = np.concatenate(lines).astype(np.float32)
    for name in ("hemisphere_tris", "hemisphere_colours", "hemisphere_lines", "disc_tris", "disc_colours", "disc_lines",
                 "frame_lines", "top_lines"):
        # GPU vertex buffers read the raw buffer: C order (concatenated broadcasts can come out in F order)
        setattr(out, name, np.ascontiguousarray(getattr(out, name), dtype=np.float32))
    return out
