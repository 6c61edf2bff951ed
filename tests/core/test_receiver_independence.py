"""A receiver's exact value does not depend on the other receivers of its call or chunk, to the bit.

The batch entry points cut the receivers into chunks, and the visibility stage runs on a whole chunk at
once. A chunk-wide decision once reordered one receiver's terms because of another's geometry, and the
sums then moved in the last bit:

* sub-tile refinement ran only when some receiver of the chunk had a cut tile (found 2026-12-07: 10 of
  65,536 pixels of the 9,468-polygon 256² image moved by 1 ulp when the pixels were shuffled);
* one receiver with a one-sided limit put the whole chunk on the infinitesimal path (245 of 299
  receivers moved, by up to 1.3e-15).

The adaptive pass, tiles on a farm and the even cutting of chunks for workers rely on this property.
"""

from __future__ import annotations

import numpy as np
import pytest

from hemisphere_local_pass.core import form_factors, irradiance, irradiance_gradient
from hemisphere_local_pass.scenes import cornell_box


@pytest.fixture(scope="module")
def box():
    return cornell_box(35, block_detail=1.05)  # 9,468 polygons: tiles of several sub-tiles


@pytest.fixture(scope="module")
def receivers(box):
    """Points just off random polygons: some see cut tiles (behind the blocks), some do not."""
    rng = np.random.default_rng(20261207)
    i = rng.integers(0, box.n_polygons, 60)
    n = box.normals()[i]
    p = box.centroids()[i] + 0.02 * np.cross(n, rng.normal(size=(60, 3)))
    return p, n


def _bits(a):
    return a.view(np.uint64)


def test_a_receiver_alone_and_among_others(box, receivers):
    scene = box.scene(radiance=box.emission + 0.3 * box.reflectivity)
    p, n = receivers
    together = irradiance(scene, p, n, workers=1)
    reordered = np.empty_like(together)
    order = np.random.default_rng(1).permutation(len(p))
    reordered[order] = irradiance(scene, p[order], n[order], workers=1)
    ff_together = form_factors(scene, p, n, workers=1)
    alone = np.concatenate([irradiance(scene, p[j:j + 1], n[j:j + 1], workers=1) for j in range(len(p))])
    ff_alone = np.concatenate([form_factors(scene, p[j:j + 1], n[j:j + 1], workers=1) for j in range(len(p))])
    assert np.array_equal(_bits(alone), _bits(together)), np.flatnonzero((alone != together).any(axis=1))
    assert np.array_equal(_bits(reordered), _bits(together))
    assert np.array_equal(_bits(ff_alone), _bits(ff_together)), np.flatnonzero((ff_alone != ff_together).any(axis=1))


def test_another_receivers_limit_direction_changes_nothing(box, receivers):
    scene = box.scene(radiance=box.emission + 0.3 * box.reflectivity)
    p, n = receivers
    lim = np.zeros_like(p)
    lim[7] = np.cross(n[7], [0.3, 0.5, 0.8])
    lim[7] /= np.linalg.norm(lim[7])
    free = np.ones(len(p), dtype=bool)
    free[7] = False
    for fn in (irradiance, form_factors):
        plain = fn(scene, p, n, workers=1)
        mixed = fn(scene, p, n, limit_directions=lim, workers=1)
        assert np.array_equal(_bits(mixed[free]), _bits(plain[free])), fn.__name__
        # the receiver with the limit gets the value of a call of its own
        own = fn(scene, p[~free], n[~free], limit_directions=lim[~free], workers=1)
        assert np.array_equal(_bits(mixed[~free]), _bits(own)), fn.__name__


def test_another_receivers_limit_leaves_the_gradients_alone(box, receivers):
    scene = box.scene(radiance=box.emission + 0.3 * box.reflectivity)
    p, n = (a[:12] for a in receivers)
    lim = np.zeros_like(p)
    lim[3] = np.cross(n[3], [0.3, 0.5, 0.8])
    lim[3] /= np.linalg.norm(lim[3])
    plain = irradiance_gradient(scene, p, n)
    mixed = irradiance_gradient(scene, p, n, limit_directions=lim)
    free = ~lim.any(axis=1)
    assert np.array_equal(_bits(mixed[free]), _bits(plain[free]))


def test_repeated_receivers_are_evaluated_once_to_the_same_bits(box, receivers):
    """A mesh vertex's corners on one plane are the same receiver (once their idle limits are dropped,
    receivers.idle_limits_dropped): the core evaluates each distinct receiver once and copies its value, which
    by the property above is bit for bit what each copy's own evaluation gives. -0.0 and 0.0 are kept apart."""
    scene = box.scene(radiance=box.emission + 0.3 * box.reflectivity)
    p, n = (a[:20] for a in receivers)
    rep = np.r_[np.arange(20), [3, 3, 11, 0, 19, 11]]
    totals = []
    for fn in (irradiance, form_factors):
        distinct = fn(scene, p, n, workers=1)
        repeated = fn(scene, p[rep], n[rep], workers=1, progress=lambda done, total: totals.append(total))
        assert np.array_equal(_bits(repeated), _bits(distinct[rep])), fn.__name__
    assert set(totals) == {20}  # the distinct receivers only
    from hemisphere_local_pass.core.local_pass import _distinct_receivers

    q = np.array([[0.0, 1.0, 2.0], [-0.0, 1.0, 2.0], [0.0, 1.0, 2.0]])
    reps, copies = _distinct_receivers(q, np.ones_like(q), None)
    assert reps.tolist() == [0, 1] and copies.tolist() == [0, 1, 0]
    assert _distinct_receivers(q[:2], np.ones((2, 3)), None) == (None, None)
