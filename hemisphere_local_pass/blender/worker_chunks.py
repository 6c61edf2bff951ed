"""A job's chunks on a pool of worker processes (:class:`..core.parallel.WorkerPool`), results the
same bits as in one process.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

from .chunk_evaluation import evaluate_chunk
from .job_report import JobStep

__all__ = ["compute_on_workers"]


def compute_on_workers(exported, points, normals, limit, ck, todo, workers, prog, cancel, tolerance=0.0):
    """The job's chunks on a pool of ``workers`` processes: each chunk is the same core call as in one
    process (so the same bits), several at once (one parent thread each, which only waits), results
    saved in this thread as they finish. ``progress`` and ``cancel`` run in this thread only (they may
    touch bpy); cancel, Ctrl-C, an error or closing the generator kill the pool at once. A generator:
    yields a :class:`JobStep` at every poll (``POLL_SECONDS``), finished chunks or not."""
    import concurrent.futures as cf
    import threading

    from ..core import Cancelled
    from ..core.parallel import POLL_SECONDS, WorkerDied, job_pool

    m, chunk = len(points), ck.chunk
    stop = threading.Event()
    pool, owned = job_pool(workers)  # the caller's kept pool (a render's bands, frames) or one for this job

    def one(c):
        s, e = c * chunk, min(m, (c + 1) * chunk)
        lim = None if limit is None else limit[s:e]
        return evaluate_chunk(exported, points[s:e], normals[s:e], lim, None, stop.is_set, pool, tolerance)

    threads = cf.ThreadPoolExecutor(max_workers=workers, thread_name_prefix="hlp-job")
    inflight = {}
    queue = list(reversed(todo))
    try:
        while queue or inflight:
            while queue and len(inflight) < workers:
                c = queue.pop()
                inflight[threads.submit(one, c)] = c
            finished, _ = cf.wait(list(inflight), timeout=POLL_SECONDS, return_when=cf.FIRST_COMPLETED)
            for fut in sorted(finished, key=inflight.get):
                if isinstance(fut.exception(), Cancelled) and isinstance(pool.failure, WorkerDied):
                    raise pool.failure  # another chunk's worker died and stopped the pool: say that
                c = inflight.pop(fut)
                s, e = c * chunk, min(m, (c + 1) * chunk)
                ck.h[s:e], ck.fsum[s:e], ck.bound[s:e] = fut.result()
                ck.done[c] = True
                ck.save()
                prog.advance(e - s)
            yield JobStep(prog.base, m)  # every poll: a modal caller returns to Blender's event loop (Esc)
            if cancel is not None and cancel():
                raise Cancelled("local pass cancelled")
    except BaseException:
        stop.set()
        pool.kill(reap=owned)  # a kept pool's owner reaps it (Esc does not wait for niced workers to exit)
        threads.shutdown(wait=True, cancel_futures=True)
        raise
    threads.shutdown(wait=True)
    if owned:
        pool.shutdown(wait=True)
