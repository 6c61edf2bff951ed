"""A job's receivers evaluated chunk by chunk, checkpointed (:mod:`.checkpoint`), in this process or
on worker processes (:mod:`.worker_chunks`); a generator yielding a :class:`.job_report.JobStep`
at every chunk boundary.

Receivers per chunk are ``clip(ceil(m / CHUNKS_PER_JOB), MIN_CHUNK, MAX_CHUNK)`` (a function of the
job only, so a resumed run computes the same chunks and the same bits).

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import math

import numpy as np

from .checkpoint import Checkpoint
from .chunk_evaluation import evaluate_chunk, prepare
from .job_report import JobStep, stage
from .worker_chunks import compute_on_workers

__all__ = ["CHUNKS_PER_JOB", "MAX_CHUNK", "MAX_ELEMENTS", "MIN_CHUNK", "MIN_POOL_POINTS", "ChunkProgress",
           "chunk_size", "compute_chunks"]

#: Receivers per chunk are ``clip(ceil(m / CHUNKS_PER_JOB), MIN_CHUNK, MAX_CHUNK)``: few enough
#: checkpoint writes, small enough that an interruption loses little.
CHUNKS_PER_JOB = 100
MIN_CHUNK = 64
MAX_CHUNK = 4096
#: Largest (receivers x input polygons) form-factor block per chunk (32 MB of float64).
MAX_ELEMENTS = 2**22
#: a job starts worker processes only for at least this many receivers (a worker costs ~0.15 s to start)
MIN_POOL_POINTS = 128


def chunk_size(m: int, n_input: int = 0) -> int:
    """Receivers per chunk: a function of the job only (receivers m, input polygons n_input), so a
    resumed run computes the same chunks. The dense (chunk, n_input) form-factor arrays stay below
    ``MAX_ELEMENTS`` entries."""
    size = min(MAX_CHUNK, max(MIN_CHUNK, math.ceil(m / CHUNKS_PER_JOB)))
    return int(max(1, min(size, MAX_ELEMENTS // max(n_input, 1))))


class ChunkProgress:
    """Maps chunk progress to ``progress(done, total)`` over the whole job."""

    def __init__(self, callback, total, already=0):
        self.callback = callback
        self.total = total
        self.base = already

    def inner(self, size):
        if self.callback is None:
            return None
        base = self.base

        def report(done, total):
            self.callback(base + int(round(size * done / max(total, 1))), self.total)

        return report

    def advance(self, size):
        self.base += size
        if self.callback is not None:
            self.callback(self.base, self.total)


def compute_chunks(exported, points, normals, limit, *, checkpoint_path, fingerprint, resume, progress, cancel, report,
                   tolerance=0.0):
    """Evaluate all receivers chunk by chunk with checkpointing -> the :class:`.checkpoint.Checkpoint`
    (``h (m, 3)``, ``fsum (m,)``, ``bound (m, 3)``). ``tolerance``: see :func:`.evaluate_chunk` (it
    belongs in ``fingerprint``)."""
    from ..core import Cancelled

    m = len(points)
    chunk = chunk_size(m, exported.scene.n_input)
    ck = Checkpoint(checkpoint_path, fingerprint, m, chunk)
    if resume and ck.load():
        report.resumed_points = int(sum(min(chunk, m - c * chunk) for c in np.flatnonzero(ck.done)))
    prog = ChunkProgress(progress, m, report.resumed_points)
    todo = [c for c in range(len(ck.done)) if not ck.done[c]]
    workers = report.workers if report.workers > 1 and m - report.resumed_points >= MIN_POOL_POINTS else 1
    report.workers = workers
    try:
        if todo:
            s0 = int(todo[0]) * chunk
            prepare(exported, points[s0:], normals[s0:], None if limit is None else limit[s0:], progress, cancel)
            stage(progress, f"computing {m - report.resumed_points} points")
        if workers > 1:
            yield from compute_on_workers(exported, points, normals, limit, ck, todo, workers, prog, cancel,
                                          tolerance)
            return ck
        for c in todo:
            if cancel is not None and cancel():
                raise Cancelled("local pass cancelled")
            s, e = c * chunk, min(m, (c + 1) * chunk)
            lim = None if limit is None else limit[s:e]
            ck.h[s:e], ck.fsum[s:e], ck.bound[s:e] = evaluate_chunk(exported, points[s:e], normals[s:e], lim,
                                                                    prog.inner(e - s), cancel, tolerance=tolerance)
            ck.done[c] = True
            ck.save()
            prog.advance(e - s)
            yield JobStep(prog.base, m)  # a chunk boundary: the caller may return to Blender's event loop
    except (KeyboardInterrupt, Cancelled):
        report.cancelled = True
        raise
    return ck
