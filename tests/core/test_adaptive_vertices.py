"""The adaptive pass on vertex receivers (core.adaptive_vertex_irradiance, issue 11 sec. 2: "vertices use it
where it pays"): error against every receiver evaluated exactly.

The receivers are what the Blender job's vertices mode makes of a mesh with flat faces (CORNER domain): one
per face corner, the face's normal, the one-sided limit towards the face's centroid. Scenes: a subdivided
floor with a rotated block standing on it (its foot crosses the lattice between nodes and through nodes), a
floor under thin bars lit by a small bright light (shadow lines narrower than the node spacing), a floor
facing a chequerboard wall, and a subdivided Cornell box with a smooth radiance.
"""

from __future__ import annotations

import numpy as np
import pytest

from hemisphere_local_pass.core import adaptive_vertices as av
from hemisphere_local_pass.core import irradiance
from hemisphere_local_pass.core.adaptive_vertices import adaptive_vertex_irradiance, lattice_breaks, lattices
from hemisphere_local_pass.scenes import cornell_box


class Mesh:
    """Polygons on a shared vertex table (as a Blender mesh), their radiance and receiver flags."""

    def __init__(self):
        self.index, self.verts, self.polys, self.rad, self.recv = {}, [], [], [], []

    def vid(self, p):
        key = tuple(round(float(x), 12) for x in p)
        if key not in self.index:
            self.index[key] = len(self.verts)
            self.verts.append(key)
        return self.index[key]

    def add(self, pts, radiance, receiver=False):
        self.polys.append([self.vid(p) for p in pts])
        self.rad.append(np.broadcast_to(np.asarray(radiance, dtype=float), (3,)))
        self.recv.append(receiver)

    def grid(self, corners, nu, nv, radiance, receiver=True):
        c = np.asarray(corners, dtype=float)
        for i in range(nu):
            for j in range(nv):
                def at(s, t):
                    return (1 - t) * ((1 - s) * c[0] + s * c[1]) + t * ((1 - s) * c[3] + s * c[2])
                r = radiance(i, j) if callable(radiance) else radiance
                self.add([at(i / nu, j / nv), at((i + 1) / nu, j / nv), at((i + 1) / nu, (j + 1) / nv),
                          at(i / nu, (j + 1) / nv)], r, receiver)

    def scene(self):
        from hemisphere_local_pass.core import Scene

        return Scene.from_polygons(np.array(self.verts), self.polys, np.array(self.rad))

    def receivers(self, only_flagged=True):
        """CORNER-domain receivers ``(points, normals, limits, polygons)`` of the flagged polygons."""
        v = np.array(self.verts)
        P, N, U, G = [], [], [], []
        for i, poly in enumerate(self.polys):
            if only_flagged and not self.recv[i]:
                continue
            c = v[poly]
            n = np.cross(c[1] - c[0], c[2] - c[0])
            n /= np.linalg.norm(n)
            cen = c.mean(axis=0)
            for p in c:
                u = cen - p
                u -= (u @ n) * n
                P.append(p)
                N.append(n)
                U.append(u / np.linalg.norm(u))
                G.append(i)
        return np.array(P), np.array(N), np.array(U), np.array(G)


def quad(x0, x1, y0, y1, z):
    return [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]


def down(pts):
    return list(pts)[::-1]


def block_on_floor():
    """A floor of 32 × 32 cells with a block (rotated 20°) standing on it, a light above, a sky: the block's
    foot cuts the floor's lattice, through nodes where a corner of the block sits on one."""
    m = Mesh()
    m.grid(quad(0, 1, 0, 1, 0.0), 32, 32, 0.0)
    m.add(down(quad(0.2, 0.3, 0.6, 0.7, 1.2)), 40.0)
    m.add(down(quad(-3, 4, -3, 4, 3.0)), 0.5)
    a = np.radians(20.0)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    # a corner exactly on the node (12, 12), the rest between nodes
    foot = np.array([[0.0, 0.0], [0.22, 0.0], [0.22, 0.18], [0.0, 0.18]]) @ rot.T + [12 / 32, 12 / 32]
    h = 0.25
    m.add([(x, y, h) for x, y in foot], 0.0)
    for k in range(4):
        (x0, y0), (x1, y1) = foot[k], foot[(k + 1) % 4]
        m.add([(x0, y0, 0.0), (x1, y1, 0.0), (x1, y1, h), (x0, y0, h)], 0.0)
    return m


def thin_bars():
    """A floor of 40 × 40 cells lit by a small bright light through bars 0.003 wide: penumbra lines about a
    tenth of the node spacing wide, from occluders no receiver sees."""
    m = Mesh()
    m.grid(quad(0, 1, 0, 1, 0.0), 40, 40, 0.0)
    m.add(down(quad(-0.6, -0.58, 0.49, 0.51, 1.0)), 200.0)
    m.add(down(quad(-3, 4, -3, 4, 3.0)), 0.3)
    for k in range(5):
        x = -0.25 + 0.031 * k
        m.add(quad(x, x + 0.003, -1, 2, 0.5), 0.0)
        m.add(down(quad(x, x + 0.003, -1, 2, 0.5)), 0.0)
    return m


def chequer():
    """A floor of 32 × 32 cells facing a back wall whose radiosity is a chequerboard (1.0 / 0.05)."""
    m = Mesh()
    m.grid(quad(0, 1, 0, 1, 0.0), 32, 32, 0.0)
    m.grid([(0, 1, 0), (1, 1, 0), (1, 1, 1), (0, 1, 1)], 8, 8, lambda i, j: 1.0 if (i + j) % 2 else 0.05,
           receiver=False)
    return m


def cornell_smooth():
    """The Cornell box at 12 subdivisions (a 13-line lattice on every wall), radiance smooth over the walls."""
    box = cornell_box(subdivisions=12)
    m = Mesh()
    m.verts = [tuple(v) for v in box.vertices]
    m.polys = [list(p) for p in box.polygons]
    c = box.centroids()
    smooth = 0.1 + 0.05 * np.sin(3 * c[:, :1]) * np.cos(2 * c[:, 2:3]) * np.ones((1, 3))
    m.rad = list(np.where(box.emission.any(axis=1)[:, None], box.emission * 10, smooth))
    m.recv = [True] * len(m.polys)
    return m


SCENES = {"block on floor": block_on_floor, "thin bars": thin_bars, "chequerboard": chequer,
          "cornell": cornell_smooth}
_CACHE: dict = {}


def prepared(name):
    if name not in _CACHE:
        m = SCENES[name]()
        scene = m.scene()
        P, N, U, G = m.receivers()
        _CACHE[name] = (scene, P, N, U, G, irradiance(scene, P, N, limit_directions=U))
    return _CACHE[name]


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("rel", [1e-2, 1e-3])
def test_measured_error_within_tolerance(name, rel):
    scene, P, N, U, G, exact = prepared(name)
    tol = rel * exact.mean()
    H, st = adaptive_vertex_irradiance(scene, P, N, G, limit_directions=U, tolerance=tol, workers=1)
    err = np.abs(H - exact).max()
    assert err <= tol, f"{name}: max error {err / tol:.3f} x the tolerance"
    assert st.lattices >= 1 and st.lattice_receivers > 0.8 * len(P) * (name != "cornell") + 0
    assert st.exact_points < len(P)
    # a receiver marked exact carries its node's core value: its own exact value up to rounding
    np.testing.assert_allclose(H[st.exact_mask], exact[st.exact_mask], rtol=0, atol=1e-12 * exact.max())
    assert st.error_estimate == st.receiver_error.max()


@pytest.mark.parametrize("name", ["thin bars"])
def test_interpolation_does_skip_work(name):
    """The dense lattice interpolates: at 1e-2 under half its nodes are evaluated (42 %, 2026-12-08)."""
    scene, P, N, U, G, exact = prepared(name)
    nodes = len(np.unique(np.round(P * 1e9), axis=0))
    H, st = adaptive_vertex_irradiance(scene, P, N, G, limit_directions=U, tolerance=1e-2 * exact.mean(), workers=1)
    assert st.exact_points < 0.5 * nodes, (st.exact_points, nodes)


def test_tolerance_zero_is_bitwise_exact():
    scene, P, N, U, G, exact = prepared("block on floor")
    H, st = adaptive_vertex_irradiance(scene, P, N, G, limit_directions=U, tolerance=0.0, workers=1)
    np.testing.assert_array_equal(H, exact)
    assert st.exact_points == len(P) and st.exact_mask.all() and st.error_estimate == 0.0


def test_block_foot_breaks_the_lattice():
    """The block's foot crosses the floor's lattice: its squares are breaks, the node under the block's corner
    is on a segment (its corners' limits differ), and without the breaks interpolation crosses the foot."""
    scene, P, N, U, G, exact = prepared("block on floor")
    (floor,) = [la for la in lattices(scene, P, N, G) if abs(la.normal[2]) > 0.5]
    assert floor.shape == (33, 33)
    bx, by, on = lattice_breaks(scene, floor)
    q = np.array([12 / 32, 12 / 32, 0.0]) - floor.origin  # the node under the block's corner
    j, i = np.argmin(np.abs(floor.v - q @ floor.axes[1])), np.argmin(np.abs(floor.u - q @ floor.axes[0]))
    assert on[j, i] and on.sum() == 1 and bx.sum() > 20 and by.sum() > 20
    assert not bx[[0, -1]].any() and not by[:, [0, -1]].any()  # the room's edges are no breaks
    tol = 1e-2 * exact.mean()
    _, st = adaptive_vertex_irradiance(scene, P, N, G, limit_directions=U, tolerance=tol, workers=1)
    assert st.on_segment >= 4  # the 4 corners at node (12, 12)


def test_breaks_are_needed(monkeypatch):
    """Without the foot's breaks (and its node taken apart) the pass interpolates across the foot and errs
    beyond the tolerance: the reason for step 2 of the module docstring."""
    scene, P, N, U, G, exact = prepared("block on floor")
    tol = 1e-2 * exact.mean()

    def no_breaks(scene, lat):
        nv, nu = lat.shape
        return (np.zeros((nv, nu - 1), bool), np.zeros((nv - 1, nu), bool), np.zeros((nv, nu), bool))

    monkeypatch.setattr(av, "lattice_breaks", no_breaks)
    H, _ = adaptive_vertex_irradiance(scene, P, N, G, limit_directions=U, tolerance=tol, workers=1)
    assert np.abs(H - exact).max() > tol


def test_irregular_and_rotated_meshes():
    """A rotated grid is a lattice; a jittered one (no lattice lines) is evaluated exactly, every receiver."""
    m = Mesh()
    a = np.radians(33.0)
    ex, ey = np.array([np.cos(a), np.sin(a), 0.0]), np.array([-np.sin(a), np.cos(a), 0.0])
    m.grid([tuple(ex * 0 + ey * 0), tuple(ex), tuple(ex + ey), tuple(ey)], 12, 12, 0.0)
    m.add(down(quad(-3, 4, -3, 4, 2.0)), 1.0)
    scene = m.scene()
    P, N, U, G = m.receivers()
    (lat,) = lattices(scene, P, N, G)
    assert lat.shape == (13, 13) and len(lat.receivers) == len(P)
    rng = np.random.default_rng(3)
    jitter = {v: np.array([*rng.uniform(-0.01, 0.01, 2), 0.0]) for v in range(len(m.verts))}  # one per vertex
    m2 = Mesh()
    for poly in m.polys[:-1]:
        m2.add([tuple(np.array(m.verts[v]) + jitter[v]) for v in poly], 0.0, True)
    m2.add(down(quad(-3, 4, -3, 4, 2.0)), 1.0)
    s2 = m2.scene()
    P2, N2, U2, G2 = m2.receivers()
    assert lattices(s2, P2, N2, G2) == []
    H, st = adaptive_vertex_irradiance(s2, P2, N2, G2, limit_directions=U2, tolerance=1e-2, workers=1)
    assert st.exact_points == len(P2) and st.lattices == 0
    np.testing.assert_array_equal(H, irradiance(s2, P2, N2, limit_directions=U2))


def test_bad_input():
    scene, P, N, U, G, _ = prepared("chequerboard")
    with pytest.raises(ValueError, match="tolerance"):
        adaptive_vertex_irradiance(scene, P, N, G, tolerance=-1.0)
    with pytest.raises(ValueError, match="polygons"):
        adaptive_vertex_irradiance(scene, P, N, G.astype(float), tolerance=1.0)
    with pytest.raises(ValueError, match="input polygons"):
        adaptive_vertex_irradiance(scene, P, N, G + 10**6, tolerance=1.0)
    with pytest.raises(ValueError, match="limit_directions"):
        adaptive_vertex_irradiance(scene, P, N, G, limit_directions=U[:3], tolerance=1.0)
