"""Structure prediction: the irradiance at nearby receivers from the visible fragments' fixed lines.

At a receiver P with unit normal N the exact irradiance is a sum over the visible fragments ``Ω_f``
(spherical polygons, paper sec. 2.5), ``H = π Σ_f L_f F_f`` with ``F_f`` Lambert's contour integral (eq. 4).
Every fragment edge lies on a great circle that is the plane through P and a *fixed 3-D line* — a source
polygon's edge, an occluder's (merged face's) edge whose shadow-volume plane cut the source, the line
where the source meets another polygon's plane (interpenetration / depth clip, sec. 2.4) — or on the
horizon ``N·ω = 0``, which is the same circle at every receiver of one normal. (This is the
identification :mod:`.gradient` uses for Arvo's irradiance Jacobian.)

The *structure* of P is, per fragment, its radiance and the cyclic list of the fixed lines of its edges.
At another receiver P' of the same normal the plane of line ``k`` through P' has the normal
``n_k(P') = (A_k − P') × (B_k − A_k)`` (horizon: N), the vertex between consecutive edges on lines
``a, b`` is ``s_ab (n_a × n_b)`` with the sign ``s_ab = ±1`` fixed at P (so that the vertex at P is the
fragment's own vertex direction), and eq. 4 (atan2 form) over these vertices gives ``F_f(P')``. As long
as the combinatorial structure of the visible set does not change between P and P' (no visibility event:
an occluder vertex crossing a shadow or source edge, an edge–edge–edge event, a receiver crossing a
polygon's plane), this is the exact irradiance at P' — not an interpolation. Past an event the error is
the sliver that the event adds or removes (second order in the distance past the event, for EV events).

Only constant radiance per polygon is handled (``scene.linear`` raises); one-sided limits
(``limit_directions``) are not handled (P is a regular receiver).

The identification of each edge's line is checked, not trusted: the structure rebuilds every vertex at
P from its two lines and compares it with the visibility stage's vertex; a structure is flagged
``ambiguous`` (and the reason kept) when a vertex does not come back to ``VERTEX_MATCH`` radians, when a
fragment edge's plane through P holds two distinct candidate lines (a visibility event at P itself: H
has a kink there), when two consecutive edges lie on one plane through P, or when the structure does not
reproduce the exact H at P to ``SELF_MATCH`` relative. Callers should not predict from a flagged
structure.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .gradient import _EPS, LINE_MATCH_EPS, _cross, _dot, _norm, _occluder_edges, _plane_matches
from .local_pass import _emitter_mask, _occluders, _prepare_receivers, visible_fragments_with_ff
from .scene import Scene
from .tolerances import COORD_EPS

__all__ = ["FragmentStructure", "evaluate_structure", "fragment_structure"]

#: line kinds
SOURCE, OCCLUDER, OWN, HORIZON = 0, 1, 2, 3
#: a vertex rebuilt at P from its two lines must agree with the visibility stage's to this angle (radians)
VERTEX_MATCH = 1e-8
#: the structure's H at P must agree with the fragments' own eq. 4 sum to this relative difference
SELF_MATCH = 1e-11

@dataclass
class FragmentStructure:
    """The visible-fragment structure of one receiver (world coordinates, float64).

    Attributes:
        point (3,), normal (3,) unit: the receiver it was taken at.
        line_a, line_b (L, 3): two points of each fixed line (world); ``kind (L,)`` SOURCE / OCCLUDER /
            OWN / HORIZON (horizon rows: unused points).
        ptr (F + 1,): fragment f's edges are ``ptr[f]:ptr[f+1]`` of ``edge_line (V,)``; edge j of a
            fragment lies on line ``edge_line[j]``; its vertex j (the start of edge j) is the
            intersection of the lines of edges j − 1 and j (cyclic), with sign ``vertex_sign (V,)``.
        weight (F, 3): ``π L_f σ_f / (2π)`` per fragment (σ_f = ±1 the orientation of its vertex cycle),
            so that ``H = Σ_f weight_f Σ_e θ_e ĉ_e·N``.
        H (3,): the irradiance at ``point`` from the structure (W m⁻²).
        ambiguous: the line identification failed a check (module docstring); ``reasons`` says which.
    """

    point: np.ndarray
    normal: np.ndarray
    line_a: np.ndarray
    line_b: np.ndarray
    kind: np.ndarray
    ptr: np.ndarray
    edge_line: np.ndarray
    vertex_sign: np.ndarray
    weight: np.ndarray
    H: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ambiguous: bool = False
    reasons: list = field(default_factory=list)
    _cycle: tuple | None = field(default=None, repr=False)

    @property
    def n_edges(self) -> int:
        return len(self.edge_line)


def _plane_normals(s: FragmentStructure, points):
    """Unit normals ``(k, L, 3)`` of the planes through ``points (k, 3)`` and the structure's lines."""
    a = s.line_a[None] - points[:, None]                                         # (k, L, 3)
    e = (s.line_b - s.line_a)[None]
    n = _cross(a, e)                                                             # = a × b without cancellation
    hz = s.kind == HORIZON
    if hz.any():
        n[:, hz] = s.normal
    return n / _norm(n)[..., None]


def _cycle(s: FragmentStructure):
    """(prev (V,), nxt (V,)): the previous / next edge of each edge in its fragment's cycle (cached)."""
    if s._cycle is None:
        s._cycle = _cycle_of(s.ptr, np.repeat(np.arange(len(s.ptr) - 1), np.diff(s.ptr)))
    return s._cycle


def _vertices(s: FragmentStructure, nl):
    """Vertex directions ``(k, V, 3)`` (unit) from the plane normals ``nl (k, L, 3)``: vertex j (the start
    of edge j) is ``s_j (n_prev × n_j)``."""
    prev, _ = _cycle(s)
    v = _cross(nl[:, s.edge_line[prev]], nl[:, s.edge_line]) * s.vertex_sign[None, :, None]
    return v / _norm(v)[..., None]


def _edge_terms(s: FragmentStructure, v, normal):
    """eq. 4's raw sum per fragment ``(k, F)`` over vertex directions ``v (k, V, 3)``: ``Σ_e θ_e ĉ_e·N``."""
    _, nxt = _cycle(s)
    a, b = v, v[:, nxt]
    c = _cross(a, b)
    sn = _norm(c)
    theta = np.arctan2(sn, _dot(a, b))
    term = np.divide(_dot(c, normal) * theta, sn, out=np.zeros_like(sn), where=sn > 0)   # (k, V)
    return np.add.reduceat(term, s.ptr[:-1], axis=1)


def evaluate_structure(structure: FragmentStructure, points) -> np.ndarray:
    """The irradiance ``(k, 3)`` (W m⁻²) at receivers ``points (k, 3)`` (world) of the structure's normal,
    predicted from its fixed lines: exact while the visible set's combinatorial structure is that of the
    structure's receiver (module docstring). Vectorised over points and edges."""
    s = structure
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if s.n_edges == 0:
        return np.zeros((len(p), 3))
    v = _vertices(s, _plane_normals(s, p))
    return _edge_terms(s, v, s.normal) @ s.weight


def _source_lines(scene: Scene, poly, P, c_hat, tol):
    """For edges with plane normals ``c_hat (E, 3)`` through their receivers ``P (E, 3)``: (E,) index of
    the source polygon's boundary edge in that plane (−1: none) and (E,) count of such edges."""
    sv = scene.poly_vertices[poly] - P[:, None]                                  # (E, K, 3)
    k = sv.shape[1]
    cnt = scene.poly_counts[poly]
    nxt = np.where(np.arange(k)[None, :] + 1 < cnt[:, None], np.arange(k)[None, :] + 1, 0)
    d = np.abs(np.einsum("ekc,ec->ek", sv, c_hat))
    small = d <= tol[:, None] * _norm(sv) + COORD_EPS * np.abs(P).max(axis=1)[:, None]
    hit = small & np.take_along_axis(small, nxt, axis=1) & (np.arange(k)[None, :] < cnt[:, None])
    hit &= _norm(np.take_along_axis(sv, nxt[..., None], axis=1) - sv) > 0
    j = np.where(hit.any(axis=1), np.argmax(hit, axis=1), -1)
    return j, hit.sum(axis=1), nxt


def _collinear(a1, b1, a2, b2, tol):
    """(r,) bool: the lines through ``a1, b1`` and ``a2, b2 (r, 3)`` are one line (to relative ``tol``)."""
    e = b1 - a1
    el = _norm(e)
    scale = np.maximum.reduce([_norm(a1), _norm(b1), _norm(a2), _norm(b2)])
    d2 = _norm(_cross(a2 - a1, e)) / el
    d3 = _norm(_cross(b2 - a1, e)) / el
    return (d2 <= tol * scale) & (d3 <= tol * scale)


def fragment_structure(scene: Scene, points, normals, *, occluders=None) -> list[FragmentStructure]:
    """The structures of receivers ``points, normals (m, 3)`` (world; one visibility pass for all):
    a list of m :class:`FragmentStructure`. Constant radiance only."""
    if scene.linear:
        raise NotImplementedError("structure prediction handles constant radiance per polygon only")
    p, n, _ = _prepare_receivers(points, normals, None)
    m = len(p)
    occ = _occluders(scene, occluders)
    edges = _occluder_edges(scene, occ)
    include = np.broadcast_to(_emitter_mask(scene)[None, :], (m, scene.n_polygons))
    frags, ff = visible_fragments_with_ff(scene, p, n, occluders=occ, include=include)
    lit = frags.side < 0 if not scene.double_sided else np.ones(len(ff), dtype=bool)
    keep = np.flatnonzero(lit & (frags.counts >= 3))
    keep = keep[np.argsort(frags.point[keep], kind="stable")]                      # grouped by receiver
    frags, ff = frags.take(keep), ff[keep]
    reasons = [[] for _ in range(m)]
    if frags.inf is not None and (frags.inf != 0).any():
        for i in np.unique(frags.point[(frags.inf != 0).any(axis=(1, 2))]):
            reasons[i].append("one-sided limit vertex")
    F = len(frags.point)
    dirs = frags.verts                                                           # (F, K, 3) P-local
    K = dirs.shape[1]
    bdirs = np.concatenate([dirs[:, 1:], dirs[:, :1]], axis=1)
    valid = _norm(_cross(dirs, bdirs - dirs)) > 0
    flat = np.flatnonzero(valid)                                                 # edges, by fragment
    fi = flat // K
    a, b = dirs.reshape(-1, 3)[flat], bdirs.reshape(-1, 3)[flat]
    pt = frags.point[fi]
    P = p[pt]
    N = n[pt]
    E = len(flat)
    c = _cross(a, b - a)
    c_hat = c / _norm(c)[:, None]
    la, lb = _norm(a), _norm(b)
    tol = LINE_MATCH_EPS + 64 * _EPS * np.maximum(la, lb) / _norm(b - a)
    kind = np.full(E, OWN)
    A = P + a                                                                    # world line points (own)
    B = P + b
    horizon = (np.abs(_dot(N, a)) <= 1e-12 * la) & (np.abs(_dot(N, b)) <= 1e-12 * lb)
    kind[horizon] = HORIZON
    poly = frags.poly[fi]
    rest = np.flatnonzero(~horizon)
    js, nsrc, nxt = _source_lines(scene, poly[rest], P[rest], c_hat[rest], tol[rest])
    on = js >= 0
    r_on = rest[on]
    sv = scene.poly_vertices[poly[r_on]]
    A[r_on] = sv[np.arange(len(r_on)), js[on]]
    B[r_on] = sv[np.arange(len(r_on)), nxt[on, js[on]]]
    kind[r_on] = SOURCE
    flag_edge = np.zeros(E, dtype=bool)
    flag_edge[rest[nsrc > 1]] = True      # two source edges in one plane through P: P in the source's plane
    # occluder edges in the plane of every non-horizon edge: candidates; distinct from the edge's line → event
    row, OA, OB = _plane_matches(occ, edges, P[rest], c_hat[rest], tol[rest])
    if len(row):
        er = rest[row]
        OA_w, OB_w = OA + P[er], OB + P[er]
        src = kind[er] == SOURCE
        # an edge on its source's boundary: an occluder edge in the same plane must be the same line
        same = _collinear(A[er], B[er], OA_w, OB_w, 1e-7)
        flag_edge[er[src & ~same]] = True
        # the other edges: the occluder line (all matched occluder edges of one edge must be one line)
        oth = np.flatnonzero(~src)
        if len(oth):
            e_o = er[oth]
            order = np.argsort(e_o, kind="stable")
            e_o, oth = e_o[order], oth[order]
            firsts = np.flatnonzero(np.concatenate([[True], e_o[1:] != e_o[:-1]]))
            lead = np.repeat(oth[firsts], np.diff(np.concatenate([firsts, [len(e_o)]])))
            one = _collinear(OA_w[lead], OB_w[lead], OA_w[oth], OB_w[oth], 1e-7)
            bad = np.unique(e_o[~one])
            flag_edge[bad] = True
            ed = e_o[firsts]
            A[ed], B[ed] = OA_w[oth[firsts]], OB_w[oth[firsts]]
            kind[ed] = OCCLUDER
    for i in np.unique(pt[flag_edge]):
        reasons[i].append("two distinct lines in one edge's plane (visibility event at P)")

    # merge consecutive edges on one plane through P (a vertex on a straight edge) into one edge
    nl = _cross(A - P, B - A)
    nl[horizon] = N[horizon]
    nl /= _norm(nl)[:, None]
    f_ptr = np.concatenate([[0], np.cumsum(np.bincount(fi, minlength=F))])
    prev, nxt = _cycle_of(f_ptr, fi)
    par = _norm(_cross(nl, nl[nxt])) <= 1e-9
    same_line = (kind == kind[nxt]) & ((kind == HORIZON) | _collinear(A, B, A[nxt], B[nxt], 1e-7))
    for i in np.unique(pt[par & ~same_line]):
        reasons[i].append("consecutive edges on one plane through P but different lines")
    kept = ~par[prev]
    cnt = np.bincount(fi[kept], minlength=F)
    kept &= cnt[fi] >= 3
    e = np.flatnonzero(kept)
    fi_k = fi[e]
    frag_k = np.flatnonzero(cnt >= 3)                    # fragments kept, in order (fi is sorted)
    new_f = np.cumsum(cnt >= 3) - 1
    f_ptr_k = np.concatenate([[0], np.cumsum(cnt[frag_k])])
    prev_k, nxt_k = _cycle_of(f_ptr_k, new_f[fi_k])
    # each kept edge's start vertex: the visibility stage's vertex, rebuilt from the two lines
    d = dirs.reshape(-1, 3)[flat[e]]
    vv = _cross(nl[e][prev_k], nl[e])
    sg = np.where(_dot(vv, d) >= 0, 1.0, -1.0)
    vv = vv * sg[:, None]
    vu = vv / _norm(vv)[:, None]
    ang = np.arctan2(_norm(_cross(vu, d / _norm(d)[:, None])), _dot(vu, d / _norm(d)[:, None]))
    for i in np.unique(pt[e][~(ang <= VERTEX_MATCH)]):
        reasons[i].append(f"a vertex not rebuilt from its lines to {VERTEX_MATCH:g} rad")
    # orientation σ_f: eq. 4's raw sum is positive for a cycle counter-clockwise about the outward
    # direction; every fragment contributes |F_f| (ff >= 0)
    cc = _cross(vu, vu[nxt_k])
    sn = _norm(cc)
    term = np.divide(_dot(cc, N[e]) * np.arctan2(sn, _dot(vu, vu[nxt_k])), sn, out=np.zeros_like(sn),
                     where=sn > 0)
    raw = np.add.reduceat(term, f_ptr_k[:-1]) if len(e) else np.zeros(0)
    rad = scene.poly_radiance[frags.poly]                                        # (F, 3)
    weight = rad[frag_k] / 2.0 * np.where(raw < 0, -1.0, 1.0)[:, None]          # π L σ / (2π)
    h_frag = (np.abs(raw) / 2.0)[:, None] * rad[frag_k]                          # π L |F_f|
    h_ref = np.zeros((m, 3))
    np.add.at(h_ref, frags.point, np.pi * ff[:, None] * rad)
    h_own = np.zeros((m, 3))
    np.add.at(h_own, frags.point[frag_k], h_frag)
    # split by receiver (fragments come grouped by receiver)
    fp = frags.point[frag_k]
    f_by_pt = np.searchsorted(fp, np.arange(m + 1))
    out = []
    for i in range(m):
        fl, fh = f_by_pt[i], f_by_pt[i + 1]
        el, eh = f_ptr_k[fl], f_ptr_k[fh]
        sl = e[el:eh]
        s = FragmentStructure(p[i].copy(), n[i].copy(), A[sl], B[sl], kind[sl], f_ptr_k[fl:fh + 1] - el,
                              np.arange(eh - el), sg[el:eh], weight[fl:fh])
        s.H = h_own[i]
        scale = max(float(np.abs(h_ref[i]).max()), 1e-300)
        if np.abs(h_own[i] - h_ref[i]).max() > SELF_MATCH * scale:
            reasons[i].append("the structure's H at P differs from the fragments' eq. 4 sum")
        s.reasons = reasons[i]
        s.ambiguous = bool(reasons[i])
        out.append(s)
    return out


def _cycle_of(ptr, fidx):
    """(prev, nxt) indices of each edge's neighbours in its fragment's cycle; ``ptr (F + 1,)``, ``fidx (E,)``
    the (sorted) fragment of each edge."""
    j = np.arange(len(fidx))
    prev = np.where(j == ptr[:-1][fidx], ptr[1:][fidx] - 1, j - 1)
    nxt = np.where(j + 1 == ptr[1:][fidx], ptr[:-1][fidx], j + 1)
    return prev, nxt
