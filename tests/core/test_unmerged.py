"""Scenes whose polygons do not merge (issue 10: a curved mesh costs what it shows).

A UV sphere's faces are all in different planes, so every face is a merged face of its own and
the (face, volume) pairs of the culling's level 1 (:func:`.visibility.coverage`) are over n_o² per
receiver if built densely. They come from the scene's sparse lists (:class:`.culling.VolumePairs`):

* receivers inside a closed 512-face sphere see all of it: the form factors sum to 1 (closed form,
  to 1e-12: rounding of ~500 contour integrals), and equal the dense path's bit for bit;
* with a solid box and a free quad inside the sphere (occluders, a convex solid) the same holds;
* the sparse pairs are those of the dense path, in the same order;
* a chunk's traced peak memory for the pairs is output-sized (< 64 B a pair + 8 MB), and inside the
  sphere, where nothing hides anything, below 1/20 of the dense path's (measured 0.9 vs 88 MB);
  level 1 as a whole (pairs tested a block at a time) equals the dense path's with < 1/4 of its peak,
  also from outside, where front faces hide back faces.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from hemisphere_local_pass.core import Scene, form_factors, visibility
from hemisphere_local_pass.core.chunk import prepare_scene
from hemisphere_local_pass.core.visibility import _cluster_pairs, _cluster_pairs_dense, coverage, shadow_volumes
from hemisphere_local_pass.scenes import uv_sphere


def _with_occluders(v, polys):
    """The sphere plus a closed box (outward) and a free quad inside it."""
    lo, hi = np.array([-0.3, -0.2, -0.25]), np.array([0.1, 0.25, 0.2])
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    box = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    quad = np.array([[0.3, -0.4, 0.3], [0.6, -0.4, 0.3], [0.6, 0.1, 0.45], [0.3, 0.1, 0.45]])
    n = len(v)
    verts = np.concatenate([v, corners, quad])
    return verts, polys + [[n + i for i in f] for f in box] + [[n + 8, n + 9, n + 10, n + 11]]


def _receivers(m, seed=1):
    d = np.random.default_rng(seed).normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return 0.9 * d, -d                     # inside the sphere, facing the centre (outside the box)


@pytest.mark.parametrize("occluders", [False, True], ids=["sphere", "sphere+box+quad"])
def test_sphere_sums_to_one_and_equals_dense(monkeypatch, occluders):
    v, p = uv_sphere(32, 16)
    if occluders:
        v, p = _with_occluders(v, p)
    sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
    pts, nrm = _receivers(24)
    f = form_factors(sc, pts, nrm, workers=1)
    assert np.abs(f.sum(axis=1) - 1.0).max() < 1e-12          # closed sphere: sum F = 1
    if occluders:
        assert (f[:, 512:] > 0).any() and (f[:, :512] == 0).any()   # the box and quad hide something
    monkeypatch.setattr(visibility, "DENSE_COVERAGE", True)
    assert np.array_equal(form_factors(sc, pts, nrm, workers=1), f)


def test_sparse_pairs_are_the_dense_pairs_and_memory_is_bounded(monkeypatch):
    v, p = _with_occluders(*uv_sphere(32, 16))
    sc = Scene.from_polygons(v, p, np.full((len(p), 3), 0.5))
    occ = prepare_scene(sc)
    # inside receivers, and outside ones (where front faces hide back faces)
    d = _receivers(16)[1]
    for inside, pts, nrm in ((True, 0.9 * -d, d), (False, 3.0 * d, -d)):
        sv, table = shadow_volumes(occ, pts, nrm)
        out, peaks = [], []
        for fn in (_cluster_pairs, _cluster_pairs_dense):
            tracemalloc.start()
            out.append(fn(sv, table, occ))
            peaks.append(tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
        assert len(out[0][0]) and all(np.array_equal(a, b) for a, b in zip(*out))
        print(f"pairs {len(out[0][0])}, traced peak sparse {peaks[0] / 2**20:.1f} MB, dense {peaks[1] / 2**20:.1f} MB")
        # output-sized: the pairs as int64 (k, q), their concatenation and sort (measured 59 B a pair)
        assert peaks[0] < 64 * len(out[0][0]) + 8 * 2**20, peaks
        if inside:        # nothing hides anything: ~1/100 of the dense path's (measured 0.9 vs 88 MB)
            assert peaks[0] < peaks[1] / 20, peaks
        # level 1 as a whole, its pairs tested a block at a time (small blocks: many of them), equals the
        # dense path's, with a fraction of its peak (outside: measured 13 vs 97 MB at 16 receivers)
        res, peaks = [], []
        for dense in (False, True):
            monkeypatch.setattr(visibility, "DENSE_COVERAGE", dense)
            monkeypatch.setattr(visibility, "PAIR_BLOCK", 1 << 12 if not dense else visibility.PAIR_BLOCK)
            tracemalloc.start()
            res.append(coverage(sv, table, occ, pts))
            peaks.append(tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
        for f in ("cluster_covered", "k_ptr", "kq"):
            assert np.array_equal(getattr(res[0], f), getattr(res[1], f))
        print(f"coverage: traced peak sparse {peaks[0] / 2**20:.1f} MB, dense {peaks[1] / 2**20:.1f} MB")
        assert peaks[0] < peaks[1] / 4, peaks
