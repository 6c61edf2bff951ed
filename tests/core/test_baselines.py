"""Baselines: hemicube, ray-traced form factors, Monte Carlo, unoccluded eq. 4."""

import numpy as np
import pytest

from hemisphere_local_pass.baselines import (
    delta_form_factors,
    hemicube,
    monte_carlo,
    raytraced_form_factors,
    unoccluded_form_factors,
)
from hemisphere_local_pass.core.scene import Scene
from hemisphere_local_pass.scenes import PAPER_SETTINGS, cornell_box

UP = np.array([[0.0, 0.0, 1.0]])
ORIGIN = np.zeros((1, 3))
# Howell's catalogue (issue 4): differential element to a parallel unit square, normal through a corner
PARALLEL_CORNER = 0.138531605994893
PERPENDICULAR = 0.055734197002554
EMITTER_VISIBLE = 0.179592352845580


def _square(z, x0, x1, y0, y1, down=True):
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], dtype=float)
    return v[::-1] if down else v


def _occluded_scene():
    """Issue 4's occluded case: emitter [-1, 1]^2 at z = 2 facing down, occluder [0, 1]^2 at z = 1."""
    v = np.concatenate([_square(2.0, -1, 1, -1, 1), _square(1.0, 0, 1, 0, 1)])
    return Scene.from_polygons(v, [[0, 1, 2, 3], [4, 5, 6, 7]], radiance=[[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])


@pytest.fixture(scope="module")
def box_receivers():
    box = cornell_box(**PAPER_SETTINGS["small"])
    rng = np.random.default_rng(42)
    p = rng.uniform(0.02, 0.98, (12, 3))
    p[:, 2] = rng.uniform(0.62, 0.97, 12)  # free space above the tall block
    n = rng.normal(size=(12, 3))
    scene = box.scene(radiance=np.where(box.emission > 0, box.emission, 0.3))
    return box, scene, p, n / np.linalg.norm(n, axis=1)[:, None]


def test_delta_form_factor_tables_match_the_paper():
    # the paper's "max FF sum" of the hemicube: 0.000217 at 50x50 and 0.000014 at 200x200
    assert delta_form_factors(50).size == 50 * 50 + 4 * 50 * 25
    assert abs(delta_form_factors(50).sum() - 1 - 2.17e-4) < 5e-7
    assert abs(delta_form_factors(200).sum() - 1 - 1.36e-5) < 5e-7


def test_unoccluded_matches_closed_forms():
    s = Scene.from_polygons(_square(1.0, 0, 1, 0, 1), [[0, 1, 2, 3]])
    np.testing.assert_allclose(unoccluded_form_factors(s, ORIGIN, UP)[0, 0], PARALLEL_CORNER, rtol=1e-13)
    wall = np.array([[0, 1, 0], [1, 1, 0], [1, 1, 1], [0, 1, 1]], dtype=float)
    s = Scene.from_polygons(wall, [[0, 1, 2, 3]])
    np.testing.assert_allclose(unoccluded_form_factors(s, ORIGIN, UP)[0, 0], PERPENDICULAR, rtol=1e-13)
    # a wall reaching below the horizon is clipped to it; a polygon in P's plane contributes 0
    wall2 = wall - [0, 0, 1] + np.array([0, 0, 1]) * np.array([[0], [0], [1], [1]])
    wall2[:2, 2] = -1.0
    s = Scene.from_polygons(np.concatenate([wall2, _square(0.0, 1, 2, 1, 2)]), [[0, 1, 2, 3], [4, 5, 6, 7]])
    f = unoccluded_form_factors(s, ORIGIN, UP)[0]
    np.testing.assert_allclose(f, [PERPENDICULAR, 0.0], rtol=1e-13, atol=0)


@pytest.mark.parametrize("res", [50, 200])
def test_hemicube_sum_in_closed_box_is_its_table(box_receivers, res):
    box, scene, p, n = box_receivers
    r = hemicube(scene, p, n, res, rng=1)
    # every pixel sees some polygon: the sum is exactly the table's sum
    np.testing.assert_allclose(r.form_factors.sum(axis=1), delta_form_factors(res).sum(), rtol=1e-12)
    assert (r.form_factors >= 0).all()


def test_hemicube_converges_to_exact_factors():
    s = _occluded_scene()
    errs = []
    for res in (50, 200):
        f = hemicube(s, ORIGIN, UP, res, rng=3).form_factors[0]
        errs.append(np.abs(f - [EMITTER_VISIBLE, PARALLEL_CORNER]).max())
    assert errs[0] < 5e-3 and errs[1] < 1e-3 and errs[1] < errs[0]
    # the receiver's own plane: a polygon containing P covers nothing
    floor = Scene.from_polygons(_square(0.0, -1, 1, -1, 1, down=False), [[0, 1, 2, 3]])
    assert hemicube(floor, ORIGIN, UP, 20).form_factors.sum() == 0.0


def test_hemicube_irradiance_uses_front_sides_only():
    s = _occluded_scene()
    r = hemicube(s, ORIGIN, UP, 100, rng=0)
    np.testing.assert_allclose(r.irradiance[0], np.pi * r.form_factors[0, 0] * np.array([1.0, 2.0, 3.0]))
    # seen from above, the emitter shows its back: no irradiance, same geometry
    r = hemicube(s, np.array([[0.0, 0.0, 3.0]]), -UP, 100, rng=0)
    assert r.form_factors[0, 0] > 0.1 and (r.irradiance == 0).all()


def test_monte_carlo_within_confidence_interval():
    s = _occluded_scene()
    n = 20000
    r = monte_carlo(s, np.repeat(ORIGIN, 3, axis=0), np.repeat(UP, 3, axis=0), n, rng=5)
    exact = np.array([EMITTER_VISIBLE, PARALLEL_CORNER])
    sigma = np.sqrt(exact * (1 - exact) / n)
    assert (np.abs(r.form_factors - exact) < 4.5 * sigma).all()
    h = np.pi * EMITTER_VISIBLE * np.array([1.0, 2.0, 3.0])  # H = π Σ L F
    assert (np.abs(r.irradiance - h) < 4.5 * r.stderr).all()
    expected = np.pi * np.sqrt(EMITTER_VISIBLE * (1 - EMITTER_VISIBLE) / n) * np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(r.stderr, np.broadcast_to(expected, (3, 3)), rtol=0.05)


def test_monte_carlo_closed_box_sums_to_one(box_receivers):
    box, scene, p, n = box_receivers
    r = monte_carlo(scene, p, n, 512, rng=2)
    np.testing.assert_allclose(r.form_factors.sum(axis=1), 1.0, atol=1e-12)


def test_raytraced_ff_exact_when_unoccluded_and_close_when_occluded():
    s = _occluded_scene()
    r = raytraced_form_factors(s, ORIGIN, UP, rays=2000, max_rays_per_polygon=2000, rng=4)
    assert r.form_factors[0, 1] == pytest.approx(PARALLEL_CORNER, rel=1e-13)  # nothing hides the occluder
    assert abs(r.form_factors[0, 0] - EMITTER_VISIBLE) < 0.01
    np.testing.assert_allclose(r.irradiance[0], np.pi * r.form_factors[0, 0] * np.array([1.0, 2.0, 3.0]))
    # alone, a polygon gets exactly its eq. 4 factor
    alone = Scene.from_polygons(_square(1.0, 0, 1, 0, 1), [[0, 1, 2, 3]])
    assert raytraced_form_factors(alone, ORIGIN, UP, rng=0).form_factors[0, 0] == pytest.approx(PARALLEL_CORNER,
                                                                                                rel=1e-13)


def test_baselines_agree_with_each_other_in_the_box(box_receivers):
    box, scene, p, n = box_receivers
    hc = hemicube(scene, p, n, 100, rng=0).form_factors
    rt = raytraced_form_factors(scene, p, n, rays=256, rng=0).form_factors
    mc = monte_carlo(scene, p, n, 4096, rng=0).form_factors
    assert np.abs(hc - mc).max() < 0.05
    assert np.abs(rt - mc).max() < 0.05
