"""The one pipeline of the local pass: every entry point (operator, ``blender -c`` command, plain
Python in the bpy module or under Blender 3.4's ``--python-expr``) calls :func:`run_local_pass`.

Pixels mode::

    Blender scene --scene_export--> core Scene, rho, E per polygon
    scene camera  --camera-->       one ray per pixel centre (k x k samples)
    core.raycast.cast_rays           visible point P, polygon, side
    core.form_factors / irradiance   H(P) on the hit side, sum of F
    L = E + rho / pi * H             (eq. 5) -> OpenEXR, "Local Pass" image, PNG preview

Vertices mode: the selected meshes' vertices (or corners) become receivers (one-sided limit from
inside their faces) and the results go into ``hlp_radiance`` / ``hlp_irradiance`` colour attributes.

Receivers are evaluated in chunks of fixed size (a function of the job only), so a run that was
interrupted and resumed computes exactly the same chunks as an uninterrupted one and writes the same
file. Finished chunks go to a checkpoint ``<output>.checkpoint.npz`` (replaced atomically after each
chunk, removed when the job completes); ``resume=True`` continues from it.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax; newer bpy APIs behind hasattr.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import shutil
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from .interrupts import stops_on_first_sigint

__all__ = ["JobReport", "JobStep", "cli_main", "local_pass_steps", "parse_tile", "run_local_pass", "tile_window"]

#: Receivers per chunk are ``clip(ceil(m / CHUNKS_PER_JOB), MIN_CHUNK, MAX_CHUNK)``: few enough
#: checkpoint writes, small enough that an interruption loses little.
CHUNKS_PER_JOB = 100
MIN_CHUNK = 64
MAX_CHUNK = 4096
#: Largest (receivers x input polygons) form-factor block per chunk (32 MB of float64).
MAX_ELEMENTS = 2**22
#: a job starts worker processes only for at least this many receivers (a worker costs ~0.15 s to start)
MIN_POOL_POINTS = 128
#: Name of the image datablock that receives the pixels-mode result.
IMAGE_NAME = "Local Pass"
_CHECKPOINT_VERSION = 1


@dataclass
class JobReport:
    """What a local-pass job did.

    Attributes:
        mode: "pixels" or "vertices".
        points: receiver points evaluated (hit samples, or vertices/corners).
        seconds: wall-clock time of the whole job.
        max_form_factor_error: max |sum F - 1| over the receivers (0 in a closed scene up to rounding;
            large where a receiver sees the open sky).
        black_occluders: objects without the radiosity attribute exported as black occluders.
        dropped_polygons: degenerate polygons the core dropped ("Object.polygon i: reason").
        outputs: files written (EXR, PNG) and attributes written ("Object:hlp_radiance").
        refused: files not written, each a message naming the path and why (an existing PNG preview
            that is not ours, or that may not be overwritten); see :mod:`.output_paths`.
        image_size, window: pixels mode: (W, H) and the computed (x0, y0, x1, y1).
        resumed_points: receivers taken from a checkpoint instead of being computed.
        cancelled: the job stopped early (finished chunks are in the checkpoint).
        workers: worker processes the receivers were computed on (1: this process only).
        objects: names of the exported objects; the EXR's ``object_index`` indexes this list.
        result: the float64 results: pixels mode the image layers of the window (see
            :mod:`.outputs`; row 0 at the bottom); vertices mode ``{object name: (domain, radiance,
            irradiance, computed mask)}``.
    """

    mode: str
    points: int = 0
    seconds: float = 0.0
    max_form_factor_error: float = 0.0
    black_occluders: list = field(default_factory=list)
    dropped_polygons: list = field(default_factory=list)
    outputs: list = field(default_factory=list)
    refused: list = field(default_factory=list)
    image_size: tuple | None = None
    window: tuple | None = None
    resumed_points: int = 0
    cancelled: bool = False
    workers: int = 1
    objects: list = field(default_factory=list, repr=False)
    result: dict = field(default_factory=dict, repr=False)
    exact_points: int | None = None       # adaptive pass: exact evaluations (None: every point exact)
    tolerance: float | None = None        # adaptive pass: the absolute tolerance on H used
    error_estimate: float | None = None   # adaptive pass: largest per-pixel error estimate of H

    @property
    def points_per_second(self) -> float:
        computed = self.points - self.resumed_points
        return computed / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        """One line for the UI and the command line."""
        parts = [f"{self.points} points in {self.seconds:.1f} s ({self.points_per_second:.0f} points/s)"]
        if self.exact_points is None:
            parts.append(f"max |sum F - 1| = {self.max_form_factor_error:.2e}")
        else:
            parts.append(f"adaptive: {self.exact_points} exact, estimated error <= {self.error_estimate:.2e} "
                         f"(tolerance {self.tolerance:.2e} W/m2)")
        if self.black_occluders:
            parts.append(f"{len(self.black_occluders)} black occluder(s)")
        if self.dropped_polygons:
            parts.append(f"{len(self.dropped_polygons)} degenerate polygon(s) dropped")
        if self.workers > 1:
            parts.append(f"{self.workers} workers")
        return "Local pass: " + ", ".join(parts)


@dataclass
class JobStep:
    """What :func:`local_pass_steps` yields after every finished chunk (and, on workers, at every poll
    of the pool): ``done`` of ``total`` receivers (points) evaluated so far. Between two steps nothing
    of Blender's data is touched, so a modal operator can return to the event loop there
    (``blender/modal.py``)."""

    done: int
    total: int


# ---------------------------------------------------------------------------------------- helpers
def parse_tile(tile) -> tuple:
    """``"I/N"`` (1-based, ``1 <= I <= N``) -> ``(I, N)``."""
    if isinstance(tile, (tuple, list)):
        i, n = (int(v) for v in tile)
    else:
        try:
            i_s, n_s = str(tile).split("/")
            i, n = int(i_s), int(n_s)
        except ValueError:
            raise ValueError(f"tile must look like I/N (e.g. 2/8), got {tile!r}") from None
    if not (n >= 1 and 1 <= i <= n):
        raise ValueError(f"tile {i}/{n}: need 1 <= I <= N")
    return i, n


def tile_window(window, tile) -> tuple:
    """Row band ``I`` of ``N`` of the pixel window (bands counted from the top row down, sizes
    differing by at most one row)."""
    i, n = parse_tile(tile)
    x0, y0, x1, y1 = window
    rows = y1 - y0
    if n > rows:
        raise ValueError(f"tile {i}/{n}: the window has only {rows} rows")
    top = y1 - (rows * (i - 1)) // n
    bottom = y1 - (rows * i) // n
    return x0, bottom, x1, top


def _chunk_size(m: int, n_input: int = 0) -> int:
    """Receivers per chunk: a function of the job only (receivers m, input polygons n_input), so a
    resumed run computes the same chunks. The dense (chunk, n_input) form-factor arrays stay below
    ``MAX_ELEMENTS`` entries."""
    size = min(MAX_CHUNK, max(MIN_CHUNK, math.ceil(m / CHUNKS_PER_JOB)))
    return int(max(1, min(size, MAX_ELEMENTS // max(n_input, 1))))


def _settings(scene):
    return getattr(scene, "hlp_settings", None)


def _digest(*arrays) -> str:
    h = hashlib.sha1()
    for a in arrays:
        if isinstance(a, np.ndarray):
            h.update(str(a.dtype).encode() + str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())
        else:
            h.update(repr(a).encode())
    return h.hexdigest()


class _Progress:
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


class _Reporter:
    """The job's ``progress(done, total)`` for the receivers plus ``stage(text)`` for the steps before
    them (export, ray casting, preparation), which take a minute on a 200,000-polygon scene; either
    callback may be None. ``stage(None)``: the job is over."""

    def __init__(self, progress, status):
        self.progress = progress
        self.status = status

    def __call__(self, done, total):
        if self.progress is not None:
            self.progress(done, total)

    def stage(self, text):
        if self.status is not None:
            self.status(text)


def _stage(progress, text):
    """Tell the job's status callback (if any) that a stage begins: ``text`` (None: the job is over)."""
    stage = getattr(progress, "stage", None)
    if stage is not None:
        stage(text)


def _prepare(exported, points, normals, limit, progress, cancel):
    """Build the core's per-scene structures (merged occluders, depth tables, tiles, solids, tile edges,
    the hierarchy: :func:`core.prepare_scene`, cached on the scene) as a stage of its own, each of its
    steps named as it ends, so the job says what it is doing before the first chunk (results are the
    same bit for bit: the first core call would build the same structures)."""
    from ..core import prepare_scene
    from ..core.chunk import PREPARATION_STAGES

    sc = exported.scene
    _stage(progress, f"preparing the scene for the exact projection ({sc.n_polygons} convex polygons)")

    def step(done, total):
        _stage(progress, f"preparing the scene: {PREPARATION_STAGES[done - 1]} ready ({done}/{total})")

    prepare_scene(sc, progress=step, cancel=cancel)


def _evaluate(exported, points, normals, limit, progress, cancel, executor=None):
    """H (m, 3) and sum F (m,) at the receivers.

    In general two core calls: ``core.irradiance`` (front sides emit, linear radiance integrated
    exactly) and ``core.form_factors``. When the radiance is constant, no receiver has a limit
    direction and every input polygon is one convex polygon, one ``form_factors`` call gives both:
    a plane's front side is visible exactly from the points in front of it, so
    ``H = c * sum_i [P in front of polygon i] F_i L_i`` — eq. 3, with ``c`` the core's own ratio
    ``irradiance / sum F`` measured on a probe (so the result follows the core's convention).
    """
    from ..core import form_factors, irradiance

    scene = exported.scene
    # the job's own pool (or this process): the core starts no pool per call
    kw = {"limit_directions": limit, "cancel": cancel, "workers": 1, "executor": executor}
    fast = _constant_planes(exported) if limit is None else None
    if fast is not None:
        normals_in, offsets_in, radiance_in = fast
        ff = form_factors(scene, points, normals, **kw)  # (m, n_input)
        if not scene.double_sided:
            side = points @ normals_in.T - offsets_in  # (m, n_input) signed distances
            ff_lit = np.where(side > 0.0, ff, 0.0)
        else:
            ff_lit = ff
        # einsum's own loops (not BLAS): each row's sum is independent of the chunk's other rows
        h = np.einsum("mn,nc->mc", ff_lit, radiance_in, optimize=False)
        return np.pi * h, ff.sum(axis=1)  # the core's irradiance is eq. 1: H = pi sum L F
    h = irradiance(scene, points, normals, **kw)
    if progress is not None:
        progress(1, 2)
    ff = form_factors(scene, points, normals, **kw)  # (m, n_input)
    return h, ff.sum(axis=1)


def _constant_planes(exported):
    """``(normals (n_in, 3), offsets (n_in,), radiance (n_in, 3))`` per input polygon when the scene
    has constant radiance and no input polygon was split; else None. Cached on the export."""
    cached = getattr(exported, "_hlp_planes", False)
    if cached is not False:
        return cached
    scene = exported.scene
    result = None
    if not scene.linear and np.bincount(scene.poly_source, minlength=scene.n_input).max(initial=0) <= 1:
        n_in = scene.n_input
        normals_in = np.zeros((n_in, 3))
        offsets_in = np.full(n_in, np.inf)  # dropped polygons: never in front (and F = 0)
        radiance_in = np.zeros((n_in, 3))
        normals_in[scene.poly_source] = scene.poly_normals
        offsets_in[scene.poly_source] = scene.poly_offsets
        radiance_in[scene.poly_source] = scene.poly_radiance
        result = (normals_in, offsets_in, radiance_in)
    exported._hlp_planes = result
    return result


class _Checkpoint:
    """Finished chunks of a job: ``<output>.checkpoint.npz``, replaced atomically after each chunk."""

    def __init__(self, path, fingerprint, m, chunk):
        self.path = path
        self.fingerprint = fingerprint
        self.chunk = chunk
        n_chunks = (m + chunk - 1) // chunk
        self.done = np.zeros(n_chunks, dtype=bool)
        self.h = np.zeros((m, 3))
        self.fsum = np.zeros(m)

    def load(self) -> bool:
        """Take over a matching checkpoint file; False when there is none or it belongs to another job."""
        if self.path is None or not os.path.isfile(self.path):
            return False
        try:
            with np.load(self.path, allow_pickle=False) as z:
                if (str(z["fingerprint"]) != self.fingerprint or int(z["chunk"]) != self.chunk
                        or z["h"].shape != self.h.shape or int(z["version"]) != _CHECKPOINT_VERSION):
                    return False
                self.done[:] = z["done"]
                self.h[:] = z["h"]
                self.fsum[:] = z["fsum"]
        except (OSError, KeyError, ValueError):
            return False
        return True

    def save(self):
        if self.path is None:
            return
        from .outputs import replace_atomically

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez(fh, fingerprint=np.array(self.fingerprint), chunk=np.array(self.chunk), done=self.done,
                         h=self.h, fsum=self.fsum, version=np.array(_CHECKPOINT_VERSION))

        replace_atomically(self.path, write)

    def remove(self):
        if self.path is not None and os.path.isfile(self.path):
            os.unlink(self.path)


def _compute(exported, points, normals, limit, *, checkpoint_path, fingerprint, resume, progress, cancel, report):
    """Evaluate all receivers chunk by chunk with checkpointing -> (H (m, 3), sum F (m,))."""
    from ..core import Cancelled

    m = len(points)
    chunk = _chunk_size(m, exported.scene.n_input)
    ck = _Checkpoint(checkpoint_path, fingerprint, m, chunk)
    if resume and ck.load():
        report.resumed_points = int(sum(min(chunk, m - c * chunk) for c in np.flatnonzero(ck.done)))
    prog = _Progress(progress, m, report.resumed_points)
    todo = [c for c in range(len(ck.done)) if not ck.done[c]]
    workers = report.workers if report.workers > 1 and m - report.resumed_points >= MIN_POOL_POINTS else 1
    report.workers = workers
    try:
        if todo:
            s0 = int(todo[0]) * chunk
            _prepare(exported, points[s0:], normals[s0:], None if limit is None else limit[s0:], progress, cancel)
            _stage(progress, f"computing {m - report.resumed_points} points")
        if workers > 1:
            yield from _compute_on_workers(exported, points, normals, limit, ck, todo, workers, prog, cancel)
            return ck
        for c in todo:
            if cancel is not None and cancel():
                raise Cancelled("local pass cancelled")
            s, e = c * chunk, min(m, (c + 1) * chunk)
            lim = None if limit is None else limit[s:e]
            h, fs = _evaluate(exported, points[s:e], normals[s:e], lim, prog.inner(e - s), cancel)
            ck.h[s:e], ck.fsum[s:e] = h, fs
            ck.done[c] = True
            ck.save()
            prog.advance(e - s)
            yield JobStep(prog.base, m)  # a chunk boundary: the caller may return to Blender's event loop
    except (KeyboardInterrupt, Cancelled):
        report.cancelled = True
        raise
    return ck


def _compute_on_workers(exported, points, normals, limit, ck, todo, workers, prog, cancel):
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
        return _evaluate(exported, points[s:e], normals[s:e], lim, None, stop.is_set, pool)

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
                ck.h[s:e], ck.fsum[s:e] = fut.result()
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


# ---------------------------------------------------------------------------------------- pixels
def _run_pixels(scene, exported, report, *, output, region, tile, resume, samples, progress, cancel, preview, image,
                depsgraph=None, tolerance=0.0):
    from ..core.raycast import cast_rays
    from . import camera as hcam
    from . import outputs

    params = hcam.camera_params(scene, depsgraph=depsgraph)
    size = hcam.image_size(params)
    window = hcam.pixel_window(params, region)
    full_window = window
    if tile is not None:
        window = tile_window(window, tile)
    report.image_size, report.window = size, window
    px, py, sx, sy = hcam.pixel_samples(window, samples)
    k2 = sx.shape[1]
    origins, directions, t0, t1 = hcam.camera_rays(params, sx, sy)
    core_scene = exported.scene
    _stage(progress, f"casting {len(origins)} camera rays ({core_scene.n_polygons} convex polygons)")
    hits = cast_rays(core_scene, origins, directions, t_min=t0, t_max=t1)
    hit = hits.hit
    poly = hits.polygon[hit]
    src = hits.source[hit]
    front = hits.front[hit]
    nrm = core_scene.poly_normals[poly]
    normals = np.where(front[:, None], nrm, -nrm)  # the receiver's hemisphere faces the camera
    # put P exactly on the hit polygon's plane (removes the ray's rounding off the plane)
    pts = hits.point[hit]
    pts = pts - (np.einsum("ij,ij->i", nrm, pts) - core_scene.poly_offsets[poly])[:, None] * nrm

    npix = len(px)
    shape = (window[3] - window[1], window[2] - window[0])
    ck = None
    if tolerance > 0:
        h_hit, exact_hit, err_hit = _adaptive_pixels(core_scene, pts, normals, src, hit, shape, k2, tolerance,
                                                     progress, cancel, report)
        fsum_hit = np.full(len(pts), np.nan)  # not computed: the adaptive pass evaluates H only
        report.max_form_factor_error = float("nan")
    else:
        fingerprint = _digest("pixels", core_scene.poly_vertices, core_scene.poly_radiance,
                              core_scene.corner_radiance if core_scene.linear else 0, pts, normals)
        ck_path = None if output is None else os.path.abspath(output) + ".checkpoint.npz"
        ck = yield from _compute(exported, pts, normals, None, checkpoint_path=ck_path, fingerprint=fingerprint,
                                 resume=resume, progress=progress, cancel=cancel, report=report)
        h_hit, fsum_hit = ck.h, ck.fsum
        exact_hit, err_hit = np.ones(len(pts)), np.zeros(len(pts))
        report.max_form_factor_error = float(np.abs(fsum_hit - 1.0).max()) if len(pts) else 0.0
    report.points = len(pts)

    emits = exported.emission[src] * (front | core_scene.double_sided)[:, None]
    l_hit = emits + exported.reflectivity[src] / np.pi * h_hit  # eq. 5

    n_samples = len(hit)
    radiance = np.zeros((n_samples, 3))
    irr = np.zeros((n_samples, 3))
    fsum = np.zeros(n_samples)
    radiance[hit], irr[hit], fsum[hit] = l_hit, h_hit, fsum_hit
    exact_s, err_s = np.zeros(n_samples), np.zeros(n_samples)
    exact_s[hit], err_s[hit] = exact_hit, err_hit
    hit2 = hit.reshape(npix, k2)
    cover = hit2.mean(axis=1)
    lay_rad = radiance.reshape(npix, k2, 3).mean(axis=1)
    lay_irr = irr.reshape(npix, k2, 3).mean(axis=1)
    n_hit = hit2.sum(axis=1)
    lay_f = np.where(n_hit > 0, fsum.reshape(npix, k2).sum(axis=1) / np.maximum(n_hit, 1), 0.0)
    centre = (k2 // 2) if samples % 2 else (samples // 2) * samples + samples // 2  # sample nearest the centre
    cidx = np.arange(npix) * k2 + centre
    chit = hit[cidx]
    depth = np.where(chit, hits.t[cidx], outputs.MISS_DEPTH)
    src_all = hits.source[cidx]
    obj_idx = np.where(chit, exported.polygon_object[np.maximum(src_all, 0)], -1)
    pol_idx = np.where(chit, exported.polygon_index[np.maximum(src_all, 0)], -1)

    x0, y0, x1, y1 = window
    layers = {
        # the adaptive pass (tolerance > 0): error estimate of H (mean over the pixel's samples; 0 where
        # exact) and the fraction of the pixel's samples evaluated exactly (1 everywhere at tolerance 0)
        "error_estimate": err_s.reshape(npix, k2).mean(axis=1).reshape(shape),
        "exact_sample": exact_s.reshape(npix, k2).mean(axis=1).reshape(shape),
        "radiance": lay_rad.reshape(shape + (3,)), "irradiance": lay_irr.reshape(shape + (3,)),
        "alpha": cover.reshape(shape), "form_factor_sum": lay_f.reshape(shape), "depth": depth.reshape(shape),
        "object_index": obj_idx.reshape(shape).astype(np.float64),
        "polygon_index": pol_idx.reshape(shape).astype(np.float64),
    }
    report.result = layers
    job_id = _digest(core_scene.poly_vertices, core_scene.poly_radiance, exported.reflectivity, exported.emission,
                     size, params.fingerprint(), samples, full_window)
    meta = {"hlp_fingerprint": job_id}  # the same for every tile of one job
    if tile is not None:
        meta["hlp_tile"] = "{}/{}".format(*parse_tile(tile))
    if output is not None:
        report.outputs.append(outputs.write_exr(output, layers, size=size, window=window, metadata=meta))
        if preview:  # the preview's path, checked by output_paths.plan_outputs (None: not written)
            png = preview
            full = np.zeros((size[1], size[0], 3))
            full[y0:y1, x0:x1] = layers["radiance"]
            report.outputs.append(outputs.write_png(png, full))
        if ck is not None:
            ck.remove()
    if image:
        rgba = np.zeros((size[1], size[0], 4))
        rgba[y0:y1, x0:x1, :3] = layers["radiance"]
        rgba[y0:y1, x0:x1, 3] = layers["alpha"]
        outputs.store_image(IMAGE_NAME, rgba)
    return layers


def _adaptive_pixels(core_scene, pts, normals, src, hit, shape, k2, tolerance, progress, cancel, report):
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


# -------------------------------------------------------------------------------------- vertices
def _selected_meshes(scene, view_layer, names=None):
    """The receiving mesh objects: ``names`` (``--objects``) when given, else the selected meshes."""
    if names:
        obs = []
        for name in names:
            ob = scene.objects.get(name)
            if ob is None:
                raise ValueError(f"--objects: scene '{scene.name}' has no object '{name}'")
            if ob.type != "MESH":
                raise ValueError(f"--objects: object '{name}' is a {ob.type.lower()}, not a mesh")
            if ob not in obs:
                obs.append(ob)
        return obs
    obs = [ob for ob in scene.objects if ob.type == "MESH" and ob.select_get(view_layer=view_layer)]
    if not obs:
        raise ValueError("vertices mode needs at least one selected mesh object (or name them: --objects NAME ...)")
    return obs


def _newell(verts, loops, start, total) -> np.ndarray:
    """(P, 3) unit Newell normals of polygons (vectorised over corners)."""
    v = verts[loops]  # (L, 3)
    poly = np.repeat(np.arange(len(start)), total)
    nxt_idx = np.arange(len(loops)) + 1
    last = start + total - 1
    nxt_idx[last] = start  # wrap around each polygon
    cross = np.cross(v, v[nxt_idx])
    area = np.zeros((len(start), 3))
    np.add.at(area, poly, cross)
    norm = np.linalg.norm(area, axis=1, keepdims=True)
    return area / np.where(norm > 0, norm, 1.0)


def _tangent_towards(target, point, normal) -> np.ndarray:
    """Unit vectors from ``point`` towards ``target`` projected into the plane normal to ``normal``."""
    d = target - point
    d = d - np.einsum("ij,ij->i", d, normal)[:, None] * normal
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.where(n > 0, d / np.where(n > 0, n, 1.0), 0.0)


def _receivers(ob, mesh, matrix):
    """Receiver points of one original mesh in world space.

    Returns ``(domain, points (n, 3), normals (n, 3), limits (n, 3), corner_poly (L,), elem_of_corner)``:
    CORNER domain (some face flat): one receiver per corner, the face normal for flat faces and the
    vertex normal for smooth ones, the limit direction towards the face centroid; POINT domain (all
    faces smooth): one receiver per vertex, its normal, the limit direction the normalised sum of
    the directions to the adjacent faces' centroids.
    """
    from .scene_export import mesh_arrays, polygon_of_corner

    arrays = mesh_arrays(mesh)
    m = np.asarray(matrix, dtype=np.float64).reshape(4, 4)
    lin = m[:3, :3]
    world = arrays.vertices @ lin.T + m[:3, 3]
    det = np.linalg.det(lin)
    face_n = _newell(world, arrays.loop_vertices, arrays.loop_start, arrays.loop_total)
    if det < 0:
        face_n = -face_n  # the exported scene reverses mirrored polygons: same front side
    vn = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    if len(mesh.vertices):
        mesh.vertices.foreach_get("normal", vn)
    vn = vn.reshape(-1, 3).astype(np.float64) @ np.linalg.inv(lin)  # inverse transpose, row vectors
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
    cpoly = polygon_of_corner(arrays)
    centroid = np.add.reduceat(world[arrays.loop_vertices], arrays.loop_start, axis=0) / arrays.loop_total[:, None]
    if arrays.n_polygons and arrays.use_smooth.all():
        n_v = len(world)
        lim = np.zeros((n_v, 3))
        corner_dir = _tangent_towards(centroid[cpoly], world[arrays.loop_vertices], vn[arrays.loop_vertices])
        np.add.at(lim, arrays.loop_vertices, corner_dir)
        first = np.full(n_v, -1, dtype=np.int64)
        first[arrays.loop_vertices[::-1]] = np.arange(len(arrays.loop_vertices))[::-1]
        norm = np.linalg.norm(lim, axis=1)
        weak = (norm < 1e-6) & (first >= 0)
        lim[weak] = corner_dir[first[weak]]  # symmetric neighbourhood: use the first face's direction
        norm = np.linalg.norm(lim, axis=1, keepdims=True)
        lim = np.where(norm > 0, lim / np.where(norm > 0, norm, 1.0), 0.0)
        return "POINT", world, vn, lim, arrays, cpoly
    smooth_c = arrays.use_smooth[cpoly]
    pts = world[arrays.loop_vertices]
    nrm = np.where(smooth_c[:, None], vn[arrays.loop_vertices], face_n[cpoly])
    lim = _tangent_towards(centroid[cpoly], pts, nrm)
    return "CORNER", pts, nrm, lim, arrays, cpoly


def _receiver_materials(ob, mesh, arrays, rho_attr, emit_attr):
    """(P, 3) rho and E of the polygons of an original mesh (attributes, else material, else defaults)."""
    from .scene_export import _per_polygon, material_colours, read_attribute

    rho_vals = read_attribute(mesh, arrays, rho_attr, ob.name, allow_grey=True) if rho_attr else None
    emit_vals = read_attribute(mesh, arrays, emit_attr, ob.name, allow_grey=True) if emit_attr else None
    slots = [s.material for s in ob.material_slots] or [None]
    table = [material_colours(mat) for mat in slots]
    slot = np.clip(arrays.material_index, 0, len(table) - 1)
    rho = _per_polygon(arrays, *rho_vals) if rho_vals is not None else np.array([t[0] for t in table])[slot]
    emit = _per_polygon(arrays, *emit_vals) if emit_vals is not None else np.array([t[1] for t in table])[slot]
    return rho.reshape(-1, 3), emit.reshape(-1, 3)


def _run_vertices(scene, view_layer, exported, report, *, attribute, rho_attr, emit_attr, radiance_attribute,
                  irradiance_attribute, output, resume, progress, cancel, explicit_targets, objects=None):
    import bpy

    from . import outputs

    obs = _selected_meshes(scene, view_layer, objects)
    edit_objects = [ob for ob in obs if ob.mode == "EDIT"]
    if edit_objects:
        for ob in edit_objects:
            ob.update_from_editmode()
    depsgraph = view_layer.depsgraph
    jobs = []
    for ob in obs:
        mesh = ob.data
        for name in (radiance_attribute, irradiance_attribute):
            outputs.prepare_vertex_attribute(mesh, name, "", protected=(attribute, rho_attr, emit_attr),
                                             explicit=name in explicit_targets, owner=ob.name,
                                             role="radiance" if name == radiance_attribute else "irradiance")
        matrix = np.array(ob.evaluated_get(depsgraph).matrix_world, dtype=np.float64)
        domain, pts, nrm, lim, arrays, cpoly = _receivers(ob, mesh, matrix)
        rho, emit = _receiver_materials(ob, mesh, arrays, rho_attr, emit_attr)
        if domain == "POINT":
            count = np.bincount(arrays.loop_vertices, minlength=len(pts)).astype(np.float64)[:, None]
            rho_r = np.zeros((len(pts), 3))
            emit_r = np.zeros((len(pts), 3))
            np.add.at(rho_r, arrays.loop_vertices, rho[cpoly])
            np.add.at(emit_r, arrays.loop_vertices, emit[cpoly])
            rho_r /= np.maximum(count, 1)
            emit_r /= np.maximum(count, 1)
        else:
            rho_r, emit_r = rho[cpoly], emit[cpoly]
        mask = None
        if ob.mode == "EDIT" or ob in edit_objects:
            sel = np.zeros(len(mesh.vertices), dtype=bool)
            if len(sel):
                mesh.vertices.foreach_get("select", sel)
            mask = sel if domain == "POINT" else sel[arrays.loop_vertices]
        used = np.ones(len(pts), dtype=bool) if domain == "CORNER" else np.bincount(
            arrays.loop_vertices, minlength=len(pts)) > 0  # loose vertices are no receivers
        todo = used if mask is None else used & mask
        if mask is not None and not todo.any():
            continue  # Edit Mode, nothing selected on this object: nothing is written on it
        jobs.append((ob, domain, pts, nrm, lim, rho_r, emit_r, mask, todo))
    if not any(j[8].any() for j in jobs):
        if edit_objects:
            names = ", ".join(f"'{ob.name}'" for ob in edit_objects)
            raise ValueError(f"nothing selected: {names} in Edit Mode with no vertex selected; select the vertices "
                             "to evaluate, or leave Edit Mode to evaluate whole meshes")
        names = ", ".join(f"'{ob.name}'" for ob in obs)
        raise ValueError(f"nothing to evaluate: {names} have no faces (loose vertices are no receivers)")
    all_pts = np.concatenate([j[2][j[8]] for j in jobs])
    all_nrm = np.concatenate([j[3][j[8]] for j in jobs])
    all_lim = np.concatenate([j[4][j[8]] for j in jobs])
    core_scene = exported.scene
    fingerprint = _digest("vertices", core_scene.poly_vertices, core_scene.poly_radiance,
                          core_scene.corner_radiance if core_scene.linear else 0, all_pts, all_nrm, all_lim)
    ck_path = None if output is None else os.path.abspath(output) + ".checkpoint.npz"
    ck = yield from _compute(exported, all_pts, all_nrm, all_lim, checkpoint_path=ck_path, fingerprint=fingerprint,
                  resume=resume, progress=progress, cancel=cancel, report=report)
    report.points = len(all_pts)
    report.max_form_factor_error = float(np.abs(ck.fsum - 1.0).max()) if len(all_pts) else 0.0
    results = {}
    mode_restore = None
    if edit_objects and bpy.context.mode.startswith("EDIT"):
        mode_restore = "EDIT"
        bpy.ops.object.mode_set(mode="OBJECT")  # attribute edits must not be overwritten by the edit mesh
    try:
        s = 0
        for ob, domain, pts, _nrm, _lim, rho_r, emit_r, _mask, todo in jobs:
            n = int(todo.sum())
            h = np.zeros((len(pts), 3))
            h[todo] = ck.h[s:s + n]
            s += n
            radiance = emit_r + rho_r / np.pi * h  # eq. 5
            outputs.write_vertex_colours(ob.data, radiance_attribute, domain, radiance, todo)
            outputs.write_vertex_colours(ob.data, irradiance_attribute, domain, h, todo)
            outputs.make_active_colour(ob.data, radiance_attribute)  # the viewport shows L, not H
            ob.data.update()
            report.outputs += [f"{ob.name}:{radiance_attribute}", f"{ob.name}:{irradiance_attribute}"]
            results[ob.name] = (domain, radiance, h, todo)
    finally:
        if mode_restore:
            bpy.ops.object.mode_set(mode=mode_restore)
    ck.remove()
    report.result = results
    return results


# ------------------------------------------------------------------------------------------- job
@stops_on_first_sigint
def run_local_pass(*args, **kwargs):
    """Run the exact local pass to the end: :func:`local_pass_steps` (same arguments) drained.

    Returns:
        :class:`JobReport`.
    """
    steps = local_pass_steps(*args, **kwargs)
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


def local_pass_steps(
    scene=None,
    *,
    output=None,
    mode=None,
    attribute=None,
    region=None,
    tile=None,
    resume=False,
    samples=None,
    missing=None,
    progress=None,
    cancel=None,
    status=None,
    reflectivity_attribute=None,
    emission_attribute=None,
    double_sided=None,
    radiance_attribute=None,
    irradiance_attribute=None,
    preview=True,
    image=True,
    view_layer=None,
    overwrite=False,
    objects=None,
    workers=None,
    exported=None,
    depsgraph=None,
    tolerance=None,
):
    """The exact local pass on ``scene`` (default: the context's scene) as a generator: it yields a
    :class:`JobStep` after every chunk and returns the :class:`JobReport` (``StopIteration.value``).
    :func:`run_local_pass` drains it; a modal operator advances it one timer tick at a time; closing
    it (``.close()``) between steps stops the job before anything is written.

    Arguments left at ``None`` come from the scene's settings (``scene.hlp_settings`` when the
    extension is registered), else the defaults: ``mode="pixels"``, ``attribute="radiosity"``,
    ``samples=1``, ``missing="error"``, ``reflectivity_attribute="reflectivity"``,
    ``emission_attribute="emission"``, ``double_sided=False``.

    Args:
        output: pixels mode: the OpenEXR file (a PNG preview is written next to it unless
            ``preview=False``); ``None`` keeps the result in the "Local Pass" image only.
            Vertices mode: optional, only names the checkpoint file.
        mode: "pixels" or "vertices".
        attribute: the radiosity attribute.
        region: (x0, y0, x1, y1) pixels (x from the left, y from the bottom, half-open); default the
            render border if enabled, else the whole image.
        tile: "I/N": compute row band I of N (1-based, from the top) of the window and write a
            partial EXR (assemble with :func:`hemisphere_local_pass.blender.outputs.merge_exr`).
        resume: continue from ``<output>.checkpoint.npz`` if it matches this job.
        samples: k for k x k rays per pixel.
        missing: "error" or "black" (objects without the attribute become black occluders).
        progress: ``progress(done, total)`` receivers; cancel: ``cancel() -> bool``.
        status: ``status(text)`` when a stage begins or moves on ("exporting the scene: 3 objects,
            1,200 polygons read", "casting 4,096 camera rays", "preparing the scene ...", "computing
            4,096 points"), from the job's first moment on; ``status(None)`` when the job ends.
        radiance_attribute, irradiance_attribute: vertices mode targets (default ``hlp_radiance``,
            ``hlp_irradiance``); an existing attribute of that name is overwritten only if it was
            made by this extension or is named here explicitly.
        image: store the pixels in the image datablock "Local Pass".
        overwrite: replace an existing output (EXR, PNG preview, checkpoint) that this extension
            wrote; files it did not write are never replaced (:mod:`.output_paths`). A refused
            preview is listed in ``report.refused``.
        objects: vertices mode: names of the mesh objects to evaluate (default: the selected ones).
        workers: worker processes (0: every core this process may use; 1: this process only; default
            the scene setting, else 0). Results are the same bits for any number. Workers run the
            bpy-free core in a real Python (see :mod:`hemisphere_local_pass.core.parallel`).
        exported: an :class:`~.scene_export.ExportedScene` of this scene made with the same
            attribute settings, to reuse (the render engine's bands); default: export the scene.
        depsgraph: an evaluated depsgraph to read the objects and the camera from as it is (the
            render engine's); default: the view layer's.
        tolerance: pixels mode: 0 (default) evaluates every pixel exactly; > 0 runs the adaptive pass
            (``core.adaptive_irradiance``) with an error tolerance on H *relative to the image's mean
            irradiance* (estimated from exact values on a 16-pixel grid), e.g. 1e-3; the EXR's
            ``error_estimate`` and ``exact_sample`` layers show where it interpolated. The adaptive
            pass neither checkpoints nor computes the ``form_factor_sum`` layer (NaN there).

    Returns:
        :class:`JobReport`.

    Raises:
        ValueError: bad input (message names the object / attribute / polygon).
        hemisphere_local_pass.core.Cancelled, KeyboardInterrupt: stopped; finished chunks are in
            the checkpoint.
    """
    import bpy

    start = time.perf_counter()
    if scene is None:
        scene = bpy.context.scene
    settings = _settings(scene)

    def pick(value, prop, default, convert=None):
        if value is not None:
            return value
        if settings is not None and hasattr(settings, prop):
            v = getattr(settings, prop)
            return convert(v) if convert else v
        return default

    mode = str(pick(mode, "mode", "pixels", str.lower)).lower()
    attribute = pick(attribute, "attribute", "radiosity")
    samples = int(pick(samples, "samples", 1))
    missing = str(pick(missing, "missing_attribute", "error", str.lower)).lower()
    rho_attr = pick(reflectivity_attribute, "reflectivity_attribute", "reflectivity")
    emit_attr = pick(emission_attribute, "emission_attribute", "emission")
    double_sided = bool(pick(double_sided, "double_sided", False))
    workers = pick(workers, "workers", 0)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ValueError(f"workers must be 0 (every core) or a positive number, got {workers!r}")
    tolerance = float(pick(tolerance, "tolerance", 0.0))
    if not (np.isfinite(tolerance) and tolerance >= 0.0):
        raise ValueError(f"tolerance must be a number >= 0 (relative to the mean irradiance), got {tolerance}")
    if mode not in ("pixels", "vertices"):
        raise ValueError(f"mode must be 'pixels' or 'vertices', got {mode!r}")
    if not attribute:
        raise ValueError("the radiosity attribute name is empty")
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    if tile is not None:
        parse_tile(tile)
        if mode != "pixels":
            raise ValueError("--tile applies to pixels mode only")
    refused = []
    if output is not None:
        from .output_paths import plan_outputs

        output, preview, refused = plan_outputs(output, mode=mode, tile=tile, preview=preview, overwrite=overwrite,
                                                resume=resume)
    elif tile is not None:
        raise ValueError("a tile needs an output file")
    if view_layer is None:
        ctx_layer = getattr(bpy.context, "view_layer", None)
        view_layer = ctx_layer if ctx_layer is not None and ctx_layer.id_data == scene else scene.view_layers[0]
    if objects and mode != "pixels":
        _selected_meshes(scene, view_layer, objects)  # unknown names: fail before the (slow) export
    elif objects:
        raise ValueError("--objects applies to vertices mode only")
    if mode == "pixels":
        from .camera import camera_params

        camera_params(scene, depsgraph=depsgraph)  # no camera: fail before the (slow) export

    from .scene_export import export_scene

    progress = _Reporter(progress, status)
    if exported is None:
        _stage(progress, "exporting the scene")
        try:
            exported = export_scene(scene, depsgraph=depsgraph, view_layer=view_layer, attribute=attribute,
                                    reflectivity_attribute=rho_attr, emission_attribute=emit_attr, missing=missing,
                                    double_sided=double_sided, status=progress.stage)
        except BaseException:
            _stage(progress, None)
            raise
        sc = exported.scene
        _stage(progress, f"exported {len(exported.objects)} objects, {sc.n_input} polygons ({sc.n_polygons} "
                         f"convex) in {time.perf_counter() - start:.1f} s")
    report = JobReport(mode=mode, black_occluders=list(exported.black_occluders),
                       dropped_polygons=exported.dropped_names(), objects=list(exported.objects), refused=refused)
    if workers == 0:
        from ..core.parallel import default_workers

        workers = default_workers()
    report.workers = workers  # at most; _compute uses one process for small jobs
    try:
        if mode == "pixels":
            yield from _run_pixels(scene, exported, report, output=output, region=region, tile=tile, resume=resume,
                        samples=samples, progress=progress, cancel=cancel, preview=preview, image=image,
                        depsgraph=depsgraph, tolerance=tolerance)
        else:
            explicit = {n for n in (radiance_attribute, irradiance_attribute) if n}
            yield from _run_vertices(scene, view_layer, exported, report, attribute=attribute, rho_attr=rho_attr,
                          emit_attr=emit_attr,
                          radiance_attribute=(radiance_attribute or pick(None, "radiance_attribute", "")
                                              or "hlp_radiance"),
                          irradiance_attribute=(irradiance_attribute or pick(None, "irradiance_attribute", "")
                                                or "hlp_irradiance"), output=output,
                          resume=resume, progress=progress, cancel=cancel, explicit_targets=explicit, objects=objects)
    finally:
        report.seconds = time.perf_counter() - start
        _stage(progress, None)
    return report


# ------------------------------------------------------------------------------------------- CLI
class _StderrProgress:
    """Percent, points/s and ETA on stderr, at most every ``interval`` seconds (and at the end);
    before the points, the job's stages (``stage(text)``), and while nothing else is printed a line
    every ``interval`` seconds saying what is running and for how long (from a daemon thread, stopped
    by ``stage(None)``), so a long export or preparation is never silent."""

    def __init__(self, stream=None, interval=1.0):
        self.stream = stream if stream is not None else sys.stderr
        self.interval = interval
        self.start = None
        self.first = None
        self.last = 0.0
        self.text = None
        self.since = 0.0
        self.lock = threading.Lock()
        self.stop = None

    def _write(self, line):
        with self.lock:
            self.last = time.perf_counter()
            self.stream.write(f"hemisphere_local_pass: {line}\n")
            self.stream.flush()

    def stage(self, text):
        """A stage begins (None: the job is over)."""
        if text is None:
            if self.stop is not None:
                self.stop.set()
                self.stop = None
            self.text = None
            return
        now = time.perf_counter()
        head = text.split(":")[0]  # "exporting the scene: 3 objects ..." moves on within one stage
        if self.text is None or head != self.text.split(":")[0]:
            self.text, self.since = text, now
            self._write(text)
        else:
            self.text = text  # printed now if a line is due, else by the heartbeat
            if now - self.last >= self.interval:
                self._write(f"{text} ({now - self.since:.0f} s)")
        if self.stop is None:
            self.stop = threading.Event()
            threading.Thread(target=self._heartbeat, args=(self.stop,), daemon=True,
                             name="hlp-progress").start()

    def _heartbeat(self, stop):
        while not stop.wait(self.interval / 4):
            now = time.perf_counter()
            text = self.text
            if text is not None and now - self.last >= self.interval:
                self._write(f"{text} ({now - self.since:.0f} s)")

    def __call__(self, done, total):
        now = time.perf_counter()
        if self.start is None:
            self.start, self.first = now, done
        if now - self.last < self.interval and done < total:
            return
        rate = (done - self.first) / (now - self.start) if now > self.start else 0.0
        eta = (total - done) / rate if rate > 0 else float("nan")
        pct = 100.0 * done / total if total else 100.0
        eta_s = f"{eta:.0f} s" if math.isfinite(eta) else "?"
        line = f"{pct:5.1f}% {done}/{total} points, {rate:.0f} points/s, ETA {eta_s}"
        self.text, self.since = line, now
        self._write(line)


def _region(values):
    if values is None:
        return None
    return tuple(int(v) for v in values)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="blender --command hemisphere_local_pass",
        description="Exact local pass of two-pass global illumination for the loaded .blend file.",
    )
    sub = parser.add_subparsers(dest="command", metavar="{render,merge,solve}")
    sub.required = True
    r = sub.add_parser("render", help="compute the local pass (pixels: EXR + PNG; vertices: colour attributes)")
    r.add_argument("--output", "-o", help="pixels: the OpenEXR file (a PNG preview goes next to it); "
                   "vertices: the .blend file to save with the colour attributes")
    r.add_argument("--mode", choices=("pixels", "vertices"), default=None)
    r.add_argument("--attribute", default=None, help="radiosity attribute (default: scene setting or 'radiosity')")
    r.add_argument("--region", nargs=4, type=int, metavar=("X0", "Y0", "X1", "Y1"),
                   help="pixel window, x from the left, y from the bottom, half-open")
    r.add_argument("--tile", metavar="I/N", help="compute row band I of N (1-based, from the top) as a partial EXR")
    r.add_argument("--resume", action="store_true", help="continue from OUTPUT.checkpoint.npz")
    r.add_argument("--samples", type=int, default=None, metavar="K", help="K x K rays per pixel")
    r.add_argument("--tolerance", type=float, default=None, metavar="REL",
                   help="pixels: adaptive pass with this error tolerance relative to the mean irradiance "
                   "(e.g. 1e-3); 0 = every pixel exact (default: scene setting or 0)")
    r.add_argument("--missing", choices=("error", "black"), default=None,
                   help="objects without the attribute: error (default) or black occluders")
    r.add_argument("--no-preview", action="store_true", help="do not write the PNG preview")
    r.add_argument("--overwrite", action="store_true",
                   help="replace existing outputs this extension wrote (EXR, PNG, checkpoint; vertices: the .blend, "
                   "keeping the old one as .blend1); files it did not write are never replaced")
    r.add_argument("--objects", nargs="+", metavar="NAME",
                   help="vertices: the mesh objects to evaluate (default: the objects selected in the file)")
    r.add_argument("--radiance-attribute", metavar="NAME", help="vertices: radiance target (default hlp_radiance)")
    r.add_argument("--irradiance-attribute", metavar="NAME",
                   help="vertices: irradiance target (default hlp_irradiance)")
    r.add_argument("--workers", "-j", type=int, default=None, metavar="N",
                   help="worker processes (0: every core this process may use, the default; 1: none)")
    r.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    sub.add_parser("solve", add_help=False, help="first pass: solve radiosity and write the FACE-domain attribute "
                   "(options: solve --help; hemisphere_local_pass.blender.first_pass)")
    m = sub.add_parser("merge", help="assemble tile EXRs into one image (and its PNG preview)")
    m.add_argument("tiles", nargs="+", metavar="TILE_FILES")
    m.add_argument("--output", "-o", required=True)
    m.add_argument("--no-preview", action="store_true", help="do not write the PNG preview of the merged image")
    m.add_argument("--overwrite", action="store_true", help="replace an existing merged image this extension wrote")
    return parser


def _check_blend_output(path: str, overwrite: bool) -> str:
    """Vertices mode's ``--output FILE.blend``: resolved and writable; never the open file itself,
    never an existing file that is not a .blend; an existing .blend only with ``--overwrite``."""
    import bpy

    from . import output_paths as op

    path = op.check_writable(path)
    if not path.lower().endswith(".blend"):
        raise ValueError("in vertices mode --output names the .blend file to save the colour attributes to")
    if not os.path.lexists(path):
        return path
    if bpy.data.filepath and os.path.exists(bpy.data.filepath) and os.path.samefile(path, bpy.data.filepath):
        raise op.OutputRefused(f"--output '{path}' is the open .blend file: the job never overwrites its input; "
                               "give another file name")
    found = op.describe(path)
    if not os.path.isfile(path) or op.file_kind(path) != "blend":
        raise op.OutputRefused(f"--output '{path}' exists and is {found}, not a .blend file: it is never replaced")
    if not overwrite:
        raise op.OutputRefused(f"--output '{path}' exists: pass --overwrite to replace it (the old file is kept "
                               "as .blend1)")
    return path


def _save_blend(path: str) -> str:
    """Save a copy of the current file (with the new attributes) to ``path``, atomically; an existing
    file there is kept as ``path + "1"`` (Blender's own backup name)."""
    import bpy

    from .outputs import replace_atomically

    def save(tmp):
        os.unlink(tmp)  # a new file: Blender then keeps no .blend1 backup of the placeholder
        bpy.ops.wm.save_as_mainfile(filepath=tmp, copy=True)
        if os.path.isfile(path):  # only with --overwrite (_check_blend_output): keep the old file
            backup = path + "1"
            if os.path.lexists(backup):
                os.unlink(backup)
            shutil.copy2(path, backup)

    return replace_atomically(path, save)


def error_line(exc: BaseException) -> str:
    """``error: ...``, the one stderr line of a failed command: the first line of the message, prefixed
    by the exception's type unless it is a user error (ValueError, OSError)."""
    text = str(exc).strip()
    msg = text.splitlines()[0] if text else type(exc).__name__
    kind = "" if isinstance(exc, (ValueError, OSError)) else f"{type(exc).__name__}: "
    return f"error: {kind}{msg}"


def cli_main(argv) -> int:
    """The ``blender --command hemisphere_local_pass`` program: returns the exit code; errors are
    one line on stderr (exit 1), Ctrl-C exits 130 after the finished chunks are saved."""
    if list(argv)[:1] == ["solve"]:  # the first pass: its own program (blender/first_pass.py)
        from .first_pass import cli_main as solve_main

        return solve_main(list(argv)[1:])
    parser = build_parser()
    args = parser.parse_args(list(argv))
    prefix = "hemisphere_local_pass: "
    checkpoint = ""
    try:
        if args.command == "merge":
            from .outputs import merge_exr

            done = {"written": [], "refused": []}
            path = merge_exr(args.tiles, args.output, overwrite=args.overwrite, preview=not args.no_preview,
                             report=done)
            print(f"{prefix}merged {len(args.tiles)} tile(s) into {path}")
            for written in done["written"]:
                print(f"{prefix}wrote {written}")
            for message in done["refused"]:
                print(f"{prefix}not written: {message}", file=sys.stderr)
            return 0
        import bpy

        mode = args.mode
        settings = _settings(bpy.context.scene)
        if mode is None:
            mode = str(settings.mode).lower() if settings is not None else "pixels"
        if args.output is None:
            raise ValueError("render needs --output FILE.exr (pixels mode) or --output FILE.blend (vertices mode)")
        output = args.output
        if mode == "vertices":
            output = _check_blend_output(output, args.overwrite)
        elif args.objects:
            raise ValueError("--objects applies to vertices mode only (--mode vertices)")
        from .output_paths import checkpoint_path, resolve

        checkpoint = checkpoint_path(resolve(output))
        reporter = None if args.quiet else _StderrProgress()
        report = run_local_pass(
            output=output, mode=mode, attribute=args.attribute, region=_region(args.region),
            tile=args.tile, resume=args.resume, samples=args.samples, missing=args.missing,
            progress=reporter, status=None if reporter is None else reporter.stage, preview=not args.no_preview,
            overwrite=args.overwrite, objects=args.objects, radiance_attribute=args.radiance_attribute,
            irradiance_attribute=args.irradiance_attribute, workers=args.workers,
            tolerance=args.tolerance,
        )
        if mode == "vertices":
            report.outputs.append(_save_blend(output))
    except KeyboardInterrupt:
        where = checkpoint if os.path.isfile(checkpoint) else None
        kept = f"finished chunks are kept in {where}" if where else "no chunk had finished (nothing to keep)"
        print(f"{prefix}interrupted (Ctrl-C); {kept}; rerun with --resume to continue", file=sys.stderr)
        return 130
    except Exception as exc:  # one line, non-zero: the command is for scripts and render farms
        from ..core import Cancelled

        if isinstance(exc, Cancelled):
            print(f"{prefix}cancelled; finished chunks are saved, rerun with --resume", file=sys.stderr)
            return 130
        print(f"{prefix}{error_line(exc)}", file=sys.stderr)
        return 1
    print(f"{prefix}{report.summary()}")
    for path in report.outputs:
        print(f"{prefix}wrote {path}")
    for message in report.refused:
        print(f"{prefix}not written: {message}", file=sys.stderr)
    return 0
