"""Batch entry points of the core: form factors (eq. 4), irradiance (eq. 3) and radiance (eq. 5).

Receivers are processed in chunks of points; within a chunk everything is vectorised across points,
polygons and fragments. A chunk holds ``budget // (n_polygons × vertex slots)`` points, at most
``MAX_CHUNK_POINTS``, so the candidates' coordinate arrays stay below ``budget × 3 × 8`` bytes (12 MB at
the default 2**19; 4× that in a group of at most 64 receivers, :data:`.chunk.GROUP_CAP`) whatever the scene
size, and the clear tiles' edge terms go in batches of
``clear_tiles.EDGE_BATCH``. Both defaults were measured (9,468 polygons: 2**18 → 2**19 saves 10–20 %;
175 polygons: chunks of 384 points instead of 744 or 192 save 5–10 %; larger chunks lose cache locality, smaller
ones pay numpy's per-call overhead more often).

The chunks are a function of the job only (scene, receivers, budget); :mod:`.parallel` runs them in this
process (``workers=1``), on worker processes (default: every core) or on any executor, and stores each
chunk's result by its index, so the result is bit-identical whatever runs it.
"""

from __future__ import annotations

import concurrent.futures as cf
from collections.abc import Callable

import numpy as np

from .chunk import (
    DEFAULT_BUDGET,
    Cancelled,
    contour_by_width,
    prepare_scene,
    scene_hierarchy,
    scene_node_edges,
    scene_occluders,
    scene_tile_edges,
    visible,
    visible_fragments_with_ff,
)
from .clear_tiles import clear_form_factors, clear_irradiance
from .culling import Occluders
from .far_field import ROUNDING, FarFieldStats, far_field_irradiance, proxy_scene
from .parallel import PREPARE_LOCK, run_chunks
from .receivers import idle_limits_dropped, limit_groups, prepare_receivers
from .scene import Scene

__all__ = ["Cancelled", "FarFieldStats", "form_factors", "irradiance", "prepare_scene", "radiance",
           "visible_fragments_and_clear_tiles",
           "visible_fragments_with_ff"]

#: at most this many receivers per chunk: small scenes' chunks then stay in cache (175 polygons: chunks
#: of 150–220 points were ~10 % faster than of 744; after session 7's cuts, 384 is 5–10 % faster than 192,
#: CPU time interleaved: 0.246 / 0.274 ms per point fastest, 0.260 / 0.281 median of 7). Scenes of more
#: than ~680 polygons get smaller chunks from the budget anyway.
MAX_CHUNK_POINTS = 384
#: irradiance chunks are sized as for a scene of at most this many polygons (see :func:`irradiance`)
IRRADIANCE_CHUNK_POLYGONS = 682


# the visibility stage of a chunk and the scene preparation live in .chunk (also used by the inspector's
# project_point); these names stay here for the callers of the batch drivers
_prepare_receivers = prepare_receivers
_occluders = scene_occluders
_visible = visible
_contour_by_width = contour_by_width
_tile_edges = scene_tile_edges


def visible_fragments_and_clear_tiles(scene: Scene, points, normals, limit=None, *, occluders=None, include=None):
    """As :func:`visible_fragments_with_ff`, but the clear tiles (see :mod:`.clear_tiles`) are left out of
    the fragments and returned apart: ``(fragments, ff, clear)`` with ``clear = (pairs, tile_edges)`` or
    None. The fragments are the real visible pieces (with vertices) of everything else."""
    return _visible(scene, points, normals, limit, _occluders(scene, occluders), include, use_clear=True, signed=False)


def _chunks(scene: Scene, m: int, budget: int, polygons: int | None = None):
    """Chunks ``(start, end)`` of ``m`` receivers: ``budget // ((polygons + 1) × K)`` points each (at most
    :data:`MAX_CHUNK_POINTS`); ``polygons`` defaults to the scene's (form factors: the output rows)."""
    k = scene.poly_vertices.shape[1] if scene.n_polygons else 3
    per_point = max(1, ((scene.n_polygons if polygons is None else polygons) + 1) * k)
    size = max(1, min(m, budget // per_point, MAX_CHUNK_POINTS))
    return [(s, min(m, s + size)) for s in range(0, m, size)]


_ALLOCATOR_READY = False


def _settle_allocator():
    """Free one 30 MB block, once per process.

    glibc's malloc adapts its mmap threshold to the largest block freed (up to 32 MB) and returns heap
    memory above twice that to the OS. A chunk's temporaries are a few MB each, so by default the heap
    is trimmed after every chunk and the next one faults its pages in afresh: ~94,000 page faults per
    five 1,024-point calls at 175 polygons, ~17 % of the time. After one 30 MB block has been freed the
    heap is kept up to 60 MB and the same calls take ~11,000. This is glibc's own rule, not a setting
    (no ``mallopt``); elsewhere it is one short-lived allocation.
    """
    global _ALLOCATOR_READY
    if not _ALLOCATOR_READY:
        np.empty(30 * 2**20 // 8)
        _ALLOCATOR_READY = True


def _run(scene, occ, points, normals, limit_directions, progress, cancel, budget, chunk_fn, out, workers,
         executor, polygons=None, extra=()):
    """``out[s:e] = chunk_fn((scene, occ, budget), p, n, u)`` for every chunk ``(s, e)`` of the receivers
    (sized by :func:`_chunks` with ``polygons``), here or on workers (see :func:`.parallel.run_chunks`);
    ``out`` is ``(m, ...)``; ``extra``: further arguments of every chunk (after ``p, n, u``)."""
    _settle_allocator()
    p, n, u = _prepare_receivers(points, normals, limit_directions)
    u = idle_limits_dropped(scene, p, n, u)  # the limit path costs ~10x; most vertex receivers need none
    reps, copies = _distinct_receivers(p, n, u)
    if reps is not None:
        # the same receiver several times (a mesh vertex's corners on one plane, their idle limits dropped):
        # evaluated once, the value copied; a receiver's value does not depend on the others of its call
        # (tests/core/test_receiver_independence.py), so the copies are bit for bit their own evaluations
        full = out
        out = np.zeros((len(reps),) + full.shape[1:], dtype=full.dtype)
        p, n, u = p[reps], n[reps], None if u is None else u[reps]
    chunks = _chunks(scene, len(p), budget, polygons)
    if len(chunks) > 1 and (executor is not None or workers != 1) and len(occ.tile_occluder):
        with PREPARE_LOCK:
            _tile_edges(scene, occ)  # prepared once here and shipped with the scene, not in every worker
            scene_hierarchy(scene, occ)
            if chunk_fn is _irradiance_far_chunk and not scene.linear:
                scene_node_edges(scene, occ)

    def args_of(s, e):
        # fresh arrays in every case: a chunk sees the same memory layout here and in a worker
        return (chunk_fn, p[s:e].copy(), n[s:e].copy(), None if u is None else u[s:e].copy()) + tuple(extra)

    def store(s, e, value):
        out[s:e] = value

    run_chunks(_limits_apart, (scene, occ, budget), chunks, args_of, store, workers=workers, executor=executor,
               progress=progress, cancel=cancel, key=scene)
    if reps is not None:
        full[:] = out[copies]


def _distinct_receivers(p, n, u):
    """``(reps (k,), copies (m,))`` with ``receiver i == receiver reps[copies[i]]`` bit for bit (point, normal and
    limit direction), ``reps`` in their first order; ``(None, None)`` when all ``m`` receivers differ."""
    m = len(p)
    if m < 2:
        return None, None
    key = np.ascontiguousarray(np.column_stack([p, n] + ([] if u is None else [u])))
    rows = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1]))).reshape(-1)  # the bytes: -0.0 != 0.0
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    if len(first) == m:
        return None, None
    order = np.argsort(first, kind="stable")  # distinct receivers in the order they came (chunks stay coherent)
    rank = np.empty(len(first), dtype=np.int64)
    rank[order] = np.arange(len(first))
    return first[order], rank[inverse.reshape(-1)]


def _limits_apart(shared, chunk_fn, p, n, u, *extra) -> np.ndarray:
    """``chunk_fn(shared, p, n, u, *extra)`` on the chunk's receivers with and without a one-sided limit apart
    (:func:`.receivers.limit_groups`): ``(m_chunk, ...)``."""
    groups = limit_groups(u)
    if len(groups) == 1:
        return chunk_fn(shared, p, n, groups[0][1], *extra)
    parts = [(at, chunk_fn(shared, p[at], n[at], lim, *extra)) for at, lim in groups]
    out = np.empty((len(p),) + parts[0][1].shape[1:], dtype=np.result_type(*(v for _, v in parts)))
    for at, value in parts:
        out[at] = value
    return out


def _form_factor_chunk(shared, p, n, u) -> np.ndarray:
    """One chunk of :func:`form_factors`: ``(m_chunk, n_input)``."""
    _settle_allocator()  # also in worker processes
    scene, occ, budget = shared
    m = len(p)
    frags, ff, clear = _visible(scene, p, n, u, occ, None, use_clear=True, budget=budget)
    point, poly = frags.point, frags.poly
    if clear is not None:
        cp, cpoly, cff = clear_form_factors(clear[1], occ, clear[0], p, n, scene.poly_vertices)
        point, poly, ff = np.concatenate([point, cp]), np.concatenate([poly, cpoly]), np.concatenate([ff, cff])
    key = point * scene.n_input + scene.poly_source[poly]
    # float64 even when nothing is seen (bincount of empty int weights is int64)
    out = np.bincount(key, weights=ff, minlength=m * scene.n_input).astype(np.float64, copy=False)
    out = out.reshape(m, scene.n_input)
    # a polygon can fill the hemisphere (F = 1 exactly); the fragment sum may round to 1 + 2e-16, and
    # a hidden polygon's terms (F(A) - F(A ∩ V)) to -1e-17
    np.clip(out, 0.0, 1.0, out=out)
    return out


def form_factors(
    scene: Scene,
    points,
    normals,
    *,
    limit_directions=None,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    occluders: Occluders | None = None,
    budget: int = DEFAULT_BUDGET,
    workers: int | None = None,
    executor: cf.Executor | None = None,
) -> np.ndarray:
    """Visible form factor of every input polygon from every receiver (eq. 2/4 with exact visibility).

    Args:
        scene: the scene.
        points: (m, 3) receiver positions (world space); normals: (m, 3) receiver normals (normalised here).
        limit_directions: (m, 3) tangent directions u or None. Where non-zero, the one-sided limit at
            ``P + εu`` (ε → 0+) is returned instead of the value at P itself: at the foot of a wall or in
            a room corner the exact value at P sees the walls edge-on (ΣF = 0.5 or 0.25 in a closed
            box); the limit from inside the face sees them as any point of the face does.
        progress: called as ``progress(done, total)`` after each chunk.
        cancel: called before each chunk (and while waiting for workers); returning True raises
            :class:`Cancelled` (worker processes are stopped first).
        workers: worker processes (None: every core this process may use, ``os.sched_getaffinity``;
            1: this process only). Ignored when ``executor`` is given.
        executor: any :class:`concurrent.futures.Executor` to run the chunks on (a
            :class:`.parallel.WorkerPool` kept for many calls, a ``dask.distributed`` Client's
            ``get_executor()`` for a cluster). The result is bit-identical for any workers and executor.
    Returns:
        (m, n_input) float64. Polygons are opaque from both sides; the factor is geometric (it does not
        depend on which side emits). In a closed scene every row sums to 1.
    """
    out = np.zeros((len(np.asarray(points).reshape(-1, 3)), scene.n_input))
    with PREPARE_LOCK:  # see parallel.PREPARE_LOCK
        occ = _occluders(scene, occluders)
    # a chunk's output rows hold (points × n_input); its candidates are bounded by the visibility stage
    _run(scene, occ, points, normals, limit_directions, progress, cancel, budget, _form_factor_chunk, out, workers,
         executor, polygons=max(scene.n_polygons // 8, IRRADIANCE_CHUNK_POLYGONS))
    return out


def _emitter_mask(scene: Scene) -> np.ndarray:
    """(n,) polygons with any non-zero radiance (the only ones whose fragments irradiance needs)."""
    if scene.linear:
        emits = (scene.corner_radiance != 0).any(axis=(1, 2))
    else:
        emits = (scene.poly_radiance != 0).any(axis=1)
    if (scene.dup_rep == np.arange(scene.n_polygons)).all():
        return emits
    # a group is projected if any copy emits (bincount: ufunc.at is ~10x slower on 10^6 polygons)
    group = np.bincount(scene.dup_rep, weights=emits, minlength=scene.n_polygons) > 0
    return group[scene.dup_rep]


def irradiance(
    scene: Scene,
    points,
    normals,
    *,
    limit_directions=None,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    occluders: Occluders | None = None,
    budget: int = DEFAULT_BUDGET,
    workers: int | None = None,
    executor: cf.Executor | None = None,
    tolerance=0.0,
    return_stats: bool = False,
):
    """Irradiance ``H = ∫ L cosθ dω = π Σ_i L_i F_i`` at every receiver, ``(m, 3)`` float64 (W m^-2).

    This is the paper's eq. 1 with radiance ``L_i`` (W sr^-1 m^-2) on the polygons. Its eq. 2–3 write
    ``H = Σ L_i F_i``, which holds when ``L_i`` is read as the radiosity ``B_i = π L_i``; with radiance
    the factor π is needed for eq. 5 (``L = E + ρ/π H``, :func:`radiance`) to give the diffusely
    reflected radiance ``E + ρ Σ L_i F_i`` — what a path tracer (Cycles) renders.

    Polygons emit from their front side only unless the scene is ``double_sided``; polygons with zero
    radiance are only occluders. With per-corner radiance, radiance varies linearly over each triangle and
    is integrated over the visible fragments (see :mod:`.linear_radiance`). Arguments as for
    :func:`form_factors`, and:

    Args:
        tolerance: absolute tolerance on H (W m^-2), a number or one per channel (3,), >= 0. 0 (the
            default) is the exact result. With ``tolerance > 0`` (constant radiance per polygon) clear
            parts of the spatial hierarchy are summed whole over their welded edges and edges between
            polygons of nearly equal radiance may be bounded instead of computed (:mod:`.far_field`); the
            bound used is at most the tolerance per receiver and channel (plus a rounding allowance of
            ~1e-10 of the sums; :data:`.far_field.ROUNDING`). Form factors have one weight per polygon
            and take no tolerance.
        return_stats: also return a :class:`.far_field.FarFieldStats` (``error_bound (m, 3)``):
            ``(H, stats)``.
    """
    m = len(np.asarray(points).reshape(-1, 3))
    tol = _tolerance(tolerance)
    far = bool((tol > 0).any()) and not scene.linear
    out = np.zeros((m, 10 if far else 3))
    with PREPARE_LOCK:  # see parallel.PREPARE_LOCK
        occ = _occluders(scene, occluders)
        if far:
            # half the tolerance for the nearly uniform faces (proxies), half (all without proxies) for the
            # clear nodes' linear proxies and the edges left out
            given = scene
            scene, _ = proxy_scene(given, occ, 0.5 * tol)
            if scene is not given:
                occ = _occluders(scene, None)
                tol = 0.5 * tol
        _radiance_tables(scene)  # once here, and shipped to the workers with the scene
    # the chunk's candidates are bounded by the visibility stage itself (it splits a chunk whose surviving
    # tiles hold too many), and the output is (m, 3): chunks need not shrink with the scene's size
    _run(scene, occ, points, normals, limit_directions, progress, cancel, budget,
         _irradiance_far_chunk if far else _irradiance_chunk, out, workers, executor,
         polygons=min(scene.n_polygons, IRRADIANCE_CHUNK_POLYGONS), extra=(tol,) if far else ())
    h = out[:, :3] if far else out
    if far:
        h = np.ascontiguousarray(h)
    if not return_stats:
        return h
    if not far:
        return h, FarFieldStats(tol, np.zeros((m, 3)), np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m))
    return h, FarFieldStats(tol, np.ascontiguousarray(out[:, 3:6]), out[:, 6].copy(), out[:, 7].copy(),
                            out[:, 8].copy(), out[:, 9].copy())


def _tolerance(tolerance) -> np.ndarray:
    """``tolerance`` as a (3,) float64 array, checked: finite and >= 0."""
    tol = np.asarray(tolerance, dtype=np.float64)
    if tol.ndim > 1 or (tol.ndim == 1 and len(tol) != 3) or not np.isfinite(tol).all() or (tol < 0).any():
        raise ValueError(f"tolerance must be a number >= 0 or three of them (W/m2 per channel), got {tolerance!r}")
    return np.broadcast_to(tol, (3,)).copy()


def _radiance_tables(scene: Scene):
    """``(emits (n,), radiance columns (3, n) or None, nonnegative)`` for :func:`irradiance`, computed once
    per scene (O(n) passes per call are what a scene with 10^6 hidden polygons must not cost per point)."""
    cached = getattr(scene, "_radiance_tables", None)
    if cached is None:
        rad_cols = None if scene.linear else np.ascontiguousarray(scene.poly_radiance.T)   # (3, n) for gathers
        nonnegative = bool((scene.corner_radiance >= 0).all() if scene.linear else (scene.poly_radiance >= 0).all())
        cached = (_emitter_mask(scene), rad_cols, nonnegative)
        scene._radiance_tables = cached
    return cached


def _irradiance_chunk(shared, p, n, u) -> np.ndarray:
    """One chunk of :func:`irradiance`: ``(m_chunk, 3)``."""
    _settle_allocator()  # also in worker processes
    scene, occ, budget = shared
    emits, rad_cols, nonnegative = _radiance_tables(scene)
    m = len(p)
    out = np.zeros((m, 3))
    include = np.broadcast_to(emits[None, :], (m, scene.n_polygons))
    frags, ff, clear = _visible(scene, p, n, u, occ, include, use_clear=not scene.linear, budget=budget)
    lit = frags.side < 0 if not scene.double_sided else np.ones(len(ff), dtype=bool)
    if scene.linear:
        from .linear_radiance import linear_irradiance

        tri = scene.poly_vertices[frags.poly, :3] - p[frags.point][:, None, :]
        contrib = linear_irradiance(frags.verts, frags.counts, n[frags.point], scene.poly_normals[frags.poly],
                                    tri, scene.corner_radiance[frags.poly], form_factor=ff)
        contrib = np.where(lit[:, None], contrib, 0.0)
        for c in range(3):
            out[:, c] = np.pi * np.bincount(frags.point, weights=contrib[:, c], minlength=m)
    else:
        w = np.where(lit, ff, 0.0)
        for c in range(3):
            out[:, c] = np.pi * np.bincount(frags.point, weights=w * rad_cols[c][frags.poly], minlength=m)
    if clear is not None:
        out += np.pi * clear_irradiance(clear[1], clear[0], p, n, scene.double_sided)
    if nonnegative:
        # the sums mix signed terms (F(A) - F(A ∩ V), welded edges); with radiance >= 0 the exact
        # irradiance is >= 0, and a rounding-level -1e-22 where nothing is seen is clamped
        np.maximum(out, 0.0, out=out)
    return out


def _irradiance_far_chunk(shared, p, n, u, tol) -> np.ndarray:
    """One chunk of :func:`irradiance` with a tolerance: ``(m_chunk, 10)``: H, its error bound, edges skipped,
    edges summed, clear nodes and linear proxies per receiver (see :class:`.far_field.FarFieldStats`)."""
    _settle_allocator()  # also in worker processes
    scene, occ, budget = shared
    emits, rad_cols, nonnegative = _radiance_tables(scene)
    m = len(p)
    out = np.zeros((m, 10))
    include = np.broadcast_to(emits[None, :], (m, scene.n_polygons))
    frags, ff, clear = _visible(scene, p, n, u, occ, include, use_clear=True, budget=budget, far_field=True,
                                far_tolerance=tol)
    lit = frags.side < 0 if not scene.double_sided else np.ones(len(ff), dtype=bool)
    w = np.where(lit, ff, 0.0)
    half = getattr(scene, "_half_range", None)
    for c in range(3):
        lw = w * rad_cols[c][frags.poly]
        out[:, c] = np.pi * np.bincount(frags.point, weights=lw, minlength=m)
        # rounding allowance: this sum and the exact path's add (partly) different terms
        out[:, 3 + c] = ROUNDING * np.pi * np.bincount(frags.point, weights=np.abs(lw), minlength=m)
        if half is not None:  # the proxies' bound, π Σ ½ range F (the signed terms sum to F >= 0)
            hw = w * half[frags.poly, c]
            out[:, 3 + c] += (np.abs(np.pi * np.bincount(frags.point, weights=hw, minlength=m))
                              + ROUNDING * np.pi * np.bincount(frags.point, weights=np.abs(hw), minlength=m))
        if frags.ff_bound is not None:  # the float64 sums kept where the exact path redoes them (and |hw|'s)
            fb = np.where(lit, frags.ff_bound, 0.0) * (np.abs(rad_cols[c][frags.poly])
                                                       + (0.0 if half is None else half[frags.poly, c]))
            out[:, 3 + c] += np.pi * np.bincount(frags.point, weights=fb, minlength=m)
    out[:, 3:6] *= 1.0 + 1e-9
    if clear is not None:
        pairs, _, nodes = clear
        point = np.concatenate([nodes[0], pairs.point])
        node = np.concatenate([nodes[1], pairs.tile])       # a tile is the hierarchy's leaf of the same id
        side = np.concatenate([nodes[2], pairs.side])
        lit = np.ones(len(side), dtype=bool) if scene.double_sided else side < 0
        hier = scene_hierarchy(scene, occ)
        h, bound, skipped, summed, linear = far_field_irradiance(scene_node_edges(scene, occ), hier, point[lit],
                                                                 node[lit], side[lit], p, n, tol, te=clear[1])
        out[:, :3] += h
        out[:, 3:6] += bound
        out[:, 6], out[:, 7] = skipped, summed
        out[:, 8] = np.bincount(nodes[0], minlength=m)
        out[:, 9] = linear
    if nonnegative:
        np.maximum(out[:, :3], 0.0, out=out[:, :3])
    return out


def radiance(scene: Scene, points, normals, reflectivity, emission=0.0, **kwargs) -> np.ndarray:
    """Outgoing radiance ``L = E + ρ/π H`` (eq. 5) of diffuse receivers, ``(m, 3)`` float64.

    With :func:`irradiance`'s ``H = π Σ L_i F_i`` this is ``E + ρ Σ L_i F_i`` (W sr^-1 m^-2).

    ``reflectivity`` ρ and ``emission`` E broadcast to ``(m, 3)`` (scalars, RGB triples or per point).
    Other keyword arguments go to :func:`irradiance`; with ``return_stats=True`` the result is ``(L,
    stats)`` and ``stats.error_bound`` is the bound on L (``ρ/π`` times the bound on H).
    """
    res = irradiance(scene, points, normals, **kwargs)
    h, stats = res if kwargs.get("return_stats") else (res, None)
    rho = np.broadcast_to(np.asarray(reflectivity, dtype=np.float64), h.shape)
    e = np.broadcast_to(np.asarray(emission, dtype=np.float64), h.shape)
    out = e + rho / np.pi * h
    if stats is None:
        return out
    return out, FarFieldStats(stats.tolerance, np.abs(rho) / np.pi * stats.error_bound, stats.edges_skipped,
                              stats.edges_summed, stats.clear_nodes, stats.linear_proxies)
