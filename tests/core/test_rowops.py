"""The row-wise helpers agree exactly with the numpy expressions they replace (core/rowops.py)."""

import numpy as np
import pytest

from hemisphere_local_pass.core import rowops


@pytest.mark.parametrize("k", [0, 1, 3, 4, 5, 9])
@pytest.mark.parametrize("f", [0, 1, 257])
def test_rowops_match_numpy(f, k):
    rng = np.random.default_rng(f * 31 + k)
    b = rng.random((f, k)) < 0.3
    a = rng.normal(size=(f, k))
    v = rng.normal(size=(f, k, 3)) * 10.0 ** rng.integers(-6, 7, size=(f, 1, 1))
    assert np.array_equal(rowops.any_rows(b), b.any(axis=1))
    assert np.array_equal(rowops.sum_rows(b), b.sum(axis=1))
    expect = np.zeros(f) if k == 0 else np.cumsum(a, axis=1)[:, -1]   # left to right, as documented
    assert np.array_equal(rowops.sum_rows(a), expect)
    assert np.array_equal(rowops.max_abs_rows(v), np.zeros(f) if k == 0 else np.abs(v).max(axis=(1, 2)))
    idx = rng.integers(0, max(f, 1), size=2 * f) if f else np.zeros(0, dtype=np.int64)
    assert np.array_equal(rowops.take_rows(v, idx), v[idx])
    r, c = rowops.nonzero_rows(b)
    r0, c0 = np.nonzero(b)
    assert np.array_equal(r, r0) and np.array_equal(c, c0)
    eps = rng.random(f)[:, None] * 0.5
    assert np.array_equal(rowops.sides(a, eps), np.where(a > eps, 1, np.where(a < -eps, -1, 0)))
    assert rowops.sides(a, eps).dtype == np.int8
    if f and k:
        table = rng.normal(size=(f, k))
        i, j = rng.integers(0, f, size=50), rng.integers(0, k, size=50)
        assert np.array_equal(rowops.at2(table, i, j), table[i, j])
