"""The adaptive pass of pixels mode (``tolerance > 0``): H at the hit samples by
``core.adaptive_irradiance``, exactly only where interpolation would err by more than the tolerance.

The pass is one core call per sub-sample image, run in a thread of its own while the job keeps yielding
(:mod:`.core_thread`).

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import numpy as np

from .core_thread import in_thread

__all__ = ["adaptive_pixels"]


def adaptive_pixels(core_scene, pts, normals, src, hit, shape, k2, tolerance, progress, cancel, report):
    """H, exact mask and error estimate (all (m,) over the hit samples) by ``core.adaptive_irradiance``.

    ``tolerance`` is relative to the image's mean irradiance, which is estimated first from the exact
    values at the pixels of the adaptive pass's coarse grid (every ``DEFAULT_COARSE``-th pixel each way,
    first sub-sample): the absolute tolerance is ``tolerance * mean(H)`` per channel. Each of the k×k
    sub-samples of the pixels forms a regular image of its own and is interpolated separately.

    A generator (as :func:`.receiver_chunks.compute_chunks`, through :func:`.core_thread.in_thread`): yields
    ``JobStep(done, total)`` (``done``: exact evaluations so far, ``total``: the hit samples, an upper bound:
    most are interpolated) and returns ``(H (m, 3), exact (m,), error (m,))``; cancel raises ``core.Cancelled``.
    """

    def work(state, stop, pool):
        return _adaptive_work(core_scene, pts, normals, src, hit, shape, k2, tolerance, state, stop, pool)

    result = yield from in_thread(work, int(hit.sum()), progress, cancel, report.workers)
    h_hit, exact_hit, err_hit, exact_points, absolute, error_estimate = result
    report.exact_points = exact_points
    report.tolerance = absolute
    report.error_estimate = error_estimate
    return h_hit, exact_hit, err_hit


def _adaptive_work(core_scene, pts, normals, src, hit, shape, k2, tolerance, state, cancel, pool=None):
    """The core calls of :func:`adaptive_pixels` (in its thread): ``state["done"]`` follows the exact
    evaluations; ``cancel`` is the thread's stop event; ``pool`` the job's worker pool (None: this process
    only). Returns ``(H, exact, error, exact points,
    absolute tolerance, largest error estimate)``."""
    from ..core import irradiance
    from ..core.adaptive import DEFAULT_COARSE, FINAL_SHARE, SAMPLE_SHARE, adaptive_irradiance

    h, w = shape
    n_samples = len(hit)
    p_all, n_all = np.zeros((n_samples, 3)), np.zeros((n_samples, 3))
    g_all = np.full(n_samples, -1, dtype=np.int64)
    p_all[hit], n_all[hit], g_all[hit] = pts, normals, src
    p_all, n_all, g_all = p_all.reshape(h, w, k2, 3), n_all.reshape(h, w, k2, 3), g_all.reshape(h, w, k2)
    ys = np.unique(np.r_[np.arange(0, h, DEFAULT_COARSE), h - 1])
    xs = np.unique(np.r_[np.arange(0, w, DEFAULT_COARSE), w - 1])
    on = {"workers": 1} if pool is None else {"executor": pool}  # the same bits either way
    probe = (g_all[ys[:, None], xs[None, :], 0] >= 0)
    py, px = np.nonzero(probe)
    mean = 0.0
    if len(py):
        mean = float(irradiance(core_scene, p_all[ys[py], xs[px], 0], n_all[ys[py], xs[px], 0], cancel=cancel,
                                **on).mean())
    absolute = tolerance * mean
    out_h = np.zeros((h, w, k2, 3))
    exact = np.zeros((h, w, k2))
    err = np.zeros((h, w, k2))
    base = 0
    for j in range(k2):
        def prog(d, _t, base=base):
            state["done"] = base + d

        # the samples from the far field with SAMPLE_SHARE of the tolerance, the final ones (no interpolation
        # uses them) with FINAL_SHARE (core.adaptive steps 5-6; figures in docs/adaptive.md); their bounds in
        # the error_estimate layer
        hj, st = adaptive_irradiance(core_scene, p_all[:, :, j], n_all[:, :, j], g_all[:, :, j],
                                     tolerance=absolute, progress=prog, cancel=cancel, sample_share=SAMPLE_SHARE,
                                     final_share=FINAL_SHARE, **on)
        out_h[:, :, j], exact[:, :, j], err[:, :, j] = hj, st.exact_mask, st.pixel_error
        base += st.exact_points
    sel = hit.reshape(h, w, k2)
    return (out_h[sel], exact[sel], err[sel], int(exact.sum()), absolute,
            float(err.max()) if err.size else 0.0)
