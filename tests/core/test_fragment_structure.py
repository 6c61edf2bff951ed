"""Structure prediction (core.fragment_structure): the visible fragments' fixed lines carried to nearby
receivers, checked against the exact core (irradiance, irradiance_gradient)."""

from __future__ import annotations

import numpy as np

from hemisphere_local_pass.core import Scene, irradiance, irradiance_gradient
from hemisphere_local_pass.core.fragment_structure import evaluate_structure, fragment_structure


def _penumbra_scene():
    """A square source (z = 2, facing down) over a square occluder (z = 1); receivers on z = 0."""
    V = np.array([[-0.5, -0.5, 2], [0.5, -0.5, 2], [0.5, 0.5, 2], [-0.5, 0.5, 2],
                  [-0.3, -0.3, 1], [0.3, -0.3, 1], [0.3, 0.3, 1], [-0.3, 0.3, 1]], float)
    return Scene.from_polygons(V, [[0, 3, 2, 1], [4, 5, 6, 7]], radiance=np.array([[1.0, 2.0, 3.0], [0, 0, 0]]))


def _receivers(k=20, seed=0):
    rng = np.random.default_rng(seed)
    P = np.column_stack([rng.uniform(-0.8, 0.8, k), rng.uniform(-0.8, 0.8, k), np.zeros(k)])
    return P, np.tile([0, 0, 1.0], (k, 1))


def test_structure_reproduces_irradiance_at_its_receiver():
    s = _penumbra_scene()
    P, N = _receivers()
    H = irradiance(s, P, N, workers=1)
    for i, st in enumerate(fragment_structure(s, P, N)):
        assert not st.ambiguous, st.reasons
        assert np.abs(st.H - H[i]).max() <= 1e-13 * H[i].max()
        assert np.abs(evaluate_structure(st, P[i:i + 1])[0] - H[i]).max() <= 1e-13 * H[i].max()


def test_structure_is_exact_a_small_step_away_without_an_event():
    s = _penumbra_scene()
    P, N = _receivers()
    step = np.array([1e-3, 0.7e-3, 0.0])
    H2 = irradiance(s, P + step, N, workers=1)
    for i, st in enumerate(fragment_structure(s, P, N)):
        got = evaluate_structure(st, (P[i] + step)[None])[0]
        assert np.abs(got - H2[i]).max() <= 1e-12 * H2[i].max()


def test_structure_derivative_agrees_with_the_gradient():
    s = _penumbra_scene()
    P, N = _receivers(8, seed=3)
    G = irradiance_gradient(s, P, N)
    h = 1e-5
    for i, st in enumerate(fragment_structure(s, P, N)):
        fd = np.stack([(evaluate_structure(st, (P[i] + h * e)[None])[0]
                        - evaluate_structure(st, (P[i] - h * e)[None])[0]) / (2 * h) for e in np.eye(3)], axis=1)
        assert np.abs(fd - G[i]).max() <= 1e-7 * np.abs(G[i]).max()


def test_structure_differs_across_a_visibility_event():
    # from the umbra's centre to far outside the shadow: the occluder's whole shadow leaves the source
    s = _penumbra_scene()
    P, N = np.array([[0.0, 0.0, 0.0]]), np.array([[0, 0, 1.0]])
    st = fragment_structure(s, P, N)[0]
    far = np.array([[2.0, 0.0, 0.0]])
    assert np.abs(evaluate_structure(st, far)[0] - irradiance(s, far, N, workers=1)[0]).max() > 1e-3
