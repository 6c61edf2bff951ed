"""The adaptive pass of pixels mode (``tolerance > 0``): H at the hit samples by
``core.adaptive_irradiance``, exactly only where interpolation would err by more than the tolerance.

The pass is one core call per sub-sample image, each a quadtree of batches of exact evaluations:
no chunk boundary of the job's own falls inside it. So that a modal operator can still return to
Blender's event loop while it runs (as it does between the exact path's chunks), the core calls run
in a thread of their own and :func:`adaptive_pixels` is a generator that yields a
:class:`.job_report.JobStep` every ``POLL_SECONDS`` meanwhile. The same core calls in the same order
as in one thread: the same bits.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import threading

import numpy as np

from .job_report import JobStep

__all__ = ["POLL_SECONDS", "adaptive_pixels"]

#: Seconds between two steps while the pass runs (the exact path's pool polls as often:
#: ``core.parallel.POLL_SECONDS``); Esc and ``cancel()`` are seen within that.
POLL_SECONDS = 0.05


def adaptive_pixels(core_scene, pts, normals, src, hit, shape, k2, tolerance, progress, cancel, report):
    """H, exact mask and error estimate (all (m,) over the hit samples) by ``core.adaptive_irradiance``.

    ``tolerance`` is relative to the image's mean irradiance, which is estimated first from the exact
    values at the pixels of the adaptive pass's coarse grid (every ``DEFAULT_COARSE``-th pixel each way,
    first sub-sample): the absolute tolerance is ``tolerance * mean(H)`` per channel. Each of the k×k
    sub-samples of the pixels forms a regular image of its own and is interpolated separately.

    A generator (as :func:`.receiver_chunks.compute_chunks`): the core calls run in a thread
    ("hlp-adaptive") while this generator, in the caller's thread, yields ``JobStep(done, total)``
    every :data:`POLL_SECONDS` (``done``: exact evaluations so far, ``total``: the hit samples, an
    upper bound: most are interpolated) and returns ``(H (m, 3), exact (m,), error (m,))``.
    ``progress(done, total)`` and ``cancel()`` run in the caller's thread only (they may touch
    bpy). ``cancel()`` returning True, Ctrl-C, an error or closing the generator stop the thread at
    the core's next chunk (its ``cancel`` is an event) and wait for it; cancel raises
    ``core.Cancelled``.
    """
    from ..core import Cancelled
    from ..core.parallel import job_pool

    total = int(hit.sum())
    # the pool is picked up here, in the caller's thread: a render's kept pool (PoolKeeper.scope) is
    # thread-local, and the pass's thread would otherwise start a pool per core call site
    pool, owned = job_pool(report.workers) if report.workers > 1 else (None, False)
    stop = threading.Event()
    # waited on instead of Thread.join(timeout): on Python 3.11 a KeyboardInterrupt inside join()
    # marks the still running thread as stopped (threading's bpo-45274 handler), so the next join()
    # returns at once and the interpreter may exit under the running thread (measured: a segfault)
    finished = threading.Event()
    state = {"done": 0, "result": None, "error": None}

    def work():
        try:
            state["result"] = _adaptive_work(core_scene, pts, normals, src, hit, shape, k2, tolerance, state,
                                             stop.is_set, pool)
        except BaseException as exc:  # raised again in the caller's thread
            state["error"] = exc
        finally:
            finished.set()

    thread = threading.Thread(target=work, name="hlp-adaptive", daemon=True)
    thread.start()
    reported = None
    try:
        while True:
            finished.wait(POLL_SECONDS)
            done = state["done"]
            if progress is not None and done != reported:
                progress(done, total)
                reported = done
            if finished.is_set():
                break
            yield JobStep(done, total)  # the caller may return to Blender's event loop
            if cancel is not None and cancel():
                raise Cancelled("local pass cancelled")
    except BaseException:
        stop.set()
        if pool is not None:
            pool.kill(reap=owned)  # the running chunks stop now (a kept pool's owner reaps it)
        _wait(finished)
        raise
    finally:
        if pool is not None and owned and finished.is_set():
            pool.shutdown(wait=True)
    thread.join()  # it has finished: only its end is left
    if state["error"] is not None:
        raise state["error"]
    h_hit, exact_hit, err_hit, exact_points, absolute, error_estimate = state["result"]
    report.exact_points = exact_points
    report.tolerance = absolute
    report.error_estimate = error_estimate
    return h_hit, exact_hit, err_hit


def _wait(finished):
    """Wait for the thread to see its stop event (at the core's next chunk, a fraction of a second):
    a further Ctrl-C meanwhile does not leave it running under the caller."""
    while True:
        try:
            finished.wait()
            return
        except KeyboardInterrupt:
            continue


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
