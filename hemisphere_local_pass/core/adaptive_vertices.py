"""The adaptive local pass for dense vertex sets (issue 11, sec. 2: "vertices use it where it pays").

A radiosity mesh is a subdivided one: the vertices (or face corners) of a subdivided wall, floor or block
face lie on one plane at the nodes of a tensor lattice ``(u_i, v_j)`` of that plane. Laid out as an image
of ``(n_v, n_u)`` nodes they are what :func:`.adaptive.adaptive_irradiance` works on: a quadtree over the
nodes, exact samples at its corners, the spot checks (and the check extended one spacing beyond a cell),
bilinear interpolation in lattice-index space where the estimate is within the tolerance, and every node
evaluated where it is not. Receivers on no lattice (an irregular or triangulated mesh, a curved one, a
plane with fewer than :data:`MIN_SIDE` lattice lines each way) are evaluated exactly: there interpolation
does not pay, or cannot be set up.

What differs from an image, and how it is handled:

1. **Nodes missing from the lattice** (holes in a mesh, an L-shaped wall): the image's *missed* pixels
   (``polygons = -1``): a cell touching one is split down to its nodes (a surface break).
2. **Other geometry meeting the plane** inside the lattice (a block standing on a subdivided floor, a
   wall passing through it): an image sees such a junction as a change of plane between adjacent
   pixels; a lattice on one plane does not, and H jumps there (lit floor outside the block's foot, the
   inside of the block under it). Every lattice square the intersection segment of such a polygon meets
   gets its four sides marked as breaks (``breaks=`` of :func:`.adaptive.adaptive_irradiance`), so the
   quadtree refines down to the nodes around the segment, whatever its width. Segments on the lattice's
   outer boundary (the walls the floor meets at its edges) are no breaks: H is continuous up to the
   boundary from inside, as at an image's border (factor 4 there, as for pixels).
3. **Nodes on such a segment** (a block's side standing exactly on a lattice line): the node's corners on
   either side of the segment have different one-sided limits (``limit_directions``), so the node is taken
   out of the lattice (a hole, step 1) and each of its receivers is evaluated exactly with its own limit.
4. **Several receivers at a node** (a vertex's corners, CORNER domain): one of them is the lattice's sample;
   where H is continuous (every node not on a segment, step 3) its limits agree, and every receiver of the
   node gets the node's value. At an exact node that is the representative's exact value; the others'
   own evaluations may differ from it in the last bits only (their limit directions differ).
5. **Non-uniform spacing** (grid lines added at a light's boundary): the interpolation is bilinear in
   lattice-index space, as the image's is in pixel space (itself not affine on a surface under
   perspective); the spot checks measure that interpolant's misses. Lattices whose adjacent spacings differ
   by more than :data:`MAX_SPACING_RATIO` are evaluated exactly.

``tolerance=0`` evaluates every receiver exactly, with one :func:`.local_pass.irradiance` call: bit for bit
the exact result.

Measured (docs/adaptive.md, *Vertex sets*; ``benchmarks/bench_adaptive_vertices.py``): on radiosity meshes of
36 and 161 lattice lines a side it is slower than evaluating every distinct receiver from the far field
(0.82× and 0.76×: H between patch corners carries the kinks of every patch edge, and the spot checks sample
74 % of a 161-line floor's nodes at 1e-2), so the Blender job's vertices mode does not use it.
"""

from __future__ import annotations

import concurrent.futures as cf
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .adaptive import _input_planes, adaptive_irradiance
from .local_pass import irradiance
from .parallel import _resolve_workers, job_pool
from .scene import Scene

__all__ = ["MAX_SPACING_RATIO", "MIN_FILL", "MIN_SIDE", "Lattice", "VertexAdaptiveStats",
           "adaptive_vertex_irradiance", "lattice_breaks", "lattices"]

#: a plane's receivers form a lattice only with at least this many lattice lines each way
MIN_SIDE = 8
#: ... and when they occupy at least this share of the lattice's nodes (an irregular mesh fills ~1/n of them)
MIN_FILL = 0.5
#: ... and when no two adjacent spacings of a lattice line differ by more than this factor
MAX_SPACING_RATIO = 4.0


@dataclass
class Lattice:
    """Receivers on one plane at the nodes of a tensor lattice.

    ``receivers (k,)``: indices into the receiver arrays; ``iu, iv (k,)``: their node; ``u (n_u,)``,
    ``v (n_v,)``: the lattice lines (world units along ``axes[0]`` / ``axes[1]`` from ``origin``);
    ``origin (3,)``, ``axes (2, 3)`` orthonormal in the plane, ``normal (3,)`` the receivers' unit normal;
    ``plane``: the input plane id (:func:`.adaptive._input_planes`).
    """

    receivers: np.ndarray
    iu: np.ndarray
    iv: np.ndarray
    u: np.ndarray
    v: np.ndarray
    origin: np.ndarray
    axes: np.ndarray
    normal: np.ndarray
    plane: int

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.v), len(self.u)

    def node_points(self) -> np.ndarray:
        """(n_v, n_u, 3) world position of every node."""
        return (self.origin + self.u[None, :, None] * self.axes[0] + self.v[:, None, None] * self.axes[1])


@dataclass
class VertexAdaptiveStats:
    """What :func:`adaptive_vertex_irradiance` evaluated.

    ``exact_points``: core evaluations (lattice samples plus receivers on no lattice); ``receivers``: all
    receivers; ``lattice_receivers``: those on a lattice; ``lattices``: their count; ``error_estimate``:
    the largest per-receiver estimate; ``receiver_error (m,)``: the estimate (W m^-2, largest channel; 0
    where exact, a far-field sample's bound); ``exact_mask (m,)`` bool: the receiver's value is a core
    evaluation (its own or its node's); ``on_segment``: receivers taken out of a lattice (step 3 of the
    module docstring).
    """

    exact_points: int
    receivers: int
    lattice_receivers: int = 0
    lattices: int = 0
    on_segment: int = 0
    error_estimate: float = 0.0
    receiver_error: np.ndarray = field(default_factory=lambda: np.zeros(0))
    exact_mask: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def exact_fraction(self) -> float:
        """Core evaluations per receiver."""
        return self.exact_points / max(self.receivers, 1)


def _clusters(x, eps):
    """Sorted distinct values of ``x (k,)`` merged within ``eps``: ``(values (n,), index (k,))``."""
    order = np.argsort(x, kind="stable")
    xs = x[order]
    new = np.r_[True, np.diff(xs) > eps]
    ident = np.cumsum(new) - 1
    values = np.bincount(ident, weights=xs) / np.bincount(ident) if len(xs) else np.zeros(0)
    index = np.empty(len(x), dtype=np.int64)
    index[order] = ident
    return values, index


def _axes(scene: Scene, pieces, normal):
    """Orthonormal in-plane axes ``(2, 3)`` along the most frequent edge direction of ``pieces``."""
    v = scene.poly_vertices[pieces]
    e = (np.roll(v, -1, axis=1) - v).reshape(-1, 3)
    e = e - (e @ normal)[:, None] * normal
    length = np.linalg.norm(e, axis=1)
    e = e[length > 1e-12 * max(float(length.max(initial=0.0)), 1e-300)]
    if not len(e):
        return None
    ref = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    ref /= np.linalg.norm(ref)
    ref2 = np.cross(normal, ref)
    # the edges' angles modulo 90 degrees (a lattice has two line directions, at right angles here)
    ang = np.mod(np.arctan2(e @ ref2, e @ ref), np.pi / 2)
    bins = np.round(ang / (np.pi / 2) * 3600).astype(np.int64) % 3600
    a = float(np.median(ang[bins == np.bincount(bins).argmax()]))
    e1 = np.cos(a) * ref + np.sin(a) * ref2
    return np.stack([e1, np.cross(normal, e1)])


def _spacing_ok(lines):
    d = np.diff(lines)
    return bool((d[1:] <= MAX_SPACING_RATIO * d[:-1]).all() and (d[:-1] <= MAX_SPACING_RATIO * d[1:]).all())


def lattices(scene: Scene, points, normals, polygons, *, min_side: int = MIN_SIDE):
    """The receivers that lie on tensor lattices of their planes.

    Args:
        points, normals: (m, 3) receiver positions and normals (world space).
        polygons: (m,) int the input polygon each receiver belongs to (its normal's face), -1 for none.
        min_side: fewest lattice lines each way.

    Returns:
        list of :class:`Lattice` (receivers on none are in none).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    g = np.asarray(polygons, dtype=np.int64).reshape(-1)
    planes = _input_planes(scene)
    plane = np.where(g >= 0, planes[np.maximum(g, 0)], -1)
    scale = float(np.abs(scene.poly_vertices).max()) if scene.n_polygons else 1.0
    eps = 1e-9 * max(scale, 1e-300)
    unit = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    out = []
    for pl in np.unique(plane[plane >= 0]):
        members = np.flatnonzero(plane == pl)
        pieces = np.flatnonzero(np.isin(scene.poly_source, np.unique(g[members])))
        normal = scene.poly_normals[pieces[0]]
        # the receivers' normals must be the plane's (flat shading; a smooth mesh's vertex normals are not)
        members = members[unit[members] @ normal >= 1.0 - 1e-12]
        if len(members) < min_side * min_side:
            continue
        axes = _axes(scene, pieces, normal)
        if axes is None:
            continue
        origin = scene.poly_vertices[pieces[0], 0]
        # receivers off the plane (a vertex of a non-planar face) are no lattice nodes
        members = members[np.abs((p[members] - origin) @ normal) <= 1e3 * eps]
        uu, iu = _clusters((p[members] - origin) @ axes[0], eps)
        vv, iv = _clusters((p[members] - origin) @ axes[1], eps)
        if len(uu) < min_side or len(vv) < min_side:
            continue
        nodes = np.unique(iv * len(uu) + iu)
        if len(nodes) < MIN_FILL * len(uu) * len(vv) or not (_spacing_ok(uu) and _spacing_ok(vv)):
            continue
        out.append(Lattice(members, iu, iv, uu, vv, origin, axes, normal, int(pl)))
    return out


def _segments(scene: Scene, lat: Lattice, eps):
    """Segments ``(k, 2, 3)`` where polygons not of the lattice's plane meet it, inside its rectangle."""
    corners = lat.node_points()[[0, 0, -1, -1], [0, -1, 0, -1]]
    lo, hi = corners.min(axis=0) - 1e3 * eps, corners.max(axis=0) + 1e3 * eps
    v = scene.poly_vertices
    box = ((v.min(axis=1) <= hi) & (v.max(axis=1) >= lo)).all(axis=1)
    cand = np.flatnonzero(box)
    if not len(cand):
        return np.zeros((0, 2, 3))
    d = (v[cand] - lat.origin) @ lat.normal  # (c, K)
    coplanar = np.abs(d).max(axis=1) <= 1e3 * eps
    cross = (d.min(axis=1) <= 1e3 * eps) & (d.max(axis=1) >= -1e3 * eps) & ~coplanar
    cand, d = cand[cross], d[cross]
    segs = []
    for c, dc in zip(cand, d):
        k = int(scene.poly_counts[c])
        pv, dd = scene.poly_vertices[c, :k], dc[:k]
        dd = np.where(np.abs(dd) <= 1e3 * eps, 0.0, dd)
        pts = [pv[i] for i in range(k) if dd[i] == 0.0]
        for i in range(k):
            j = (i + 1) % k
            if dd[i] * dd[j] < 0.0:  # the edge crosses the plane
                t = dd[i] / (dd[i] - dd[j])
                pts.append(pv[i] + t * (pv[j] - pv[i]))
        if not pts:
            continue
        pts = np.array(pts)
        # a convex polygon meets a plane in one segment: its two extreme points along the segment
        axis = pts[-1] - pts[0]
        s = pts @ axis if np.linalg.norm(axis) > 0 else np.zeros(len(pts))
        segs.append([pts[int(s.argmin())], pts[int(s.argmax())]])
    return np.array(segs) if segs else np.zeros((0, 2, 3))


def lattice_breaks(scene: Scene, lat: Lattice):
    """Breaks between adjacent nodes where other geometry meets the lattice's plane (step 2 of the module
    docstring), and the nodes on such geometry, on the lattice's outer boundary too (step 3).

    Returns ``(brk_x (n_v, n_u-1), brk_y (n_v-1, n_u), on_segment (n_v, n_u))`` bool.
    """
    nv, nu = lat.shape
    brk_x = np.zeros((nv, nu - 1), dtype=bool)
    brk_y = np.zeros((nv - 1, nu), dtype=bool)
    on = np.zeros((nv, nu), dtype=bool)
    scale = float(np.abs(scene.poly_vertices).max()) if scene.n_polygons else 1.0
    eps = 1e-9 * max(scale, 1e-300)
    segs = _segments(scene, lat, eps)
    if not len(segs):
        return brk_x, brk_y, on
    step = 0.25 * min(float(np.diff(lat.u).min()), float(np.diff(lat.v).min()))
    iu_line, iv_line = np.arange(nu, dtype=np.float64), np.arange(nv, dtype=np.float64)
    tol_u = 1e3 * eps / max(float(np.diff(lat.u).min()), 1e-300)  # eps in index units (the finest spacing)
    tol_v = 1e3 * eps / max(float(np.diff(lat.v).min()), 1e-300)
    for a, b in segs:
        count = int(np.ceil(np.linalg.norm(b - a) / step)) + 1
        t = np.linspace(0.0, 1.0, max(count, 2))[:, None]
        q = a + t * (b - a) - lat.origin
        u, v = q @ lat.axes[0], q @ lat.axes[1]
        inside = ((u >= lat.u[0] - 1e3 * eps) & (u <= lat.u[-1] + 1e3 * eps)
                  & (v >= lat.v[0] - 1e3 * eps) & (v <= lat.v[-1] + 1e3 * eps))
        fu = np.interp(u[inside], lat.u, iu_line)  # fractional node index
        fv = np.interp(v[inside], lat.v, iv_line)
        # on the outer boundary (both points' index on the first or last line): no break (module docstring)
        border = ((np.abs(fu) <= tol_u) | (np.abs(fu - (nu - 1)) <= tol_u)
                  | (np.abs(fv) <= tol_v) | (np.abs(fv - (nv - 1)) <= tol_v))
        fu, fv = fu[~border], fv[~border]
        if not len(fu):
            continue
        # the lattice squares each point lies in (both, when it lies on a lattice line)
        for su in (np.floor(fu + tol_u), np.floor(fu - tol_u)):
            for sv in (np.floor(fv + tol_v), np.floor(fv - tol_v)):
                i = np.clip(su.astype(np.int64), 0, nu - 2)
                j = np.clip(sv.astype(np.int64), 0, nv - 2)
                brk_x[j, i] = brk_x[j + 1, i] = True
                brk_y[j, i] = brk_y[j, i + 1] = True
    # the nodes on a segment, the lattice's outer boundary included: their limits may depend on the side
    nodes = lat.node_points().reshape(-1, 3)
    for a, b in segs:
        ab = b - a
        t = np.clip(((nodes - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
        on |= (np.linalg.norm(nodes - (a + t[:, None] * ab), axis=1) <= 1e3 * eps).reshape(nv, nu)
    return brk_x, brk_y, on


def adaptive_vertex_irradiance(
    scene: Scene,
    points,
    normals,
    polygons,
    *,
    tolerance: float,
    limit_directions=None,
    workers=None,
    executor: cf.Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    sample_share: float = 0.0,
    final_share: float | None = None,
    min_side: int = MIN_SIDE,
):
    """Irradiance at vertex receivers, exact only where interpolation on their lattices would err by more
    than ``tolerance`` (module docstring).

    Args:
        scene: the scene (its radiance is the first pass's).
        points, normals: (m, 3) receiver positions and normals (world space).
        polygons: (m,) int the input polygon of each receiver's face (the one its normal and limit come
            from), -1 for none (evaluated exactly).
        tolerance: absolute tolerance on H (W m^-2, each RGB channel); 0: every receiver exactly.
        limit_directions: (m, 3) or None: one-sided limits as in :func:`.local_pass.irradiance`.
        workers, executor, cancel, sample_share, final_share: as :func:`.adaptive.adaptive_irradiance`.
        progress: ``progress(done, m)`` after each chunk of core evaluations.
        min_side: fewest lattice lines each way of a lattice (:data:`MIN_SIDE`).

    Returns:
        ``(H (m, 3), stats)``: float64 W m^-2, :class:`VertexAdaptiveStats`.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    g = np.asarray(polygons).reshape(-1)
    m = len(p)
    if n.shape != p.shape:
        raise ValueError(f"normals must have shape {p.shape}, got {n.shape}")
    if g.shape != (m,) or not np.issubdtype(g.dtype, np.integer):
        raise ValueError(f"polygons must be ({m},) integer input polygon indices, got {g.shape} {g.dtype}")
    g = g.astype(np.int64)
    if (g >= scene.n_input).any():
        raise ValueError(f"polygons holds index {int(g.max())}, the scene has {scene.n_input} input polygons")
    lim = None if limit_directions is None else np.asarray(limit_directions, dtype=np.float64).reshape(-1, 3)
    if lim is not None and lim.shape != p.shape:
        raise ValueError(f"limit_directions must have shape {p.shape}, got {lim.shape}")
    tol = float(tolerance)
    if not (tol >= 0.0) or not np.isfinite(tol):
        raise ValueError(f"tolerance must be a finite number >= 0, got {tolerance!r}")
    H = np.zeros((m, 3))
    err = np.zeros(m)
    exact = np.zeros(m, dtype=bool)
    stats = VertexAdaptiveStats(0, m, receiver_error=err, exact_mask=exact)
    if m == 0:
        return H, stats
    if tol == 0.0:
        H[:] = irradiance(scene, p, n, limit_directions=lim, workers=workers, executor=executor, progress=progress,
                          cancel=cancel)
        exact[:] = True
        stats.exact_points = m
        return H, stats
    # one pool for every core call of the pass (as adaptive_irradiance keeps one for its rounds)
    pool, owned = (executor, False) if executor is not None else (
        job_pool(workers) if _resolve_workers(workers) > 1 else (None, False))
    on = {"workers": 1} if pool is None else {"executor": pool}
    try:
        _vertex_pass(scene, p, n, g, lim, tol, on, progress, cancel, sample_share, final_share, min_side, H, stats)
    finally:
        if owned:
            pool.shutdown(wait=True, cancel_futures=True)
    stats.error_estimate = float(err.max(initial=0.0))
    return H, stats


def _vertex_pass(scene, p, n, g, lim, tol, on, progress, cancel, sample_share, final_share, min_side, H, stats):
    """The body of :func:`adaptive_vertex_irradiance` (``tol > 0``; fills ``H`` and ``stats``)."""
    m = len(p)
    err, exact = stats.receiver_error, stats.exact_mask
    covered = np.zeros(m, dtype=bool)
    for lat in lattices(scene, p, n, g, min_side=min_side):
        nv, nu = lat.shape
        brk_x, brk_y, on_seg = lattice_breaks(scene, lat)
        node = lat.iv * nu + lat.iu
        first = np.full(nv * nu, -1, dtype=np.int64)
        first[node[::-1]] = lat.receivers[::-1]  # the node's sample: its first receiver
        # a node on a segment (other geometry meets the plane there) is a hole, its receivers exact on their own
        # (step 3): inside the lattice always (the two sides differ), on its outer boundary when the node's
        # receivers' one-sided limits differ (the adjacent surface's radiance may jump at the node)
        border = on_seg.copy()
        border[1:-1, 1:-1] = False
        if lim is not None and border.any():
            differ = np.zeros(nv * nu, dtype=bool)
            far_off = np.abs(lim[lat.receivers] - lim[first[node]]).max(axis=1) > 1e-9
            differ[node[far_off]] = True
            apart = (on_seg & ~border) | (border & differ.reshape(nv, nu))
        else:
            apart = on_seg & ~border
        keep = ~apart.reshape(-1)[node]
        stats.on_segment += int((~keep).sum())
        rec, node = lat.receivers[keep], node[keep]
        first = np.full(nv * nu, -1, dtype=np.int64)
        first[node[::-1]] = rec[::-1]
        has = first >= 0
        P = lat.node_points().reshape(-1, 3).copy()
        N = np.broadcast_to(lat.normal, (nv * nu, 3)).copy()
        G = np.full(nv * nu, -1, dtype=np.int64)
        L = np.zeros((nv * nu, 3))
        P[has], N[has], G[has] = p[first[has]], n[first[has]], g[first[has]]
        if lim is not None:
            L[has] = lim[first[has]]
        before = stats.exact_points

        def prog(d, _t, before=before):
            if progress is not None:
                progress(before + d, m)

        hl, st = adaptive_irradiance(scene, P.reshape(nv, nu, 3), N.reshape(nv, nu, 3), G.reshape(nv, nu),
                                     tolerance=tol, limit_directions=None if lim is None else L.reshape(nv, nu, 3),
                                     breaks=(brk_x, brk_y), progress=prog, cancel=cancel,
                                     sample_share=sample_share, final_share=final_share, **on)
        hl = hl.reshape(-1, 3)
        H[rec] = hl[node]
        err[rec] = st.pixel_error.reshape(-1)[node]
        exact[rec] = st.exact_mask.reshape(-1)[node]
        covered[rec] = True
        stats.exact_points += st.exact_points
        stats.lattices += 1
        stats.lattice_receivers += len(rec)
    rest = np.flatnonzero(~covered)
    if len(rest):
        # receivers on no lattice are final samples (no interpolation uses them): the final share, as in the
        # image pass (step 6 of core.adaptive)
        final = sample_share if final_share is None else final_share
        before = stats.exact_points
        kw = dict(limit_directions=None if lim is None else lim[rest], cancel=cancel,
                  progress=None if progress is None else (lambda d, _t: progress(before + d, m)), **on)
        if final > 0.0:
            H[rest], far = irradiance(scene, p[rest], n[rest], tolerance=final * tol, return_stats=True, **kw)
            err[rest] = far.error_bound.max(axis=1)
        else:
            H[rest] = irradiance(scene, p[rest], n[rest], **kw)
        exact[rest] = True
        stats.exact_points += len(rest)
