"""The procedural Cornell box (closed, oriented, the paper's sizes) and the radiosity first pass."""

from collections import Counter

import numpy as np
import pytest

from hemisphere_local_pass.core.raycast import cast_rays
from hemisphere_local_pass.scenes import PAPER_SETTINGS, camera_rays, cornell_box, radiosity
from hemisphere_local_pass.scenes.radiosity import centroid_form_factors, gathered_radiance


@pytest.fixture(scope="module")
def small():
    return cornell_box(**PAPER_SETTINGS["small"])


def _directed_edges(polys):
    return Counter((p[i], p[(i + 1) % len(p)]) for p in polys for i in range(len(p)))


def test_paper_sizes():
    assert cornell_box(**PAPER_SETTINGS["small"]).n_polygons == 175
    big = cornell_box(**PAPER_SETTINGS["large"])
    assert big.n_polygons == 9468
    assert abs(big.n_polygons - 9504) / 9504 < 0.01


@pytest.mark.parametrize("subdivisions", [1, 3, 5, 8])
def test_room_is_a_closed_oriented_manifold(subdivisions):
    box = cornell_box(subdivisions)
    room = [p for p, nm in zip(box.polygons, box.names, strict=True) if "block" not in nm]
    edges = _directed_edges(room)
    bad = [e for e, c in edges.items() if c != 1 or edges.get((e[1], e[0]), 0) != 1]
    assert not bad, f"edges not shared by exactly two oppositely oriented polygons: {bad[:5]}"
    for block in ("short block", "tall block"):
        polys = [p for p, nm in zip(box.polygons, box.names, strict=True) if nm == block]
        edges = _directed_edges(polys)
        open_edges = [e for e, c in edges.items() if c != 1 or edges.get((e[1], e[0]), 0) != 1]
        # only the bottom rim (standing on the floor) is open
        assert open_edges and all(box.vertices[list(e), 2].max() == 0.0 for e in open_edges)


def test_polygons_are_planar_convex_and_face_the_free_space(small):
    scene = small.scene()
    assert scene.n_polygons == scene.n_input == small.n_polygons and not scene.dropped
    normals, centres = small.normals(), small.centroids()
    np.testing.assert_allclose(normals, scene.poly_normals, atol=1e-12)
    room = np.array(["block" not in nm for nm in small.names])
    inward = np.einsum("nc,nc->n", normals, 0.5 - centres)
    assert (inward[room] > 0).all()
    for block in ("short block", "tall block"):
        sel = np.array([nm == block for nm in small.names])
        axis = small.vertices[np.unique(np.concatenate([small.polygons[i] for i in np.flatnonzero(sel)]))].mean(0)
        outward = np.einsum("nc,nc->n", normals[sel], centres[sel] - axis)
        assert (outward > 0).all()
    counts = Counter(small.names)
    assert counts["light"] >= 1 and set(counts) == {"floor", "ceiling", "light", "back wall", "front wall",
                                                   "left wall", "right wall", "short block", "tall block"}
    light = np.array([nm == "light" for nm in small.names])
    assert (small.emission[light] > 0).all() and (small.emission[~light] == 0).all()
    assert small.reflectivity[small.names.index("left wall"), 0] > small.reflectivity[small.names.index("left wall"), 1]


@pytest.mark.parametrize("subdivisions", [2, 5, 12])
def test_every_ray_from_the_free_space_hits_a_front_face(subdivisions):
    box = cornell_box(subdivisions, size=555.0)
    scene = box.scene()
    rng = np.random.default_rng(subdivisions)
    m = 20000
    # free space: above the tall block (z > 330) and left of both blocks (x < 80)
    o = rng.uniform(1.0, 554.0, (m, 3))
    o[: m // 2, 2] = rng.uniform(331.0, 554.0, m // 2)
    o[m // 2:, 0] = rng.uniform(1.0, 80.0, m - m // 2)
    d = rng.normal(size=(m, 3))
    # through exact room vertices (a ray through a block's corner may graze its back faces)
    room_vertices = np.unique(np.concatenate([p for p, nm in zip(box.polygons, box.names, strict=True)
                                              if "block" not in nm]))
    d[:500] = box.vertices[rng.choice(room_vertices, 500)] - o[:500]
    h = cast_rays(scene, o, d)
    assert h.hit.all(), f"{(~h.hit).sum()} rays escaped"
    assert h.front.all()


def test_form_factors_sum_to_one_inside(small):
    from hemisphere_local_pass.core import form_factors

    rng = np.random.default_rng(0)
    p = rng.uniform(0.02, 0.98, (20, 3))
    p[:, 2] = rng.uniform(0.61, 0.98, 20)
    n = rng.normal(size=(20, 3))
    f = form_factors(small.scene(), p, n / np.linalg.norm(n, axis=1, keepdims=True))
    np.testing.assert_allclose(f.sum(axis=1), 1.0, atol=1e-10)


def test_camera_rays_see_the_box(small):
    o, d = camera_rays(small, 16, 12)
    assert o.shape == d.shape == (192, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    assert ((o > 0) & (o < 1)).all()  # started inside the room
    h = cast_rays(small.scene(), o, d)
    assert h.hit.all() and h.front.all()
    names = {small.names[i] for i in h.source}
    assert {"back wall", "left wall", "right wall", "floor", "ceiling"} <= names
    assert "front wall" not in names
    left = h.source.reshape(12, 16)[6, 0]
    assert small.names[left] == "left wall"  # red on the left


def test_radiosity_white_furnace(small):
    # closed box, uniform reflectivity and emission: L = E / (1 - ρ) exactly, since every row of F sums to 1
    from hemisphere_local_pass.core import form_factors

    n = small.n_polygons
    geometric = form_factors(small.scene(), small.centroids(), small.normals())
    np.testing.assert_allclose(geometric.sum(axis=1), 1.0, atol=1e-10)
    lum = radiosity(small.vertices, small.polygons, np.full(n, 0.5), np.full(n, 2.0),
                    form_factor_matrix=geometric, iterations=100, tol=1e-14)
    np.testing.assert_allclose(lum, 4.0, rtol=1e-12)
    # front-side factors: patches under a block see only its back faces, their rows are 0
    f = centroid_form_factors(small.scene(), small.centroids(), small.normals(), dtype=np.float64)
    seen = f.sum(axis=1) > 0.5
    assert {small.names[i] for i in np.flatnonzero(~seen)} <= {"floor"}
    np.testing.assert_allclose(f[seen].sum(axis=1), 1.0, atol=1e-10)
    np.testing.assert_array_equal(f[~seen], 0.0)
    # the Cornell box itself: L >= E, coloured walls bleed their colour, finite and converged
    lum = radiosity(small.vertices, small.polygons, small.reflectivity, small.emission, form_factor_matrix=f)
    assert np.isfinite(lum).all() and (lum >= small.emission).all()
    red = lum[small.names.index("left wall")]
    assert red[0] > red[1] and red[0] > red[2]
    residual = lum - small.emission - small.reflectivity * (f @ lum)
    assert np.abs(residual).max() <= 1e-9 * lum.max()
    # one gather from the solved scene reproduces its own solution at the centres
    scene = small.scene(radiance=lum)
    again = gathered_radiance(scene, small.centroids(), small.normals(), small.reflectivity, small.emission)
    np.testing.assert_allclose(again, lum, rtol=1e-8, atol=1e-10 * lum.max())


def test_radiosity_validates():
    box = cornell_box(1)
    with pytest.raises(ValueError):
        radiosity(box.vertices, box.polygons, np.ones(box.n_polygons), box.emission,
                  form_factor_matrix=np.eye(box.n_polygons))
    with pytest.raises(ValueError):
        cornell_box(0)
