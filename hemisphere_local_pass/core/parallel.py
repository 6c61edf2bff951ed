"""Every core, and beyond one machine: the chunks of a batch entry point on worker processes.

The batch entry points (:func:`.local_pass.form_factors`, :func:`.local_pass.irradiance`, ...) cut
their receivers into chunks fixed by the job (scene size, receiver count, memory budget — never by the
number of workers) and hand them to :func:`run_chunks`, which runs ``fn(shared, *args)`` per chunk

* in this process (``workers=1``, no executor: exactly today's loop),
* on a :class:`WorkerPool` of ``workers`` processes (the default: every core this process may use), or
* on any :class:`concurrent.futures.Executor` the caller passes — a ``ProcessPoolExecutor``, or a
  ``dask.distributed`` Client's ``get_executor()``, which runs the same chunks on a cluster.

Each chunk's result is stored under its own index, never by completion order, and a chunk computes the
same arithmetic on the same inputs wherever it runs: results are bit-identical for any number of
workers and any executor — given the same numpy and the same BLAS threading. :class:`WorkerPool`
workers inherit this process's environment; a dask nanny starts its workers with
``OPENBLAS_NUM_THREADS=1`` (``distributed.nanny.pre-spawn-environ``), which with numpy 1.24's
OpenBLAS moved the last bit of linear-radiance results: run the parent with the same setting there.

The shared object (the prepared scene, with the caches preparation left on it) is pickled once per
call site and reaches each worker once: a :class:`WorkerPool` sends it before a worker's first chunk,
a dask client scatters it to every worker (``broadcast``), and any other executor gets it back on
demand (a worker without it answers :data:`_MISS` and the chunk is resubmitted with it). Workers keep
the last :data:`SHARED_KEEP` shared objects.

:class:`WorkerPool` is a small executor of our own rather than ``multiprocessing``: its workers run a
real Python (:func:`worker_python`: inside Blender ``sys.executable`` may be Blender itself, or — Debian's
Blender 3.4 — whatever ``python3.11`` comes first on ``PATH``) with ``-c`` and import *only* this core
(the package around it is replaced by empty module stubs, so neither ``bpy`` nor the parent's
``__main__`` script is imported: ``multiprocessing``'s spawn would re-run the main script, which under
Blender is ``<blender string>`` or a script importing ``bpy``). Tasks and results travel as
length-prefixed pickles over the workers' stdin/stdout; the workers ignore SIGINT (the parent decides),
exit when their parent dies, and one task at a time per worker keeps a worker's memory at one chunk's.
Cancel (``cancel()``, Esc, Ctrl-C) kills the pool's processes at once (SIGKILL, reaped); a worker that
dies fails the job with :class:`WorkerDied` naming its exit status and the tail of its stderr.
"""

from __future__ import annotations

import collections
import concurrent.futures as cf
import contextlib
import itertools
import os
import pickle
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import uuid
import weakref
from collections.abc import Callable, Sequence

__all__ = ["Cancelled", "PoolKeeper", "WorkerDied", "WorkerPool", "default_workers", "job_pool", "run_chunks",
           "worker_python"]

#: shared objects (scenes) a worker keeps; older ones are dropped (bounded worker memory)
SHARED_KEEP = 2
#: a call makes its own pool only for at least this many chunks (starting a worker costs ~0.15 s of CPU:
#: Python, numpy and the core's imports); smaller calls run here, or on the caller's executor
MIN_POOL_CHUNKS = 4
#: the parent computes chunks while its pool's workers start only while a chunk takes less than this (s)
HELP_SECONDS = 0.2
#: how often the waiting parent polls ``cancel()`` (s)
POLL_SECONDS = 0.05
#: the answer of a worker that lacks the shared object (see :func:`_chunk_task`)
_MISS = "hemisphere_local_pass.parallel:missing-shared-object"
_HEADER = struct.Struct("!Q")  # frame length


class Cancelled(Exception):
    """Raised when the ``cancel`` callback of a batch entry point returns True."""


class WorkerDied(RuntimeError):
    """A worker process ended while the job needed it (killed, out of memory, crashed, failed to start)."""


def default_workers() -> int:
    """The cores this process may use (``os.sched_getaffinity`` where it exists, else ``os.cpu_count``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _resolve_workers(workers) -> int:
    if workers is None or workers == 0:
        return default_workers()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ValueError(f"workers must be a positive integer (0 or None: every core), got {workers!r}")
    return workers


def worker_python() -> str:
    """The Python interpreter that runs the workers.

    ``HLP_WORKER_PYTHON`` if set; else the interpreter of this process's own installation
    (``sys.prefix/bin/pythonX.Y``: the venv's python for the bpy module, Blender's bundled python,
    ``/usr/bin/python3.11`` for Debian's Blender 3.4 — whose ``sys.executable`` is the first
    ``python3.11`` on PATH, possibly another installation without Debian's numpy); else
    ``sys.executable``. The pool checks the workers' Python and numpy versions against this process's.
    """
    explicit = os.environ.get("HLP_WORKER_PYTHON")
    if explicit:
        return explicit
    version = f"{sys.version_info[0]}.{sys.version_info[1]}"
    if os.name == "nt":
        candidates = [os.path.join(sys.prefix, "python.exe"), os.path.join(sys.prefix, "bin", "python.exe")]
    else:
        candidates = [os.path.join(sys.prefix, "bin", f"python{version}"), os.path.join(sys.prefix, "bin", "python3")]
    exe = sys.executable or ""
    if os.path.basename(exe).lower().startswith("python"):
        # a venv's prefix is the venv; its bin/pythonX.Y and sys.executable are the same interpreter
        candidates.insert(0 if os.path.dirname(exe) == os.path.join(sys.prefix, "bin") else 1, exe)
    for path in candidates:
        if path and os.path.isfile(path) and os.access(path, os.X_OK):
            return path
    return exe


# ------------------------------------------------------------------------------------ worker side
_SHARED: collections.OrderedDict = collections.OrderedDict()  # token -> object (or its pickle, not yet loaded)
_SHARED_LOCK = threading.Lock()


def _remember(token: str, value) -> None:
    with _SHARED_LOCK:
        _SHARED[token] = value
        _SHARED.move_to_end(token)
        while len(_SHARED) > SHARED_KEEP:
            _SHARED.popitem(last=False)


def _shared(token: str):
    """The shared object ``token`` in this process, unpickled on first use; None if unknown."""
    with _SHARED_LOCK:
        value = _SHARED.get(token)
        if value is None:
            return None
        _SHARED.move_to_end(token)
    if isinstance(value, (bytes, bytearray)):
        value = pickle.loads(value)
        _remember(token, value)
    return value


def _chunk_task(token: str, blob, fn: Callable, args: tuple):
    """One chunk in a worker: ``fn(shared, *args)``, the shared object taken from this process's cache.

    ``blob`` is the shared object's pickle, or None when the worker should have it already; a worker
    that does not answers :data:`_MISS` and gets the chunk again with the pickle.
    """
    shared = _shared(token)
    if shared is None:
        if blob is None:
            return _MISS
        _remember(token, blob)
        shared = _shared(token)
    return fn(shared, *args)


def _read_frame(stream) -> bytes | None:
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        return None
    (size,) = _HEADER.unpack(head)
    data = stream.read(size)
    if len(data) < size:
        return None
    return data


def _write_frame(stream, data: bytes) -> None:
    stream.write(_HEADER.pack(len(data)))
    stream.write(data)
    stream.flush()


def _watch_parent(parent: int) -> None:
    """Exit when the parent process is gone (the worker was re-parented), even in the middle of a chunk."""
    while True:
        time.sleep(0.2)
        if os.getppid() != parent:
            os._exit(3)


def _worker_main() -> None:
    """The worker loop (started by :class:`WorkerPool` through ``python -c``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the parent decides
    inp = os.fdopen(os.dup(0), "rb")
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # whatever a library prints goes to stderr, never into the protocol
    sys.stdout = sys.stderr
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.close(null)
    parent = int(os.environ.get("HLP_WORKER_PARENT", "0")) or os.getppid()
    nice = int(os.environ.get("HLP_WORKER_NICE", "0") or 0)
    if nice > 0 and hasattr(os, "nice"):
        os.nice(nice)  # below the interactive parent: its window keeps the CPU it needs to draw and see Esc
    if os.name != "nt":
        threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="hlp-parent-watch").start()
    import numpy

    _write_frame(out, pickle.dumps(("hello", os.getpid(), tuple(sys.version_info[:3]), numpy.__version__)))
    while True:
        data = _read_frame(inp)
        if data is None:
            return
        message = pickle.loads(data)
        if message[0] == "share":
            _remember(message[1], message[2])  # unpickled on first use
            continue
        _, task_id, payload = message
        try:
            fn, args, kwargs = pickle.loads(payload)
            reply = ("ok", task_id, fn(*args, **kwargs))
            data = pickle.dumps(reply, protocol=pickle.HIGHEST_PROTOCOL)
        except BaseException as exc:  # the parent gets the exception with the worker's traceback
            text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
            try:
                data = pickle.dumps(("err", task_id, exc, text), protocol=pickle.HIGHEST_PROTOCOL)
                pickle.loads(data)
            except Exception:
                data = pickle.dumps(("err", task_id, RuntimeError(f"{type(exc).__name__}: {exc}"), text))
        _write_frame(out, data)


_BOOT = """\
import sys, types
package, directory = sys.argv[1], sys.argv[2]
parts = package.split(".")
for i in range(1, len(parts) + 1):
    name = ".".join(parts[:i])
    module = types.ModuleType(name)
    module.__path__ = [directory] if i == len(parts) else []
    sys.modules[name] = module
    if i > 1:
        setattr(sys.modules[".".join(parts[:i - 1])], parts[i - 1], module)
__import__(package + ".core.parallel", fromlist=["_worker_main"])._worker_main()
"""


# ------------------------------------------------------------------------------------ parent side
class _RemoteTraceback(Exception):
    def __str__(self):
        return self.args[0]


class _Worker:
    def __init__(self, proc, stderr_file):
        self.proc = proc
        self.stderr = stderr_file
        self.ready = False
        self.task = None  # (future, task id) in flight
        self.shared: collections.OrderedDict = collections.OrderedDict()  # tokens sent (mirrors _remember)
        self.thread = None

    def stderr_tail(self, limit=2000) -> str:
        try:
            self.stderr.flush()
            self.stderr.seek(0, os.SEEK_END)
            size = self.stderr.tell()
            self.stderr.seek(max(0, size - limit))
            return self.stderr.read().decode("utf-8", "replace").strip()
        except (OSError, ValueError):
            return ""


def _kill_all(workers) -> None:
    for w in workers:
        if w.proc.poll() is None:
            try:
                w.proc.kill()
            except OSError:
                pass
    for w in workers:
        try:
            w.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass
        for stream in (w.proc.stdin, w.proc.stdout):
            try:
                if stream is not None:
                    stream.close()
            except OSError:
                pass
        try:
            w.stderr.close()
        except OSError:
            pass


def _describe_exit(code) -> str:
    if code is None:
        return "stopped answering"
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    return f"exited with status {code}"


class WorkerPool(cf.Executor):
    """``workers`` processes running the bpy-free core (a :class:`concurrent.futures.Executor`).

    ``submit(fn, *args)`` runs functions of this core or of the standard library (the workers import
    nothing else). Workers start at once, in parallel, and announce themselves; a worker whose Python or
    numpy differs from this process's fails the pool (results would not be bit-identical).

    Args:
        workers: processes (None or 0: :func:`default_workers`).
        python: the interpreter (default :func:`worker_python`).
        nice: added to the workers' nice value (``os.nice``; 0: none): an interactive parent (Blender's
            window) gives its workers a lower priority so that its own drawing and event handling — with
            software OpenGL, CPU work of the window's threads — is not starved by them.
    """

    def __init__(self, workers: int | None = None, *, python: str | None = None, nice: int = 0):
        self.n_workers = _resolve_workers(workers)
        self.nice = int(nice)
        self.python = python or worker_python()
        self._lock = threading.RLock()
        self._pending: collections.deque = collections.deque()
        self._blobs: dict = {}  # token -> pickle of a shared object (the latest SHARED_KEEP)
        self._ids = itertools.count()
        self._broken: BaseException | None = None
        self._closed = False
        package = __name__.rsplit(".", 2)[0]  # "hemisphere_local_pass" or "bl_ext.<repo>.hemisphere_local_pass"
        directory = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env = dict(os.environ)
        env["HLP_WORKER_PARENT"] = str(os.getpid())
        env["HLP_WORKER_NICE"] = str(max(0, self.nice))
        # The workers inherit this process's BLAS settings on purpose (no OPENBLAS_NUM_THREADS=1): the
        # OpenBLAS of numpy 1.24 splits a large matrix product differently with another thread count
        # and the last bit of a result moves (seen in linear_radiance's quadrature); the core's products
        # are small, so the BLAS threads rarely start at all.
        self._workers = []
        try:
            for _ in range(self.n_workers):
                err = tempfile.TemporaryFile()
                try:
                    proc = subprocess.Popen([self.python, "-c", _BOOT, package, directory], stdin=subprocess.PIPE,
                                            stdout=subprocess.PIPE, stderr=err, env=env, cwd=directory)
                except OSError:
                    err.close()
                    raise
                self._workers.append(_Worker(proc, err))
        except OSError as exc:
            _kill_all(self._workers)
            raise WorkerDied(f"cannot start worker Python {self.python!r}: {exc} (set HLP_WORKER_PYTHON)") from exc
        self._finalizer = weakref.finalize(self, _kill_all, list(self._workers))
        for w in self._workers:
            w.thread = threading.Thread(target=self._reader, args=(w,), daemon=True, name=f"hlp-worker-{w.proc.pid}")
            w.thread.start()

    # -------------------------------------------------------------------------------- public
    @property
    def pids(self) -> list:
        """Process ids of the workers."""
        return [w.proc.pid for w in self._workers]

    @property
    def starting(self) -> bool:
        """True while a worker has not yet announced itself (and the pool has not failed)."""
        return self._broken is None and any(not w.ready for w in self._workers)

    @property
    def failure(self) -> BaseException | None:
        """Why the pool stopped: a :class:`WorkerDied`, :class:`Cancelled` after :meth:`kill`, or None."""
        return self._broken

    def submit(self, fn, /, *args, **kwargs) -> cf.Future:
        return self._submit(fn, args, kwargs, None)

    def share(self, token: str, blob: bytes) -> None:
        """Make the pickled object ``blob`` available to every worker as ``token`` (sent once each)."""
        with self._lock:
            self._blobs[token] = blob
            while len(self._blobs) > SHARED_KEEP:
                self._blobs.pop(next(iter(self._blobs)))

    def kill(self, *, reap: bool = True) -> None:
        """Stop every worker now (SIGKILL); pending and running futures are cancelled or fail.

        ``reap``: wait until the processes have exited (False: return at once and leave that to
        :meth:`shutdown` — a killed worker with a nice value may need a moment of CPU to exit, which a
        job stopping for Esc should not wait for)."""
        with self._lock:
            self._closed = True
            if self._broken is None:
                self._broken = Cancelled("the worker pool was stopped")
            pending, self._pending = list(self._pending), collections.deque()
            tasks = [w.task for w in self._workers if w.task is not None]
            for w in self._workers:
                w.task = None
        for fut, *_ in pending:
            fut.cancel()
        if reap:
            self._finalizer()  # kills and reaps once
        else:
            for w in self._workers:
                if w.proc.poll() is None:
                    try:
                        w.proc.kill()
                    except OSError:
                        pass
        for fut, _ in tasks:
            if not fut.done():
                fut.set_exception(Cancelled("the worker pool was stopped"))
        if not reap:
            return
        for w in self._workers:
            if w.thread is not None and w.thread is not threading.current_thread():
                w.thread.join(timeout=2)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        with self._lock:
            self._closed = True
            if cancel_futures:
                pending, self._pending = list(self._pending), collections.deque()
                for fut, *_ in pending:
                    fut.cancel()
        if wait:
            while True:
                with self._lock:
                    busy = self._pending or any(w.task is not None for w in self._workers)
                if not busy or self._broken is not None:
                    break
                time.sleep(POLL_SECONDS)
        for w in self._workers:  # end of input: an idle worker exits
            try:
                w.proc.stdin.close()
            except OSError:
                pass
        if wait:
            deadline = time.monotonic() + 2.0
            for w in self._workers:
                try:
                    w.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    pass
        self._finalizer()
        for w in self._workers:
            if w.thread is not None and w.thread is not threading.current_thread():
                w.thread.join(timeout=2)

    # -------------------------------------------------------------------------------- internals
    def _submit(self, fn, args, kwargs, needs) -> cf.Future:
        fut = cf.Future()
        with self._lock:
            if self._broken is not None:
                raise self._broken if isinstance(self._broken, WorkerDied) else RuntimeError(
                    "the worker pool was stopped")
            if self._closed:
                raise RuntimeError("cannot schedule new futures after shutdown")
            self._pending.append((fut, fn, args, kwargs, needs))
            self._dispatch()
        return fut

    def _dispatch(self) -> None:
        """Give pending tasks to idle ready workers (lock held)."""
        for w in self._workers:
            if not self._pending:
                return
            if not w.ready or w.task is not None:
                continue
            while self._pending:
                fut, fn, args, kwargs, needs = self._pending.popleft()
                if not fut.set_running_or_notify_cancel():
                    continue
                try:
                    payload = pickle.dumps((fn, args, kwargs), protocol=pickle.HIGHEST_PROTOCOL)
                except Exception as exc:
                    fut.set_exception(exc)
                    continue
                task_id = next(self._ids)
                w.task = (fut, task_id)
                try:
                    if needs is not None and needs not in w.shared:
                        blob = self._blobs.get(needs)
                        if blob is not None:
                            _write_frame(w.proc.stdin, pickle.dumps(("share", needs, blob),
                                                                    protocol=pickle.HIGHEST_PROTOCOL))
                            w.shared[needs] = True
                            while len(w.shared) > SHARED_KEEP:
                                w.shared.popitem(last=False)
                        else:
                            w.shared.pop(needs, None)
                    _write_frame(w.proc.stdin, pickle.dumps(("call", task_id, payload)))
                except (OSError, ValueError):
                    pass  # the worker is gone: its reader thread reports it
                break

    def _reader(self, w: _Worker) -> None:
        stream = w.proc.stdout
        try:
            while True:
                try:
                    data = _read_frame(stream)
                except (OSError, ValueError):
                    data = None
                if data is None:
                    break
                message = pickle.loads(data)
                kind = message[0]
                with self._lock:
                    if kind == "hello":
                        self._hello(w, message)
                        self._dispatch()
                        continue
                    fut, task_id = w.task if w.task is not None else (None, None)
                    if fut is None or message[1] != task_id:
                        continue
                    w.task = None
                    self._dispatch()
                if kind == "ok":
                    fut.set_result(message[2])
                else:
                    exc = message[2]
                    exc.__cause__ = _RemoteTraceback(f"\n'''\n{message[3]}'''")
                    fut.set_exception(exc)
        except BaseException as exc:  # a reader must not die silently: fail the pool
            self._fail(w, WorkerDied(f"reading from worker {w.proc.pid} failed: {exc!r}"))
            return
        self._died(w)

    def _hello(self, w: _Worker, message) -> None:
        import numpy

        _, pid, version, numpy_version = message
        if tuple(version[:2]) != tuple(sys.version_info[:2]) or numpy_version != numpy.__version__:
            here = f"Python {'.'.join(map(str, sys.version_info[:3]))} with numpy {numpy.__version__}"
            there = f"Python {'.'.join(map(str, version))} with numpy {numpy_version}"
            self._fail(w, WorkerDied(f"worker Python {self.python} is {there}, this process runs {here}: results "
                                     "would not be bit-identical; set HLP_WORKER_PYTHON to a matching interpreter"))
            return
        w.ready = True

    def _died(self, w: _Worker) -> None:
        with self._lock:
            stopping = self._closed and (self._broken is not None or (w.task is None and not self._pending))
        if stopping:
            return
        try:
            code = w.proc.wait(timeout=2)
        except subprocess.TimeoutExpired:
            code = None
        tail = w.stderr_tail()
        what = "while computing a chunk" if w.task is not None else ("before it was ready" if not w.ready else "")
        msg = f"worker process {w.proc.pid} ({self.python}) {_describe_exit(code)} {what}".rstrip()
        if tail:
            msg += "; its last output:\n" + tail
        self._fail(w, WorkerDied(msg))

    def _fail(self, w: _Worker, exc: BaseException) -> None:
        with self._lock:
            if self._broken is None:
                self._broken = exc
            pending, self._pending = list(self._pending), collections.deque()
            tasks = [x.task for x in self._workers if x.task is not None]
            for x in self._workers:
                x.task = None
        for fut, _ in tasks:
            if not fut.done():
                fut.set_exception(exc)
        for fut, *_ in pending:
            if fut.set_running_or_notify_cancel():
                fut.set_exception(exc)


# ------------------------------------------------------------------------------------ one pool for many jobs
class PoolKeeper:
    """One :class:`WorkerPool` kept for a sequence of jobs (the bands of a render, the frames of an
    animation) instead of one pool per job: workers start once and keep the scene they were sent
    (:data:`SHARED_KEEP`), so a later job on the same scene sends nothing but its chunks.

    :meth:`get` returns the live pool, starting one when there is none, when the last one was stopped
    (a cancel kills it) or when another size or nice value is asked for; :meth:`close` shuts it down
    and reaps its processes (none is left behind). Jobs pick the keeper up through :meth:`scope`.
    Thread-safe.
    """

    def __init__(self):
        self._lock = threading.Lock()
        self._pool: WorkerPool | None = None
        self.started = 0  # pools started so far (tests, diagnostics)

    @property
    def pool(self) -> WorkerPool | None:
        """The current pool (None: none started, or closed)."""
        return self._pool

    def get(self, workers: int | None = None, *, nice: int = 0) -> WorkerPool:
        n = _resolve_workers(workers)
        with self._lock:
            pool = self._pool
            if pool is not None and (pool.failure is not None or pool._closed or pool.n_workers != n
                                     or pool.nice != nice):
                self._pool = None
                pool.shutdown(wait=False, cancel_futures=True)
                pool = None
            if pool is None:
                pool = self._pool = WorkerPool(n, nice=nice)
                self.started += 1
            return pool

    def close(self, *, wait: bool = True) -> None:
        """Shut the pool down (idle workers exit; the processes are reaped). ``wait=False``: reap them
        in a background thread (an Esc handler returns at once; the processes are gone moments later)."""
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is None:
            return
        if wait:
            pool.shutdown(wait=True, cancel_futures=True)
        else:
            threading.Thread(target=pool.shutdown, kwargs={"wait": True, "cancel_futures": True}, daemon=True,
                             name="hlp-pool-reaper").start()

    @contextlib.contextmanager
    def scope(self, *, nice: int = 0):
        """Within the block, :func:`job_pool` in this thread takes its pool from this keeper (the pool
        stays running afterwards: :meth:`close` ends it)."""
        previous = getattr(_KEEPER, "value", None)
        _KEEPER.value = (self, nice)
        try:
            yield self
        finally:
            _KEEPER.value = previous


_KEEPER = threading.local()  # (PoolKeeper, nice) of the running scope in this thread


def job_pool(workers: int | None = None) -> tuple:
    """``(pool, owned)`` for a job's chunks: the pool of the :meth:`PoolKeeper.scope` this thread is in
    (``owned`` False: the caller must not shut it down; killing it on cancel is fine), else a new
    :class:`WorkerPool` of ``workers`` processes that the caller owns."""
    current = getattr(_KEEPER, "value", None)
    if current is not None:
        keeper, nice = current
        return keeper.get(workers, nice=nice), False
    return WorkerPool(workers), True


# ------------------------------------------------------------------------------------ the driver
_PAYLOADS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # key -> (weakrefs of shared, token, blob)
_SCATTERED: dict = {}  # (id(client), token) -> the dask future of the blob (of the kept payloads)
#: held while a call prepares the scene's caches and pickles it: the job runs core calls in threads, and a
#: scene must not be pickled while another thread adds a cache to it
PREPARE_LOCK = threading.RLock()


_VALUES = (int, float, str, bytes, bool, type(None))


def _refs(shared):
    """A weak reference to each object of ``shared`` (a plain value, e.g. the chunks' ``budget``, is kept as
    itself: compared by value); None if an object cannot be referenced weakly."""
    items = shared if isinstance(shared, tuple) else (shared,)
    try:
        return tuple(("value", x) if isinstance(x, _VALUES) else weakref.ref(x) for x in items)
    except TypeError:
        return None


def _same(ref, x) -> bool:
    return ref == ("value", x) if isinstance(ref, tuple) else ref() is x


def _payload(key, shared) -> tuple:
    """``(token, blob)`` of ``shared``, pickled once while ``key`` and the objects of ``shared`` live (a
    tuple is compared item by item); the parent keeps the latest :data:`SHARED_KEEP` such pickles, as the
    workers keep that many shared objects (calls alternating two scenes ship each once)."""
    with PREPARE_LOCK:
        entry = _PAYLOADS.get(key)
        items = shared if isinstance(shared, tuple) else (shared,)
        if entry is not None and entry[0] is not None and len(entry[0]) == len(items) and all(
                _same(r, x) for r, x in zip(entry[0], items)):
            return entry[1], entry[2]
        blob = pickle.dumps(shared, protocol=pickle.HIGHEST_PROTOCOL)
        token = uuid.uuid4().hex
        _PAYLOADS.pop(key, None)
        while len(_PAYLOADS) >= SHARED_KEEP:  # the oldest first (insertion order)
            _PAYLOADS.pop(next(iter(_PAYLOADS.keys())))
        try:
            _PAYLOADS[key] = (_refs(shared), token, blob)
        except TypeError:  # not weak-referenceable: pickled on every call
            pass
        live = {entry[1] for entry in _PAYLOADS.values()}  # the scattered blobs of dropped payloads go too
        for k in [k for k in _SCATTERED if k[1] not in live]:
            del _SCATTERED[k]
        return token, blob


def _scatter(client, token, blob):
    """The blob on every dask worker (``broadcast``), scattered once per client and token."""
    with PREPARE_LOCK:
        fut = _SCATTERED.get((id(client), token))
        if fut is None:
            fut = _SCATTERED[(id(client), token)] = client.scatter(blob, broadcast=True, hash=False)
        return fut


def _executor_width(executor) -> int:
    """How many chunks to keep in flight on a foreign executor: twice its workers where it tells."""
    if isinstance(executor, WorkerPool):
        return 2 * executor.n_workers
    n = getattr(executor, "_max_workers", None)
    client = getattr(executor, "_client", None)
    if client is not None and hasattr(client, "nthreads"):
        try:
            n = sum(client.nthreads().values())
        except Exception:
            n = None
    return 2 * max(1, int(n or default_workers()))


def run_chunks(
    fn: Callable,
    shared,
    chunks: Sequence[tuple],
    args_of: Callable[[int, int], tuple],
    store: Callable[[int, int, object], None],
    *,
    workers: int | None = None,
    executor: cf.Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    key=None,
) -> None:
    """Run ``store(s, e, fn(shared, *args_of(s, e)))`` for every chunk ``(s, e)`` of ``chunks``.

    ``fn`` must be a module-level function of this core (workers import nothing else); ``shared`` is
    pickled once (cached while ``key``, default ``shared``, is alive) and reaches each worker once.
    ``store`` and ``progress(done, total)`` run in this thread; ``total`` is the last chunk's end. With
    ``workers=1`` and no executor (or fewer than :data:`MIN_POOL_CHUNKS` chunks) everything runs here, in
    order; else on ``executor`` or, with ``executor=None``, on a :class:`WorkerPool` of ``workers``
    processes (None: every core) made for this call and stopped after it.

    ``cancel()`` is polled before each chunk and every :data:`POLL_SECONDS` while waiting; when it
    returns True (or on KeyboardInterrupt) pending chunks are dropped, a :class:`WorkerPool` is killed
    (also a caller's: it cannot be used afterwards; its processes are reaped when the caller shuts it
    down, this call's own pool at once), and :class:`Cancelled` is raised.

    Raises:
        Cancelled; WorkerDied; whatever ``fn`` raised in a worker.
    """
    chunks = list(chunks)
    total = chunks[-1][1] if chunks else 0
    n_workers = None if executor is not None else _resolve_workers(workers)
    if executor is None and (n_workers == 1 or len(chunks) < MIN_POOL_CHUNKS):
        for s, e in chunks:
            if cancel is not None and cancel():
                raise Cancelled(f"cancelled after {s} of {total} points")
            store(s, e, fn(shared, *args_of(s, e)))
            if progress is not None:
                progress(e, total)
        return
    if cancel is not None and cancel():
        raise Cancelled(f"cancelled after 0 of {total} points")
    own = executor is None
    pool = WorkerPool(min(n_workers, len(chunks))) if own else executor
    token, blob = _payload(shared if key is None else key, shared)
    scattered = None
    client = getattr(pool, "_client", None)
    if not isinstance(pool, WorkerPool) and client is not None and hasattr(client, "scatter"):
        scattered = _scatter(client, token, blob)  # dask: once to every worker

    def submit(i, with_blob=False):
        s, e = chunks[i]
        args = args_of(s, e)
        if isinstance(pool, WorkerPool):
            pool.share(token, blob)
            return pool._submit(_chunk_task, (token, None, fn, args), {}, token)
        return pool.submit(_chunk_task, token, blob if with_blob else scattered, fn, args)

    width = _executor_width(pool)
    # While a WorkerPool's workers start (~0.3-0.4 s wall for two: Python, numpy and the core's imports),
    # this process would wait on an idle core: it computes chunks itself, from the end of the list, while
    # more than two chunks per worker are left unsubmitted (so it never holds one of the job's last chunks)
    # and while its chunks are short against the start (HELP_SECONDS: a long chunk here would outlast the
    # start and share a core with a worker). Not for an interactive parent (nice workers): its thread would
    # hold the GIL that Blender's window needs. A chunk here is the arithmetic of workers=1: same bits.
    helps = isinstance(pool, WorkerPool) and pool.nice == 0
    inflight: dict = {}
    done_points = 0
    next_chunk = 0
    last = len(chunks)  # chunks[last:] were computed here
    try:
        while next_chunk < last or inflight:
            starting = helps and pool.starting
            while next_chunk < last and len(inflight) < (pool.n_workers if starting else width):
                inflight[submit(next_chunk)] = next_chunk
                next_chunk += 1
            if starting and last - next_chunk > 2 * pool.n_workers:
                if cancel is not None and cancel():
                    raise Cancelled(f"cancelled after {done_points} of {total} points")
                last -= 1
                s, e = chunks[last]
                t0 = time.perf_counter()
                store(s, e, fn(shared, *args_of(s, e)))
                helps = time.perf_counter() - t0 < HELP_SECONDS
                done_points += e - s
                if progress is not None:
                    progress(done_points, total)
                continue
            finished, _ = cf.wait(list(inflight), timeout=POLL_SECONDS, return_when=cf.FIRST_COMPLETED)
            for fut in finished:
                i = inflight.pop(fut)
                value = fut.result()
                if isinstance(value, str) and value == _MISS:
                    inflight[submit(i, with_blob=True)] = i
                    continue
                s, e = chunks[i]
                store(s, e, value)
                done_points += e - s
                if progress is not None:
                    progress(done_points, total)
            if cancel is not None and cancel():
                raise Cancelled(f"cancelled after {done_points} of {total} points")
    except BaseException as exc:
        for fut in inflight:
            fut.cancel()
        if isinstance(pool, WorkerPool):
            pool.kill(reap=own)
        elif own:
            pool.shutdown(wait=False, cancel_futures=True)
        if isinstance(exc, WorkerDied):
            raise WorkerDied(f"{exc}\n(the job was stopped after {done_points} of {total} points)") from None
        raise
    if own:
        pool.shutdown(wait=True)
