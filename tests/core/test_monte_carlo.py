"""Agreement with an independent Monte Carlo estimate on random occluded scenes.

The reference is a brute-force ray caster written here (scenes_for_tests.nearest_hits: Möller–
Trumbore against every triangle, first hit wins) with cosine-weighted directions. A cosine-weighted
ray's first hit is polygon i with probability exactly F_i (the visible form factor), so the hit
count of polygon i is Binomial(N, F_i). The bound checked for every polygon is

    |F_mc - F| <= 4 sigma + 1/N,   sigma = sqrt(F (1 - F) / N),   N = 200,000 rays per point,

with F the implementation's value (the null hypothesis); the 1/N term covers the lattice of the
estimate when F is (nearly) 0. Each comparison fails by chance with probability ~6e-5; the seeds
are fixed, so the test is deterministic.

Also: F >= 0 and F never exceeds the unoccluded factor of the same polygon alone (a scene with
just that polygon), up to rounding: F <= F_alone (1 + 1e-12) + 1e-15.
"""

from __future__ import annotations

import numpy as np
import pytest
from scenes_for_tests import (
    Mesh,
    howell_parallel_corner,
    lambert_unoccluded,
    monte_carlo_form_factors,
    random_occluded_scene,
    random_polygon,
    receivers,
)

N_SAMPLES = 200_000
N_SCENES = 8


def mc_bound(F, n=N_SAMPLES):
    F = np.clip(F, 0.0, 1.0)
    return 4.0 * np.sqrt(F * (1.0 - F) / n) + 1.0 / n


def crosses_plane(c1, c2):
    """Whether polygon c2 has vertices strictly on both sides of c1's plane (and vice versa)."""
    n = np.cross(c1[1] - c1[0], c1[2] - c1[0])
    d = (c2 - c1[0]) @ n
    return d.min() < 0 < d.max()


# --------------------------------------------------------------------------------------------
# the machinery on its own


def test_machinery_mc_matches_analytic(rng):
    """The ray caster reproduces Howell's value and the exact occluded case within the bound."""
    rect = np.array([[0, 0, 1], [0, 1, 1], [1, 1, 1], [1, 0, 1]], dtype=np.float64)
    m = Mesh()
    m.add(rect)
    v, p = m.arrays()
    F = monte_carlo_form_factors(rng, v, p, np.zeros(3), np.array([0, 0, 1.0]), N_SAMPLES)
    want = howell_parallel_corner(1, 1, 1)
    assert abs(F[0] - want) <= mc_bound(want)

    m = Mesh()
    m.add(np.array([[-1, -1, 2], [-1, 1, 2], [1, 1, 2], [1, -1, 2]], dtype=np.float64))
    m.add(rect)
    v, p = m.arrays()
    F = monte_carlo_form_factors(rng, v, p, np.zeros(3), np.array([0, 0, 1.0]), N_SAMPLES)
    want = np.array([0.179592352845580, 0.138531605994893])
    assert np.all(np.abs(F - want) <= mc_bound(want)), (F, want)


def test_machinery_mc_matches_lambert_unoccluded(rng):
    for _ in range(5):
        pts, nrm = receivers(rng)
        c = random_polygon(rng, np.array([0.2, -0.1, 1.0]), 1.2)
        m = Mesh()
        m.add(c)
        v, p = m.arrays()
        for P, N in zip(pts, nrm, strict=True):
            want = lambert_unoccluded(P, N, c)
            F = monte_carlo_form_factors(rng, v, p, P, N, N_SAMPLES)
            assert abs(F[0] - want) <= mc_bound(want), (F[0], want)


def test_machinery_random_scenes_interpenetrate(rng):
    crossing = 0
    for _ in range(N_SCENES):
        mesh, verts, polys = random_occluded_scene(rng)
        cs = [verts[p] for p in polys]
        crossing += sum(crosses_plane(cs[i], cs[j]) and crosses_plane(cs[j], cs[i])
                        for i in range(len(cs)) for j in range(i + 1, len(cs)))
    assert crossing >= N_SCENES


# --------------------------------------------------------------------------------------------
# the implementation


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(N_SCENES))
def test_agrees_with_monte_carlo(core, seed):
    rng = np.random.default_rng(9000 + seed)
    mesh, verts, polys = random_occluded_scene(rng)
    pts, nrm = receivers(rng)
    scene = core.Scene.from_polygons(verts, polys, mesh.radiance_array())
    F = core.form_factors(scene, pts, nrm)
    assert F.shape == (len(pts), len(polys))
    occlusion_visible = False
    for k, (P, N) in enumerate(zip(pts, nrm, strict=True)):
        Fmc = monte_carlo_form_factors(rng, verts, polys, P, N, N_SAMPLES)
        unoccluded = np.array([lambert_unoccluded(P, N, verts[p]) for p in polys])
        occlusion_visible |= bool(np.any(np.abs(Fmc - unoccluded) > 3 * mc_bound(unoccluded)))
        bound = mc_bound(F[k])
        bad = np.abs(Fmc - F[k]) > bound
        assert not bad.any(), (
            f"seed {seed} receiver {k} P={P.tolist()} N={N.tolist()}: polygons {np.flatnonzero(bad).tolist()} "
            f"exact {F[k][bad].tolist()} vs MC {Fmc[bad].tolist()} (bound {bound[bad].tolist()})"
        )
        total = F[k].sum()
        assert abs(Fmc.sum() - total) <= mc_bound(total)
    # the test has power: ignoring occlusion would be detected in this scene
    assert occlusion_visible, f"seed {seed}: occlusion too weak to be seen by the Monte Carlo reference"


@pytest.mark.parametrize("seed", range(N_SCENES))
def test_never_exceeds_unoccluded(core, seed):
    rng = np.random.default_rng(9000 + seed)
    mesh, verts, polys = random_occluded_scene(rng)
    pts, nrm = receivers(rng)
    F = core.form_factors(core.Scene.from_polygons(verts, polys), pts, nrm)
    assert np.all(np.isfinite(F))
    assert F.min() >= 0.0
    assert np.all(F.sum(axis=1) <= 1.0 + 1e-10)
    for i, poly in enumerate(polys):
        alone = core.form_factors(core.Scene.from_polygons(verts, [poly]), pts, nrm)[:, 0]
        ref = np.array([lambert_unoccluded(P, N, verts[poly]) for P, N in zip(pts, nrm, strict=True)])
        np.testing.assert_allclose(alone, ref, rtol=1e-12, atol=1e-15,
                                   err_msg=f"seed {seed}: polygon {i} alone vs Lambert's contour integral")
        assert np.all(F[:, i] <= alone * (1 + 1e-12) + 1e-15), (
            f"seed {seed}: polygon {i}: occluded F {F[:, i].tolist()} > unoccluded {alone.tolist()}"
        )
