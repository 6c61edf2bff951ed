"""The clustered first pass (emitted light from the elements, reflected light from clusters of them).

* closed scene, uniform ρ: total power = Φ_E / (1 − ρ) up to the stated ρ · unshot term (cluster points lie
  strictly inside elements, so their factors sum to 1 too);
* the stated fixed point with the two operators the solver used (element rows for the emission, cluster
  rows for the reflected light), to rounding;
* one element per cluster is the flat solver; clusters follow planes and materials; more clusters, less
  difference from the flat solution.
"""

from __future__ import annotations

import numpy as np
from test_first_pass import closed_room

from hemisphere_local_pass.first_pass import (
    ClusteredSolver,
    make_clusters,
    make_solver,
    patch_quadrature,
    shooter_form_factors,
    solve_radiosity,
)
from hemisphere_local_pass.scenes import cornell_box


def test_closed_box_total_power_with_clusters():
    scene, emission = closed_room(4)
    rho = 0.6
    tol = 1e-6
    r = solve_radiosity(scene, rho, emission, tolerance=tol, clusters=12)
    assert r.converged and r.unshot_fraction <= tol and 0 < r.clusters < scene.n_input
    e = r.emitted_power
    assert abs(r.back_face_power).max() <= 1e-12 * e.sum()
    assert abs(r.escaped_power).max() <= 1e-10 * e.sum()
    assert r.balance_error <= 1e-12
    total = r.total_power
    exact = e / (1 - rho)
    np.testing.assert_allclose(total, exact - rho * r.unshot_power / (1 - rho), rtol=1e-10)
    assert (np.abs(total / exact - 1) <= rho * tol + 1e-10).all()


def test_fixed_point_with_the_operators_used():
    box = cornell_box(4)
    scene = box.scene()
    s = make_solver(scene, box.reflectivity, box.emission, tolerance=1e-4, clusters=30)
    assert isinstance(s, ClusteredSolver)
    r = s.run()
    assert r.converged and r.cluster_shots > 0 and np.isfinite(r.cluster_error)
    area, cl = r.areas, s.clusters
    emitters = np.flatnonzero(box.emission.sum(axis=1) > 0)
    quad = patch_quadrature(scene, 2)
    fe = np.array([shooter_form_factors(scene, i, quadrature=quad) for i in emitters])   # (e, n)
    c_rows = np.array([s.cluster_form_factors(c) for c in range(cl.count)])              # (count, n)
    shot_e = np.pi * area[emitters, None] * (box.emission[emitters] - s.unshot_emitted[emitters])
    reflected_unshot = s.unshot - s.unshot_emitted
    held = np.pi * area[:, None] * (r.radiance - box.emission - reflected_unshot)        # reflected power shot
    shot_c = np.zeros((cl.count, 3))
    np.add.at(shot_c, cl.of[cl.members], held[cl.members])
    # points strictly inside an element: the rows of the clusters that shot sum to 1 (a cluster of floor
    # cells hidden under a block never gets light, and its point may lie there)
    assert np.abs(c_rows[shot_c.sum(axis=1) > 0].sum(axis=1) - 1).max() <= 1e-9
    received = fe.T @ shot_e + c_rows.T @ shot_c                                        # (n, 3) W
    lhs = r.radiance - box.emission
    rhs = box.reflectivity * received / (np.pi * area[:, None])
    np.testing.assert_allclose(lhs, rhs, rtol=0, atol=1e-12 * r.radiance.max())
    # the stated tolerance on what is left: the unshot reflected power is at most tol · Φ_E
    assert (np.pi * area @ reflected_unshot).sum() <= 1e-4 * r.emitted_power.sum() * (1 + 1e-9)


def test_one_element_per_cluster_is_the_flat_solver():
    box = cornell_box(2)
    scene = box.scene()
    flat = solve_radiosity(scene, box.reflectivity, box.emission, tolerance=1e-5, order=1)
    one = solve_radiosity(scene, box.reflectivity, box.emission, tolerance=1e-5, order=1, clusters=10**6)
    assert one.clusters == scene.n_input
    np.testing.assert_allclose(one.radiance, flat.radiance, rtol=0, atol=1e-12 * flat.radiance.max())


def test_clusters_follow_planes_and_materials():
    box = cornell_box(6)
    scene = box.scene()
    quad1 = patch_quadrature(scene, 1)
    cl = make_clusters(quad1, box.reflectivity, box.emission, 20, scene=scene)
    names = np.array(box.names)
    normals = scene.poly_normals[np.searchsorted(scene.poly_source, np.arange(scene.n_input))]
    for c in range(cl.count):
        mem = cl.members[cl.start[c]:cl.start[c + 1]]
        assert len(set(names[mem])) == 1                              # the light is never merged with the ceiling
        assert np.abs(normals[mem] - normals[mem[0]]).max() < 1e-9
        assert np.abs(box.reflectivity[mem] - box.reflectivity[mem[0]]).max() == 0
        assert cl.element[c] in mem
    assert (cl.of >= 0).all() and np.bincount(cl.of).min() >= 1


def test_more_clusters_closer_to_the_flat_solution():
    box = cornell_box(6)
    scene = box.scene()
    flat = solve_radiosity(scene, box.reflectivity, box.emission, tolerance=1e-3, order=1)
    lit = flat.radiance.sum(axis=1) > 1e-9
    diffs = []
    for k in (15, 60):
        r = solve_radiosity(scene, box.reflectivity, box.emission, tolerance=1e-3, order=1, clusters=k)
        d = np.abs(r.radiance - flat.radiance).sum(axis=1)[lit] / flat.radiance.sum(axis=1)[lit]
        diffs.append(np.average(d, weights=flat.areas[lit]))
        assert r.point_evaluations < flat.point_evaluations / 2
    assert diffs[1] < diffs[0]
