"""Scene builders and reference formulas for the core's independent test suite.

Nothing here imports ``hemisphere_local_pass``: these helpers are the *test machinery* (scene
builders, closed-form configuration factors, an unoccluded Lambert reference, a brute-force Monte
Carlo ray caster), written independently of the implementation and validated on their own in the
``test_*machinery*`` tests.

Conventions: polygons are lists of vertex indices; the front (emitting) side of a polygon is the
side from which its vertices are seen counter-clockwise, i.e. its normal is right-handed with the
vertex order. Closed rooms face inward, solid boxes outward.
"""

from __future__ import annotations

import math

import numpy as np

# --------------------------------------------------------------------------------------------
# small vector helpers


def unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def newell_normal(coords: np.ndarray) -> np.ndarray:
    """Area-weighted normal (not normalised) of a polygon given by its coordinates (k, 3)."""
    c = np.asarray(coords, dtype=np.float64)
    c = c - c.mean(axis=0)
    return 0.5 * np.cross(c, np.roll(c, -1, axis=0)).sum(axis=0)


def random_unit_vectors(rng: np.random.Generator, m: int) -> np.ndarray:
    v = rng.normal(size=(m, 3))
    return unit(v)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniformly random proper rotation matrix (3, 3)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def tangent_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors t, b with (t, b, n) a right-handed orthonormal frame."""
    n = unit(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = unit(np.cross(a, n))
    b = np.cross(n, t)
    return t, b


# --------------------------------------------------------------------------------------------
# mesh building


class Mesh:
    """Collects polygons given by coordinates; identical coordinates share one vertex index."""

    def __init__(self) -> None:
        self.vertices: list[tuple[float, float, float]] = []
        self.polygons: list[list[int]] = []
        self.radiance: list[tuple[float, float, float]] = []
        self._index: dict[tuple[float, float, float], int] = {}

    def vertex(self, p) -> int:
        key = (float(p[0]), float(p[1]), float(p[2]))
        i = self._index.get(key)
        if i is None:
            i = len(self.vertices)
            self.vertices.append(key)
            self._index[key] = i
        return i

    def add(self, coords, radiance=(0.0, 0.0, 0.0), *, facing=None) -> int:
        """Add a polygon; if ``facing`` (a direction) is given, orient its front side towards it."""
        coords = np.asarray(coords, dtype=np.float64)
        if facing is not None and np.dot(newell_normal(coords), facing) < 0:
            coords = coords[::-1]
        self.polygons.append([self.vertex(p) for p in coords])
        self.radiance.append(tuple(float(x) for x in radiance))
        return len(self.polygons) - 1

    def extend(self, other: Mesh) -> list[int]:
        ids = []
        verts = np.asarray(other.vertices, dtype=np.float64).reshape(-1, 3)
        for poly, rad in zip(other.polygons, other.radiance, strict=True):
            ids.append(self.add(verts[poly], rad))
        return ids

    @property
    def n(self) -> int:
        return len(self.polygons)

    def arrays(self) -> tuple[np.ndarray, list[list[int]]]:
        return np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3), [list(p) for p in self.polygons]

    def radiance_array(self) -> np.ndarray:
        return np.asarray(self.radiance, dtype=np.float64).reshape(-1, 3)

    def coords(self, i: int) -> np.ndarray:
        verts = np.asarray(self.vertices, dtype=np.float64)
        return verts[self.polygons[i]]


def polygon_coords(vertices: np.ndarray, polygons) -> list[np.ndarray]:
    vertices = np.asarray(vertices, dtype=np.float64)
    return [vertices[list(p)] for p in polygons]


def fan_triangles(poly: list[int]) -> list[list[int]]:
    return [[poly[0], poly[i], poly[i + 1]] for i in range(1, len(poly) - 1)]


# --------------------------------------------------------------------------------------------
# boxes and rooms


_BOX_FACES = (
    # (axis, side, e1 axis, e2 axis) with e1 x e2 == +axis direction
    (0, 0, 1, 2),
    (0, 1, 1, 2),
    (1, 0, 2, 0),
    (1, 1, 2, 0),
    (2, 0, 0, 1),
    (2, 1, 0, 1),
)


def box_face_quads(lo, hi, *, inward: bool) -> list[np.ndarray]:
    """The six faces of the axis-aligned box [lo, hi] as (4, 3) arrays, oriented in- or outward."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    quads = []
    for axis, side, a1, a2 in _BOX_FACES:
        o = lo.copy()
        o[axis] = hi[axis] if side else lo[axis]
        e1 = np.zeros(3)
        e1[a1] = hi[a1] - lo[a1]
        e2 = np.zeros(3)
        e2[a2] = hi[a2] - lo[a2]
        q = np.array([o, o + e1, o + e1 + e2, o + e2])
        outward = 1.0 if side else -1.0  # e1 x e2 is +axis
        want = -outward if inward else outward
        if want < 0:
            q = q[::-1]
        quads.append(q)
    return quads


def split_box(lo, hi, rng: np.random.Generator, *, inward: bool = True, cells=(1, 4)) -> Mesh:
    """A box whose every face is cut into a random grid of quads, triangle pairs and triangle fans.

    The cut positions are multiples of 1/16 of the face size (exactly representable for the
    dyadic box sizes the tests use), and each face has its own cuts, so the faces meet in
    T-junctions along the box edges; the surface is closed as a point set.
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    mesh = Mesh()
    for axis, side, a1, a2 in _BOX_FACES:
        o = lo.copy()
        o[axis] = hi[axis] if side else lo[axis]
        e1 = np.zeros(3)
        e1[a1] = hi[a1] - lo[a1]
        e2 = np.zeros(3)
        e2[a2] = hi[a2] - lo[a2]
        outward = np.zeros(3)
        outward[axis] = 1.0 if side else -1.0
        facing = -outward if inward else outward
        cuts = []
        for _ in range(2):
            k = int(rng.integers(cells[0], cells[1] + 1))
            inner = np.sort(rng.choice(np.arange(1, 16), size=k - 1, replace=False)) / 16.0
            cuts.append(np.concatenate([[0.0], inner, [1.0]]))
        s, t = cuts
        for i in range(len(s) - 1):
            for j in range(len(t) - 1):
                c00 = o + s[i] * e1 + t[j] * e2
                c10 = o + s[i + 1] * e1 + t[j] * e2
                c11 = o + s[i + 1] * e1 + t[j + 1] * e2
                c01 = o + s[i] * e1 + t[j + 1] * e2
                kind = int(rng.integers(0, 4))
                if kind == 0:
                    mesh.add([c00, c10, c11, c01], facing=facing)
                elif kind == 1:
                    mesh.add([c00, c10, c11], facing=facing)
                    mesh.add([c00, c11, c01], facing=facing)
                elif kind == 2:
                    mesh.add([c00, c10, c01], facing=facing)
                    mesh.add([c10, c11, c01], facing=facing)
                else:
                    c = 0.5 * (c00 + c11)
                    ring = [c00, c10, c11, c01]
                    for q in range(4):
                        mesh.add([c, ring[q], ring[(q + 1) % 4]], facing=facing)
    return mesh


# The Cornell box, from the Cornell University Program of Computer Graphics' measured data
# (millimetres, y up). The red wall is slightly non-planar in the original data; the open
# front is closed here with a planar wall so that every interior point sees a closed room.
CORNELL_ROOM = {
    "floor": [[552.8, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 559.2], [549.6, 0.0, 559.2]],
    "ceiling": [[556.0, 548.8, 0.0], [556.0, 548.8, 559.2], [0.0, 548.8, 559.2], [0.0, 548.8, 0.0]],
    "back": [[549.6, 0.0, 559.2], [0.0, 0.0, 559.2], [0.0, 548.8, 559.2], [556.0, 548.8, 559.2]],
    "green": [[0.0, 0.0, 559.2], [0.0, 0.0, 0.0], [0.0, 548.8, 0.0], [0.0, 548.8, 559.2]],
    "red": [[552.8, 0.0, 0.0], [549.6, 0.0, 559.2], [556.0, 548.8, 559.2], [556.0, 548.8, 0.0]],
    "front": [[552.8, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 548.8, 0.0], [556.0, 548.8, 0.0]],
}
CORNELL_LIGHT = [[343.0, 548.7, 227.0], [343.0, 548.7, 332.0], [213.0, 548.7, 332.0], [213.0, 548.7, 227.0]]
CORNELL_SHORT_BLOCK_FOOT = [[130.0, 65.0], [82.0, 225.0], [240.0, 272.0], [290.0, 114.0]]  # (x, z)
CORNELL_TALL_BLOCK_FOOT = [[423.0, 247.0], [265.0, 296.0], [314.0, 456.0], [472.0, 406.0]]
CORNELL_SHORT_HEIGHT = 165.0
CORNELL_TALL_HEIGHT = 330.0
CORNELL_CENTRE = np.array([278.0, 274.4, 279.6])


def prism(foot_xz, height) -> list[np.ndarray]:
    """Top and side faces (no bottom) of a vertical prism standing on y = 0, facing outward."""
    foot = np.asarray(foot_xz, dtype=np.float64)
    base = np.column_stack([foot[:, 0], np.zeros(len(foot)), foot[:, 1]])
    top = base + np.array([0.0, height, 0.0])
    centre = np.array([foot[:, 0].mean(), 0.5 * height, foot[:, 1].mean()])
    faces = [top]
    k = len(foot)
    for i in range(k):
        j = (i + 1) % k
        faces.append(np.array([base[i], base[j], top[j], top[i]]))
    out = []
    for f in faces:
        away = f.mean(axis=0) - centre
        if np.dot(newell_normal(f), away) < 0:
            f = f[::-1]
        out.append(f)
    return out


def cornell_box(light_radiance=(17.0, 12.0, 4.0)) -> Mesh:
    """Closed Cornell box (room facing inward) with its two blocks (facing outward) and the light."""
    mesh = Mesh()
    colours = {"red": (0.63, 0.065, 0.05), "green": (0.14, 0.45, 0.091)}
    for name, quad in CORNELL_ROOM.items():
        q = np.asarray(quad)
        mesh.add(q, colours.get(name, (0.725, 0.71, 0.68)), facing=CORNELL_CENTRE - q.mean(axis=0))
    mesh.add(CORNELL_LIGHT, light_radiance, facing=[0.0, -1.0, 0.0])
    for foot, h in ((CORNELL_SHORT_BLOCK_FOOT, CORNELL_SHORT_HEIGHT), (CORNELL_TALL_BLOCK_FOOT, CORNELL_TALL_HEIGHT)):
        for f in prism(foot, h):
            mesh.add(f, (0.725, 0.71, 0.68))
    return mesh


def _inside_convex_prism(points: np.ndarray, foot_xz, height: float, margin: float) -> np.ndarray:
    foot = np.asarray(foot_xz, dtype=np.float64)
    inside = (points[:, 1] > -margin) & (points[:, 1] < height + margin)
    c = foot.mean(axis=0)
    for i in range(len(foot)):
        a, b = foot[i], foot[(i + 1) % len(foot)]
        n = np.array([b[1] - a[1], -(b[0] - a[0])])  # one of the two edge normals
        if np.dot(n, c - a) > 0:
            n = -n  # make it point outward
        n = n / np.linalg.norm(n)
        d = (points[:, [0, 2]] - a) @ n
        inside &= d < margin
    return inside


def cornell_free_points(rng: np.random.Generator, m: int) -> np.ndarray:
    """m random points strictly inside the Cornell room and outside both blocks."""
    lo = np.array([1.0, 1.0, 1.0])
    hi = np.array([548.0, 547.8, 558.2])  # inside every wall, including the slanted red one
    out = np.empty((0, 3))
    while len(out) < m:
        p = lo + (hi - lo) * rng.random(size=(2 * m, 3))
        bad = _inside_convex_prism(p, CORNELL_SHORT_BLOCK_FOOT, CORNELL_SHORT_HEIGHT, 1e-6)
        bad |= _inside_convex_prism(p, CORNELL_TALL_BLOCK_FOOT, CORNELL_TALL_HEIGHT, 1e-6)
        out = np.concatenate([out, p[~bad]])
    return out[:m]


class OrientedBox:
    def __init__(self, centre, rotation, half):
        self.centre = np.asarray(centre, dtype=np.float64)
        self.rotation = np.asarray(rotation, dtype=np.float64)  # columns: the box's local axes
        self.half = np.asarray(half, dtype=np.float64)

    def faces(self) -> list[np.ndarray]:
        local = box_face_quads(-self.half, self.half, inward=False)
        return [self.centre + q @ self.rotation.T for q in local]

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        local = (np.asarray(points) - self.centre) @ self.rotation
        return np.all(np.abs(local) < self.half + margin, axis=1)


def random_box_room(rng: np.random.Generator, n_boxes: int = 50, size: float = 10.0):
    """A closed room [0, size]^3 (faces split 2x2, inward) holding n randomly rotated boxes.

    The boxes overlap and interpenetrate each other (and some poke through the room's walls).
    Returns (mesh, boxes).
    """
    mesh = Mesh()
    for q in box_face_quads([0.0] * 3, [size] * 3, inward=True):
        # split each wall 2x2 through its centre (T-junction free)
        c = q.mean(axis=0)
        mids = [(q[i] + q[(i + 1) % 4]) / 2 for i in range(4)]
        for i in range(4):
            mesh.add([q[i], mids[i], c, mids[i - 1]], (0.5, 0.5, 0.5))
    boxes = []
    for _ in range(n_boxes):
        centre = rng.uniform(0.1 * size, 0.9 * size, size=3)
        hs = rng.uniform(0.02, 0.15, size=3) * size
        box = OrientedBox(centre, random_rotation(rng), hs)
        boxes.append(box)
        for f in box.faces():
            mesh.add(f, tuple(rng.uniform(0, 1, size=3)))
    return mesh, boxes


def random_free_points_in_room(rng: np.random.Generator, boxes, m: int, size: float = 10.0) -> np.ndarray:
    out = np.empty((0, 3))
    while len(out) < m:
        p = rng.uniform(1e-3 * size, (1 - 1e-3) * size, size=(2 * m, 3))
        bad = np.zeros(len(p), dtype=bool)
        for b in boxes:
            bad |= b.contains(p, margin=1e-9 * size)
        out = np.concatenate([out, p[~bad]])
    return out[:m]


# random occluded scenes above a few receivers near the origin


def random_polygon(rng, centre, size):
    """A random convex planar triangle, quad or pentagon around centre, randomly oriented."""
    while True:
        ang = np.sort(rng.uniform(0, 2 * np.pi, size=int(rng.choice([3, 4, 5]))))
        if np.diff(np.append(ang, ang[0] + 2 * np.pi)).min() > 0.2:
            break
    k = len(ang)
    ax = size * rng.uniform(0.4, 1.0, size=2)  # vertices on an ellipse: convex
    local = np.column_stack([ax[0] * np.cos(ang), ax[1] * np.sin(ang), np.zeros(k)])
    return centre + local @ random_rotation(rng).T


RECEIVERS = np.array([[0.0, 0.0, 0.0], [0.35, -0.2, 0.1], [-0.3, 0.25, -0.05]])


def add_facing_receivers(mesh, coords) -> bool:
    """Add the polygon showing its front to every receiver; False if its plane separates them."""
    n = np.cross(coords[1] - coords[0], coords[2] - coords[0])
    d = (RECEIVERS - coords[0]) @ n
    if d.min() > 0:
        mesh.add(coords)
    elif d.max() < 0:
        mesh.add(coords[::-1])
    else:
        return False
    return True


def random_occluded_scene(rng):
    """7-10 random polygons above the receivers near the origin; overlapping, some interpenetrating.

    Every polygon shows its front to all receivers, so one-sided emission does not matter for
    what is compared.
    """
    mesh = Mesh()
    n = int(rng.integers(4, 7))
    while mesh.n < n:
        centre = np.array([rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(0.4, 2.5)])
        add_facing_receivers(mesh, random_polygon(rng, centre, rng.uniform(0.4, 1.4)))
    # an occluder half-way between the receivers and the first polygon (occlusion always matters)
    first = mesh.coords(0).mean(axis=0)
    while not add_facing_receivers(mesh, random_polygon(rng, 0.5 * first, rng.uniform(0.2, 0.5))):
        pass
    n += 1
    # interpenetrating pairs: a polygon and a second one through its middle, crossing its plane
    pairs = int(rng.integers(1, 3))
    while mesh.n < n + 2 * pairs:
        centre = np.array([rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), rng.uniform(0.6, 2.0)])
        a = random_polygon(rng, centre, 0.8)
        b = random_polygon(rng, centre + rng.uniform(-0.1, 0.1, size=3), 0.8)
        probe = Mesh()
        if add_facing_receivers(probe, a) and add_facing_receivers(probe, b):
            mesh.extend(probe)
    verts, polys = mesh.arrays()
    return mesh, verts, polys


def receivers(rng):
    nrm = []
    for _ in range(len(RECEIVERS)):
        tilt = rng.uniform(0, 1.1)  # up to ~63 degrees: some polygons cross the horizon
        phi = rng.uniform(0, 2 * np.pi)
        nrm.append([np.sin(tilt) * np.cos(phi), np.sin(tilt) * np.sin(phi), np.cos(tilt)])
    return RECEIVERS.copy(), unit(np.array(nrm))


def signed_volume(vertices: np.ndarray, polygons) -> float:
    """Signed enclosed volume (divergence theorem): > 0 for an outward closed surface."""
    vol = 0.0
    for c in polygon_coords(vertices, polygons):
        vol += np.dot(c[0], newell_normal(c)) / 3.0
    return float(vol)


# --------------------------------------------------------------------------------------------
# closed-form configuration factors (Howell's catalogue)


# The formulas are evaluated in numpy's extended precision (80-bit on x86: eps 1.1e-19), because
# the perpendicular one cancels badly for small factors (atan(1/Y) ~ Y/r atan(1/r)); the result is
# rounded to float64. EXTENDED says whether that precision is really available on this platform.
EXTENDED = np.finfo(np.longdouble).eps < 1e-18


def howell_parallel_corner(a, b, c):
    """Differential element to a parallel a x b rectangle at distance c, normal through a corner."""
    A = np.asarray(a, dtype=np.longdouble) / np.longdouble(c)
    B = np.asarray(b, dtype=np.longdouble) / np.longdouble(c)
    sa = np.sqrt(1 + A * A)
    sb = np.sqrt(1 + B * B)
    two_pi = 2 * np.arctan(np.longdouble(1)) * 4
    return ((A / sa * np.arctan(B / sa) + B / sb * np.arctan(A / sb)) / two_pi).astype(np.float64)


def howell_perpendicular_corner(a, b, c):
    """Differential element to a rectangle in a perpendicular plane (Howell B-3).

    Geometry used by the tests: element at the origin, normal +z; rectangle in the plane y = c,
    x in [0, b], z in [0, a] (one edge on the element's plane, the element opposite a corner).
    X = a / b, Y = c / b.
    """
    X = np.asarray(a, dtype=np.longdouble) / np.longdouble(b)
    Y = np.asarray(c, dtype=np.longdouble) / np.longdouble(b)
    r = np.sqrt(X * X + Y * Y)
    two_pi = 2 * np.arctan(np.longdouble(1)) * 4
    return ((np.arctan(1 / Y) - Y / r * np.arctan(1 / r)) / two_pi).astype(np.float64)


def howell_perpendicular_condition(a, b, c) -> float:
    """Relative rounding error of howell_perpendicular_corner (cancellation factor x eps)."""
    X, Y = a / b, c / b
    r = math.hypot(X, Y)
    t1, t2 = math.atan(1 / Y), Y / r * math.atan(1 / r)
    return (abs(t1) + abs(t2)) / abs(t1 - t2) * float(np.finfo(np.longdouble).eps)


# --------------------------------------------------------------------------------------------
# an independent reference: one polygon, no occlusion


def clip_to_halfspace(coords: np.ndarray, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Sutherland–Hodgman clip of a polygon to {x : (x - p) . n >= 0}."""
    out = []
    k = len(coords)
    d = (coords - p) @ n
    for i in range(k):
        j = (i + 1) % k
        if d[i] >= 0:
            out.append(coords[i])
        if (d[i] >= 0) != (d[j] >= 0):
            t = d[i] / (d[i] - d[j])
            out.append(coords[i] + t * (coords[j] - coords[i]))
    return np.asarray(out).reshape(-1, 3)


def lambert_unoccluded(p, n, coords) -> float:
    """Unoccluded point-to-polygon form factor by Lambert's contour integral (either facing)."""
    p = np.asarray(p, dtype=np.float64)
    n = unit(np.asarray(n, dtype=np.float64))
    c = clip_to_halfspace(np.asarray(coords, dtype=np.float64), p, n)
    if len(c) < 3:
        return 0.0
    r = unit(c - p)
    r2 = np.roll(r, -1, axis=0)
    cr = np.cross(r, r2)
    s = np.linalg.norm(cr, axis=1)
    gamma = np.arctan2(s, np.sum(r * r2, axis=1))
    ok = s > 0
    total = np.sum(gamma[ok] * (cr[ok] @ n) / s[ok])
    return float(abs(total) / (2.0 * math.pi))


# --------------------------------------------------------------------------------------------
# an independent Monte Carlo reference: brute-force ray casting


def cosine_directions(rng: np.random.Generator, n: np.ndarray, count: int) -> np.ndarray:
    """count cosine-weighted directions on the hemisphere around unit normal n."""
    u1 = rng.random(count)
    u2 = rng.random(count)
    r = np.sqrt(u1)
    phi = 2.0 * math.pi * u2
    t, b = tangent_frame(n)
    z = np.sqrt(np.maximum(0.0, 1.0 - u1))
    return (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b + z[:, None] * unit(n)


def nearest_hits(origin: np.ndarray, dirs: np.ndarray, triangles: np.ndarray, owner: np.ndarray,
                 chunk: int = 20000) -> np.ndarray:
    """Index (in ``owner``) of the first polygon hit by each ray, -1 for a miss (Möller–Trumbore).

    triangles (T, 3, 3); owner (T,) polygon id of each triangle.
    """
    v0 = triangles[:, 0] - origin
    e1 = triangles[:, 1] - triangles[:, 0]
    e2 = triangles[:, 2] - triangles[:, 0]
    result = np.empty(len(dirs), dtype=np.int64)
    for s in range(0, len(dirs), chunk):
        d = dirs[s:s + chunk]  # (R, 3)
        pvec = np.cross(d[:, None, :], e2[None, :, :])  # (R, T, 3)
        det = np.einsum("tk,rtk->rt", e1, pvec)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tvec = -v0  # origin - v0, (T, 3)
            u = np.einsum("tk,rtk->rt", tvec, pvec) * inv
            qvec = np.cross(tvec, e1)  # (T, 3)
            v = np.einsum("rk,tk->rt", d, qvec) * inv
            t = np.einsum("tk,tk->t", e2, qvec)[None, :] * inv
        hit = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        t = np.where(hit, t, np.inf)
        j = np.argmin(t, axis=1)
        got = np.isfinite(t[np.arange(len(d)), j])
        result[s:s + chunk] = np.where(got, owner[j], -1)
    return result


def triangulate_for_rays(vertices: np.ndarray, polygons) -> tuple[np.ndarray, np.ndarray]:
    """Fan-triangulate (convex) polygons: (T, 3, 3) triangles and their polygon ids."""
    vertices = np.asarray(vertices, dtype=np.float64)
    tris, owner = [], []
    for i, poly in enumerate(polygons):
        for t in fan_triangles(list(poly)):
            tris.append(vertices[t])
            owner.append(i)
    return np.asarray(tris).reshape(-1, 3, 3), np.asarray(owner, dtype=np.int64)


def monte_carlo_form_factors(rng, vertices, polygons, p, n, samples: int) -> np.ndarray:
    """Estimate of the visible form factor of every polygon from point p with normal n.

    Each cosine-weighted ray hits (first) polygon i with probability exactly F_i, so the count
    of polygon i is Binomial(samples, F_i): the estimate is unbiased with standard deviation
    sqrt(F_i (1 - F_i) / samples).
    """
    tris, owner = triangulate_for_rays(vertices, polygons)
    dirs = cosine_directions(rng, np.asarray(n, dtype=np.float64), samples)
    hits = nearest_hits(np.asarray(p, dtype=np.float64), dirs, tris, owner)
    counts = np.bincount(hits[hits >= 0], minlength=len(polygons))
    return counts / samples
