"""Monte Carlo local pass: cosine-weighted hemisphere sampling with ray casting.

With directions drawn with density ``cos θ / π`` the form factor of polygon i is the probability
that a ray from P hits it first, and the irradiance ``H = ∫ L cos θ dω = π Σ L_i F_i`` is π times the
mean radiance of the hits: ``F_i ≈ hits_i / n`` and ``H ≈ π mean(L)``, unbiased, with standard error
``π std(L) / sqrt(n)`` (the returned ``stderr``; a 95 % confidence interval is ± 1.96 stderr).
"""

from __future__ import annotations

import numpy as np

from ..core.raycast import build_bvh, cast_rays
from .hemicube import _frames
from .result import BaselineResult

__all__ = ["cosine_directions", "monte_carlo"]


def cosine_directions(normals: np.ndarray, samples: int, rng) -> np.ndarray:
    """``(m, samples, 3)`` unit directions with density cos θ / π about unit ``normals (m, 3)``.

    Malley's method: uniform points on the unit disk lifted to the hemisphere.
    """
    m = len(normals)
    u1 = rng.random((m, samples))
    u2 = rng.random((m, samples))
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    z = np.sqrt(np.maximum(0.0, 1.0 - u1))
    t1, t2 = _frames(normals, np.zeros(m))
    return ((r * np.cos(phi))[..., None] * t1[:, None, :] + (r * np.sin(phi))[..., None] * t2[:, None, :]
            + z[..., None] * normals[:, None, :])


def monte_carlo(scene, points, normals, samples: int = 256, *, rng=None, bvh=None,
                max_rays: int = 2**18) -> BaselineResult:
    """Monte Carlo form factors and irradiance with ``samples`` cosine-weighted rays per receiver.

    Args:
        scene: core Scene; points, normals: (m, 3) receivers and their normals.
        samples: rays per receiver.
        rng: numpy Generator or seed. bvh: a prebuilt :func:`~..core.raycast.build_bvh` of the scene.
        max_rays: rays cast per batch (memory bound, see :mod:`..core.raycast`).

    Returns:
        :class:`BaselineResult`: ``form_factors (m, n_input)``, ``irradiance (m, 3)`` (``π Σ L F``, front
        sides lit unless double sided) and its ``stderr (m, 3)``.
    """
    p_all = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n_all = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    n_all = n_all / np.linalg.norm(n_all, axis=1, keepdims=True)
    m = len(p_all)
    samples = int(samples)
    if samples < 2:
        raise ValueError(f"samples must be >= 2, got {samples}")
    rng = np.random.default_rng(rng)
    bvh = build_bvh(scene) if bvh is None else bvh
    ff = np.zeros((m, scene.n_input))
    mean = np.zeros((m, 3))
    err = np.zeros((m, 3))
    step = max(1, max_rays // samples)
    for s in range(0, m, step):
        e = min(s + step, m)
        c = e - s
        d = cosine_directions(n_all[s:e], samples, rng).reshape(-1, 3)  # (c * samples, 3)
        o = np.repeat(p_all[s:e], samples, axis=0)
        h = cast_rays(scene, o, d, bvh=bvh)
        hit = h.hit
        rows = np.repeat(np.arange(c), samples)
        np.add.at(ff, (s + rows[hit], h.source[hit]), 1.0 / samples)
        lit = hit & (h.front | scene.double_sided)
        val = np.zeros((c * samples, 3))
        val[lit] = scene.poly_radiance[h.polygon[lit]]
        val = np.pi * val.reshape(c, samples, 3)  # H = π E[L] under cosine-weighted sampling
        mean[s:e] = val.mean(axis=1)
        err[s:e] = val.std(axis=1, ddof=1) / np.sqrt(samples)
    return BaselineResult(ff, mean, err)
