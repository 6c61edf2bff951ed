"""The adaptive pass of pixels mode (``tolerance > 0``): H at the hit samples by
``core.adaptive_irradiance``, exactly only where interpolation would err by more than the tolerance.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import numpy as np

__all__ = ["adaptive_pixels"]


def adaptive_pixels(core_scene, pts, normals, src, hit, shape, k2, tolerance, progress, cancel, report):
    """H, exact mask and error estimate (all (m,) over the hit samples) by ``core.adaptive_irradiance``.

    ``tolerance`` is relative to the image's mean irradiance, which is estimated first from the exact
    values at the pixels of the adaptive pass's coarse grid (every ``DEFAULT_COARSE``-th pixel each way,
    first sub-sample): the absolute tolerance is ``tolerance * mean(H)`` per channel. Each of the k×k
    sub-samples of the pixels forms a regular image of its own and is interpolated separately.
    """
    from ..core import irradiance
    from ..core.adaptive import DEFAULT_COARSE, adaptive_irradiance

    h, w = shape
    n_samples = len(hit)
    p_all, n_all = np.zeros((n_samples, 3)), np.zeros((n_samples, 3))
    g_all = np.full(n_samples, -1, dtype=np.int64)
    p_all[hit], n_all[hit], g_all[hit] = pts, normals, src
    p_all, n_all, g_all = p_all.reshape(h, w, k2, 3), n_all.reshape(h, w, k2, 3), g_all.reshape(h, w, k2)
    ys = np.unique(np.r_[np.arange(0, h, DEFAULT_COARSE), h - 1])
    xs = np.unique(np.r_[np.arange(0, w, DEFAULT_COARSE), w - 1])
    probe = (g_all[ys[:, None], xs[None, :], 0] >= 0)
    py, px = np.nonzero(probe)
    mean = 0.0
    if len(py):
        mean = float(irradiance(core_scene, p_all[ys[py], xs[px], 0], n_all[ys[py], xs[px], 0], cancel=cancel).mean())
    absolute = tolerance * mean
    out_h = np.zeros((h, w, k2, 3))
    exact = np.zeros((h, w, k2))
    err = np.zeros((h, w, k2))
    total = int(hit.sum())
    done = [0]
    for j in range(k2):
        def prog(d, _t, base=done[0]):
            if progress is not None:
                progress(base + d, total)
        hj, st = adaptive_irradiance(core_scene, p_all[:, :, j], n_all[:, :, j], g_all[:, :, j],
                                     tolerance=absolute, progress=prog, cancel=cancel)
        out_h[:, :, j], exact[:, :, j], err[:, :, j] = hj, st.exact_mask, st.pixel_error
        done[0] += st.exact_points
    report.exact_points = int(exact.sum())
    report.tolerance = absolute
    report.error_estimate = float(err.max()) if err.size else 0.0
    sel = hit.reshape(h, w, k2)
    return out_h[sel], exact[sel], err[sel]
