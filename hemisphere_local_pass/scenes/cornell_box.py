"""A closed, procedurally subdivided Cornell box (pure numpy).

Geometry follows the classic Cornell box data (www.graphics.cornell.edu/online/box/data.html),
idealised to a cube of side 555 units and scaled to side ``size``:

* Blender's axes: x to the right, y into the box (depth), z up. The camera looks along +y from
  just inside the front wall; the red wall is on the left (x = 0), the green wall on the right.
* The box is **closed**: the classic open front gets a white front wall, and the light is cut into
  the ceiling (the light's cells are part of the ceiling grid, flush with it), so the room's shell
  is a watertight 2-manifold: every edge is shared by exactly two polygons with opposite
  orientation, and from any point inside the room (outside the blocks) the visible form factors
  sum to 1.
* All room polygons face inward, the blocks' faces outward (toward the free space). The blocks
  (short and tall, rotated, from the classic data) stand on the floor without bottom faces: each
  block is a manifold except for its bottom edges, which lie on the floor.
* Subdivision: the room uses one set of grid lines per axis (uniform lines plus the light's
  boundary lines), shared by every face, so there are no T-junctions; the blocks are subdivided
  into cells of about the same size, with matching vertices along their own edges.

Polygon counts: ``cornell_box(5)`` has 175 polygons (the paper's scene 1 has 176) and
``cornell_box(35, block_detail=1.05)`` has 9,468 (the paper's scene 2 has 9,504); see
:data:`PAPER_SETTINGS`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["CornellBox", "PAPER_SETTINGS", "camera_rays", "cornell_box"]

#: :func:`cornell_box` arguments giving about the paper's scene sizes: 175 and 9,468 polygons
#: (the paper: 176 and 9,504). ``cornell_box(**PAPER_SETTINGS["small"])``.
PAPER_SETTINGS = {"small": {"subdivisions": 5}, "large": {"subdivisions": 35, "block_detail": 1.05}}

_CLASSIC = 555.0
# classic reflectivities (RGB approximations of the measured spectra)
WHITE = (0.73, 0.73, 0.73)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
LIGHT_REFLECTIVITY = (0.78, 0.78, 0.78)
#: emitted radiance of the light (W sr^-1 m^-2, linear RGB), the usual RGB stand-in for the spectrum
LIGHT_EMISSION = (17.0, 12.0, 4.0)

# Classic data in (x, y = up, z = depth) mapped to ours: x' = 555 - x (keeps the red wall on the
# left after swapping the axes), y' = z, z' = y.
_LIGHT_X = (555.0 - 343.0, 555.0 - 213.0)
_LIGHT_Y = (227.0, 332.0)
_SHORT_TOP = [(130.0, 65.0), (82.0, 225.0), (240.0, 272.0), (290.0, 114.0)]  # classic (x, z) at y = 165
_TALL_TOP = [(423.0, 247.0), (265.0, 296.0), (314.0, 456.0), (472.0, 406.0)]  # classic (x, z) at y = 330
_SHORT_H, _TALL_H = 165.0, 330.0


@dataclass
class CornellBox:
    """A Cornell box as arrays.

    Attributes:
        vertices: (V, 3) float64 world coordinates.
        polygons: list of n index lists (all quads), counter-clockwise seen from the front side.
        reflectivity: (n, 3) float64 diffuse reflectivity ρ (linear RGB, 0..1).
        emission: (n, 3) float64 emitted radiance E (W sr^-1 m^-2); non-zero on the light only.
        names: list of n part names: "floor", "ceiling", "light", "back wall", "front wall",
            "left wall" (red), "right wall" (green), "short block", "tall block".
        size: side of the cube (the classic box is 555 units).
        camera: dict with ``location`` (3,), ``direction`` (3,), ``up`` (3,) and ``fov`` (radians,
            full angle of the square image) of the classic pinhole camera, outside the box in front of
            the front wall, its frame exactly covering the front wall. The front wall must be
            invisible to camera rays (in Cycles: ``visible_camera = False``); :func:`camera_rays`
            starts the rays just inside it instead.
    """

    vertices: np.ndarray
    polygons: list
    reflectivity: np.ndarray
    emission: np.ndarray
    names: list
    size: float
    camera: dict = field(default_factory=dict)

    @property
    def n_polygons(self) -> int:
        return len(self.polygons)

    def loops(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Blender's layout: ``loop_vertices (L,)``, ``loop_start (n,)``, ``loop_total (n,)`` int64."""
        total = np.array([len(p) for p in self.polygons], dtype=np.int64)
        start = np.concatenate([[0], np.cumsum(total)[:-1]]).astype(np.int64)
        return np.array([i for p in self.polygons for i in p], dtype=np.int64), start, total

    def centroids(self) -> np.ndarray:
        """(n, 3) vertex mean of every polygon (its centre: the cells are parallelograms or close)."""
        return np.array([self.vertices[p].mean(axis=0) for p in self.polygons])

    def normals(self) -> np.ndarray:
        """(n, 3) unit front-side normals (Newell's method)."""
        out = np.empty((self.n_polygons, 3))
        for i, p in enumerate(self.polygons):
            v = self.vertices[p]
            a = 0.5 * np.cross(v, np.roll(v, -1, axis=0)).sum(axis=0)
            out[i] = a / np.linalg.norm(a)
        return out

    def scene(self, radiance=None, **kw):
        """A core :class:`Scene` of the box; ``radiance (n, 3)`` defaults to the emission."""
        from ..core.scene import Scene

        rad = self.emission if radiance is None else radiance
        return Scene.from_polygons(self.vertices, self.polygons, rad, polygon_names=self.names, **kw)


def _lines(n: int, extra: tuple[float, ...]) -> np.ndarray:
    """Grid coordinates in classic units: ``n`` uniform intervals on [0, 555] plus the ``extra``
    lines; uniform lines closer than a quarter cell to an extra line are dropped (no slivers)."""
    uni = np.linspace(0.0, _CLASSIC, n + 1)
    cell = _CLASSIC / n
    keep = [u for u in uni if all(abs(u - e) > 0.25 * cell for e in extra) or u in (0.0, _CLASSIC)]
    return np.unique(np.array(keep + list(extra)))


class _Builder:
    """Collects quads on a shared vertex table (exactly shared coordinates -> shared indices)."""

    def __init__(self):
        self.index: dict[tuple[float, float, float], int] = {}
        self.verts: list[tuple[float, float, float]] = []
        self.polys: list[list[int]] = []
        self.names: list[str] = []

    def vid(self, p) -> int:
        key = (float(p[0]), float(p[1]), float(p[2]))
        i = self.index.get(key)
        if i is None:
            i = self.index[key] = len(self.verts)
            self.verts.append(key)
        return i

    def quad(self, pts, want_normal, name: str):
        """Add quad ``pts (4, 3)`` with the winding whose normal points along ``want_normal (3,)``."""
        pts = np.asarray(pts, dtype=np.float64)
        a = np.cross(pts, np.roll(pts, -1, axis=0)).sum(axis=0)
        if np.dot(a, want_normal) < 0:
            pts = pts[::-1]
        self.polys.append([self.vid(p) for p in pts])
        self.names.append(name)


def _room(b: _Builder, xs, ys, zs, light_x, light_y):
    X, Y, Z = xs[-1], ys[-1], zs[-1]
    for i in range(len(xs) - 1):  # floor (z = 0, normal +z) and ceiling (z = Z, normal -z)
        for j in range(len(ys) - 1):
            x0, x1, y0, y1 = xs[i], xs[i + 1], ys[j], ys[j + 1]
            b.quad([(x0, y0, 0.0), (x1, y0, 0.0), (x1, y1, 0.0), (x0, y1, 0.0)], (0, 0, 1), "floor")
            in_light = light_x[0] <= x0 and x1 <= light_x[1] and light_y[0] <= y0 and y1 <= light_y[1]
            b.quad([(x0, y0, Z), (x1, y0, Z), (x1, y1, Z), (x0, y1, Z)], (0, 0, -1), "light" if in_light else "ceiling")
    for i in range(len(xs) - 1):  # front (y = 0, normal +y) and back (y = Y, normal -y) walls
        for k in range(len(zs) - 1):
            x0, x1, z0, z1 = xs[i], xs[i + 1], zs[k], zs[k + 1]
            b.quad([(x0, 0.0, z0), (x1, 0.0, z0), (x1, 0.0, z1), (x0, 0.0, z1)], (0, 1, 0), "front wall")
            b.quad([(x0, Y, z0), (x1, Y, z0), (x1, Y, z1), (x0, Y, z1)], (0, -1, 0), "back wall")
    for j in range(len(ys) - 1):  # left (x = 0, red, normal +x) and right (x = X, green, normal -x)
        for k in range(len(zs) - 1):
            y0, y1, z0, z1 = ys[j], ys[j + 1], zs[k], zs[k + 1]
            b.quad([(0.0, y0, z0), (0.0, y1, z0), (0.0, y1, z1), (0.0, y0, z1)], (1, 0, 0), "left wall")
            b.quad([(X, y0, z0), (X, y1, z0), (X, y1, z1), (X, y0, z1)], (-1, 0, 0), "right wall")


def _block(b: _Builder, top_classic, height: float, cell: float, name: str):
    """A rotated box without bottom: corners from the classic (x, z) data, subdivided into ~cell."""
    c = np.array([(_CLASSIC - x, z) for x, z in top_classic])  # (4, 2) our (x, y)
    centre2 = c.mean(axis=0)
    lens = np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1)
    u = max(1, round(0.5 * (lens[0] + lens[2]) / cell))  # segments along edges 0-1 and 3-2
    v = max(1, round(0.5 * (lens[1] + lens[3]) / cell))  # along edges 1-2 and 0-3
    w = max(1, round(height / cell))
    zs = np.linspace(0.0, height, w + 1)

    def grid(i, j):  # top-face point (i / u along 0->1, j / v along 0->3), computed one way only
        s, t = i / u, j / v
        p = (1 - t) * ((1 - s) * c[0] + s * c[1]) + t * ((1 - s) * c[3] + s * c[2])
        return p

    pts = np.array([[grid(i, j) for j in range(v + 1)] for i in range(u + 1)])  # (u+1, v+1, 2)
    for i in range(u):  # top
        for j in range(v):
            q = [pts[i, j], pts[i + 1, j], pts[i + 1, j + 1], pts[i, j + 1]]
            b.quad([(p[0], p[1], height) for p in q], (0, 0, 1), name)
    # sides: walk the boundary of the top grid; the same boundary points are used by the top
    ring = ([pts[i, 0] for i in range(u)] + [pts[u, j] for j in range(v)]
            + [pts[i, v] for i in range(u, 0, -1)] + [pts[0, j] for j in range(v, 0, -1)])
    for a in range(len(ring)):
        p0, p1 = ring[a], ring[(a + 1) % len(ring)]
        mid = 0.5 * (p0 + p1) - centre2
        out = (mid[0], mid[1], 0.0)
        for k in range(w):
            z0, z1 = zs[k], zs[k + 1]
            b.quad([(p0[0], p0[1], z0), (p1[0], p1[1], z0), (p1[0], p1[1], z1), (p0[0], p0[1], z1)], out, name)


def cornell_box(subdivisions: int = 5, *, block_detail: float = 1.0, size: float = 1.0) -> CornellBox:
    """Build the closed Cornell box.

    Args:
        subdivisions: uniform grid intervals per room edge (the light's boundary lines are added to
            the x and y grids); blocks get cells of about the same size. 5 -> 175 polygons
            (:data:`PAPER_SETTINGS`).
        block_detail: the blocks' cells are ``block_detail`` times finer than the room's.
        size: side of the cubic room (world units); the classic box is 555.

    Returns:
        :class:`CornellBox` (all polygons are planar convex quads).
    """
    n = int(subdivisions)
    if n < 1:
        raise ValueError(f"subdivisions must be >= 1, got {subdivisions}")
    xs = _lines(n, _LIGHT_X)
    ys = _lines(n, _LIGHT_Y)
    zs = np.linspace(0.0, _CLASSIC, n + 1)
    b = _Builder()
    _room(b, xs, ys, zs, _LIGHT_X, _LIGHT_Y)
    cell = _CLASSIC / (n * float(block_detail))
    _block(b, _SHORT_TOP, _SHORT_H, cell, "short block")
    _block(b, _TALL_TOP, _TALL_H, cell, "tall block")
    scale = float(size) / _CLASSIC
    verts = np.array(b.verts) * scale
    colour = {"left wall": RED, "right wall": GREEN, "light": LIGHT_REFLECTIVITY}
    refl = np.array([colour.get(nm, WHITE) for nm in b.names], dtype=np.float64)
    emis = np.array([LIGHT_EMISSION if nm == "light" else (0.0, 0.0, 0.0) for nm in b.names], dtype=np.float64)
    s = float(size)
    fov = 2.0 * np.arctan(0.0125 / 0.035)  # the classic 35 mm lens on a 25 mm film
    camera = {
        # classic position, moved so that the square frame exactly covers the front wall
        "location": np.array([0.5 * s, -0.5 * s / np.tan(0.5 * fov), 0.5 * s]),
        "direction": np.array([0.0, 1.0, 0.0]),
        "up": np.array([0.0, 0.0, 1.0]),
        "fov": fov,
    }
    return CornellBox(verts, b.polys, refl, emis, b.names, s, camera)


def camera_rays(box: CornellBox, width: int, height: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Camera rays through pixel centres, row-major from the top-left pixel, started just inside the box.

    The classic camera (``box.camera``) stands outside the closed box; each ray's origin is moved along
    the ray to where it enters the room (``1e-9 * size`` inside the front wall), so casting the rays
    sees what the classic camera sees through the open front. Pixels are square; ``height`` defaults
    to ``width``; with ``height != width`` the vertical extent shrinks (the frame stays inside the wall).

    Returns ``origins (width * height, 3)`` and unit ``directions (width * height, 3)``.
    """
    height = width if height is None else height
    cam = box.camera
    fwd = cam["direction"] / np.linalg.norm(cam["direction"])
    right = np.cross(fwd, cam["up"])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    half = np.tan(0.5 * cam["fov"])  # half-width of the image plane at distance 1
    aspect = height / width
    sx = ((np.arange(width) + 0.5) / width * 2.0 - 1.0) * half
    sy = (1.0 - (np.arange(height) + 0.5) / height * 2.0) * half * aspect
    gx, gy = np.meshgrid(sx, sy)  # (h, w)
    d = fwd + gx[..., None] * right + gy[..., None] * up
    d = d.reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # enter the room: the front wall is the plane y = 0
    t0 = (1e-9 * box.size - cam["location"][1]) / d[:, 1]
    o = cam["location"] + t0[:, None] * d
    return o, d
