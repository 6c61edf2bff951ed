"""Tests of core/parallel.py: the batch entry points on worker processes and on a dask cluster.

* bit-identity: form factors and irradiance (constant and linear radiance, with one-sided limits) are
  the same bits for 1, 2 and 3 workers, a kept :class:`WorkerPool` and a dask ``LocalCluster``;
* workers import only the core (no bpy, no parent ``__main__``), and stop on cancel within a second
  leaving no process behind;
* a worker that dies fails the job with a clear :class:`WorkerDied`, not a hang.

A small ``budget`` makes many chunks out of few receivers, so the tests take seconds.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

import numpy as np
import pytest

from hemisphere_local_pass.core import Cancelled, Scene, form_factors, irradiance, parallel
from hemisphere_local_pass.core.parallel import WorkerDied, WorkerPool
from hemisphere_local_pass.scenes import cornell_box

BUDGET = 2**13  # 175 polygons x 4 vertex slots: chunks of 11 points


def _children() -> set:
    """Process ids whose parent is this process (Linux /proc)."""
    me = str(os.getpid())
    out = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[1] == me and fields[0] != "Z":
                out.add(int(entry))
    return out


@pytest.fixture(scope="module")
def box():
    return cornell_box(5)


@pytest.fixture(scope="module")
def receivers(box):
    """36 receivers on the box's polygons (4 chunks), the first 12 with a limit direction (in the tangent plane)."""
    rng = np.random.default_rng(20261201)
    i = rng.integers(0, box.n_polygons, 36)
    normals = box.normals()[i]
    points = box.centroids()[i] + 0.02 * np.cross(normals, rng.normal(size=(36, 3)))
    limit = np.zeros((36, 3))
    limit[:12] = np.cross(normals[:12], rng.normal(size=(12, 3)))
    return points, normals, limit


@pytest.fixture(scope="module")
def scenes(box):
    rng = np.random.default_rng(5)
    constant = box.scene(radiance=box.emission + 0.3 * box.reflectivity)
    corners = sum(len(p) for p in box.polygons)
    linear = Scene.from_polygons(box.vertices, box.polygons, corner_radiance=rng.uniform(0.0, 2.0, size=(corners, 3)))
    return {"constant": constant, "linear": linear}


def _all(scene, receivers, **kw):
    p, n, lim = receivers
    return (form_factors(scene, p, n, budget=BUDGET, **kw),
            irradiance(scene, p, n, budget=BUDGET, **kw),
            irradiance(scene, p, n, limit_directions=lim, budget=BUDGET, **kw))


@pytest.fixture(scope="module")
def serial(scenes, receivers):
    return {k: _all(s, receivers, workers=1) for k, s in scenes.items()}


def _same_bits(a, b):
    for x, y in zip(a, b):
        assert x.shape == y.shape
        assert np.array_equal(x.view(np.uint64), y.view(np.uint64)), np.abs(x - y).max()


@pytest.mark.parametrize("workers", [2, 3])
def test_bit_identical_for_any_number_of_workers(scenes, receivers, serial, workers):
    p, n, lim = receivers
    for kind in ("constant", "linear"):
        ff = form_factors(scenes[kind], p, n, budget=BUDGET, workers=workers)
        _same_bits([ff], serial[kind][:1])
    h = irradiance(scenes["linear"], p, n, limit_directions=lim, budget=BUDGET, workers=workers)
    _same_bits([h], serial["linear"][2:])


def _pids_of_chunks(n_chunks, **kw):
    """Which process computed each of ``n_chunks`` tiny chunks (run_chunks with ``eval`` of a stdlib call)."""
    pids = [None] * n_chunks

    def store(s, e, value):
        pids[s] = value

    parallel.run_chunks(eval, "__import__('os').getpid()", [(i, i + 1) for i in range(n_chunks)],
                        lambda s, e: (), store, key=threading.Event(), **kw)  # any weak-referenceable key
    return pids


def test_the_parent_computes_chunks_while_its_workers_start(scenes, box):
    me = os.getpid()
    pids = _pids_of_chunks(200, workers=2)
    # the workers take ~0.3 s to start; chunks of microseconds are done here meanwhile, but never the
    # last ones: more than two per worker are left for them
    assert pids.count(me) > 100 and me not in pids[:5] and len(set(pids) - {me}) >= 1, pids
    # an interactive parent (nice workers) leaves every chunk to its workers
    with WorkerPool(2, nice=5) as pool:
        pids = _pids_of_chunks(200, executor=pool)
    assert me not in pids and set(pids) <= set(pool.pids)
    # the same bits with many chunks (some computed here) as on one worker
    rng = np.random.default_rng(11)
    i = rng.integers(0, box.n_polygons, 300)
    n = box.normals()[i]
    p = box.centroids()[i] + 0.02 * np.cross(n, rng.normal(size=(300, 3)))
    for kind in ("constant", "linear"):
        one = irradiance(scenes[kind], p, n, budget=BUDGET, workers=1)
        _same_bits([irradiance(scenes[kind], p, n, budget=BUDGET, workers=2)], [one])


def test_a_kept_pool_serves_many_calls_and_gets_the_scene_once(scenes, receivers, serial):
    with WorkerPool(3) as pool:
        for kind in ("constant", "linear"):
            _same_bits(_all(scenes[kind], receivers, executor=pool), serial[kind])
        # each worker keeps the last SHARED_KEEP scenes it was sent, no more
        kept = [pool.submit(eval, f"len(__import__({parallel.__name__!r}, fromlist=['_SHARED'])._SHARED)")
                for _ in range(4)]
        assert all(1 <= f.result(timeout=30) <= parallel.SHARED_KEEP for f in kept)
    assert not (_children() & set(pool.pids))


def test_two_scenes_alternating_on_a_kept_pool_are_pickled_once_each(scenes, receivers, serial, monkeypatch):
    """The adaptive pass alternates two scenes (its samples' and its final samples' proxy scenes): the parent
    keeps both pickles (as the workers keep SHARED_KEEP scenes), so neither is pickled again."""
    tokens = []  # a pickle made again gets a new token
    real = parallel._payload
    monkeypatch.setattr(parallel, "_payload", lambda *a: tokens.append(real(*a)[0]) or real(*a))
    p, n, _ = receivers
    with WorkerPool(2) as pool:
        for _ in range(3):
            for kind in ("constant", "linear"):
                h = irradiance(scenes[kind], p, n, budget=BUDGET, executor=pool)
                _same_bits((h,), (serial[kind][1],))
    assert len(tokens) == 6 and len(set(tokens)) == 2, tokens
    assert not (_children() & set(pool.pids))


def test_default_is_every_core_and_small_jobs_stay_here(scenes, receivers, serial):
    assert parallel.default_workers() == len(os.sched_getaffinity(0))
    p, n, _ = receivers
    before = _children()
    # one chunk: no pool is started for it
    one = form_factors(scenes["constant"], p[:5], n[:5])
    assert np.array_equal(one, serial["constant"][0][:5])
    assert _children() == before
    with pytest.raises(ValueError, match="workers"):
        form_factors(scenes["constant"], p, n, workers=-1, budget=BUDGET)


def test_workers_import_only_the_core():
    with WorkerPool(1) as pool:
        modules = pool.submit(eval, "sorted(__import__('sys').modules)").result(timeout=30)
        main = pool.submit(eval, "getattr(__import__('sys').modules.get('__main__'), '__file__', None)").result(30)
    package = parallel.__name__.rsplit(".", 2)[0]
    ours = [m for m in modules if m.startswith(package + ".")]
    assert ours and all(m.startswith(package + ".core") for m in ours), ours
    assert not any(m == "bpy" or m.startswith(("bpy.", "mathutils", "__mp_main__")) for m in modules)
    assert main is None  # the worker ran `python -c`, not the parent's main script


def test_exceptions_in_a_worker_come_back_with_their_traceback():
    with WorkerPool(1) as pool:
        fut = pool.submit(int, "not a number")
        with pytest.raises(ValueError, match="not a number") as info:
            fut.result(timeout=30)
        assert "Traceback" in str(info.value.__cause__)
        assert pool.submit(abs, -3).result(timeout=30) == 3  # the worker lives on


def _cancel_after_first_progress():
    state = {"at": None}

    def progress(done, total):
        if state["at"] is None:
            state["at"] = time.monotonic()

    def cancel():
        return state["at"] is not None

    return state, progress, cancel


def test_cancel_stops_every_worker_within_a_second(scenes, receivers):
    p, n, _ = receivers
    big_p, big_n = np.repeat(p, 30, axis=0), np.repeat(n, 30, axis=0)  # 1,080 receivers, ~100 chunks
    before = _children()
    state, progress, cancel = _cancel_after_first_progress()
    with pytest.raises(Cancelled):
        form_factors(scenes["constant"], big_p, big_n, budget=BUDGET, workers=2, progress=progress, cancel=cancel)
    assert time.monotonic() - state["at"] < 1.0
    assert _children() == before  # killed and reaped

    with WorkerPool(2) as pool:
        state, progress, cancel = _cancel_after_first_progress()
        with pytest.raises(Cancelled):
            irradiance(scenes["linear"], big_p, big_n, budget=BUDGET, executor=pool, progress=progress, cancel=cancel)
        assert time.monotonic() - state["at"] < 1.0
        assert pool.failure is not None  # killed; the caller's shutdown (the with block) reaps it
    assert not (_children() & set(pool.pids))


def test_ctrl_c_stops_every_worker(scenes, receivers):
    p, n, _ = receivers
    big_p, big_n = np.repeat(p, 30, axis=0), np.repeat(n, 30, axis=0)
    before = _children()

    def progress(done, total):
        raise KeyboardInterrupt  # what SIGINT raises in the main thread while it waits for the workers

    with pytest.raises(KeyboardInterrupt):
        form_factors(scenes["constant"], big_p, big_n, budget=BUDGET, workers=2, progress=progress)
    assert _children() == before


def test_a_killed_worker_fails_the_job_with_a_clear_error(scenes, receivers):
    p, n, _ = receivers
    big_p, big_n = np.repeat(p, 30, axis=0), np.repeat(n, 30, axis=0)
    with WorkerPool(2) as pool:
        victim = pool.pids[0]

        def progress(done, total):
            if done and victim in _children():
                os.kill(victim, signal.SIGKILL)

        start = time.monotonic()
        with pytest.raises(WorkerDied, match=rf"worker process {victim} .*killed by SIGKILL"):
            form_factors(scenes["constant"], big_p, big_n, budget=BUDGET, executor=pool, progress=progress)
        assert time.monotonic() - start < 30
        with pytest.raises(WorkerDied):  # the pool stays failed
            pool.submit(abs, 1)
    assert not (_children() & set(pool.pids))  # killed by the job, reaped by the caller's shutdown


def test_a_worker_that_exits_or_cannot_start(monkeypatch):
    with WorkerPool(1) as pool:
        with pytest.raises(WorkerDied, match="exited with status 7"):
            pool.submit(os._exit, 7).result(timeout=30)
    monkeypatch.setenv("HLP_WORKER_PYTHON", "/nonexistent/python3")
    with pytest.raises(WorkerDied, match="HLP_WORKER_PYTHON"):
        WorkerPool(1)


def test_a_worker_with_another_numpy_is_refused(tmp_path):
    # a "python" that reports another numpy version: results would not be bit-identical
    fake = tmp_path / "python"
    code = "import numpy, sys; numpy.__version__ = '0.0'; exec(sys.argv.pop(1))"
    fake.write_text(f'#!/bin/sh\nexec {sys.executable} -c "{code}" "$2" "$3" "$4"\n')
    fake.chmod(0o755)
    with WorkerPool(1, python=str(fake)) as pool:
        with pytest.raises(WorkerDied, match="numpy 0.0"):
            pool.submit(abs, 1).result(timeout=30)


def test_the_worker_python_is_a_python():
    exe = parallel.worker_python()
    assert os.path.basename(exe).startswith("python"), exe
    assert os.path.realpath(exe) == os.path.realpath(sys.executable) or exe.startswith(sys.prefix)


@pytest.mark.slow
def test_bit_identical_on_a_dask_local_cluster(scenes, receivers, serial):
    """A dask.distributed LocalCluster of worker processes on loopback runs the same chunks."""
    import distributed  # in the core venv (scripts/envs.sh); the slow tests run there only

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None, silence_logs=50) as cluster, \
            distributed.Client(cluster) as client:
        ex = client.get_executor()
        for kind in ("constant", "linear"):
            _same_bits(_all(scenes[kind], receivers, executor=ex), serial[kind])
        # the scene went to the workers by scatter, once each
        info = client.run(lambda: sorted(sys.modules[parallel.__name__]._SHARED))
        assert all(1 <= len(v) <= parallel.SHARED_KEEP for v in info.values()), info


def test_threads_may_share_a_pool(scenes, receivers, serial):
    """The job runs several core calls on one pool at once (one thread each)."""
    results = {}
    with WorkerPool(2) as pool:
        threads = [threading.Thread(target=lambda k=k: results.__setitem__(k, _all(scenes[k], receivers,
                                                                                  executor=pool)))
                   for k in ("constant", "linear")]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=120)
    for kind in ("constant", "linear"):
        _same_bits(results[kind], serial[kind])


def test_any_executor_a_process_pool_gets_the_scene_on_demand(scenes, receivers, serial):
    """A plain ``ProcessPoolExecutor`` (no initializer): a worker without the scene answers that it misses
    it and the chunk comes back with it; the results are the same bits."""
    import concurrent.futures as cf
    import multiprocessing

    with cf.ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as ex:
        _same_bits(_all(scenes["constant"], receivers, executor=ex), serial["constant"])


def test_a_pool_keeper_gives_one_pool_to_many_jobs_and_leaves_no_process(scenes, receivers, serial):
    """PoolKeeper: the jobs in its scope share one pool (the scene is sent once), a cancel's kill is
    replaced by a new pool on the next job, close() reaps every worker; nice lowers the workers'
    priority."""
    p, n, _ = receivers
    keeper = parallel.PoolKeeper()
    before = _children()
    with keeper.scope(nice=3):
        first, owned = parallel.job_pool(2)
        again, owned_again = parallel.job_pool(2)
        assert first is again and not owned and not owned_again and keeper.started == 1
        _same_bits(_all(scenes["constant"], receivers, executor=first), serial["constant"])
        mine = os.nice(0)
        assert first.submit(os.nice, 0).result(timeout=30) == min(19, mine + 3)
        first.kill()  # what a cancelled job does to the pool
        replaced, _ = parallel.job_pool(2)
        assert replaced is not first and replaced.failure is None and keeper.started == 2
    own, owned = parallel.job_pool(1)  # outside a scope: the caller's own pool
    assert owned and own is not keeper.pool
    own.shutdown()
    keeper.close()
    assert keeper.pool is None and _children() == before
