"""Irradiance gradients from the visible fragments, in closed form (paper sec. 5; Arvo 1994).

The exact irradiance at a receiver P with unit normal N is a sum over the visible fragments ``Ω_f``
(spherical polygons, paper sec. 2.5) of

    H = Σ_f ∫_{Ω_f} L_f(ω) (N·ω) dω                                           (eq. 1/3, W m⁻²)

Translational gradient ∂H/∂P (N held fixed)
-------------------------------------------
By Reynolds' transport theorem on the sphere, for a displacement δ of P

    dH = Σ_f [ ∫_{Ω_f} ∂_δ L_f (N·ω) dω  +  ∮_{∂Ω_f} L_f (N·ω) v_out dl ]

where ``v_out`` is the outward normal speed of the fragment's boundary (Arvo, "The Irradiance Jacobian
for Partially Occluded Polyhedral Sources", SIGGRAPH 94). Every fragment edge lies on a great
circle: the plane through P and a *fixed 3-D line* — a source polygon's edge, the line where the source
meets another polygon's plane (interpenetration, depth clip of sec. 2.4), or an occluder's silhouette
edge (the shadow-volume side planes of sec. 2.3) — or on the horizon ``N·ω = 0``, which does not move
when N is fixed (and where the integrand vanishes anyway). Vertex motion along the arcs does not
contribute (it is tangential to the boundary).

For a fixed line with *dual vector* ``q`` (P-local: the line is ``{x in the plane : q·x = 1}``, so that
``q·ω = 1/r(ω)`` with ``r`` the distance from P to the line along ω), the direction towards a point X of
the line changes by ``dω = −(δ − (δ·ω)ω)/r``, whose component normal to the circle is ``−(δ·n)/r``. So
``v_out = −(δ·n_out)(q·ω)`` and, with ``n_out = −σ ĉ`` (``ĉ = unit(a×b)`` of the edge a→b, σ = +1 for a
fragment counter-clockwise about the outward direction, see :func:`.form_factor.contour_integral`)

    ∂H/∂P = Σ_f σ_f Σ_e ĉ_e ∫_arc L_f (N·ω)(q_e·ω) dψ                        (G1)

On the arc write ``ω(ψ) = cos ψ f̂ + sin ψ ê`` with ê the edge direction and ``f̂ = ê × ĉ`` the direction
of the foot point of the edge's own line (distance ``h = |a×b|/|b−a|``); ψ runs over an interval of
length ``θ = atan2(|a×b|, a·b)`` (the atan2 form: exact for short edges, where ``acos`` loses half the
digits). With ``n1, n2 = N·f̂, N·ê`` and ``q1, q2 = q·f̂, q·ê``, and radiance ``L = ℓ0 + λ1 tan ψ`` along the
edge (constant: λ1 = 0; linear: ℓ0 = L at the foot point, ``λ1 = h g·ê``)

    ∫ (N·ω)(q·ω) L dψ = ℓ0 [n1q1 S0 + (n1q2 + n2q1) S1 + n2q2 S2] + λ1 [n1q1 S1 + (n1q2 + n2q1) S2 + n2q2 S3]

    S0 = ∫cos²ψ = θ/2 + ¼Δ sin2ψ,   S1 = ∫sinψ cosψ = ½Δ sin²ψ,   S2 = ∫sin²ψ = θ/2 − ¼Δ sin2ψ,
    S3 = ∫sin³ψ/cosψ = Δ(−log cosψ + ½cos²ψ)                                  (G2)

evaluated from the end points without cancellation (``cos ψ = h/|x|``, ``sin ψ = t/|x|``,
``t = x·ê``; see :func:`_arc_integrals`). For an edge on its own fixed line ``q = f̂/h`` (q1 = 1/h, q2 = 0).

Which fixed line an edge lies on is recovered here, from the geometry, without provenance from the
visibility stage: (1) an edge on a line of its source polygon's boundary is that line; (2) any other edge
is matched with the occluders' edges (:class:`.culling.Occluders`: merged faces, whose edges also carry
the convex solids' silhouettes) lying in its plane through P and spanning its mid-direction, and takes
the nearest of them if nearer than the edge itself (a shadow edge); (3) otherwise it is its own line (an
interpenetration/depth edge). In a generic configuration a plane through P holds at most one such line;
where two distinct ones coincide (a shadow edge falling exactly onto a source edge), H has a kink and
no gradient.

Tiles that nothing cuts (:mod:`.clear_tiles`) are whole polygons: their edges are their own lines, and an
edge two members share is evaluated once with the folded radiance weight (:func:`_clear_gradient`).
Per-edge gradients of unoccluded constant triangles are also what irradiance caching uses (Schwarzhaupt,
Jensen & Jarosz, "Practical Hessian-Based Error Control for Irradiance Caching", SIGGRAPH Asia 2012;
NREL/Radiance ``src/rt/ambcomp.c``, with an ``acos`` edge angle); (G1) is checked here independently
against the chain-rule derivative of Lambert's formula (tests/core/test_gradient.py).

Linear (CORNER/POINT) radiance has the interior term too: the radiance seen along a fixed ω changes
because the hit point ``x = P + t ω`` on the source plane ``n_s·x = n_s·V0`` moves,
``∂x/∂P·δ = δ − (n_s·δ)/(n_s·ω) ω``; with the in-plane radiance gradient g and ``D = n_s·(V0 − P)``

    ∫ (N·ω) ∂_P L dω = π (F g − (g·G) n_s / D)                               (G3)

with the fragment's form factor F (eq. 4) and first moment ``G = ∫ (x−P) cosθ cosθ'/(π r²) dA``
(:func:`.linear_radiance.first_moment`, Chen & Arvo 2000).

Rotational gradient ∂H/∂N (P held fixed)
----------------------------------------
Only the horizon depends on N, and the integrand ``L (N·ω)`` vanishes on it, so the derivative is the
interior term alone: ``∂H/∂N = ∫_Ω L ω dω =: V`` (the *vector irradiance* of Arvo 1994). For a
fragment of constant radiance ``∫ ω dω = ½ σ Σ_e ĉ_e θ_e`` (Lambert; the vector of eq. 4); for linear
radiance ``L(x) = L_P + g·x`` (x P-local, L_P the affine radiance extrapolated to P)
``∫ L ω dω = L_P ∫ ω dω + π T g`` with the symmetric tensor T of :mod:`.linear_radiance` (``G = T N``,
T from three :func:`.linear_radiance.first_moment` calls with the axes as normals). The returned
``∂H/∂N`` is the tangential part ``(I − N Nᵀ) V``: the derivative of ``H(P, N/|N|)`` at ``|N| = 1``, i.e.
for a rotation of N by a small vector angle φ (radians) ``dH = φ · (N × V)``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .csr import expand
from .culling import Occluders
from .form_factor import directions
from .local_pass import (
    DEFAULT_BUDGET,
    _emitter_mask,
    _occluders,
    _prepare_receivers,
    visible_fragments_and_clear_tiles,
    visible_fragments_with_ff,
)
from .receivers import idle_limits_dropped, limit_groups
from .scene import Scene
from .tolerances import COORD_EPS

__all__ = ["irradiance_gradient", "irradiance_normal_gradient"]

#: two lines (a fragment edge and an occluder edge, or a source edge) are taken to be the same plane
#: through P / the same line when they agree to this relative angle / distance (plus the rounding of the
#: fragment's clipped vertices and the coordinate noise). Distinct lines closer than this are a
#: visibility event (H has a kink there), not a configuration with a gradient.
LINE_MATCH_EPS = 1e-9
#: at most this many receivers per chunk (fewer in large scenes: the same ``budget`` rule as irradiance)
CHUNK_POINTS = 128
#: at most this many (edge, occluder) pairs are tested at once in the shadow-edge matching
PAIR_BUDGET = 2**21

_EPS = np.finfo(np.float64).eps


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _cross(a, b):
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _norm(a):
    return np.sqrt(_dot(a, a))


def _line_dual(a, b):
    """Dual vector ``q (.., 3)`` of the lines through ``a, b (.., 3)`` (P-local): ``q·x = 1`` on the line,
    q in the plane through P and the line, ``|q| = 1/h`` (h its distance from P). ``q = e × c / |c|²`` with
    ``e = b − a`` and ``c = a × e`` (= a × b without the cancellation of a short edge far from P)."""
    e = b - a
    c = _cross(a, e)
    c2 = _dot(c, c)
    return _cross(e, c) / np.where(c2 > 0, c2, 1.0)[..., None]


def _arc_integrals(a, b):
    """Geometry and the integrals (G2) of the edges ``a → b (E, 3)`` (P-local, non-degenerate).

    Returns ``(c_hat, f_hat, e_hat (E, 3), h (E,) length, theta (E,) radians, S (E, 4))``, S = S0..S3.
    ``Δ sin2ψ = 2h Δ(t/|x|²)``, ``Δ sin²ψ = h² (|b|² − |a|²)/(|a|²|b|²)``, ``Δ log cosψ = −½ log1p((b−a)·(b+a)/|a|²)``:
    every difference of end-point values is formed from differences of the end points themselves."""
    e = b - a
    el = _norm(e)
    c = _cross(a, e)
    s = _norm(c)
    c_hat = c / s[:, None]
    e_hat = e / el[:, None]
    f_hat = _cross(e_hat, c_hat)
    h = s / el
    theta = np.arctan2(s, _dot(a, b))
    a2, b2 = _dot(a, a), _dot(b, b)
    ta, tb = _dot(a, e_hat), _dot(b, e_hat)
    dsin2 = 2.0 * h * (tb / b2 - ta / a2)
    dsinsq = h * h * _dot(e, a + b) / (a2 * b2)
    s3 = 0.5 * np.log1p(_dot(e, a + b) / a2) - 0.5 * dsinsq
    S = np.stack([0.5 * theta + 0.25 * dsin2, 0.5 * dsinsq, 0.5 * theta - 0.25 * dsin2, s3], axis=1)
    return c_hat, f_hat, e_hat, h, theta, S


def _edge_integral(N, q, f_hat, e_hat, S, l0, lam1=None):
    """``∫ (N·ω)(q·ω) L dψ`` over the arcs (G2): N, q, f_hat, e_hat (E, 3), S (E, 4), l0 (E, C),
    lam1 (E, C) or None (constant radiance). Returns (E, C)."""
    n1, n2 = _dot(N, f_hat), _dot(N, e_hat)
    q1, q2 = _dot(q, f_hat), _dot(q, e_hat)
    w11, w12, w22 = n1 * q1, n1 * q2 + n2 * q1, n2 * q2
    base = w11 * S[:, 0] + w12 * S[:, 1] + w22 * S[:, 2]
    out = base[:, None] * l0
    if lam1 is not None:
        out = out + (w11 * S[:, 1] + w12 * S[:, 2] + w22 * S[:, 3])[:, None] * lam1
    return out


def _occluder_edges(scene: Scene, occ: Occluders):
    """The occluders' edges ``(O1, O2 (n_o, K_o, 3) world, valid (n_o, K_o))``, cached on the scene."""
    cached = getattr(scene, "_gradient_edges", None)
    if cached is not None and cached[0] is occ:
        return cached[1]
    v = occ.vertices
    k = v.shape[1]
    nxt = np.arange(k)[None, :] + 1
    nxt = np.where(nxt < occ.counts[:, None], nxt, 0)
    o2 = np.take_along_axis(v, nxt[..., None], axis=1)
    valid = (np.arange(k)[None, :] < occ.counts[:, None]) & (_norm(o2 - v) > 0)
    edges = (v, o2, valid)
    scene._gradient_edges = (occ, edges)
    return edges


def _plane_matches(occ: Occluders, edges, P, c_hat, tol):
    """The occluder edges lying in the planes through P of fragment edges: ``(row, A, B)`` with ``row (r,)``
    the edge and ``A, B (r, 3)`` the occluder edge's end points relative to its receiver.

    P (E, 3): each edge's receiver (world); c_hat (E, 3): the planes' unit normals; tol (E,): the
    relative angle within which a plane is the same. The plane distances of all occluder vertices are one
    matrix product ``ĉ·O − ĉ·P`` (world coordinates, so a loose first cut with the rounding of the world
    coordinates added), refined in P-local coordinates on the few that pass; in blocks of
    :data:`PAIR_BUDGET` (edge, vertex) pairs."""
    o1w, o2w, valid = edges
    n_o, k = valid.shape
    out_r, out_a, out_b = [np.zeros(0, dtype=np.int64)], [np.zeros((0, 3))], [np.zeros((0, 3))]
    if n_o == 0:
        return out_r[0], out_a[0], out_b[0]
    v1, v2 = o1w.reshape(-1, 3).T.copy(), o2w.reshape(-1, 3).T.copy()             # (3, V_o) world
    n1, n2 = _norm(v1.T), _norm(v2.T)
    ok_edge = valid.reshape(-1)
    step = max(1, PAIR_BUDGET // len(n1))
    for s in range(0, len(P), step):
        Ps, ch, ts = P[s:s + step], c_hat[s:s + step], tol[s:s + step]
        cp = _dot(ch, Ps)[:, None]
        pn = _norm(Ps)[:, None]
        both = None
        for v, vn in ((v1, n1), (v2, n2)):
            loose = (ts[:, None] + 8 * _EPS) * (vn[None] + pn)
            inp = np.abs(ch @ v - cp) <= loose                                     # (e, V_o)
            both = inp & ok_edge[None] if both is None else both & inp
        ie, ij = np.nonzero(both)
        io, j = np.divmod(ij, k)
        if len(ie) == 0:
            continue
        a = o1w[io, j] - Ps[ie]                                                    # (r, 3) P-local
        b = o2w[io, j] - Ps[ie]
        che, te = ch[ie], ts[ie][:, None]
        noise = COORD_EPS * np.abs(Ps[ie]).max(axis=1)
        ok = ((np.abs(_dot(a, che)) <= te[:, 0] * _norm(a) + noise)
              & (np.abs(_dot(b, che)) <= te[:, 0] * _norm(b) + noise))
        ok &= _norm(_cross(a, b - a)) > 0                                          # not through P
        out_r.append(s + ie[ok])
        out_a.append(a[ok])
        out_b.append(b[ok])
    return np.concatenate(out_r), np.concatenate(out_a), np.concatenate(out_b)


def _split_at(a, b, c_hat, row, A, B):
    """Cut the arcs ``a → b (E, 3)`` (points of their own lines, P-local) at the directions of the matched
    occluder edges' end points ``A, B (r, 3)`` (of edge ``row (r,)``) that fall inside them.

    Returns sub-edges ``(owner (S,), x0, x1 (S, 3))``, points of the same lines, in order along each
    edge. Where the shadow-volume planes of the visibility stage run on beyond an occluder's corner
    they cut fragments along lines that bound nothing (both sides visible): on each sub-arc the choice
    of line below is then the same from both sides, and the two terms cancel."""
    e = b - a
    rows, ts = [np.arange(len(a)), np.arange(len(a))], [np.zeros(len(a)), np.ones(len(a))]
    for O in (A, B):
        # the point a + t e of the own line in the direction of O: ((a + t e) × O)·ĉ = 0
        den = _dot(_cross(e[row], O), c_hat[row])
        t = -_dot(_cross(a[row], O), c_hat[row]) / np.where(den != 0, den, 1.0)
        x = a[row] + t[:, None] * e[row]
        inside = (den != 0) & (t > 0) & (t < 1) & (_dot(x, O) > 0)
        rows.append(row[inside])
        ts.append(t[inside])
    rows, ts = np.concatenate(rows), np.concatenate(ts)
    order = np.lexsort((ts, rows))
    rows, ts = rows[order], ts[order]
    pair = np.flatnonzero((rows[1:] == rows[:-1]) & (ts[1:] > ts[:-1]))
    owner = rows[pair]
    x0 = a[owner] + ts[pair, None] * e[owner]
    x1 = a[owner] + ts[pair + 1, None] * e[owner]
    # the end points exactly, where they are (t = 0, 1)
    x0 = np.where((ts[pair] == 0)[:, None], a[owner], x0)
    x1 = np.where((ts[pair + 1] == 1)[:, None], b[owner], x1)
    keep = _norm(_cross(x0, x1 - x0)) > 0                  # cuts that round onto each other
    return owner[keep], x0[keep], x1[keep]


def _nearest_lines(owner, x0, x1, q_own, row, A, B):
    """The line of every sub-arc ``x0 → x1 (S, 3)`` of edge ``owner (S,)``: the nearest (largest ``q·mid``)
    of its own line ``q_own (E, 3)`` and the matched occluder edges ``A → B`` of that edge spanning its
    mid-direction. Returns q (S, 3) and (S,) bool: an occluder edge's line was taken."""
    mid = x0 / _norm(x0)[:, None] + x1 / _norm(x1)[:, None]
    mid /= _norm(mid)[:, None]
    q = q_own[owner].copy()
    score = _dot(q, mid)
    taken = np.zeros(len(owner), dtype=bool)
    if len(row) == 0:
        return q, taken
    # (sub-arc, match) pairs of the same edge: matches sorted by edge, CSR over edges
    order = np.argsort(row, kind="stable")
    row, A, B = row[order], A[order], B[order]
    first = np.searchsorted(row, owner, side="left")
    count = np.searchsorted(row, owner, side="right") - first
    sub = np.repeat(np.arange(len(owner)), count)
    if len(sub) == 0:
        return q, taken
    k = np.arange(len(sub)) - np.repeat(np.cumsum(count) - count, count) + np.repeat(first, count)
    Ak, Bk, md = A[k], B[k], mid[sub]
    w = _cross(Ak, Bk - Ak)
    spans = (_dot(_cross(Ak, md), w) > 0) & (_dot(_cross(md, Bk), w) > 0)
    qo = _line_dual(Ak, Bk)
    sc = np.where(spans, _dot(qo, md), -np.inf)
    best = np.full(len(owner), -np.inf)
    np.maximum.at(best, sub, sc)
    win = spans & (sc == best[sub]) & (sc > score[sub])
    q[sub[win]] = qo[win]
    taken[sub[win]] = True
    return q, taken


def _whole_fragments(scene: Scene, frags, p):
    """(F,) bool: fragments that are their whole source polygon, vertex for vertex (the candidates'
    P-local vertices ``v − P`` are bitwise those computed here; a cut or clipped one differs)."""
    src = scene.poly_vertices[frags.poly]                                          # (F, Ks, 3)
    k = min(src.shape[1], frags.verts.shape[1])
    same = frags.counts == scene.poly_counts[frags.poly]
    if not same.any():
        return same
    rel = src[:, :k] - p[frags.point][:, None]
    used = np.arange(k)[None, :] < frags.counts[:, None]
    eq = (frags.verts[:, :k] == rel).all(axis=2) | ~used
    return same & eq.all(axis=1) & (frags.counts <= k)


def _on_source_boundary(scene: Scene, poly, p, c_hat, tol):
    """(E,) bool: the edges with plane normals ``c_hat (E, 3)`` through their receivers ``p (E, 3)`` lie on
    a line of their source polygon's boundary; and the dual vectors (E, 3) of those lines (from the
    source's own vertices, not the clipped ones).

    Both lie in the source's plane, which does not contain P: they are on one line exactly when they
    lie in one plane through P, i.e. when the source edge's end points are in the edge's plane (to the
    relative angle ``tol (E,)``)."""
    sv = scene.poly_vertices[poly] - p[:, None]                                    # (E, K, 3)
    k = sv.shape[1]
    cnt = scene.poly_counts[poly]
    nxt = np.where(np.arange(k)[None, :] + 1 < cnt[:, None], np.arange(k)[None, :] + 1, 0)
    d = np.abs(np.einsum("ekc,ec->ek", sv, c_hat))
    small = d <= tol[:, None] * _norm(sv) + COORD_EPS * np.abs(p).max(axis=1)[:, None]
    hit = small & np.take_along_axis(small, nxt, axis=1) & (np.arange(k)[None, :] < cnt[:, None])
    on = hit.any(axis=1)
    rows = np.flatnonzero(on)
    j = np.argmax(hit[rows], axis=1)
    q = np.zeros((len(poly), 3))
    q[rows] = _line_dual(sv[rows, j], sv[rows, nxt[rows, j]])
    return on, q


def _scatter(out, index, values):
    """``out[index[i]] += values[i]`` for ``out (m, ...)``, ``values (E, ...)`` (np.add.at, by sorted
    segment sums: the edges come grouped by receiver, up to the cut sub-arcs)."""
    if len(index) == 0:
        return
    flat = values.reshape(len(values), -1)
    if (np.diff(index) < 0).any():
        order = np.argsort(index, kind="stable")
        index, flat = index[order], flat[order]
    starts = np.flatnonzero(np.concatenate([[True], index[1:] != index[:-1]]))
    out.reshape(out.shape[0], -1)[index[starts]] += np.add.reduceat(flat, starts, axis=0)


def _triangle_gradient(tri, vals):
    """In-plane radiance gradient ``g (F, 3, C)`` of triangles ``tri (F, 3, 3)`` with corner values
    ``vals (F, 3, C)`` (barycentric, as :func:`.linear_radiance.linear_irradiance`)."""
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    nt = _cross(e1, e2)
    a2 = _dot(nt, nt)
    inv = np.where(a2 > 0, 1.0 / np.where(a2 > 0, a2, 1.0), 0.0)
    gl1 = _cross(e2, nt) * inv[:, None]
    gl2 = _cross(nt, e1) * inv[:, None]
    return gl1[:, :, None] * (vals[:, 1] - vals[:, 0])[:, None] + gl2[:, :, None] * (vals[:, 2] - vals[:, 0])[:, None]


def _chunk_gradient(scene, occ, edges, emits, p, n, u, want_pos, want_nrm):
    """(dH/dP (m, 3, 3), dH/dN (m, 3, 3) before the tangential projection) for one chunk of receivers."""
    m = len(p)
    gp = np.zeros((m, 3, 3))
    gn = np.zeros((m, 3, 3))
    include = np.broadcast_to(emits[None, :], (m, scene.n_polygons))
    if scene.linear:
        frags, ff = visible_fragments_with_ff(scene, p, n, u, occluders=occ, include=include)
    else:
        # tiles nothing cuts come apart, as whole-polygon edge sets (see _clear_gradient)
        frags, ff, clear = visible_fragments_and_clear_tiles(scene, p, n, u, occluders=occ, include=include)
        if clear is not None:
            _clear_gradient(clear[1], clear[0], p, n, scene.double_sided, gp if want_pos else None,
                            gn if want_nrm else None)
    lit = frags.side < 0 if not scene.double_sided else np.ones(len(ff), dtype=bool)
    keep = np.flatnonzero(lit & (frags.counts >= 3))
    if len(keep) == 0:
        return gp, gn
    frags = frags.take(keep)
    ff = ff[keep]
    F = len(keep)
    dirs = directions(frags.verts, frags.inf)                                      # (F, K, 3)
    K = dirs.shape[1]
    # edge j runs from slot j to slot j + 1 (mod K): padding repeats the last vertex up to slot K − 1
    # (:func:`.visibility._fit`), so padded edges have zero length and K − 1 → 0 closes the polygon
    bdirs = np.concatenate([dirs[:, 1:], dirs[:, :1]], axis=1)
    valid = _norm(_cross(dirs, bdirs - dirs)) > 0
    flat = np.flatnonzero(valid)                                                   # edges (E,), by fragment
    fi = flat // K
    a, b = dirs.reshape(-1, 3).take(flat, axis=0), bdirs.reshape(-1, 3).take(flat, axis=0)
    pt = frags.point[fi]
    N = n[pt]
    sigma = frags.side[fi].astype(np.float64)
    c = _cross(a, b - a)                                                           # = a × b, (E, 3)
    s_ab = _norm(c)
    c_hat = c / s_ab[:, None]
    poly = frags.poly[fi]
    fi0, a0, b0, sigma0, c_hat0 = fi, a, b, sigma, c_hat                           # before the cuts below

    if scene.linear:
        tri_w = scene.poly_vertices[frags.poly, :3]                                # (F, 3, 3) world
        tri = tri_w - p[frags.point][:, None]                                      # P-local
        vals = scene.corner_radiance[frags.poly]                                   # (F, 3, C)
        g = _triangle_gradient(tri, vals)                                          # (F, 3, C)
        ref = tri[:, 0]
        l_ref = vals[:, 0]                                                         # L at tri[:, 0]

    if want_pos:
        # horizon edges: N·ω = 0 along the arc, no contribution (and their circle does not move)
        la, lb = _norm(a), _norm(b)
        horizon = (np.abs(_dot(N, a)) <= 1e-12 * la) & (np.abs(_dot(N, b)) <= 1e-12 * lb)
        singular = np.zeros(0, dtype=np.int64)
        if frags.inf is not None:
            # one-sided limits: an edge ending at P itself (its direction only a limit) lies on a line
            # through P, whose circle turns infinitely fast as P moves; off the horizon the position
            # gradient does not exist there (returned as NaN)
            at_p = (dirs != frags.verts).any(axis=2).reshape(-1)                  # (F*K,)
            ends = at_p.take(flat) | at_p.take(fi * K + (flat + 1 - fi * K) % K)
            singular = np.unique(pt[ends & ~horizon])
        # q of each edge: its own line (``own``; q = f̂/h from the arc frame below) or ``q_exp``
        own = np.ones(len(a), dtype=bool)
        q_exp = np.zeros((len(a), 3))
        # the relative angle to which two planes through P are the same: the match tolerance plus the
        # rounding of the clipped end points, ~eps |x| / |b − a| in the direction of a short edge
        tol = LINE_MATCH_EPS + 64 * _EPS * np.maximum(la, lb) / _norm(b - a)
        # fragments that are their whole source polygon (not cut: bitwise the candidates' vertices)
        # have only source edges; the others are tested edge by edge
        whole = _whole_fragments(scene, frags, p)
        cut = np.flatnonzero(~whole[fi])
        on_src = whole[fi]
        on_cut, q_cut = _on_source_boundary(scene, poly[cut], p[pt[cut]], c_hat[cut], tol[cut])
        on_src[cut] = on_cut
        q_exp[cut[on_cut]] = q_cut[on_cut]              # the source's own vertices, not the clipped ones
        own[cut[on_cut]] = False
        inner = np.flatnonzero(~on_src & ~horizon)
        row, A, B = _plane_matches(occ, edges, p[pt[inner]], c_hat[inner], tol[inner])
        if len(row):
            # edges with occluder edges in their plane: cut at those edges' corners, a line per sub-arc
            owner, x0, x1 = _split_at(a[inner], b[inner], c_hat[inner], row, A, B)
            q_sub, shadow = _nearest_lines(owner, x0, x1, _line_dual(a[inner], b[inner]), row, A, B)
            owner = inner[owner]
            rest = np.ones(len(a), dtype=bool)
            rest[inner] = False
            rest = np.flatnonzero(rest)
            src = np.concatenate([rest, owner])
            q_exp = np.concatenate([q_exp[rest], q_sub])
            own = np.concatenate([own[rest], ~shadow])
            a = np.concatenate([a[rest], x0])
            b = np.concatenate([b[rest], x1])
            fi, pt, N, sigma, poly, horizon = fi[src], pt[src], N[src], sigma[src], poly[src], horizon[src]
        c_hat, f_hat, e_hat, h, _, S = _arc_integrals(a, b)
        q = np.where(own[:, None], f_hat / h[:, None], q_exp)                      # (G1): own line q = f̂/h
        if scene.linear:
            foot = f_hat * h[:, None]                                              # P-local foot point
            ge = g[fi]                                                             # (E, 3, C)
            l0 = l_ref[fi] + np.einsum("ekc,ek->ec", ge, foot - ref[fi])
            lam1 = h[:, None] * np.einsum("ekc,ek->ec", ge, e_hat)
        else:
            l0 = scene.poly_radiance[poly]
            lam1 = None
        ie = _edge_integral(N, q, f_hat, e_hat, S, l0, lam1)                      # (E, C)
        ie = np.where(horizon[:, None], 0.0, ie)
        contrib = ie[:, :, None] * (sigma[:, None] * c_hat)[:, None, :]            # (E, C, 3)
        _scatter(gp, pt, contrib)
        gp[singular] = np.nan
        if scene.linear:
            # interior term (G3): π (F g − (g·G) n_s / D), G the first moment about P
            from .linear_radiance import first_moment

            ns = scene.poly_normals[frags.poly]
            G = first_moment(frags.verts, frags.counts, n[frags.point], ns)        # (F, 3)
            D = _dot(ns, tri[:, 0])
            gG = np.einsum("fkc,fk->fc", g, G)                                     # (F, C)
            inner_t = np.pi * (ff[:, None, None] * g
                               - ns[:, :, None] * (gG / np.where(D != 0, D, 1.0)[:, None])[:, None, :])
            _scatter(gp, frags.point, inner_t.transpose(0, 2, 1))

    if want_nrm:
        # ∫ω dω = ½ σ Σ_e ĉ_e θ_e per fragment (the vector of eq. 4), with the edges before any cut
        theta0 = np.arctan2(s_ab, _dot(a0, b0))
        vf = np.zeros((F, 3))
        _scatter(vf, fi0, 0.5 * (sigma0 * theta0)[:, None] * c_hat0)               # (F, 3)
        if scene.linear:
            from .linear_radiance import first_moment

            ns = scene.poly_normals[frags.poly]
            T = np.stack([first_moment(frags.verts, frags.counts, np.eye(3)[k], ns) for k in range(3)],
                         axis=2)                                                   # (F, 3, 3), G = T N
            l_origin = l_ref - np.einsum("fkc,fk->fc", g, ref)                     # L extrapolated to P
            vc = (vf[:, :, None] * l_origin[:, None, :]
                  + np.pi * np.einsum("fik,fic->fkc", T, g))                       # (F, 3, C)
        else:
            vc = vf[:, :, None] * scene.poly_radiance[frags.poly][:, None, :]
        _scatter(gn, frags.point, vc.transpose(0, 2, 1))
    return gp, gn


#: clear-tile edge terms per batch (the fast path's temporaries stay small)
CLEAR_EDGE_BATCH = 2**15


def _clear_gradient(te, pairs, p, n, double_sided, gp, gn):
    """Add the clear tiles' share to ``gp`` / ``gn (m, 3, 3)`` (either None to skip).

    A clear tile's members are whole polygons, nothing cuts them, and they lie above the horizon: every
    edge is its own fixed line (q = f̂/h in (G1)), and an edge shared by two members appears in both
    with opposite directions, so — as for eq. 4 in :mod:`.clear_tiles` — each unique edge is evaluated once
    with the folded weight ``W_e = Σ_i σ_ei L_i``: ``∂H/∂P += side · Σ_e W_e ĉ_e I_e`` with
    ``I_e = (n1 S0 + n2 S1)/h`` and ``∂H/∂N += side · Σ_e W_e ½ θ_e ĉ_e``. Component arrays throughout."""
    lit = np.ones(len(pairs.point), dtype=bool) if double_sided else pairs.side < 0
    point, tile, side = pairs.point[lit], pairs.tile[lit], pairs.side[lit]
    if len(point) == 0:
        return
    n_edges = np.diff(te.edge_ptr)[tile]
    ends = np.cumsum(n_edges)
    cuts = np.searchsorted(ends, np.arange(CLEAR_EDGE_BATCH, ends[-1], CLEAR_EDGE_BATCH), side="right")
    bounds = np.unique(np.concatenate([[0], cuts, [len(point)]]))
    P = [np.ascontiguousarray(p[:, i]) for i in range(3)]
    Nc = [np.ascontiguousarray(n[:, i]) for i in range(3)]
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        pr, e = expand(tile[lo:hi], te.edge_ptr, np.arange(len(te.edge_a)))      # (pair in batch, edge)
        pt = point[lo:hi][pr]
        ax, ay, az = (te.a_xyz[i][e] - P[i][pt] for i in range(3))
        bx, by, bz = (te.b_xyz[i][e] - P[i][pt] for i in range(3))
        ex, ey, ez = bx - ax, by - ay, bz - az
        cx, cy, cz = ay * ez - az * ey, az * ex - ax * ez, ax * ey - ay * ex       # a × b as a × (b − a)
        sn = np.sqrt(cx * cx + cy * cy + cz * cz)
        ok = sn > 0
        inv_s = np.divide(1.0, sn, out=np.zeros_like(sn), where=ok)
        cx, cy, cz = cx * inv_s, cy * inv_s, cz * inv_s
        theta = np.arctan2(sn, ax * bx + ay * by + az * bz)
        w = te.weight[e] * side[lo:hi][pr][:, None]                                # (B, 3) side · W_e
        seg = np.cumsum(n_edges[lo:hi]) - n_edges[lo:hi]
        targets = point[lo:hi]
        nx, ny, nz = Nc[0][pt], Nc[1][pt], Nc[2][pt]
        if gp is not None:
            el = np.sqrt(ex * ex + ey * ey + ez * ez)
            inv_l = np.divide(1.0, el, out=np.zeros_like(el), where=ok)
            ux, uy, uz = ex * inv_l, ey * inv_l, ez * inv_l                        # ê
            fx, fy, fz = uy * cz - uz * cy, uz * cx - ux * cz, ux * cy - uy * cx   # f̂ = ê × ĉ
            h = sn * inv_l
            a2 = ax * ax + ay * ay + az * az
            b2 = bx * bx + by * by + bz * bz
            ta, tb = ax * ux + ay * uy + az * uz, bx * ux + by * uy + bz * uz
            s0 = 0.5 * theta + 0.5 * h * (tb / b2 - ta / a2)
            s1 = 0.5 * h * h * (ex * (ax + bx) + ey * (ay + by) + ez * (az + bz)) / (a2 * b2)
            n1, n2 = nx * fx + ny * fy + nz * fz, nx * ux + ny * uy + nz * uz
            ie = np.divide(n1 * s0 + n2 * s1, h, out=np.zeros_like(h), where=ok)   # (G2), q = f̂/h
            vec = np.stack([cx * ie, cy * ie, cz * ie], axis=1)                    # (B, 3)
            per = np.add.reduceat(w[:, :, None] * vec[:, None, :], seg, axis=0)    # (pairs, C, 3)
            np.add.at(gp, targets, per)
        if gn is not None:
            half = 0.5 * theta
            vec = np.stack([cx * half, cy * half, cz * half], axis=1)
            per = np.add.reduceat(w[:, :, None] * vec[:, None, :], seg, axis=0)
            np.add.at(gn, targets, per)


def _gradients(scene, points, normals, limit_directions, progress, cancel, occluders, budget, want_pos, want_nrm):
    from .local_pass import Cancelled

    p, n, u = _prepare_receivers(points, normals, limit_directions)
    u = idle_limits_dropped(scene, p, n, u)  # as irradiance does (receivers.idle_limits_dropped)
    m = len(p)
    gp = np.zeros((m, 3, 3))
    gn = np.zeros((m, 3, 3))
    occ = _occluders(scene, occluders)
    edges = _occluder_edges(scene, occ)
    emits = _emitter_mask(scene)
    # as many receivers per chunk as local_pass.irradiance takes: the visibility stage's candidate arrays
    # hold about ``budget`` coordinates whatever the scene size
    k = scene.poly_vertices.shape[1] if scene.n_polygons else 3
    size = max(1, min(CHUNK_POINTS, budget // max(1, (scene.n_polygons + 1) * k)))
    for s in range(0, m, size):
        e = min(m, s + size)
        if cancel is not None and cancel():
            raise Cancelled(f"cancelled after {s} of {m} points")
        # receivers with and without a one-sided limit apart (see receivers.limit_groups)
        for at, lim in limit_groups(None if u is None else u[s:e]):
            at = slice(s, e) if at is None else s + at
            gp[at], gn[at] = _chunk_gradient(scene, occ, edges, emits, p[at], n[at], lim, want_pos, want_nrm)
        if progress is not None:
            progress(e, m)
    # the normal gradient is tangential: the derivative of H(P, N/|N|) at |N| = 1
    gn -= np.einsum("mck,mk->mc", gn, n)[:, :, None] * n[:, None, :]
    return gp, gn


def irradiance_gradient(
    scene: Scene,
    points,
    normals,
    *,
    limit_directions=None,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    occluders: Occluders | None = None,
    budget: int = DEFAULT_BUDGET,
    normal_gradient: bool = False,
):
    """Gradient of the exact occluded irradiance with respect to the receiver position, in closed form.

    Args:
        scene, points (m, 3), normals (m, 3), limit_directions, progress, cancel, occluders, budget: as
            for :func:`.local_pass.irradiance` (receivers go in chunks of the same size, at most
            :data:`CHUNK_POINTS`).
        normal_gradient: also return :func:`irradiance_normal_gradient` (sharing the visibility work).
    Returns:
        ``dH_dP (m, 3, 3)`` float64, ``dH_dP[i, c, k] = ∂H_c/∂P_k`` at receiver i (channel c of
        :func:`.local_pass.irradiance`, world axis k; W m⁻² per unit length), the normal held fixed
        (eq. G1–G3 of the module docstring); with ``normal_gradient`` the tuple ``(dH_dP, dH_dN)``.

    H is piecewise smooth: where P lies on a visibility event (a shadow edge falling onto a source or
    another shadow edge, P in a polygon's plane) it has no gradient and the value returned is one of the
    one-sided ones or undefined.
    """
    gp, gn = _gradients(scene, points, normals, limit_directions, progress, cancel, occluders, budget, True,
                        normal_gradient)
    return (gp, gn) if normal_gradient else gp


def irradiance_normal_gradient(scene: Scene, points, normals, **kwargs) -> np.ndarray:
    """Rotational gradient ``(m, 3, 3)``: ``[i, c, k] = ∂H_c/∂N_k``, the derivative of the irradiance
    ``H_c(P, N/|N|)`` with respect to the receiver normal at unit length, P held fixed.

    It is tangential, ``(I − N Nᵀ) V`` with the vector irradiance ``V = ∫ L ω dω`` over the visible
    fragments (module docstring); a rotation of N by the small vector angle φ (radians) changes H by
    ``φ · (N × V)`` and a new unit normal N' by ``dH_dN · (N' − N)`` to first order. Keyword arguments
    as for :func:`irradiance_gradient`.
    """
    kwargs.pop("normal_gradient", None)
    budget = kwargs.pop("budget", DEFAULT_BUDGET)
    opts = {k: kwargs.pop(k, None) for k in ("limit_directions", "progress", "cancel", "occluders")}
    if kwargs:
        raise TypeError(f"unexpected keyword arguments {sorted(kwargs)}")
    return _gradients(scene, points, normals, opts["limit_directions"], opts["progress"], opts["cancel"],
                      opts["occluders"], budget, False, True)[1]
