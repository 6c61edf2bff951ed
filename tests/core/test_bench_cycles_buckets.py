"""``bench_cycles.radiance_buckets``: the bucketed Cycles recipe of the time-vs-error benchmark at ~170,000
polygons keeps each polygon's light-sampling weight within the square root of the bucket ratio per channel."""

import numpy as np
from benchmark_modules import load


def test_buckets_hold_one_reflectivity_and_levels_within_the_ratio():
    mod = load("bench_cycles")
    rng = np.random.default_rng(3)
    n = 5000
    wall = rng.integers(0, 3, n)
    rho = np.array([[0.7, 0.1, 0.1], [0.1, 0.7, 0.1], [0.7, 0.7, 0.7]])[wall]
    # a radiosity solution's colours: a wall's tint times a level spread over three decades
    tint = np.array([[1.0, 0.3, 0.3], [0.3, 1.0, 0.3], [1.0, 1.0, 0.9]])[wall]
    lum = tint * np.exp(rng.uniform(-7.0, 0.0, n))[:, None]
    lum[rng.random((n, 3)) < 0.05] = 0.0  # some channels dark
    lum[:7] = 0.0  # some polygons dark in every channel
    ratio = 1.05
    rhos, level, bucket = mod.radiance_buckets(rho, lum, ratio)
    assert bucket.shape == (n,) and level.shape == (len(rhos), 3) and rhos.shape == (len(rhos), 3)
    np.testing.assert_array_equal(rhos[bucket], rho)  # the Diffuse colour is exact
    lv = level[bucket]
    np.testing.assert_array_equal(lv == 0.0, lum == 0.0)  # no emission where there is none, and only there
    pos = lum > 0.0
    r = lum[pos] / lv[pos]  # the face attribute's value
    assert r.min() >= ratio**-0.5 * (1 - 1e-12) and r.max() <= ratio**0.5 * (1 + 1e-12)
    assert len(rhos) < n / 2  # it does bucket
    # polygons of one reflectivity whose channels share levels share a bucket
    same = (rho[:, None] == rho[None]).all(-1) & (lv[:, None] == lv[None]).all(-1)
    np.testing.assert_array_equal(same, bucket[:, None] == bucket[None])
