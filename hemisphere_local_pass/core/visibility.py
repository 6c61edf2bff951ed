"""Exact hidden-part removal on the hemisphere (paper sec. 2.3–2.4), order-independent.

A point x of polygon A is hidden from P by polygon B exactly when the segment P→x crosses B, i.e. when
x lies in B's *shadow volume*: beyond B's plane (on the side away from P) and inside the cone from P
over B. The cone is bounded by the planes through P and B's edges — the great circles of B's projected
edges (sec. 2.3) — so the shadow volume of a convex B is a convex polyhedron bounded by k + 1 planes.

The visible part of A is A minus the union of its occluders' shadow volumes. Subtracting a convex
polyhedron from a convex polygon is a chain of plane clips: the part outside plane 1 is kept, the part
inside continues to plane 2, and so on; what is inside all planes is hidden. Because the depth test is
B's own plane, the part of A on P's side of B's plane is never hidden by B, which resolves depth order,
cyclic overlaps and interpenetrating polygons (sec. 2.4) without any sort. Every test and every
intersection is a plane evaluation in 3D, P-local coordinates.

All fragments of all receivers of a chunk are processed together: round r subtracts the r-th occluder
(nearest first) of every fragment's polygon, vectorised over fragments. A fragment that turns out not
to meet a shadow volume is kept whole (no needless splitting).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .clipping import split_convex
from .csr import expand
from .culling import Occluders
from .depth_pairs import ball_pairs
from .form_factor import edge_noise
from .projection import Candidates, flat_rows, onto_planes_through_p, receiver_side, snap_to_receiver
from .rowops import any_rows, at2, bit_at, max_abs_rows, nonzero_rows, sides, sum_rows, take_rows, unpack_rows
from .solids import solid_volumes
from .tolerances import COORD_EPS, PLANE_EPS

__all__ = ["Coverage", "Fragments", "ShadowVolumes", "coverage", "occluder_pairs", "shadow_volumes",
           "subtract_shadow_volumes", "visible_terms"]


@dataclass
class Fragments:
    """Visible fragments (P-local), flat over all receivers of a chunk.

    Attributes: verts (F, K, 3); inf (F, K, 3) or None; counts (F,); point (F,) receiver; poly (F,)
    convex polygon; side (F,) receiver side of the polygon's plane (+1 behind, -1 in front); owner
    (F,) the candidate each fragment was cut from (internal to the visibility stage); ff_bound (F,) or
    None: with a tolerance, a bound on how far each fragment's form factor may be from the exact path's
    (:func:`.form_factor.contour_integral_bounded`; None: it is the exact path's).
    """

    verts: np.ndarray
    inf: np.ndarray | None
    counts: np.ndarray
    point: np.ndarray
    poly: np.ndarray
    side: np.ndarray
    owner: np.ndarray
    ff_bound: np.ndarray | None = None

    def take(self, sel) -> Fragments:
        """The fragments ``sel`` (an integer index or a boolean mask)."""
        sel = np.asarray(sel)
        if sel.dtype == bool:
            sel = np.flatnonzero(sel)
        return Fragments(take_rows(self.verts, sel), None if self.inf is None else take_rows(self.inf, sel),
                         self.counts[sel], self.point[sel], self.poly[sel], self.side[sel], self.owner[sel])

    def pieces(self, src, verts, counts, inf) -> Fragments:
        """New fragments ``verts (p, K, 3)`` cut from fragments ``src (p,)`` of this set."""
        return Fragments(verts, inf, counts, self.point[src], self.poly[src], self.side[src], self.owner[src])

    @staticmethod
    def concat(parts: list[Fragments]) -> Fragments:
        parts = [p for p in parts if len(p.owner)] or parts[:1]
        width = max(3, max(int(p.counts.max(initial=3)) for p in parts))
        dual = parts[0].inf is not None
        return Fragments(
            np.concatenate([_fit(p.verts, p.counts, width) for p in parts]),
            np.concatenate([_fit(p.inf, p.counts, width) for p in parts]) if dual else None,
            np.concatenate([p.counts for p in parts]),
            np.concatenate([p.point for p in parts]),
            np.concatenate([p.poly for p in parts]),
            np.concatenate([p.side for p in parts]),
            np.concatenate([p.owner for p in parts]),
        )


@dataclass
class ShadowVolumes:
    """Shadow volumes of the occluders active at each receiver (flat over instances q).

    ``x`` is inside instance q's volume when ``normal[q, j] . x - offset[q, j] > 0`` for every j.
    Unused plane slots have a zero normal and offset -1 (always inside).

    Attributes: point (Q,), occluder (Q,), side (Q,) receiver side of the occluder's plane, verts
    (Q, Ko, 3) P-local occluder polygon, inf (Q, Ko, 3) or None its first-order part, counts (Q,),
    normal (Q, J, 3), offset (Q, J), offset_inf (Q, J) or None, near (Q,) distance from P to the
    nearest point of the occluder's bounding sphere (for ordering).

    Instances ``0..n_face-1`` are merged faces (``occluder < n_o``, also the *clusters* of their
    member polygons), then come the convex solids' volumes (``occluder = n_o + s``, see :mod:`.solids`;
    no vertices: ``counts`` 0). ``occludes (Q,)`` is False for a face whose solid's volume is used
    instead at that receiver (the face still is a cluster); ``covered (Q,)``, if set, marks faces whose
    members are all hidden there (the back faces of a virtual solid's surface, see :mod:`.inner_solids`).
    """

    point: np.ndarray
    occluder: np.ndarray
    side: np.ndarray
    verts: np.ndarray
    inf: np.ndarray | None
    counts: np.ndarray
    normal: np.ndarray
    offset: np.ndarray
    offset_inf: np.ndarray | None
    near: np.ndarray
    n_base: int = -1          # instances 0..n_base-1 are full volumes; the rest their cone-only copies
    n_face: int = -1
    occludes: np.ndarray | None = None
    covered: np.ndarray | None = None   # (n_base,) bool or None: the cluster is known to be hidden
    # volumes wider than ``normal``'s J planes (a convex solid's with many faces facing P: a finely
    # tessellated ball) are stored apart, so that the face volumes are not padded to their width (which
    # made a receiver's volumes O(n_o²)): ``wide_row (Q,)`` their row (-1: none; their ``normal`` /
    # ``offset`` rows are unused slots), ``wide_normal (W, Jw, 3)``, ``wide_offset (W, Jw)``,
    # ``wide_offset_inf (W, Jw)`` or None. Read planes through :meth:`plane` and :meth:`rows`
    wide_row: np.ndarray | None = None
    wide_normal: np.ndarray | None = None
    wide_offset: np.ndarray | None = None
    wide_offset_inf: np.ndarray | None = None

    def __post_init__(self):
        if self.n_base < 0:
            self.n_base = len(self.point)
        if self.n_face < 0:
            self.n_face = self.n_base
        if self.occludes is None:
            self.occludes = np.ones(self.n_base, dtype=bool)

    @property
    def n_planes(self) -> int:
        """J: plane slots of the widest volume (the planes arrays of the pairs have this width)."""
        return self.normal.shape[1] if self.wide_row is None else max(self.normal.shape[1], self.wide_normal.shape[1])

    def plane(self, q: np.ndarray, j):
        """Plane ``j`` (an int or ``(n,)``, < :attr:`n_planes`) of volumes ``q (n,)``: ``normal (n, 3),
        offset (n,), offset_inf (n,) or None`` (slots beyond a volume's planes: unused, always inside)."""
        q = np.asarray(q)
        j = np.broadcast_to(np.asarray(j), q.shape)
        jf = self.normal.shape[1]
        jn = np.minimum(j, jf - 1)
        nrm, off = self.normal[q, jn], self.offset[q, jn]
        oi = None if self.offset_inf is None else self.offset_inf[q, jn]
        past = j >= jf
        if past.any():
            nrm[past], off[past] = 0.0, -1.0
            if oi is not None:
                oi[past] = 0.0
        if self.wide_row is not None:
            w = np.flatnonzero(self.wide_row[q] >= 0)
            if len(w):
                r, jw = self.wide_row[q[w]], j[w]
                nrm[w], off[w] = self.wide_normal[r, jw], self.wide_offset[r, jw]
                if oi is not None:
                    oi[w] = self.wide_offset_inf[r, jw]
        return nrm, off, oi

    def rows(self, q: np.ndarray):
        """All planes of volumes ``q (n,)``: ``normal (n, J', 3), offset (n, J')``, J' = :attr:`n_planes`
        if a wide volume is among them, else the narrow width (padding: unused slots)."""
        nrm, off = take_rows(self.normal, q), take_rows(self.offset, q)
        if self.wide_row is None:
            return nrm, off
        w = np.flatnonzero(self.wide_row[q] >= 0)
        if not len(w):
            return nrm, off
        jw = self.n_planes
        nrm = np.concatenate([nrm, np.zeros((len(q), jw - nrm.shape[1], 3))], axis=1)
        off = np.concatenate([off, np.full((len(q), jw - off.shape[1]), -1.0)], axis=1)
        r = self.wide_row[q[w]]
        nrm[w, :self.wide_normal.shape[1]] = take_rows(self.wide_normal, r)
        off[w, :self.wide_offset.shape[1]] = take_rows(self.wide_offset, r)
        return nrm, off

    @cached_property
    def wide_components(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The wide volumes' normals as three contiguous (W, Jw) arrays (for gathers by row)."""
        return tuple(np.ascontiguousarray(self.wide_normal[..., c]) for c in range(3))

    @cached_property
    def wide_tree(self) -> _PlaneTree:
        """The wide volumes' planes in a bounding tree (see :class:`_PlaneTree`), one root per row."""
        return _PlaneTree.build(*self.wide_components, self.wide_offset)

    def is_wide(self, q: np.ndarray) -> np.ndarray:
        """(n,) bool: volumes ``q`` stored apart (see ``wide_row``)."""
        return np.zeros(len(q), dtype=bool) if self.wide_row is None else self.wide_row[q] >= 0


def _cone(rel_c: np.ndarray, radius: np.ndarray):
    """Bounding cone (axis (.., 3), half-angle (..,)) of spheres at ``rel_c`` with ``radius`` seen from P."""
    dist = _norm(rel_c)
    axis = rel_c / np.where(dist > 0, dist, 1.0)[..., None]
    ratio = np.where(dist > radius, radius / np.where(dist > 0, dist, 1.0), 1.0)
    half = np.where(dist > radius, np.arcsin(np.minimum(ratio, 1.0)), np.pi)
    return axis, half, dist


def shadow_volumes(occ: Occluders, points, normals, limit=None) -> tuple[ShadowVolumes, np.ndarray]:
    """Shadow volumes of every occluder that can hide something above each receiver's horizon.

    Returns the volumes and an ``(m, n_o + n_s)`` int table of instance index (-1: inactive); columns
    ``n_o + s`` are the convex solids (see :mod:`.solids`).
    """
    m = len(points)
    rel_c = occ.centers[None] - points[:, None]                                 # (m, n_o, 3)
    dist_c = np.linalg.norm(rel_c, axis=2)
    scale = dist_c + occ.radii[None]
    noise = 0.0 if occ.noise is None else occ.noise[None] + COORD_EPS * np.abs(points).max(axis=1)[:, None]
    side = receiver_side(occ.normals, occ.vertices[None, :, 0] - points[:, None], scale, limit,
                         0.0 if occ.tilt is None else occ.tilt, noise)
    # an occluder can only hide points above the horizon with its own part above the horizon
    height_c = np.matmul(rel_c, normals[:, :, None])[..., 0]
    active = (side != 0) & (height_c + occ.radii[None] > PLANE_EPS * scale)
    qp, qo = np.nonzero(active)
    x = take_rows(occ.vertices, qo) - points[qp][:, None]                       # (Q, Ko, 3)
    counts = occ.counts[qo]
    k = x.shape[1]
    xs = max_abs_rows(x)
    nq = normals[qp]
    height = x[..., 0] * nq[:, 0:1] + x[..., 1] * nq[:, 1:2] + x[..., 2] * nq[:, 2:3]
    up = np.flatnonzero(any_rows(height > PLANE_EPS * xs[:, None]))            # (padding repeats a vertex)
    qp, qo, x, counts, xs = (take_rows(a, up) for a in (qp, qo, x, counts, xs))
    valid = np.arange(k)[None] < counts[:, None]
    if limit is not None:
        # P in the occluder's plane within its uncertainty (the side came from the limit): put the
        # vertices exactly in the plane through P, as the candidates are (see hemisphere_candidates)
        flat = flat_rows(occ.normals[qo], x[:, 0], (PLANE_EPS + (0.0 if occ.tilt is None else occ.tilt[qo]))
                         * scale[qp, qo] + (0.0 if occ.noise is None else noise[qp, qo]), limit[qp], x)
        snap_eps = PLANE_EPS * (np.linalg.norm(rel_c[qp, qo], axis=1) + occ.radii[qo])
        snap_to_receiver(x, np.where(limit[qp].any(axis=1), snap_eps, -1.0))  # zero rows: exact at P
    sigma = side[qp, qo].astype(np.float64)                                     # (Q,)
    q = len(qp)

    # plane 0: the occluder's own plane, inside = beyond it (away from P)
    nrm = occ.normals[qo]
    normal = np.zeros((q, k + 1, 3))
    offset = np.full((q, k + 1), -1.0)
    normal[:, 0] = sigma[:, None] * nrm
    offset[:, 0] = sigma * np.einsum("qc,qc->q", nrm, x[:, 0])
    if limit is not None:
        # P in the plane within its uncertainty: the plane through P exactly, as for the candidates. The
        # moved vertices are in it only to rounding (n . x ~ 1e-16 |x|: 7e-11 for a 7e5 occluder, which
        # shifts a cut next to P by 1e-5 rad; its sign and size differed between numpy 1.x and 2.x)
        offset[flat, 0] = 0.0
    offset_inf = None
    if limit is not None:
        offset_inf = np.zeros((q, k + 1))
        offset_inf[:, 0] = sigma * -(np.einsum("qc,qc->q", nrm, limit[qp]))
    # planes 1..k: through P and each edge, inside = inside the cone over the occluder
    xn = np.roll(x, -1, axis=1)
    xn = np.where((np.arange(k)[None] + 1 < counts[:, None])[..., None], xn, x[:, :1])  # close the loop
    c = _cross(x, xn)                                                           # (Q, Ko, 3)
    cn = _norm(c)
    lens = _norm(x) * _norm(xn)
    if limit is not None:
        # an edge whose line passes within the coordinate noise of P goes through P: its plane through
        # P is then only known to rounding, and the limit decides (the same test as the contour integral's)
        line_tol = edge_noise(x, xn, COORD_EPS * np.abs(points[qp]).max(axis=1))
        lens = lens + line_tol * np.linalg.norm(xn - x, axis=2) / PLANE_EPS
    ok = valid & (cn > PLANE_EPS * lens)
    through_p = np.zeros_like(ok)
    if limit is not None:
        # an edge through P (one-sided limit only): its plane is the limit of the plane through P + εu
        u = -limit[qp][:, None, :]
        at_p = valid & ~ok
        if at_p.any():
            u_x = np.broadcast_to(u, x.shape)
            # only the half of the edge above the horizon can hide anything: its plane is the one through
            # P and that end point, as for the candidates' horizon clip (which cuts the edge at P)
            h = np.matmul(x, normals[qp][:, :, None])[..., 0]
            hn = np.where(np.arange(k)[None] + 1 < counts[:, None], np.roll(h, -1, axis=1), h[:, :1])
            c_inf = np.where(((hn > 0) & (h <= 0))[..., None], np.cross(u_x, xn),
                             np.where(((h > 0) & (hn <= 0))[..., None], np.cross(x, u_x),
                                      np.cross(u_x, xn) + np.cross(x, u_x)))
            cin = np.linalg.norm(c_inf, axis=2)
            use = at_p & (cin > PLANE_EPS * np.maximum(np.linalg.norm(xn, axis=2), np.linalg.norm(x, axis=2)))
            c = np.where(use[..., None], c_inf, c)
            cn = np.where(use, cin, cn)
            ok |= use
            through_p = use
    unit = c / np.where(ok, cn, 1.0)[..., None]
    normal[:, 1:] = np.where(ok[..., None], sigma[:, None, None] * unit, 0.0)
    offset[:, 1:] = np.where(ok, 0.0, -1.0)
    if limit is not None and flat.any():
        # P in the occluder's plane (its side from the limit): seen from P + εu everything behind the plane
        # is hit within O(ε) of P, so only the edges through P bound the cone; the plane through P and any
        # other edge is the occluder's own plane up to rounding: always inside if P is inside that edge,
        # always outside if not (left as planes, their rounding-level tilts would cut slivers off the cone)
        edge = ok & ~through_p & flat[:, None]
        inner = np.einsum("qjc,qc->qj", normal[:, 1:], normal[:, 0]) > 0
        normal[:, 1:][edge] = 0.0
        offset[:, 1:][edge] = np.where(inner[edge], -1.0, 1.0)
    near = dist_c[qp, qo] - occ.radii[qo]
    table = np.full((m, occ.n_vol), -1, dtype=np.int64)
    table[qp, qo] = np.arange(q)
    inf = None if limit is None else np.broadcast_to(-limit[qp][:, None, :], x.shape).copy()
    sv = ShadowVolumes(qp, qo, side[qp, qo], x, inf, counts, normal, offset, offset_inf, near)
    if occ.solids is not None and occ.solids.n:
        sv = _with_solids(sv, table, occ, points, normals, limit)
    if len(occ.coplanar_occ):
        sv = _with_cone_only(sv)
    return sv, table


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` over the last axis (3), component by component (np.cross moves axes)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _norm(a: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(a, axis=-1)`` for a last axis of 3."""
    return np.sqrt(a[..., 0] * a[..., 0] + a[..., 1] * a[..., 1] + a[..., 2] * a[..., 2])


#: the solids' volumes of a chunk are stored apart from the face volumes (:class:`ShadowVolumes`
#: ``wide_*``) when padding these to the widest would take more than this many times their own width
#: (a ball's: thousands of planes); below, one padded array (a box's 9 planes: ~9 % faster per point
#: in a room of 30 boxes than apart, the results bit for bit the same)
WIDE_FACTOR = 4
# the wide volumes' pair tests go through their groups of planes (False: every plane, the dense test;
# for the benchmark's side-by-side figures: both give the same pairs and planes)
WIDE_GROUPS = True
# ... from this many planes on (below, the dense test over every plane was as fast: 728 planes, 2,048 faces)
WIDE_TREE_MIN = 1024


def _with_solids(sv: ShadowVolumes, table: np.ndarray, occ: Occluders, points, normals, limit) -> ShadowVolumes:
    """Append the volumes of the convex solids that apply at each receiver (``table`` updated in place);
    the volumes of their faces stop occluding there (see :mod:`.solids`)."""
    sol = occ.solids
    sp, ss, s_normal, s_offset = solid_volumes(sol, points, normals, limit)
    n_s = len(sp)
    if n_s == 0:
        return sv
    q = len(sv.point)
    occludes = np.ones(q + n_s, dtype=bool)
    covered = None
    b, f_occ = expand(ss, sol.face_ptr, sol.face_occ)
    real = f_occ >= 0                                   # a virtual solid's faces are no occluders
    inst = table[sp[b[real]], f_occ[real]]
    occludes[inst[inst >= 0]] = False
    if sol.virtual is not None and sol.virtual[ss].any():
        # a virtual solid's closed surface seen from outside: the faces P is behind are entered from
        # inside, after a face facing P (see :mod:`.inner_solids`): their volumes are redundant
        vs = np.flatnonzero(sol.virtual[ss])
        cs, co = sol.covers()
        bv, c_occ = expand(ss[vs], np.searchsorted(cs, np.arange(sol.n + 1)), co)
        inst = table[sp[vs][bv], c_occ]
        inst = inst[inst >= 0]
        back = inst[sv.side[inst] > 0]
        occludes[back] = False
        covered = np.zeros(q + n_s, dtype=bool)
        covered[back] = True                            # ... and what they hold is hidden
    table[sp, occ.n + ss] = q + np.arange(n_s)
    wide = s_normal.shape[1] > WIDE_FACTOR * sv.normal.shape[1]     # stored apart (see ShadowVolumes.wide_row)
    j = sv.normal.shape[1] if wide else s_normal.shape[1]
    j = max(sv.normal.shape[1], j)
    wide_fields = {}
    if wide:
        wide_fields = dict(wide_row=np.concatenate([np.full(q, -1, dtype=np.int64), np.arange(n_s)]),
                           wide_normal=s_normal, wide_offset=s_offset,
                           wide_offset_inf=None if sv.offset_inf is None else np.zeros(s_offset.shape))
        s_normal, s_offset = np.zeros((n_s, j, 3)), np.full((n_s, j), -1.0)

    def planes(a, fill):
        if a.shape[1] == j:
            return a
        out = np.full((a.shape[0], j) + a.shape[2:], fill, dtype=a.dtype)       # np.pad, without its overhead
        out[:, :a.shape[1]] = a
        return out

    k = sv.verts.shape[1]
    rel = sol.centers[ss] - points[sp]
    zeros_v = np.zeros((n_s, k, 3))
    return ShadowVolumes(
        np.concatenate([sv.point, sp]), np.concatenate([sv.occluder, occ.n + ss]),
        np.concatenate([sv.side, np.ones(n_s, dtype=sv.side.dtype)]), np.concatenate([sv.verts, zeros_v]),
        None if sv.inf is None else np.concatenate([sv.inf, zeros_v]),
        np.concatenate([sv.counts, np.zeros(n_s, dtype=sv.counts.dtype)]),
        np.concatenate([planes(sv.normal, 0.0), planes(s_normal, 0.0)]),
        np.concatenate([planes(sv.offset, -1.0), planes(s_offset, -1.0)]),
        None if sv.offset_inf is None else np.concatenate([planes(sv.offset_inf, 0.0), np.zeros((n_s, j))]),
        np.concatenate([sv.near, np.linalg.norm(rel, axis=1) - sol.radii[ss]]),
        n_face=q, occludes=occludes, covered=covered, **wide_fields)


def _with_cone_only(sv: ShadowVolumes) -> ShadowVolumes:
    """Append, as instances Q..2Q-1, each volume's *cone only* (its depth plane made always-inside).

    Used against polygons lying in the occluder's own plane (coplanar overlapping surfaces): there the
    depth test cannot decide, and the occluder's cone is exactly the overlap.
    """
    normal = sv.normal.copy()
    offset = sv.offset.copy()
    normal[:, 0] = 0.0
    offset[:, 0] = -1.0
    offset_inf = None
    if sv.offset_inf is not None:
        offset_inf = sv.offset_inf.copy()
        offset_inf[:, 0] = 0.0

    def twice(a):
        return None if a is None else np.concatenate([a, a])

    wide_fields = {}
    if sv.wide_row is not None:
        n_w = len(sv.wide_normal)
        w_normal, w_offset = sv.wide_normal.copy(), sv.wide_offset.copy()
        w_normal[:, 0], w_offset[:, 0] = 0.0, -1.0
        w_inf = None
        if sv.wide_offset_inf is not None:
            w_inf = sv.wide_offset_inf.copy()
            w_inf[:, 0] = 0.0
        wide_fields = dict(wide_row=np.concatenate([sv.wide_row, np.where(sv.wide_row >= 0, sv.wide_row + n_w, -1)]),
                           wide_normal=np.concatenate([sv.wide_normal, w_normal]),
                           wide_offset=np.concatenate([sv.wide_offset, w_offset]),
                           wide_offset_inf=None if w_inf is None else np.concatenate([sv.wide_offset_inf, w_inf]))
    return ShadowVolumes(
        twice(sv.point), twice(sv.occluder), twice(sv.side), twice(sv.verts), twice(sv.inf), twice(sv.counts),
        np.concatenate([sv.normal, normal]), np.concatenate([sv.offset, offset]),
        None if offset_inf is None else np.concatenate([sv.offset_inf, offset_inf]), twice(sv.near), len(sv.point),
        sv.n_face, sv.occludes, sv.covered, **wide_fields)


def _test_pairs(body, q, verts, inf, counts, center_rel, radius, sv: ShadowVolumes, ax_b, half_b, ax_o, half_o,
                bodies: dict | None = None):
    """Filter (body, shadow volume) pairs; returns the kept pair indices, which of them cover the body,
    and ``planes (kept, J)`` int8: per plane of each kept pair's volume, 0 where the body cannot cross
    it, 2 where the body's vertices lie on both sides of it (it cuts the body), 1 otherwise.

    Tests, cheapest first: bounding cones from P overlap; the body's bounding sphere reaches inside every
    plane of the volume; exactly, the body's vertices are not all outside one plane. A body whose
    vertices are inside (or on) every plane lies wholly in the volume: it is *covered* (hidden).
    The exact test only looks at the planes the bounding sphere is not strictly inside of, by more
    than any vertex's on-plane tolerance (see :func:`_sphere_inside`): every vertex is inside the
    others, and so is every piece later cut from the body, so the clips skip them too.
    ``bodies``: an empty dict kept by a caller that tests the same ``verts`` in several calls (the
    bodies' slot-major copy is then made once).
    """
    cos_angle = np.einsum("ij,ij->i", take_rows(ax_b, body), take_rows(ax_o, q))
    cos_sum = np.cos(half_b[body] + np.minimum(half_o[q], np.pi))
    keep = np.flatnonzero((half_b[body] + half_o[q] >= np.pi) | (cos_angle >= cos_sum - 1e-12))
    n_j = sv.n_planes
    wide = sv.is_wide(q[keep])
    parts = []
    for grp in (np.flatnonzero(~wide), np.flatnonzero(wide)):
        # the wide volumes' pairs apart, in blocks: no (pairs, J) array over every pair's widest volume
        width = n_j if len(grp) and wide[grp[0]] else sv.normal.shape[1]
        step = max(1, int(2.5e5 // width))
        for s in range(0, len(grp), step):
            parts.append(_near_planes(keep[grp[s:s + step]], body, q, center_rel, radius, sv, n_j))
    keep = np.concatenate([keep[:0]] + [a for a, _ in parts])
    planes = np.concatenate([np.zeros((0, n_j), dtype=bool)] + [b for _, b in parts])
    order = np.argsort(keep, kind="stable")                                      # back in the pairs' order
    keep, planes = keep[order], planes[order]
    qk = q[keep]
    pr, pj = nonzero_rows(planes)                                                # (pair, plane) entries
    outside = np.zeros(len(keep), dtype=bool)
    crossed = np.zeros(len(keep), dtype=bool)
    planes = planes.astype(np.int8)
    step = max(1, int(2e6 // verts.shape[1]))
    # more (pair, plane) entries than bodies: the bodies' slot-major copy and scale once, gathered per
    # entry (bitwise the rows' own: a gather of a transpose is the transpose of the gather)
    per_body = inf is None and (len(pr) > len(verts) or bool(bodies))
    if per_body:
        if bodies:
            verts_t, scale_b = bodies["t"], bodies["scale"]
        else:
            verts_t = np.ascontiguousarray(verts.transpose(2, 1, 0))             # (3, K, C)
            scale_b = max_abs_rows(verts)
            if bodies is not None:
                bodies.update(t=verts_t, scale=scale_b)
    for s in range(0, len(pr), step):
        r, j = pr[s:s + step], pj[s:s + step]
        b = body[keep[r]]
        nrm, off, off_inf = sv.plane(qk[r], j)
        if inf is None:
            # padding slots repeat the last vertex, so they change neither test: no classification.
            # Slot-major (K, E): per-entry operands broadcast along the long axis (see rowops); the same
            # sums in the same order as _sides, so the clips see bitwise the same distances
            if per_body:
                xt, scale = np.take(verts_t, b, axis=2), np.take(scale_b, b)
            else:
                v = take_rows(verts, b)                                          # (E, K, 3)
                xt, scale = np.ascontiguousarray(v.transpose(2, 1, 0)), max_abs_rows(v)
            s_re = _distances_t(xt, nrm, off)                                     # (K, E)
            side = _own_sides(xt, s_re, PLANE_EPS * (scale + np.abs(off)), off, want_eps=False)[0]
            has_in, has_out = _any_t(side > 0), _any_t(side < 0)
        else:
            v = take_rows(verts, b)                                              # (E, K, 3)
            side = _sides(v, take_rows(inf, b), counts[b], max_abs_rows(v), nrm, off, off_inf)[0]
            has_in, has_out = any_rows(side > 0), any_rows(side < 0)
        outside[r[~has_in]] = True
        crossed[r[has_out]] = True
        planes.ravel()[(r * n_j + j)[has_in & has_out]] = 2
    meets = ~outside
    return keep[meets], ~crossed[meets], planes[meets]


def _near_planes(keep, body, q, center_rel, radius, sv: ShadowVolumes, n_j: int):
    """For pairs ``keep`` of :func:`_test_pairs`: those whose body's bounding sphere reaches inside every
    plane of the volume, and ``(kept, n_j)`` bool the planes it is not strictly inside of."""
    rel = take_rows(center_rel, body[keep])                                      # (p, 3)
    qk = q[keep]
    if len(qk) and WIDE_GROUPS and n_j >= WIDE_TREE_MIN and sv.is_wide(qk).all():
        return _near_planes_grouped(keep, body, q, center_rel, radius, sv, n_j)
    if len(qk) and sv.is_wide(qk).all():
        r = sv.wide_row[qk]
        nx, ny, nz = (take_rows(c, r) for c in sv.wide_components)              # (p, Jw) each
        off = take_rows(sv.wide_offset, r)
    else:
        nrm, off = sv.rows(qk)                                                   # (p, J')
        nx, ny, nz = nrm[..., 0], nrm[..., 1], nrm[..., 2]
    dist = nx * rel[:, 0:1] + ny * rel[:, 1:2] + nz * rel[:, 2:3] - off          # (p, J') centres' distances
    rad = radius[body[keep]]
    rmax = np.maximum(np.maximum(np.abs(rel[:, 0]), np.abs(rel[:, 1])), np.abs(rel[:, 2]))
    reach = rad * (1.0 + 1e-9) + PLANE_EPS * rmax
    near = np.flatnonzero(~any_rows(dist <= -reach[:, None]))
    keep, dist, off, rad, rmax, nx, ny, nz = (take_rows(x, near) for x in (keep, dist, off, rad, rmax, nx, ny, nz))
    unused = (nx == 0) & (ny == 0) & (nz == 0) & (off < 0)
    planes = ~(_sphere_inside(dist, off, rad, rmax) | unused)                    # (p, J')
    if planes.shape[1] < n_j:
        planes = np.concatenate([planes, np.zeros((len(keep), n_j - planes.shape[1]), dtype=bool)], axis=1)
    return keep, planes


@dataclass
class _PlaneTree:
    """A bounding tree over planes ``n . x = o`` (median cuts along the widest of (normal, offset /
    max |offset|), leaves of at most ``LEAF`` planes). Node arrays: ``lo, hi (N, 3)`` the box of its planes'
    normals, ``off_max, off_abs (N,)`` their largest offset and |offset|, ``n_abs (N,)`` their largest
    |normal component|, ``child (N, 2)`` (-1: a leaf), ``cols (N, LEAF)`` a leaf's planes' slots (-1:
    none); ``root (W,)`` per row (-1: a row with no planes). A row's unused slots (zero normal, negative
    offset) are in no node. For every plane of a node, in exact arithmetic,
    ``n . c - o >= sum_k min(lo_k c_k, hi_k c_k) - off_max``."""

    LEAF = 8
    lo: np.ndarray
    hi: np.ndarray
    off_max: np.ndarray
    off_abs: np.ndarray
    n_abs: np.ndarray
    child: np.ndarray
    cols: np.ndarray
    root: np.ndarray

    @classmethod
    def build(cls, nx: np.ndarray, ny: np.ndarray, nz: np.ndarray, off: np.ndarray) -> _PlaneTree:
        """From the rows' planes ``nx, ny, nz, off (W, Jw)``."""
        nodes, root = [], []                                      # (row, slots, parent, which child)
        for w in range(len(off)):
            cols = np.flatnonzero(~((nx[w] == 0) & (ny[w] == 0) & (nz[w] == 0) & (off[w] < 0)))
            if not len(cols):
                root.append(-1)
                continue
            scale = np.abs(off[w, cols]).max()
            feats = np.stack([nx[w, cols], ny[w, cols], nz[w, cols], off[w, cols] / (scale if scale > 0 else 1.0)], 1)
            root.append(len(nodes))
            todo = [(np.arange(len(cols)), -1, 0)]
            while todo:
                i, parent, k = todo.pop()
                me = len(nodes)
                nodes.append((w, cols[i], parent, k))
                if len(i) > cls.LEAF:
                    f = feats[i]
                    o = i[np.argsort(f[:, int(np.argmax(f.max(axis=0) - f.min(axis=0)))], kind="stable")]
                    todo += [(o[len(o) // 2:], me, 1), (o[:len(o) // 2], me, 0)]
        n = len(nodes)
        child = np.full((n, 2), -1, dtype=np.int64)
        leaf_cols = np.full((n, cls.LEAF), -1, dtype=np.int64)
        row = np.zeros(n, dtype=np.int64)
        depth = np.zeros(n, dtype=np.int64)
        for m, (w, c, parent, k) in enumerate(nodes):
            row[m] = w
            if parent >= 0:
                child[parent, k] = m
                depth[m] = depth[parent] + 1                   # (pre-order: a parent comes first)
            if len(c) <= cls.LEAF:
                leaf_cols[m, :len(c)] = c
        has = leaf_cols >= 0                                   # leaves' bounds from their planes
        rw, cs = row[:, None], np.where(has, leaf_cols, 0)
        nrm = np.stack([nx[rw, cs], ny[rw, cs], nz[rw, cs]], axis=-1)            # (N, LEAF, 3)
        lo = np.where(has[..., None], nrm, np.inf).min(axis=1)
        hi = np.where(has[..., None], nrm, -np.inf).max(axis=1)
        off_max = np.where(has, off[rw, cs], -np.inf).max(axis=1)
        off_abs = np.where(has, np.abs(off[rw, cs]), -np.inf).max(axis=1)
        for d in range(int(depth.max(initial=0)), -1, -1):      # then the inner nodes', deepest first
            m = np.flatnonzero((depth == d) & (child[:, 0] >= 0))
            c0, c1 = child[m, 0], child[m, 1]
            lo[m], hi[m] = np.minimum(lo[c0], lo[c1]), np.maximum(hi[c0], hi[c1])
            off_max[m], off_abs[m] = np.maximum(off_max[c0], off_max[c1]), np.maximum(off_abs[c0], off_abs[c1])
        n_abs = np.maximum(np.abs(lo), np.abs(hi)).max(axis=1)
        return cls(lo, hi, off_max, off_abs, n_abs, child, leaf_cols, np.array(root, dtype=np.int64))

    def leaves_near(self, r: np.ndarray, rel: np.ndarray, margin: np.ndarray):
        """Entries ``(pair (E,), leaf (E,))``: the leaves of rows ``r (p,)`` not known to lie wholly at more
        than ``margin (p,)`` + the plane tolerance ``PLANE_EPS 2 |o|`` from ``rel (p, 3)``. The bound is
        widened by 1e-9 of its operands' size (its rounding, and a plane's distance's, is ~1e-16 of it),
        so every plane left out is one whose computed distance also exceeds that."""
        pi = np.flatnonzero(self.root[r] >= 0)
        nd = self.root[r[pi]]
        out_p, out_n = [], []
        lo, hi, size = self.lo.T.copy(), self.hi.T.copy(), np.abs(rel).sum(axis=1)    # (3, N), (p,)
        while len(pi):
            lower = -self.off_max[nd]
            for k in range(3):
                c = rel[pi, k]
                lower += np.minimum(lo[k, nd] * c, hi[k, nd] * c)
            a = self.off_abs[nd]
            thr = margin[pi] + PLANE_EPS * 2.0 * a + 1e-9 * (size[pi] * self.n_abs[nd] + a)
            go = lower <= thr
            pi, nd = pi[go], nd[go]
            leaf = self.child[nd, 0] < 0
            out_p.append(pi[leaf])
            out_n.append(nd[leaf])
            pi, nd = np.tile(pi[~leaf], 2), self.child[nd[~leaf]].T.ravel()
        return np.concatenate(out_p + [pi[:0]]), np.concatenate(out_n + [nd[:0]])


def _near_planes_grouped(keep, body, q, center_rel, radius, sv: ShadowVolumes, n_j: int):
    """:func:`_near_planes` for pairs with wide volumes only: per pair only the planes of the leaves of
    :attr:`ShadowVolumes.wide_tree` its sphere's margin may reach are computed (with the same operations
    as the dense test): the others lie strictly inside the sphere's margin, so they neither put the body
    outside nor are near. The same pairs and planes as the dense test."""
    rel = take_rows(center_rel, body[keep])                                      # (p, 3)
    r = sv.wide_row[q[keep]]
    rad = radius[body[keep]]
    rmax = np.maximum(np.maximum(np.abs(rel[:, 0]), np.abs(rel[:, 1])), np.abs(rel[:, 2]))
    reach = rad * (1.0 + 1e-9) + PLANE_EPS * rmax
    margin = rad * (1.0 + 1e-9) + PLANE_EPS * 4.0 * (rmax + rad)                 # as in _sphere_inside (> -reach)
    tree = sv.wide_tree
    pi, leaf = tree.leaves_near(r, rel, margin)
    ec = tree.cols[leaf]                                                         # (E, LEAF) planes' slots
    has = ec >= 0
    ecs = np.where(has, ec, 0)
    re = r[pi][:, None]
    nx, ny, nz = (c_[re, ecs] for c_ in sv.wide_components)
    off = sv.wide_offset[re, ecs]
    rel_e = rel[pi]
    dist = nx * rel_e[:, 0:1] + ny * rel_e[:, 1:2] + nz * rel_e[:, 2:3] - off   # as in _near_planes
    outside = np.zeros(len(keep), dtype=bool)
    outside[pi[any_rows((dist <= -reach[pi][:, None]) & has)]] = True
    flag = ~_sphere_inside(dist, off, rad[pi], rmax[pi]) & has
    planes = np.zeros((len(keep), n_j), dtype=bool)
    planes[np.broadcast_to(pi[:, None], ec.shape)[flag], ec[flag]] = True
    near = np.flatnonzero(~outside)
    return keep[near], planes[near]


def _sphere_inside(dist, offset, radius, rmax):
    """``(p, J)`` planes (``offset (p, J)``) that bodies' bounding spheres (``radius (p,)``, centre at
    ``dist (p, J)`` from the planes, ``rmax (p,)`` = max |centre coordinate| from P) lie strictly inside
    of, by more than the on-plane tolerance ``PLANE_EPS (max |x| + |offset|)`` of any vertex x in the
    sphere (max |x| <= rmax + radius; the margin is doubled for rounding and for vertices snapped onto P
    in one-sided limits)."""
    margin = radius * (1.0 + 1e-9) + PLANE_EPS * 4.0 * (rmax + radius)
    return dist > margin[:, None] + PLANE_EPS * 2.0 * np.abs(offset)


def _distances_t(xt: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Signed distances ``(K, E)`` of points ``xt (3, K, E)`` (slot-major) from one plane per column,
    ``normal (E, 3) . x - offset (E,)``. Every plane test goes through here, so equal inputs give
    bitwise equal distances (the pair test's decisions are the clips' decisions)."""
    out = np.multiply(xt[0], normal[:, 0])                                       # as written out, in place
    tmp = np.multiply(xt[1], normal[:, 1])
    out += tmp
    out += np.multiply(xt[2], normal[:, 2], out=tmp)
    out -= offset
    return out


def _own_sides(xt: np.ndarray, s_t: np.ndarray, eps: np.ndarray, offset: np.ndarray, want_eps: bool = True,
               at_p: bool = False):
    """Sides ``(K, E)`` int8 of points ``xt (3, K, E)`` at distances ``s_t (K, E)`` from planes with
    ``offset (E,)``, each point on its plane within its own tolerance ``PLANE_EPS (|x|_∞ + |offset|)``
    (the rounding of its distance is ~ε (|x| + |offset|)); and (``want_eps``) those tolerances, ``(K, E)``,
    or ``eps`` itself where no point is within it. Decided first by ``eps (E,)`` (the rows' ``PLANE_EPS
    (max |x| + |offset|)``, never smaller), then again only for the points within that.

    With the rows' tolerance a vertex 1e-9 from P at 1.1e-12 from a plane through P (1e-3 rad) was on
    it when its fragment reached 3 away, and the floor behind a block face seen nearly edge-on kept
    2.8e-5 it should not have. ``at_p`` (one-sided limits): a point within the row's tolerance of P
    itself is at P, and keeps the row's tolerance, so that its side comes from its first-order part
    (a cut point at P interpolated to 1e-17 from it would otherwise take the side of its rounding)."""
    side = sides(s_t, eps)
    flat = np.flatnonzero((side == 0) & (s_t != 0.0))                             # (0 is on at any tolerance)
    if not len(flat):
        return side, eps
    e_i = flat % s_t.shape[1]
    x0, x1, x2 = (np.abs(np.take(xt[c].reshape(-1), flat)) for c in range(3))
    m = np.maximum(np.maximum(x0, x1), x2)
    own = PLANE_EPS * (m + np.abs(np.take(offset, e_i)))
    if at_p:
        row = np.take(eps, e_i)
        own = np.where(m <= row, row, own)
    side.reshape(-1)[flat] = sides(np.take(s_t.reshape(-1), flat), own)
    if not want_eps:
        return side, None
    out = np.repeat(eps[None, :], s_t.shape[0], axis=0)
    out.reshape(-1)[flat] = own
    return side, out


def _any_t(b: np.ndarray) -> np.ndarray:
    """``b.any(axis=0)`` for a slot-major ``b (K, E)``, row by row (numpy's reduction is per column)."""
    out = b[0].copy()
    for row in b[1:]:
        out |= row
    return out


def _sides(verts, inf, counts, scale, normal, offset, offset_inf):
    """Sides (E, K) int8 of vertices ``verts (E, K, 3)`` w.r.t. one plane each (``normal (E, 3)``,
    ``offset (E,)``; ``offset_inf`` its first-order part or None), padding slots 0; with the signed
    distances (E, K), their first-order parts or None, and the tolerances: ``PLANE_EPS (scale + |offset|)`` (E,), or
    (E, K) where some vertex is within that and has its own (see :func:`_own_sides`).

    Computed slot-major (the per-entry plane broadcasts along the long axis, see :mod:`.rowops`); the
    (E, K) results are transposed views."""
    xt = np.ascontiguousarray(verts.transpose(2, 1, 0))
    s_t = _distances_t(xt, normal, offset)                                        # (K, E)
    side_t, eps = _own_sides(xt, s_t, PLANE_EPS * (scale + np.abs(offset)), offset, at_p=inf is not None)
    si_t = None
    if inf is not None:
        si_t = _distances_t(np.ascontiguousarray(inf.transpose(2, 1, 0)), normal, offset_inf)
        on = side_t == 0
        if on.any():
            side_t[on] = sides(si_t[on], PLANE_EPS)
    side_t *= np.arange(verts.shape[1])[:, None] < counts[None, :]
    return side_t.T, s_t.T, None if si_t is None else si_t.T, eps.T


@dataclass
class Coverage:
    """What the merged faces (clusters) tell before any polygon is looked at (level 1 of sec. 3.4).

    Attributes (Q: shadow-volume instances):
        cluster_covered: (Q,) the cluster of instance q lies wholly inside another volume: all its
            members are hidden, and its own volume is redundant.
        k_ptr (Q+1,), kq: CSR lists of the non-redundant volumes that cut each cluster instance.
        ax_o, half_o: (Q, 3), (Q,) bounding cones of the volumes' occluders seen from their receivers.
        tiles: the tiles that survive the hierarchy (:func:`.hierarchy.visit_tiles`, level 1.5), set
            by the caller, or None.
    """

    cluster_covered: np.ndarray
    k_ptr: np.ndarray
    kq: np.ndarray
    ax_o: np.ndarray
    half_o: np.ndarray
    tiles: object = None


def coverage(sv: ShadowVolumes, table: np.ndarray, occ: Occluders, points) -> Coverage:
    """Level 1 of the culling hierarchy (sec. 3.4), before any member polygon is gathered.

    Every occluder (a merged face: the *cluster* of its member polygons) is tested against every other
    occluder's shadow volume; a cluster wholly inside a volume has all its members hidden, and as an
    occluder it is redundant (its shadow volume lies inside the other's), so it is dropped. The tiles
    of large clusters are then tested in :func:`.hierarchy.visit_tiles` (level 1.5). Each test (see
    :func:`_test_pairs`) needs the body to have a vertex strictly beyond the occluder's plane, on the
    side away from P.
    """
    n_q = sv.n_base
    o_rel = occ.vol_centers[sv.occluder] - points[sv.point]
    ax_o, half_o, _ = _cone(o_rel, occ.vol_radii[sv.occluder])
    if n_q == 0:
        e = np.zeros(0, dtype=np.int64)
        return Coverage(np.zeros(0, dtype=bool), np.zeros(1, dtype=np.int64), e, ax_o, half_o)

    # clusters (face instances) against shadow volumes
    if occ.depth is not None:
        blocks = _cluster_pairs_by_cones(sv, table, occ, ax_o, half_o)
    elif DENSE_COVERAGE or occ.vol_pairs is None:
        blocks = [_cluster_pairs_dense(sv, table, occ)]
    else:
        blocks = _cluster_pair_blocks(sv, table, occ)
    radii = occ.vol_radii[sv.occluder]
    parts = []
    bodies = {}
    for k_idx, kq in blocks:    # tested a block at a time: only the pairs that meet are kept
        if sv.covered is not None:                          # clusters known to be hidden need no test
            live = ~sv.covered[k_idx]
            k_idx, kq = k_idx[live], kq[live]
        kept, cov, _ = _test_pairs(k_idx, kq, sv.verts, sv.inf, sv.counts, o_rel, radii, sv, ax_o, half_o, ax_o,
                                   half_o, bodies)
        parts.append((k_idx[kept], kq[kept], cov))
    k_idx, kq, cov = (np.concatenate(a) for a in zip(*parts))
    order = np.lexsort((sv.occluder[kq], k_idx))          # the order of a scan over (k, volume)
    k_idx, kq, cov = k_idx[order], kq[order], cov[order]
    cluster_covered = np.zeros(n_q, dtype=bool) if sv.covered is None else sv.covered[:n_q].copy()
    cluster_covered[k_idx[cov]] = True
    live = ~cluster_covered[kq] & ~cov          # pairs with a non-redundant volume that cut the cluster
    k_idx, kq = k_idx[live], kq[live]
    order = np.argsort(k_idx, kind="stable")
    k_idx, kq = k_idx[order], kq[order]
    k_ptr = np.zeros(n_q + 1, dtype=np.int64)
    np.add.at(k_ptr, k_idx + 1, 1)
    k_ptr = np.cumsum(k_ptr)
    return Coverage(cluster_covered, k_ptr, kq, ax_o, half_o)


#: build :func:`coverage`'s (cluster, volume) pairs from the dense (instance × volume) tables, as before
#: the sparse lists (for tests and benchmarks: the same pairs in the same order)
DENSE_COVERAGE = False

#: entries of the sparse lists expanded (and pairs tested) at a time in :func:`coverage`
PAIR_BLOCK = 1 << 17


def _cluster_pairs_dense(sv: ShadowVolumes, table: np.ndarray, occ: Occluders):
    """:func:`_cluster_pairs` through dense (K, n_vol) arrays: K face instances × all volumes."""
    n_k = sv.n_face
    k_occ = sv.occluder[:n_k]
    q_tab = table[sv.point[:n_k]]                                                # (K, n_vol)
    has = q_tab >= 0
    q_safe = np.where(has, q_tab, 0)
    has &= sv.occludes[q_safe]
    sig_pos = sv.side[q_safe] > 0
    n_vol = occ.n_vol
    beyond = np.where(sig_pos, unpack_rows(occ.occ_beyond_pos, k_occ, n_vol),
                      unpack_rows(occ.occ_beyond_neg, k_occ, n_vol)) & has
    # ... and the volume's occluder must reach to P's side of the cluster's plane
    k_front_pos = sv.side[:n_k] < 0                                              # (K,) P on the + side
    beyond &= np.where(k_front_pos[:, None], unpack_rows(occ.occ_reach_pos, k_occ, n_vol),
                       unpack_rows(occ.occ_reach_neg, k_occ, n_vol))
    beyond[np.arange(n_k), k_occ] = False
    k_idx, o_idx = np.nonzero(beyond)
    return k_idx, q_tab[k_idx, o_idx]


def _cluster_pairs(sv: ShadowVolumes, table: np.ndarray, occ: Occluders):
    """:func:`_cluster_pair_blocks` joined and sorted by k, then by q's occluder (the order of a dense
    scan over (k, volume), as :func:`_cluster_pairs_dense`)."""
    k_idx, kq = (np.concatenate(a) for a in zip(*_cluster_pair_blocks(sv, table, occ)))
    order = np.lexsort((sv.occluder[kq], k_idx))
    return k_idx[order], kq[order]


def _cluster_pairs_by_cones(sv: ShadowVolumes, table: np.ndarray, occ: Occluders, ax_o, half_o):
    """:func:`_cluster_pair_blocks` for :attr:`.culling.Occluders.depth` (no receiver-independent pair
    lists over n_o² entries): a face volume q whose far side has few faces beyond it takes them from
    :class:`.depth_pairs.BeyondLists`; the others (and the solids' volumes) are paired with the face
    instances whose bounding cones from the receiver may meet theirs (:func:`.depth_pairs.ball_pairs`
    on the cones' axes: the chord is at most the angle; receivers in blocks of about :data:`PAIR_BLOCK`
    / 2 instances). Then the depth relations of just those pairs (:meth:`.depth_pairs.DepthPairs.can_hide`).
    The pairs that :func:`_test_pairs` keeps are the same as from the tables (it tests the cones first)."""
    lists = occ.depth.lists
    n_k, n_q, n_o = sv.n_face, sv.n_base, occ.n
    qs = np.flatnonzero(sv.occludes[:n_q])
    o_q = sv.occluder[qs]
    s_q = (sv.side[qs] <= 0).astype(np.int64)               # 0: the far side is the + side
    listed = o_q < n_o
    listed[listed] = ~lists.open[s_q[listed], o_q[listed]]
    yield np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    ql = qs[listed]
    if len(ql):
        o, s = o_q[listed], s_q[listed]
        n = lists.ptr[s, o + 1] - lists.ptr[s, o]
        q = np.repeat(ql, n)
        pos = np.arange(len(q)) - np.repeat(np.cumsum(n) - n, n) + np.repeat(lists.ptr[s, o], n)
        k_occ = lists.faces[pos]
        k = table[sv.point[q], k_occ]
        ok = k >= 0
        k, q = k[ok], q[ok]
        ok = occ.depth.can_hide(False, sv.occluder[k], sv.occluder[q], sv.side[q] > 0, sv.side[k] < 0)
        yield k[ok], q[ok]
    qd = qs[~listed]
    if not len(qd):
        return
    # cos(angle) >= cos(h_k + h_q) - 1e-12 in _test_pairs: the angle may exceed h_k + h_q by 1.5e-6
    slack = 1e-6
    pts_q = sv.point[qd]
    wanted = np.zeros(int(sv.point.max(initial=0)) + 1, dtype=bool)
    wanted[pts_q] = True
    ks = np.flatnonzero(wanted[sv.point[:n_k]])
    pts_k = sv.point[ks]
    ends = np.cumsum(np.bincount(pts_k, minlength=len(wanted)))
    cuts = np.unique(np.searchsorted(ends, np.arange(PAIR_BLOCK // 2, int(ends[-1]), PAIR_BLOCK // 2)))
    bounds = np.concatenate([[0], cuts + 1, [len(wanted)]])
    for a, e in zip(bounds[:-1], bounds[1:]):
        if a >= e:
            continue
        kb = ks[(pts_k >= a) & (pts_k < e)]
        qb = qd[(pts_q >= a) & (pts_q < e)]
        i, j = ball_pairs(sv.point[kb], ax_o[kb], half_o[kb] + slack, sv.point[qb], ax_o[qb], half_o[qb] + slack,
                          0.25)
        k, q = kb[i], qb[j]
        ok = sv.occluder[k] != sv.occluder[q]                                    # a face never hides itself
        k, q = k[ok], q[ok]
        ok = occ.depth.can_hide(False, sv.occluder[k], sv.occluder[q], sv.side[q] > 0, sv.side[k] < 0)
        yield k[ok], q[ok]


def _cluster_pair_blocks(sv: ShadowVolumes, table: np.ndarray, occ: Occluders):
    """The (face instance k, volume instance q) pairs at one receiver where the volume can hide part of
    the cluster: q occludes, the cluster reaches beyond q's plane away from P (``occ_beyond_*`` by P's
    side of it) and q's occluder reaches P's side of the cluster's plane (``occ_reach_*``). Yields
    blocks ``k_idx, kq`` of about :data:`PAIR_BLOCK` listed entries each (in no particular order; at
    least one block).

    Generated from the scene's sparse lists (:class:`.culling.VolumePairs`) without anything dense over
    (instance × volume): from the faces' side (each instance's lists for its own side of its plane,
    filtered by the volume's side) or from the volumes' side (the converse), whichever lists are
    shorter for this chunk. Time and memory O(K + Q + the entries listed).
    """
    vp = occ.vol_pairs
    n_k, n_q = sv.n_face, sv.n_base
    k_occ = sv.occluder[:n_k]
    t_k = (sv.side[:n_k] >= 0).astype(np.int64)             # 0: P on the + side of the cluster's plane
    qs = np.flatnonzero(sv.occludes[:n_q])
    s_q = (sv.side[qs] <= 0).astype(np.int64)               # 0: P on the - side of the volume's plane
    o_q = sv.occluder[qs]
    f_len = np.diff(vp.by_face_ptr, axis=1)                 # (4, n_o)
    v_len = np.diff(vp.by_vol_ptr, axis=1)                  # (4, n_vol)
    cost_f = int(f_len[t_k, k_occ].sum() + f_len[2 + t_k, k_occ].sum())
    cost_v = int(v_len[2 * s_q, o_q].sum() + v_len[2 * s_q + 1, o_q].sum())
    yield np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    for s in (0, 1):
        for t in (0, 1):
            c = 2 * s + t
            by_face = cost_f <= cost_v
            if by_face:
                own = np.flatnonzero(t_k == t)
                ptr, vals, row = vp.by_face_ptr[c], vp.by_face_vol[c], k_occ
            else:
                own = qs[s_q == s]
                ptr, vals, row = vp.by_vol_ptr[c], vp.by_vol_face[c], sv.occluder
            # in blocks of about PAIR_BLOCK listed entries: the temporaries stay at a few tens of MB
            ends = np.cumsum(ptr[row[own] + 1] - ptr[row[own]])
            cuts = np.searchsorted(ends, np.arange(PAIR_BLOCK, int(ends[-1]) if len(ends) else 0, PAIR_BLOCK))
            for blk in np.split(own, np.unique(cuts)):
                b, o = expand(row[blk], ptr, vals)
                if by_face:
                    kk = blk[b]
                    q = table[sv.point[kk], o]
                    ok = q >= 0
                    kk, q = kk[ok], q[ok]
                    ok = sv.occludes[q] & ((sv.side[q] <= 0) == bool(s))
                else:
                    q = blk[b]
                    kk = table[sv.point[q], o]
                    ok = kk >= 0
                    kk, q = kk[ok], q[ok]
                    ok = t_k[kk] == t
                yield kk[ok], q[ok]


def occluder_pairs(cand: Candidates, sv: ShadowVolumes, table: np.ndarray, cov: Coverage, occ: Occluders, scene,
                   points):
    """Occluders of every candidate that can hide part of it, nearest first (level 2 of sec. 3.4).

    Only the member polygons of clusters (or tiles) that straddle a volume are tested against that
    volume (see :func:`coverage`); each test (see :func:`_test_pairs`) needs the body to have a vertex
    strictly beyond the occluder's plane, on the side away from P (precomputed per scene, per side).

    Returns ``ptr (C+1,), ids`` (CSR lists of shadow-volume instances per candidate), ``planes
    (len(ids), J)`` int8 (per plane of each volume: 0 it contains the candidate, 1 it may cut it, 2 it
    cuts the candidate itself; see :func:`_test_pairs`) and ``hidden (C,)``: candidates wholly inside
    one shadow volume, which need no further work.
    """
    c_n, n_q = len(cand.point), sv.n_base
    if c_n == 0 or n_q == 0:
        return (np.zeros(c_n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64),
                np.zeros((0, sv.n_planes), dtype=bool), np.zeros(c_n, dtype=bool))
    k_of = at2(table, cand.point, occ.members[cand.poly])                       # (C,) cluster instance
    tiles = cov.tiles                                                           # the candidates' tile pairs
    by_tile = tiles.tested[cand.pair]                                           # (C,) tested at level 1.5
    hidden = np.zeros(c_n, dtype=bool)
    found = k_of >= 0
    hidden[found] = cov.cluster_covered[k_of[found]]
    from_cluster = np.flatnonzero(found & ~by_tile & ~hidden)
    from_tile = np.flatnonzero(by_tile & ~hidden)
    b1, q1 = expand(k_of[from_cluster], cov.k_ptr, cov.kq)
    b2, q2 = expand(cand.pair[from_tile], tiles.ptr, tiles.q)
    body = np.concatenate([from_cluster[b1], from_tile[b2]])
    q = np.concatenate([q1, q2])
    if (~found).any():  # a candidate whose cluster was culled (numerically at the horizon): all volumes
        lost = np.flatnonzero(~found)
        lt = table[cand.point[lost]]
        lb, lo = np.nonzero((lt >= 0) & sv.occludes[np.maximum(lt, 0)])
        body = np.concatenate([body, lost[lb]])
        q = np.concatenate([q, table[cand.point[lost[lb]], lo]])
    if len(body):
        ci = cand.poly[body]
        sig = sv.side[q] > 0
        oq = sv.occluder[q]
        p_pos = cand.side[body] < 0                                              # P on the + side of the body
        if occ.depth is not None:                                                # per pair (no tables)
            beyond = occ.depth.can_hide(True, ci, oq, sig, p_pos)
        else:
            beyond = np.where(sig, bit_at(occ.beyond_pos, ci, oq), bit_at(occ.beyond_neg, ci, oq))
            beyond &= np.where(p_pos, bit_at(occ.front_pos, ci, oq), bit_at(occ.front_neg, ci, oq))
        body, q = body[beyond], q[beyond]
    if len(occ.coplanar_occ):
        # coplanar overlapping surfaces: the one facing P wins, then the lower input index
        cb, co = expand(cand.poly, occ.coplanar_ptr, occ.coplanar_occ)
        cq = table[cand.point[cb], co]
        ok = (cq >= 0) & ~hidden[cb]
        cb, co, cq = cb[ok], co[ok], cq[ok]
        faces_o = sv.side[cq] < 0
        faces_c = cand.side[cb] < 0
        wins = (faces_o & ~faces_c) | ((faces_o == faces_c) & (occ.first_source[co] < scene.poly_source[cand.poly[cb]]))
        body = np.concatenate([body, cb[wins]])
        q = np.concatenate([q, cq[wins] + sv.n_base])                          # the cone-only copy
    c_rel = take_rows(scene.poly_centers, cand.poly)
    c_rel -= take_rows(points, cand.point)
    ax_c, half_c, _ = _cone(c_rel, scene.poly_radii[cand.poly])
    kept, covd, planes = _test_pairs(body, q, cand.verts, cand.inf, cand.counts, c_rel, scene.poly_radii[cand.poly],
                                     sv, ax_c, half_c, cov.ax_o, cov.half_o)
    body, q = body[kept], q[kept]
    hidden[body[covd]] = True
    keep = ~hidden[body]
    body, q, planes = body[keep], q[keep], planes[keep]
    order = np.lexsort((sv.near[q], body))
    ids, body, planes = q[order], body[order], planes[order]
    ptr = np.zeros(c_n + 1, dtype=np.int64)
    np.add.at(ptr, body + 1, 1)
    return np.cumsum(ptr), ids, planes, hidden


def _plane_sides(verts, inf, counts, scale, sv: ShadowVolumes, q: np.ndarray, j):
    """Sides (W, K) of fragment vertices w.r.t. plane ``j`` of volumes ``q`` (W,); invalid slots 0
    (see :func:`_sides`). ``scale (W,)`` is the fragments' length scale (max |x|) for the tolerance."""
    nrm, off, off_inf = sv.plane(q, j)
    return _sides(verts, inf, counts, scale, nrm, off, None if inf is None else off_inf)


def subtract_shadow_volumes(frags: Fragments, ptr: np.ndarray, ids: np.ndarray, sv: ShadowVolumes,
                            planes: np.ndarray | None = None, flat=None) -> Fragments:
    """Remove from every fragment the parts inside its occluders' shadow volumes.

    Args:
        frags: fragments (``owner``: their candidates); ptr, ids: the candidates' occluder instances
            (CSR, nearest first); sv: the shadow volumes; planes: ``(len(ids), J)``, non-zero for the planes
            of each volume that may cut the candidate (see :func:`occluder_pairs`), or None for all;
            flat: None or ``(candidate flags (C,), plane normals (n, 3))``: in a one-sided limit, the
            candidates lying in a plane through P (see :class:`.projection.Candidates`), whose pieces
            are put back into that plane after every cut (an intersection interpolated along a 1e6 edge
            lands ~1e-10 off the plane, which near P would tilt the piece out of edge-on).
    Returns:
        the visible fragments.
    """
    return Fragments.concat(_subtract(frags, ptr, ids, sv, planes, flat))


def _subtract(frags: Fragments, ptr, ids, sv: ShadowVolumes, planes, flat=None) -> list[Fragments]:
    """:func:`subtract_shadow_volumes` as a list of fragment sets (not padded to one width)."""
    dual = frags.inf is not None
    n_occ = np.diff(ptr)
    j_planes = sv.n_planes
    if planes is None:
        planes = np.ones((len(ids), j_planes), dtype=bool)
    done: list[tuple] = []
    work = frags
    r = 0
    while len(work.owner):
        finished = n_occ[work.owner] <= r
        if finished.any():
            done.append(work.take(finished))
            work = work.take(~finished)
            if not len(work.owner):
                break
        n_w = len(work.owner)
        entry = ptr[work.owner] + r
        q_of = ids[entry]                                                        # (W,)
        use = planes[entry]                                                      # (W, J)
        width = work.verts.shape[1] + j_planes
        cur_v = _fit(work.verts, work.counts, width)
        cur_i = _fit(work.inf, work.counts, width) if dual else None
        cur_c = work.counts.copy()
        scale = max_abs_rows(work.verts)
        item = np.arange(n_w)
        pieces = []
        for j in range(j_planes):
            rows = np.flatnonzero(use[item, j])
            # a plane that contains the candidate (not in ``use``) contains every piece of it: carry on
            if len(rows):
                k = int(cur_c[rows].max())
                side, s_re, s_inf, eps = _plane_sides(cur_v[rows, :k], cur_i[rows, :k] if dual else None,
                                                      cur_c[rows], scale[item[rows]], sv, q_of[item[rows]], j)
                has_in = any_rows(side > 0)
                # wholly outside this plane: the fragment does not meet the volume and stays whole;
                # wholly inside (or on) it: carry on unchanged to the next plane
                cut = has_in & any_rows(side < 0)
                if cut.any():
                    rc = rows[cut]
                    k = int(cur_c[rc].max())
                    (iv, ic, ii), (ov, oc, oi) = split_convex(
                        cur_v[rc, :k], cur_c[rc], s_re[cut, :k], eps[cut] if eps.ndim == 1 else eps[cut, :k],
                        inf=cur_i[rc, :k] if dual else None, s_inf=s_inf[cut, :k] if dual else None)
                    if flat is not None:
                        fr = np.flatnonzero(flat[0][work.owner[item[rc]]])
                        if len(fr):
                            nn = flat[1][work.poly[item[rc[fr]]]]
                            iv[fr] = onto_planes_through_p(iv[fr], nn)
                            ov[fr] = onto_planes_through_p(ov[fr], nn)
                    pieces.append((item[rc], ov, oc, oi))
                    cur_v, cur_i = _store_pieces(cur_v, cur_i, cur_c, rc, iv, ii, ic)
                if not has_in.all():
                    stay = np.ones(len(item), dtype=bool)
                    stay[rows[~has_in]] = False
                    item, cur_v, cur_c = item[stay], cur_v[stay], cur_c[stay]
                    cur_i = cur_i[stay] if dual else None
            if len(item) == 0:
                break
        hidden = np.zeros(n_w, dtype=bool)
        hidden[item] = True          # these fragments have a non-empty hidden part
        if hidden.any():
            parts = [work.take(~hidden)]
            for it, pv, pc, pi in pieces:
                sel = hidden[it]
                if sel.any():
                    parts.append(work.pieces(it[sel], pv[sel], pc[sel], pi[sel] if dual else None))
            work = Fragments.concat(parts)
        r += 1
    done.append(work)
    return done


def _store_pieces(v, inf, c, rows, iv, ii, ic):
    """Write clipped pieces ``iv (r, w, 3)`` (``ii`` their first-order parts or None, ``ic`` counts) into
    rows ``rows`` of ``v, inf, c`` in place, widening ``v`` and ``inf`` if a piece is wider (only where
    rounding made a fragment cross a plane more than twice); returns ``(v, inf)``."""
    w = iv.shape[1]
    if w > v.shape[1]:
        v = _fit(v, c, w)
        inf = None if inf is None else _fit(inf, c, w)
    v[rows, :w] = iv
    v[rows, w:] = iv[:, -1:]
    if inf is not None:
        inf[rows, :w] = ii
        inf[rows, w:] = ii[:, -1:]
    c[rows] = ic
    return v, inf


def _fit(v: np.ndarray, c: np.ndarray, width: int) -> np.ndarray:
    """Pad or trim padded polygons ``v (F, K, 3)`` to ``width`` slots (``width >= counts``).

    Slot K-1 always holds the last real vertex (padding repeats it), so growing repeats that slot.
    """
    del c  # the invariant above makes the counts unnecessary
    if v.shape[1] == width:
        return v
    if v.shape[1] > width:
        return v[:, :width]
    return np.concatenate([v, np.repeat(v[:, -1:], width - v.shape[1], axis=1)], axis=1)



#: candidates cut by at most this many volumes take the inclusion–exclusion path (2^k - 1 clip chains);
#: the rest are subtracted (see :func:`visible_terms`). One: with two volumes the terms' separate
#: on-plane decisions can disagree on a sliver of their overlap (a term dropped as empty that the
#: other terms count), which the subtraction, deciding once per piece, cannot do
IE_MAX_VOLUMES = 1


def visible_terms(frags: Fragments, ptr: np.ndarray, ids: np.ndarray, sv: ShadowVolumes, planes: np.ndarray,
                  use: np.ndarray | None = None, flat=None):
    """The visible part of every fragment as a signed sum of convex pieces (for sums over fragments).

    By inclusion–exclusion ``A \\ (V_1 ∪ … ∪ V_k) = A − Σ A∩V_i + Σ A∩V_i∩V_j − …`` as signed measures:
    every term is one convex polygon, ``A`` clipped to the inside of each volume of a subset in turn
    (no pieces to keep track of, as :func:`subtract_shadow_volumes` needs). Fragments with more than
    :data:`IE_MAX_VOLUMES` volumes are subtracted instead (2^k terms grow faster than the pieces).
    A term's clips are the same plane splits as the subtraction's, so ``A`` minus its inside pieces is
    the subtraction's outside pieces to rounding.

    ``planes (len(ids), J)``: the planes of each volume that may cut the candidate (see
    :func:`occluder_pairs`). ``use (F,)`` bool: the fragments to take (default all; gathered once per
    set below, so the caller need not copy); ``flat`` as for :func:`subtract_shadow_volumes`. Returns a
    list of ``(terms, sign)``: fragment sets (each padded to its own width, so that eq. 4 runs on each
    without padding them all to the widest) and the sign (+1 or -1) that weights their integrals.
    """
    n_occ = np.diff(ptr)[frags.owner]
    many = n_occ > IE_MAX_VOLUMES
    if frags.inf is not None:
        # one-sided limits: fragments touching P are integrated from first-order directions, and a
        # difference of two such integrals is not as accurate as the integrals of the pieces
        many[:] = True
    if use is None:
        use = np.ones(len(n_occ), dtype=bool)
    chain = use & (n_occ > 0) & ~many
    parts = []
    # one volume, one of its planes cutting A: A minus A ∩ V is the piece outside that plane
    one = np.flatnonzero(chain & (n_occ == 1))
    if len(one):
        entry = ptr[frags.owner[one]]
        cuts = take_rows(planes, entry) == 2                                   # (o, J)
        single = sum_rows(cuts) == 1
        one, entry, cuts = one[single], entry[single], cuts[single]
        if len(one):
            a = frags.take(one)
            pieces, whole, route = _outside_of_one_plane(a, ids[entry], np.argmax(cuts, axis=1),
                                                         take_rows(planes, entry), sv)
            parts.append((pieces, 1.0))
            chain[one] = False
            chain[one[route]] = True       # a later plane cuts the inside piece after all: the general way
            use = use.copy()
            use[one] = False
            use[one[whole]] = True         # the inside piece is empty: A is visible whole
            use[one[route]] = True
    parts.append((frags.take(use & ~many), 1.0))
    if (use & many).any():
        parts += [(sub, 1.0) for sub in _subtract(frags.take(use & many), ptr, ids, sv, planes, flat)]
    few = np.flatnonzero(chain)
    # level 1: every (fragment, volume) pair; then each term grows by a volume after its last one
    rows = np.repeat(few, n_occ[few])
    pos = np.arange(len(rows)) - np.repeat(np.cumsum(n_occ[few]) - n_occ[few], n_occ[few])
    cur = frags.take(rows)
    sign = -1.0
    while len(rows):
        entry = ptr[cur.owner] + pos
        cur, kept = _clip_into_volumes(cur, ids[entry], planes[entry], sv)
        rows, pos = rows[kept], pos[kept]
        parts.append((cur, sign))
        # extend each term by every later volume of its fragment
        more = n_occ[rows] - 1 - pos
        ext = np.repeat(np.arange(len(rows)), more)
        step = np.arange(len(ext)) - np.repeat(np.cumsum(more) - more, more) + 1
        rows, pos = rows[ext], pos[ext] + step
        cur = cur.take(ext)
        sign = -sign
    return [(f, sg) for f, sg in parts if len(f.owner)]


def _outside_of_one_plane(frags: Fragments, q: np.ndarray, cut: np.ndarray, use: np.ndarray, sv: ShadowVolumes):
    """Visible parts of fragments that one plane ``cut (F,)`` of their only volume ``q (F,)`` cuts.

    The other planes ``use (F, J)`` (codes as :func:`occluder_pairs`) contain the fragment A, so
    ``A ∩ V`` is A's piece inside the cut plane, and the visible part ``A − A ∩ V`` is the piece
    outside it: one convex piece, one integral instead of two. As the clip chain of
    :func:`_clip_into_volumes` would, the inside piece is then tested against the later planes:
    where it has no vertex strictly inside one of them ``A ∩ V`` is empty and A is visible whole;
    where one of them cuts it (a rounding-level case) the fragment takes the general way.

    Returns ``(pieces, whole, route)``: the outside pieces of the other fragments, and the indices of
    the fragments visible whole and of those to route.
    """
    n_j = sv.n_planes
    v, c = frags.verts, frags.counts
    scale = max_abs_rows(v)
    nrm, off, _ = sv.plane(q, cut)
    _, s_re, _, eps = _sides(v, None, c, scale, nrm, off, None)
    (iv, ic, _), (ov, oc, _) = split_convex(v, c, s_re, eps)
    empty = np.zeros(len(q), dtype=bool)
    route = np.zeros(len(q), dtype=bool)
    for j in range(n_j):
        rr = np.flatnonzero((use[:, j] > 0) & (cut < j))
        if not len(rr):
            continue
        side = _plane_sides(take_rows(iv, rr), None, ic[rr], scale[rr], sv, q[rr], j)[0]
        has_in = any_rows(side > 0)
        empty[rr[~has_in]] = True
        route[rr[has_in & any_rows(side < 0)]] = True
    empty &= ~route
    ok = np.flatnonzero(~empty & ~route)
    return frags.pieces(ok, take_rows(ov, ok), oc[ok], None), np.flatnonzero(empty), np.flatnonzero(route)


def _clip_into_volumes(frags: Fragments, q: np.ndarray, use: np.ndarray, sv: ShadowVolumes):
    """Clip every fragment to the inside of its volume ``q (F,)``, by the planes ``use (F, J)`` (the
    others contain the fragment): ``(clipped, kept)`` where ``kept`` indexes the fragments with a
    non-empty inside (a vertex strictly inside every plane)."""
    dual = frags.inf is not None
    kept = np.arange(len(q))
    v, inf, c = frags.verts, frags.inf, frags.counts
    scale = max_abs_rows(v)
    for j in range(sv.n_planes):
        if not len(kept):
            break
        rr = np.flatnonzero(use[:, j])
        if not len(rr):
            continue
        side, s_re, s_inf, eps = _plane_sides(take_rows(v, rr), None if not dual else take_rows(inf, rr), c[rr],
                                              scale[rr], sv, q[rr], j)
        has_in = any_rows(side > 0)
        cut = has_in & any_rows(side < 0)
        if cut.any():
            ci = np.flatnonzero(cut)
            rc = rr[ci]
            k = int(c[rc].max())
            (iv, ic, ii), _ = split_convex(take_rows(v, rc)[:, :k], c[rc], take_rows(s_re, ci)[:, :k],
                                           eps[ci] if eps.ndim == 1 else take_rows(eps, ci)[:, :k],
                                           inf=take_rows(inf, rc)[:, :k] if dual else None,
                                           s_inf=take_rows(s_inf, ci)[:, :k] if dual else None, outside=False)
            v, inf = _store_pieces(v, inf, c, rc, iv, ii, ic)  # (the caller's private copies)
        if not has_in.all():
            keep = np.ones(len(q), dtype=bool)
            keep[rr[~has_in]] = False
            keep = np.flatnonzero(keep)
            kept, q, use, v, c, scale = (take_rows(x, keep) for x in (kept, q, use, v, c, scale))
            inf = take_rows(inf, keep) if dual else None
    return Fragments(v, inf, c, frags.point[kept], frags.poly[kept], frags.side[kept], frags.owner[kept]), kept
