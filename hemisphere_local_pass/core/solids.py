"""Convex solids: one shadow volume for a whole convex block instead of one per face.

A box standing in a room hides what is behind it through two or three of its faces at once; with one
shadow volume per face (:mod:`.visibility`), a wall polygon behind the box is cut by two or three
volumes in turn and its pieces multiply. For a receiver P *outside* a convex polyhedron S the union of
its faces' shadow volumes is itself convex:

    SV(S) = { x : the segment P→x meets S } = cone(P, silhouette of S) ∩ ⋂_{f facing P} beyond(f),

because a ray from P enters S through a face facing P, at the largest of those faces' plane crossings
(the planes facing P are the same for every ray). Its planes are the planes through P and the
*silhouette edges* (edges between a face facing P and one facing away) and the depth planes of the
faces facing P. Faces facing away from P only ever matter inside SV(S): their volumes are contained in
it. So the volume of S replaces the volumes of all its faces at P, exactly.

Which groups of merged faces (:class:`.culling.Occluders`) are convex solids is decided once per scene:
faces connected through shared edges (identical end points, each edge in exactly two faces), every
face's plane supporting all vertices of the group (the group lies on one side of it), at least three
faces. A group may have one *hole* — its unshared edges all in one plane, like a box without a bottom
standing on the floor: the hole is a missing face of the polyhedron. Per receiver the solid's volume is
used only when P classifies strictly against every face plane (none edge-on, with a margin of several
times the planes' uncertainty), at least one face faces P and the hole (if any) faces away from P or
is seen edge-on — then every face facing P is present and the identity above holds. Otherwise (P
inside the room that the walls enclose, P in or next to a face plane, P looking into the hole,
one-sided limits) the faces' own volumes are used as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .tolerances import COORD_EPS, PLANE_EPS

__all__ = ["Solids", "build_solids", "no_solids", "solid_volumes"]

#: margin of the per-receiver classification against a solid's planes, in multiples of the plane
#: tolerance of :func:`.projection.receiver_side` (near a plane the faces' own volumes are used)
_MARGIN = 8.0


@dataclass
class Solids:
    """Convex solids of a scene (see the module doc); ``s`` indexes solids, ``f`` their faces.

    Attributes:
        face_ptr (n_s+1,), face_occ (F,): CSR lists of each solid's merged faces (occluder indices).
        face_out (F, 3): outward unit normals; face_point (F, 3): a vertex of each face (world);
            face_center (F, 3): the centre of each face's vertices (world); face_tilt, face_noise (F,):
            the plane uncertainty (see :func:`.scene.plane_uncertainty`).
        hole (n_s,) bool; hole_out (n_s, 3), hole_point (n_s, 3): outward plane of the missing face.
        edge_solid (E,), edge_a, edge_b (E, 3): the polyhedron's edges (world end points); edge_f (E,),
            edge_g (E,): the two faces (flat indices into the face arrays; -1: the hole).
        centers (n_s, 3), radii (n_s,): bounding spheres.
        virtual (n_s,) bool or None: polytopes inside closed surfaces that are not convex
            (:mod:`.inner_solids`): their faces are no occluders (``face_occ`` -1), their volumes are
            used besides the surface's faces' (nothing is replaced), at the receivers ``rules`` allow.
        cover_solid, cover_occ (C,) or None: the occluders whose table columns each solid's columns
            join (None: its faces, ``face_solid`` / ``face_occ``).
        rules: per solid None (a convex solid) or the receiver rules of a virtual one
            (see :func:`.inner_solids.inner_solids`).
    """

    face_ptr: np.ndarray
    face_occ: np.ndarray
    face_out: np.ndarray
    face_point: np.ndarray
    face_center: np.ndarray
    face_tilt: np.ndarray
    face_noise: np.ndarray
    hole: np.ndarray
    hole_out: np.ndarray
    hole_point: np.ndarray
    edge_solid: np.ndarray
    edge_a: np.ndarray
    edge_b: np.ndarray
    edge_f: np.ndarray
    edge_g: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    virtual: np.ndarray | None = None
    cover_solid: np.ndarray | None = None
    cover_occ: np.ndarray | None = None
    rules: list | None = None

    @property
    def n(self) -> int:
        return len(self.face_ptr) - 1

    def covers(self) -> tuple[np.ndarray, np.ndarray]:
        """``(solid (C,), occluder (C,))``: the occluders whose table columns each solid's columns join."""
        if self.cover_occ is None:
            return self.face_solid, self.face_occ
        return self.cover_solid, self.cover_occ

    def is_virtual(self) -> np.ndarray:
        """(n_s,) bool: the solids of :mod:`.inner_solids` (used besides their surfaces' faces)."""
        return np.zeros(self.n, dtype=bool) if self.virtual is None else self.virtual

    @property
    def face_solid(self) -> np.ndarray:
        return np.repeat(np.arange(self.n), np.diff(self.face_ptr))


def no_solids() -> Solids:
    """No solids (every face occludes on its own)."""
    z3 = np.zeros((0, 3))
    zi = np.zeros(0, dtype=np.int64)
    return Solids(np.zeros(1, dtype=np.int64), zi, z3, z3, z3, np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool),
                  z3, z3, zi, z3, z3, zi, zi, z3, np.zeros(0))


def join_solids(a: Solids, b: Solids) -> Solids:
    """The solids of ``a``, then those of ``b`` (face and edge indices renumbered)."""
    if b.n == 0:
        return a
    if a.n == 0:
        return b
    nf = len(a.face_occ)
    ca, cb = a.covers(), b.covers()

    def cat(name):
        return np.concatenate([getattr(a, name), getattr(b, name)])

    return Solids(
        np.concatenate([a.face_ptr, b.face_ptr[1:] + nf]), cat("face_occ"), cat("face_out"), cat("face_point"),
        cat("face_center"), cat("face_tilt"), cat("face_noise"), cat("hole"), cat("hole_out"), cat("hole_point"),
        np.concatenate([a.edge_solid, b.edge_solid + a.n]), cat("edge_a"), cat("edge_b"),
        np.concatenate([a.edge_f, b.edge_f + nf]),
        np.concatenate([a.edge_g, np.where(b.edge_g >= 0, b.edge_g + nf, -1)]),
        cat("centers"), cat("radii"), np.concatenate([a.is_virtual(), b.is_virtual()]),
        np.concatenate([ca[0], cb[0] + a.n]), np.concatenate([ca[1], cb[1]]),
        (a.rules or [None] * a.n) + (b.rules or [None] * b.n))


def build_solids(vertices: np.ndarray, counts: np.ndarray, normals: np.ndarray, tilt: np.ndarray,
                 noise: np.ndarray) -> Solids:
    """Find the convex solids among merged faces ``vertices (n_o, K, 3)``, ``counts (n_o,)`` with unit
    ``normals (n_o, 3)`` and plane uncertainty ``tilt, noise (n_o,)`` (see the module doc)."""
    n_o = len(counts)
    owners: dict[tuple[bytes, bytes], list[tuple[int, int]]] = {}
    for o in range(n_o):
        k = int(counts[o])
        keys = [v.tobytes() for v in vertices[o, :k]]
        for j in range(k):
            a, b = keys[j], keys[(j + 1) % k]
            owners.setdefault((a, b) if a < b else (b, a), []).append((o, j))
    parent = list(range(n_o))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    bad = set()
    for lst in owners.values():
        if len(lst) > 2:
            bad.update(o for o, _ in lst)
        elif len(lst) == 2:
            ra, rb = find(lst[0][0]), find(lst[1][0])
            if ra != rb:
                parent[ra] = rb
    groups: dict[int, list[int]] = {}
    for o in range(n_o):
        groups.setdefault(find(o), []).append(o)

    solids = []
    for grp in groups.values():
        if len(grp) < 3 or any(o in bad for o in grp):
            continue
        s = _convex_solid(grp, vertices, counts, normals, tilt, noise, owners)
        if s is not None:
            solids.append(s)
    if not solids:
        return no_solids()
    face_occ, face_out, hole, hole_out, hole_point, edges, centers, radii = [], [], [], [], [], [], [], []
    face_ptr = [0]
    for grp, outs, h, (ea, eb, ef, eg), c, r in solids:
        base = face_ptr[-1]
        face_occ += grp
        face_out.append(outs)
        face_ptr.append(base + len(grp))
        hole.append(h is not None)
        hole_out.append(h[0] if h is not None else np.zeros(3))
        hole_point.append(h[1] if h is not None else np.zeros(3))
        edges.append((np.full(len(ea), len(face_ptr) - 2), ea, eb, ef + base, np.where(eg >= 0, eg + base, -1)))
        centers.append(c)
        radii.append(r)
    face_occ = np.array(face_occ, dtype=np.int64)
    k_idx = np.arange(vertices.shape[1])[None, :] < counts[face_occ][:, None]
    face_center = (vertices[face_occ] * k_idx[..., None]).sum(axis=1) / counts[face_occ][:, None]
    return Solids(
        np.array(face_ptr, dtype=np.int64), face_occ, np.concatenate(face_out), vertices[face_occ, 0].copy(),
        face_center, tilt[face_occ], noise[face_occ], np.array(hole), np.array(hole_out), np.array(hole_point),
        np.concatenate([e[0] for e in edges]), np.concatenate([e[1] for e in edges]),
        np.concatenate([e[2] for e in edges]), np.concatenate([e[3] for e in edges]),
        np.concatenate([e[4] for e in edges]), np.array(centers), np.array(radii))


def _outward_loop(grp, vertices, normals, tilt, pts, size, g_noise):
    """The outward normal of every face of the group (``(F, 3)``), or None when the group lies on both
    sides of some face's plane (or is flat): not convex. O(F × points)."""
    outs = []
    for o in grp:
        d = (pts - vertices[o, 0]) @ normals[o]
        tol = (4 * PLANE_EPS + tilt[o]) * size + 2 * g_noise
        if d.max() <= tol and d.min() < -_MARGIN * tol:
            outs.append(normals[o])
        elif d.min() >= -tol and d.max() > _MARGIN * tol:
            outs.append(-normals[o])
        else:
            return None
    return outs


#: groups of this many faces on are tested by :func:`_outward`'s tree search instead of the loop
OUTWARD_SEARCH_FROM = 64


def _outward(grp, vertices, counts, normals, tilt, pts, size, g_noise):
    """:func:`_outward_loop`'s answer, for large groups without its O(F × points): a face passes when some
    vertex is clearly behind its plane (of 14 extreme points of the group) and a search of a tree over
    the group's faces (:func:`.depth_pairs.tree_above`) finds no vertex in front of it beyond the
    tolerance; every decision within a rounding bound ``e`` of its threshold, and every face the
    search cannot settle cheaply, goes through the loop's own arithmetic (same answer, bit for bit)."""
    if len(grp) < OUTWARD_SEARCH_FROM:
        return _outward_loop(grp, vertices, normals, tilt, pts, size, g_noise)
    from .depth_pairs import Bodies, face_tree, tree_above

    g = np.asarray(grp)
    v0, nrm = vertices[g, 0], normals[g]
    tol = (4 * PLANE_EPS + tilt[g]) * size + 2 * g_noise
    e = 1e-13 * size                               # >> the rounding of any d here (|d| <= 2 size)
    dirs = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [1, 1, -1], [1, -1, 1], [-1, 1, 1]], float)
    proj = pts @ dirs.T
    samples = pts[np.unique(np.concatenate([proj.argmax(axis=0), proj.argmin(axis=0)]))]
    d_s = np.einsum("fsc,fc->fs", samples[None] - v0[:, None], nrm)
    behind = d_s.min(axis=1) < -_MARGIN * tol - e            # branch 1 possible (normal outward)
    ahead = d_s.max(axis=1) > _MARGIN * tol + e              # branch 2 possible (normal inward)
    if (behind & ahead).any():       # a sample clearly on either side of a face's plane: the loop fails it
        return None
    sign = np.where(behind, 1.0, -1.0)
    exact = behind == ahead                                  # neither
    cand = np.flatnonzero(~exact)
    faces = Bodies(vertices[g], counts[g], normals[g], tilt[g])
    tree = face_tree(faces)
    worst = np.full(len(g), -np.inf)
    for a in range(0, len(cand), 1024):          # blocks of faces: ~1024 x a few hundred candidates
        cb = cand[a:a + 1024]
        pe, pk, many = tree_above(faces, v0[cb], nrm[cb] * sign[cb, None], tol[cb] - e, tree=tree)
        exact[cb[many]] = True
        # the candidates' vertices: a vertex in front beyond tol fails the face; within e of tol: exactly
        kv = vertices[g[pk]]                                                # (p, K, 3), padding repeats
        f = cb[pe]
        d = np.einsum("pkc,pc->pk", kv - v0[f][:, None], nrm[f]) * sign[f, None]
        np.maximum.at(worst, f, d.max(axis=1, initial=-np.inf))
        if (worst[cb] > tol[cb] + e).any():        # a face fails: not convex, whatever the other blocks say
            return None
    exact |= worst > tol - e
    outs = np.where(sign[:, None] > 0, nrm, -nrm)
    for i in np.flatnonzero(exact):
        one = _outward_loop([g[i]], vertices, normals, tilt, pts, size, g_noise)
        if one is None:
            return None
        outs[i] = one[0]
    return list(outs)


def _convex_solid(grp, vertices, counts, normals, tilt, noise, owners):
    """``(faces, outward normals, hole or None, edges, centre, radius)`` if the group is a convex solid."""
    pts = np.concatenate([vertices[o, : counts[o]] for o in grp])
    center = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    radius = float(np.linalg.norm(pts - center, axis=1).max())
    size = 2.0 * radius
    g_noise = COORD_EPS * float(np.abs(pts).max())
    # the edges and the hole first: independent of the normals, cheap, and they reject a group that is not
    # closed (an open UV sphere) before the convexity search (same answer: both must pass)
    local = {o: i for i, o in enumerate(grp)}
    ea, eb, ef, eg = [], [], [], []
    boundary = []
    for o in grp:
        k = int(counts[o])
        for j in range(k):
            a, b = vertices[o, j], vertices[o, (j + 1) % k]
            ka, kb = a.tobytes(), b.tobytes()
            lst = owners[(ka, kb) if ka < kb else (kb, ka)]
            if len(lst) == 1:
                boundary.append((a, b))
                ea.append(a), eb.append(b), ef.append(local[o]), eg.append(-1)
            else:
                other = lst[0][0] if lst[0][0] != o else lst[1][0]
                if other not in local:
                    return None
                if local[other] > local[o]:  # each shared edge once
                    ea.append(a), eb.append(b), ef.append(local[o]), eg.append(local[other])
    hole = None
    if boundary:
        bp = np.array(boundary)                                           # (B, 2, 3)
        newell = np.cross(bp[:, 0] - center, bp[:, 1] - center).sum(axis=0)
        length = float(np.linalg.norm(newell))
        if not length > 0:
            return None
        hn = newell / length
        hp = bp[0, 0]
        if np.dot(center - hp, hn) > 0:
            hn = -hn
        d_b = (bp.reshape(-1, 3) - hp) @ hn
        d_all = (pts - hp) @ hn
        # the unshared edges must lie in one plane (a missing planar face) that supports the group
        tol_h = max(4 * PLANE_EPS * size + 2 * g_noise, 64 * np.finfo(np.float64).eps * size)
        if np.abs(d_b).max() > tol_h or d_all.max() > tol_h or d_all.min() >= -_MARGIN * tol_h:
            return None
        hole = (hn, hp)
    outs = _outward(grp, vertices, counts, normals, tilt, pts, size, g_noise)
    if outs is None:
        return None
    return (list(grp), np.array(outs), hole,
            (np.array(ea), np.array(eb), np.array(ef, dtype=np.int64), np.array(eg, dtype=np.int64)),
            center, radius)


def solid_volumes(sol: Solids, points: np.ndarray, normals: np.ndarray, limit: np.ndarray | None):
    """Shadow volumes of the solids that apply at each receiver (see the module doc).

    Args:
        points, normals: (m, 3) receivers; limit: (m, 3) limit directions or None (rows with a limit
            direction do not use solids).
    Returns:
        ``(qp, qs, normal, offset)``: receiver (Q,) and solid (Q,) of every solid volume, its planes
        ``normal (Q, J, 3)``, ``offset (Q, J)`` (P-local; inside when ``normal . x - offset > 0`` for
        every plane; unused slots: zero normal, offset -1).
    """
    m = len(points)
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 1, 3)), np.zeros((0, 1)))
    if sol.n == 0 or m == 0:
        return empty
    fs = sol.face_solid
    rel_f = sol.face_point[None] - points[:, None]                                  # (m, F, 3)
    d = -np.einsum("mfc,fc->mf", rel_f, sol.face_out)                              # out . (P - x_f)
    rel_c = sol.centers[None] - points[:, None]                                     # (m, n_s, 3)
    dist_c = np.linalg.norm(rel_c, axis=2)
    scale = (dist_c + sol.radii[None])[:, fs]                                       # (m, F)
    p_noise = COORD_EPS * np.abs(points).max(axis=1)[:, None]
    tol = _MARGIN * ((PLANE_EPS + sol.face_tilt[None]) * scale + sol.face_noise[None] + p_noise)
    front = d > tol
    decided = front | (d < -tol)
    starts = sol.face_ptr[:-1]
    ok = np.logical_and.reduceat(decided, starts, axis=1) & np.logical_or.reduceat(front, starts, axis=1)
    if sol.hole.any():
        d_h = np.einsum("msc,sc->ms", sol.hole_point[None] - points[:, None], sol.hole_out)   # -out.(P - x_h)
        tol_h = _MARGIN * (PLANE_EPS * (dist_c + sol.radii[None]) + p_noise + COORD_EPS * np.abs(sol.hole_point).max(
            axis=1)[None])
        # P behind the hole's plane, or in it (P on the floor a box without a bottom stands on: the
        # missing face is seen edge-on and only polygons in that plane, which P sees edge-on too,
        # could tell the difference)
        ok &= ~sol.hole[None] | (d_h > -tol_h)
    if sol.virtual is not None and sol.virtual.any():
        ok &= _virtual_rules(sol, points)
    # something of the solid above the receiver's horizon (else it hides nothing there)
    height_c = np.einsum("msc,mc->ms", rel_c, normals)
    ok &= height_c + sol.radii[None] > PLANE_EPS * (dist_c + sol.radii[None])
    if limit is not None:
        ok &= ~limit.any(axis=1)[:, None]
    qp, qs = np.nonzero(ok)
    if len(qp) == 0:
        return empty
    inst = np.full((m, sol.n), -1, dtype=np.int64)
    inst[qp, qs] = np.arange(len(qp))
    # depth planes of the faces facing P: inside = beyond (on the solid's side, away from P)
    fp, ff = np.nonzero(front & ok[:, fs])
    fq = inst[fp, fs[ff]]
    f_normal = -sol.face_out[ff]
    f_offset = d[fp, ff]
    # silhouette edges: between a face facing P and one facing away (or the hole)
    es = sol.edge_solid
    e_front_f = front[:, sol.edge_f]
    e_front_g = np.where(sol.edge_g[None] >= 0, front[:, np.maximum(sol.edge_g, 0)], False)
    ep, ee = np.nonzero((e_front_f != e_front_g) & ok[:, es])
    eq = inst[ep, es[ee]]
    a = sol.edge_a[ee] - points[ep]
    b = sol.edge_b[ee] - points[ep]
    c = np.cross(a, b)
    cn = np.linalg.norm(c, axis=1)
    inner = np.where(e_front_f[ep, ee], sol.edge_f[ee], sol.edge_g[ee])           # the face facing P
    toward = np.einsum("ec,ec->e", c, sol.face_center[inner] - points[ep])
    sgn = np.sign(toward)
    good = (cn > 1e3 * PLANE_EPS * np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)) & (
        np.abs(toward) > 1e3 * PLANE_EPS * cn * np.linalg.norm(sol.face_center[inner] - points[ep], axis=1))
    # a nearly degenerate silhouette plane (P almost on an edge's line): the faces' volumes are used
    drop = np.zeros(len(qp), dtype=bool)
    drop[eq[~good]] = True
    e_normal = sgn[:, None] * c / np.where(good, cn, 1.0)[:, None]
    plane_q = np.concatenate([fq, eq])
    plane_n = np.concatenate([f_normal, e_normal])
    plane_o = np.concatenate([f_offset, np.zeros(len(eq))])
    order = np.argsort(plane_q, kind="stable")
    plane_q, plane_n, plane_o = plane_q[order], plane_n[order], plane_o[order]
    n_planes = np.bincount(plane_q, minlength=len(qp))
    first = np.cumsum(n_planes) - n_planes
    slot = np.arange(len(plane_q)) - first[plane_q]
    j = int(n_planes.max())
    normal = np.zeros((len(qp), j, 3))
    offset = np.full((len(qp), j), -1.0)
    normal[plane_q, slot] = plane_n
    offset[plane_q, slot] = plane_o
    keep = ~drop
    return qp[keep], qs[keep], normal[keep], offset[keep]


def _virtual_rules(sol: Solids, points: np.ndarray) -> np.ndarray:
    """(m, n_s) bool: where a virtual solid (:mod:`.inner_solids`) may be used — the receiver strictly
    outside the convex set around its surface (beyond one of the outer planes by 8x the plane tolerance)
    and strictly inside its base's plane, or in an exact axis plane of the base (see that module's proof);
    True for the other solids. Vectorised over receivers and solids (the rules stacked once per scene)."""
    ok = np.ones((len(points), sol.n), dtype=bool)
    vs, out_n, out_o, noise, has_base, base_n, base_lo, base_hi, exact = _rule_arrays(sol)
    p_noise = COORD_EPS * np.abs(points).max(axis=1)
    scale = np.linalg.norm(points[:, None] - sol.centers[vs][None], axis=2) + sol.radii[vs][None]   # (m, V)
    tol = _MARGIN * (PLANE_EPS * scale + p_noise[:, None] + noise[None])
    use = (np.einsum("mc,vgc->mvg", points, out_n) - out_o[None] > tol[..., None]).any(axis=2)
    d = points @ base_n.T                                                                            # (m, V)
    use &= ~has_base[None] | (d < base_lo[None] - tol) | (exact[None] & (d <= base_hi[None]))
    ok[:, vs] = use
    return ok


def _rule_arrays(sol: Solids):
    """The virtual solids' rules as arrays (cached on ``sol``): their indices (V,), outer planes
    ``(V, G, 3)``, offsets ``(V, G)`` (padding +inf: never outside), coordinate noise (V,), and the base:
    present (V,), outward normal (V, 3), lowest and highest offset of its loop (V,), exact (V,)."""
    cached = getattr(sol, "_rules_cache", None)
    if cached is not None:
        return cached
    vs = np.flatnonzero(sol.virtual)
    g = max(len(sol.rules[s][0]) for s in vs)
    out_n = np.zeros((len(vs), g, 3))
    out_o = np.full((len(vs), g), np.inf)
    noise, has_base, exact = np.zeros(len(vs)), np.zeros(len(vs), dtype=bool), np.zeros(len(vs), dtype=bool)
    base_n, base_lo, base_hi = np.zeros((len(vs), 3)), np.zeros(len(vs)), np.zeros(len(vs))
    for i, s in enumerate(vs):
        n_out, o_out, base, noise[i] = sol.rules[s]
        out_n[i, :len(n_out)], out_o[i, :len(o_out)] = n_out, o_out
        if base is not None:
            has_base[i] = True
            base_n[i], base_lo[i], base_hi[i], exact[i] = base[:4]
    sol._rules_cache = (vs, out_n, out_o, noise, has_base, base_n, base_lo, base_hi, exact)
    return sol._rules_cache
