"""Batch entry points of the core: form factors (eq. 4), irradiance (eq. 3) and radiance (eq. 5).

Receivers are processed in chunks of points; within a chunk everything is vectorised across points,
polygons and fragments. A chunk holds ``budget // (n_polygons × vertex slots)`` points, at most
``MAX_CHUNK_POINTS``, so the candidates' coordinate arrays stay below ``budget × 3 × 8`` bytes (12 MB at
the default 2**19) whatever the scene size, and the clear tiles' edge terms go in batches of
``clear_tiles.EDGE_BATCH``. Both defaults were measured (9,468 polygons: 2**18 → 2**19 saves 10–20 %;
175 polygons: chunks of 192 points instead of 744 save ~10 %; larger chunks lose cache locality).

The chunks are a function of the job only (scene, receivers, budget); :mod:`.parallel` runs them in this
process (``workers=1``), on worker processes (default: every core) or on any executor, and stores each
chunk's result by its index, so the result is bit-identical whatever runs it.
"""

from __future__ import annotations

import concurrent.futures as cf
from collections.abc import Callable

import numpy as np

from .clear_tiles import TileEdges, clear_form_factors, clear_irradiance, clear_pairs, tile_edges
from .culling import Occluders, build_occluders
from .form_factor import contour_integral
from .parallel import PREPARE_LOCK, Cancelled, run_chunks
from .projection import hemisphere_candidates
from .rowops import take_rows
from .scene import Scene
from .tolerances import COORD_EPS
from .visibility import Fragments, coverage, occluder_pairs, shadow_volumes, subtract_shadow_volumes, visible_terms

__all__ = ["Cancelled", "form_factors", "irradiance", "radiance", "visible_fragments_and_clear_tiles",
           "visible_fragments_with_ff"]

DEFAULT_BUDGET = 2**19
#: at most this many receivers per chunk: small scenes' chunks then stay in cache (175 polygons: chunks
#: of 150–220 points are ~10 % faster than of 744; the per-chunk overhead is already negligible there)
MAX_CHUNK_POINTS = 192


def _prepare_receivers(points, normals, limit_directions=None, *, single=False):
    """Validate receivers; return ``P (m, 3)``, unit ``N (m, 3)`` and tangent ``U (m, 3)`` or None."""
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if single:
        p, n = p.reshape(1, -1), n.reshape(1, -1)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (m, 3), got {p.shape}")
    if n.shape != p.shape:
        raise ValueError(f"normals must have shape {p.shape}, got {n.shape}")
    bad = np.flatnonzero(~(np.isfinite(p).all(axis=1) & np.isfinite(n).all(axis=1)))
    if len(bad):
        raise ValueError(f"receiver {int(bad[0])} has a non-finite point or normal ({p[bad[0]]}, {n[bad[0]]})")
    length = np.linalg.norm(n, axis=1)
    bad = np.flatnonzero(~(length > 0))
    if len(bad):
        raise ValueError(f"receiver {int(bad[0])} has a zero normal")
    n = n / length[:, None]
    u = None
    if limit_directions is not None:
        u = np.asarray(limit_directions, dtype=np.float64)
        if single:
            u = u.reshape(1, -1)
        if u.shape != p.shape:
            raise ValueError(f"limit_directions must have shape {p.shape}, got {u.shape}")
        if not np.isfinite(u).all():
            raise ValueError("limit_directions must be finite")
        u = u - np.einsum("mc,mc->m", u, n)[:, None] * n       # keep it in the tangent plane
        ul = np.linalg.norm(u, axis=1)
        u = np.where((ul > 1e-12)[:, None], u / np.where(ul > 0, ul, 1.0)[:, None], 0.0)
        if not u.any():
            u = None
    return p, n, u


def _occluders(scene: Scene, occluders: Occluders | None) -> Occluders:
    if occluders is not None:
        return occluders
    occ = getattr(scene, "_occluders", None)
    if occ is None:
        occ = build_occluders(scene)
        scene._occluders = occ
    return occ


def visible_fragments_with_ff(scene: Scene, points, normals, limit=None, *, occluders=None, include=None):
    """Visible fragments of every polygon for receivers ``points, normals (m, 3)`` and their form factors.

    Returns ``(fragments, ff)`` with ``ff (F,)`` the form factor of each fragment (eq. 4, >= 0).
    """
    frags, ff, _ = _visible(scene, points, normals, limit, _occluders(scene, occluders), include, use_clear=False)
    return frags, ff


def visible_fragments_and_clear_tiles(scene: Scene, points, normals, limit=None, *, occluders=None, include=None):
    """As :func:`visible_fragments_with_ff`, but the clear tiles (see :mod:`.clear_tiles`) are left out of
    the fragments and returned apart: ``(fragments, ff, clear)`` with ``clear = (pairs, tile_edges)`` or
    None. The fragments are the real visible pieces (with vertices) of everything else."""
    return _visible(scene, points, normals, limit, _occluders(scene, occluders), include, use_clear=True, signed=False)


def _tile_edges(scene: Scene, occ: Occluders) -> TileEdges:
    cached = getattr(scene, "_tile_edges", None)
    if cached is None or cached[0] is not occ:
        cached = (occ, tile_edges(scene, occ))
        scene._tile_edges = cached
    return cached[1]


def _visible(scene: Scene, points, normals, limit, occ: Occluders, include, *, use_clear: bool,
             signed: bool | None = None):
    """The visibility stage: ``(fragments, ff, clear)``; with ``use_clear`` (callers that only sum over
    fragments) the clear tiles (see :mod:`.clear_tiles`) are left out of the fragments and returned as
    ``clear = (pairs, tile_edges)``, and the visible parts come as signed terms (see
    :func:`.visibility.visible_terms`): ``ff`` is then negative for the terms to subtract, and the
    fragments carry no vertices (``verts`` None), only their ids; ``signed=False`` keeps the clear tiles
    apart but subtracts the rest into real fragments."""
    signed = use_clear if signed is None else signed
    reps = scene.dup_rep == np.arange(scene.n_polygons)
    if not reps.all():  # identical copies are projected once (see Scene._find_duplicates)
        include = reps[None, :] if include is None else include & reps[None, :]
    sv, table = shadow_volumes(occ, points, normals, limit)
    cov = coverage(sv, table, occ, points)
    skip = cov.hidden_tiles
    clear = None
    if use_clear and len(occ.tile_occluder):
        te = _tile_edges(scene, occ)
        pairs = clear_pairs(te, occ, cov, sv, table, points, normals, limit)
        skip = skip | pairs.mask
        clear = (pairs, te)
    cand = hemisphere_candidates(scene, points, normals, limit, include, occ, skip)
    ptr, ids, planes, hidden = occluder_pairs(cand, sv, table, cov, occ, scene, points)
    allc = Fragments(cand.verts, cand.inf, cand.counts, cand.point, cand.poly, cand.side, np.arange(len(hidden)))
    flat = None if cand.flat is None else (cand.flat, scene.poly_normals)
    if signed:
        # signed terms, integrated set by set; the sums need only their ids (verts None)
        terms = visible_terms(allc, ptr, ids, sv, planes, ~hidden, flat)
        ff = np.concatenate([sign * np.maximum(t.side * _contour_by_width(t, normals, points), 0.0)
                             for t, sign in terms] or [np.zeros(0)])
        frags = Fragments(None, None, *(np.concatenate([getattr(t, a) for t, _ in terms] or [np.zeros(0, dtype=int)])
                                        for a in ("counts", "point", "poly", "side", "owner")))
    else:
        frags = subtract_shadow_volumes(allc.take(~hidden), ptr, ids, sv, planes, flat)
        # a fragment's exact factor is >= 0; rounding can leave -1e-17 on a sliver
        ff = np.maximum(frags.side * _contour_by_width(frags, normals, points), 0.0)
    if not reps.all():
        # credit each fragment to the copy that faces the receiver (then the lowest index)
        rep = frags.poly
        opp = scene.dup_opp[rep]
        use_opp = (frags.side > 0) & (opp >= 0)
        frags.poly = np.where(use_opp, opp, scene.dup_same[rep])
        frags.side = np.where(use_opp, -frags.side, frags.side)
    return frags, ff, clear


def _contour_by_width(frags: Fragments, normals, points) -> np.ndarray:
    """Eq. 4 for every fragment, the many small ones (<= 4 vertices) without their padding slots."""
    width = frags.verts.shape[1]
    small = frags.counts <= 4
    noise = None if frags.inf is None else COORD_EPS * np.abs(points).max(axis=1)[frags.point]
    if width <= 4 or small.all() or not small.any():
        return contour_integral(frags.verts, take_rows(normals, frags.point), frags.inf, noise)
    out = np.empty(len(frags.counts))
    for sel, w in ((np.flatnonzero(small), 4), (np.flatnonzero(~small), width)):
        out[sel] = contour_integral(take_rows(frags.verts[:, :w], sel), take_rows(normals, frags.point[sel]),
                                    None if frags.inf is None else take_rows(frags.inf[:, :w], sel),
                                    None if noise is None else noise[sel])
    return out


def _chunks(scene: Scene, m: int, budget: int):
    k = scene.poly_vertices.shape[1] if scene.n_polygons else 3
    per_point = max(1, (scene.n_polygons + 1) * k)
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
         executor):
    """``out[s:e] = chunk_fn((scene, occ), p, n, u)`` for every chunk ``(s, e)`` of the receivers, here or on
    workers (see :func:`.parallel.run_chunks`); ``out`` is ``(m, ...)``."""
    _settle_allocator()
    p, n, u = _prepare_receivers(points, normals, limit_directions)
    chunks = _chunks(scene, len(p), budget)
    if len(chunks) > 1 and (executor is not None or workers != 1) and len(occ.tile_occluder):
        with PREPARE_LOCK:
            _tile_edges(scene, occ)  # prepared once here and shipped with the scene, not in every worker

    def args_of(s, e):
        # fresh arrays in every case: a chunk sees the same memory layout here and in a worker
        return p[s:e].copy(), n[s:e].copy(), None if u is None else u[s:e].copy()

    def store(s, e, value):
        out[s:e] = value

    run_chunks(chunk_fn, (scene, occ), chunks, args_of, store, workers=workers, executor=executor,
               progress=progress, cancel=cancel, key=scene)


def _form_factor_chunk(shared, p, n, u) -> np.ndarray:
    """One chunk of :func:`form_factors`: ``(m_chunk, n_input)``."""
    _settle_allocator()  # also in worker processes
    scene, occ = shared
    m = len(p)
    frags, ff, clear = _visible(scene, p, n, u, occ, None, use_clear=True)
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
    _run(scene, occ, points, normals, limit_directions, progress, cancel, budget, _form_factor_chunk, out, workers,
         executor)
    return out


def _emitter_mask(scene: Scene) -> np.ndarray:
    """(n,) polygons with any non-zero radiance (the only ones whose fragments irradiance needs)."""
    if scene.linear:
        emits = (scene.corner_radiance != 0).any(axis=(1, 2))
    else:
        emits = (scene.poly_radiance != 0).any(axis=1)
    group = np.zeros(scene.n_polygons, dtype=bool)
    np.logical_or.at(group, scene.dup_rep, emits)      # a group is projected if any copy emits
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
) -> np.ndarray:
    """Irradiance ``H = ∫ L cosθ dω = π Σ_i L_i F_i`` at every receiver, ``(m, 3)`` float64 (W m^-2).

    This is the paper's eq. 1 with radiance ``L_i`` (W sr^-1 m^-2) on the polygons. Its eq. 2–3 write
    ``H = Σ L_i F_i``, which holds when ``L_i`` is read as the radiosity ``B_i = π L_i``; with radiance
    the factor π is needed for eq. 5 (``L = E + ρ/π H``, :func:`radiance`) to give the diffusely
    reflected radiance ``E + ρ Σ L_i F_i`` — what a path tracer (Cycles) renders.

    Polygons emit from their front side only unless the scene is ``double_sided``; polygons with zero
    radiance are only occluders. With per-corner radiance, radiance varies linearly over each triangle and
    is integrated over the visible fragments (see :mod:`.linear_radiance`). Arguments as for
    :func:`form_factors`.
    """
    m = len(np.asarray(points).reshape(-1, 3))
    out = np.zeros((m, 3))
    with PREPARE_LOCK:  # see parallel.PREPARE_LOCK
        occ = _occluders(scene, occluders)
        _irradiance_inputs(scene)  # once here, and shipped to the workers with the scene
    _run(scene, occ, points, normals, limit_directions, progress, cancel, budget, _irradiance_chunk, out, workers,
         executor)
    return out


def _irradiance_inputs(scene: Scene):
    """``(emits (n,) bool, radiance columns (3, n) or None, nonnegative)`` for :func:`irradiance`; cached."""
    cached = getattr(scene, "_irradiance_inputs", None)
    if cached is None:
        emits = _emitter_mask(scene)
        rad_cols = None if scene.linear else np.ascontiguousarray(scene.poly_radiance.T)  # (3, n) for gathers
        nonnegative = bool((scene.corner_radiance >= 0).all() if scene.linear else (scene.poly_radiance >= 0).all())
        cached = scene._irradiance_inputs = (emits, rad_cols, nonnegative)
    return cached


def _irradiance_chunk(shared, p, n, u) -> np.ndarray:
    """One chunk of :func:`irradiance`: ``(m_chunk, 3)``."""
    _settle_allocator()  # also in worker processes
    scene, occ = shared
    emits, rad_cols, nonnegative = _irradiance_inputs(scene)
    m = len(p)
    out = np.zeros((m, 3))
    include = np.broadcast_to(emits[None, :], (m, scene.n_polygons))
    frags, ff, clear = _visible(scene, p, n, u, occ, include, use_clear=not scene.linear)
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


def radiance(scene: Scene, points, normals, reflectivity, emission=0.0, **kwargs) -> np.ndarray:
    """Outgoing radiance ``L = E + ρ/π H`` (eq. 5) of diffuse receivers, ``(m, 3)`` float64.

    With :func:`irradiance`'s ``H = π Σ L_i F_i`` this is ``E + ρ Σ L_i F_i`` (W sr^-1 m^-2).

    ``reflectivity`` ρ and ``emission`` E broadcast to ``(m, 3)`` (scalars, RGB triples or per point).
    Other keyword arguments go to :func:`irradiance`.
    """
    h = irradiance(scene, points, normals, **kwargs)
    rho = np.broadcast_to(np.asarray(reflectivity, dtype=np.float64), h.shape)
    e = np.broadcast_to(np.asarray(emission, dtype=np.float64), h.shape)
    return e + rho / np.pi * h
