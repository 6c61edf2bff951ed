"""A long core call in a thread of its own, while the job's generator keeps yielding to Blender.

The adaptive passes (pixels: :mod:`.adaptive_pixels`, vertices: :mod:`.adaptive_vertices`) are one core
call each, a quadtree of batches of exact evaluations with no chunk boundary of the job's own inside it. So
that a modal operator can still return to Blender's event loop while it runs (as it does between the exact
path's chunks), the call runs in a thread ("hlp-adaptive") and :func:`in_thread` is a generator that yields
a :class:`.job_report.JobStep` every :data:`POLL_SECONDS` meanwhile. The same core calls in the same order as
in one thread: the same bits.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import threading

from .job_report import JobStep

__all__ = ["POLL_SECONDS", "in_thread"]

#: Seconds between two steps while the pass runs (the exact path's pool polls as often:
#: ``core.parallel.POLL_SECONDS``); Esc and ``cancel()`` are seen within that.
POLL_SECONDS = 0.05


def in_thread(work, total, progress, cancel, workers):
    """Run ``work(state, stop, pool)`` in a thread; yield ``JobStep(state["done"], total)`` meanwhile; return its
    result.

    ``work`` sets ``state["done"]`` as it goes (exact evaluations so far; ``total`` is an upper bound), checks
    ``stop()`` (the thread's stop event, the core's ``cancel``) and runs its core calls on ``pool`` (the job's
    worker pool, None with one worker). ``progress(done, total)`` and ``cancel()`` run in the caller's thread
    only (they may touch bpy). ``cancel()`` returning True, Ctrl-C, an error or closing the generator stop the
    thread at the core's next chunk and wait for it; cancel raises ``core.Cancelled``.
    """
    from ..core import Cancelled
    from ..core.parallel import job_pool

    # the pool is picked up here, in the caller's thread: a render's kept pool (PoolKeeper.scope) is
    # thread-local, and the pass's thread would otherwise start a pool per core call site
    pool, owned = job_pool(workers) if workers > 1 else (None, False)
    stop = threading.Event()
    # waited on instead of Thread.join(timeout): on Python 3.11 a KeyboardInterrupt inside join()
    # marks the still running thread as stopped (threading's bpo-45274 handler), so the next join()
    # returns at once and the interpreter may exit under the running thread (measured: a segfault)
    finished = threading.Event()
    state = {"done": 0, "result": None, "error": None}

    def run():
        try:
            state["result"] = work(state, stop.is_set, pool)
        except BaseException as exc:  # raised again in the caller's thread
            state["error"] = exc
        finally:
            finished.set()

    thread = threading.Thread(target=run, name="hlp-adaptive", daemon=True)
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
    return state["result"]


def _wait(finished):
    """Wait for the thread to see its stop event (at the core's next chunk, a fraction of a second):
    a further Ctrl-C meanwhile does not leave it running under the caller."""
    while True:
        try:
            finished.wait()
            return
        except KeyboardInterrupt:
            continue
