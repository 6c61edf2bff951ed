"""Skipping work a scene does not need: merged occluders and the pair tests of sec. 3.4.

Occluders
---------
What hides a polygon A from P is the union of the *shadow volumes* of the other polygons: the part of
space beyond B's plane (seen from P) inside the cone from P over B. Coplanar polygons that tile a convex
region C have exactly the shadow volume of C (the union of their cones is C's cone), so for occlusion
the scene's subdivided walls and block faces are replaced by their merged convex faces. This is exact,
and it removes the needless splitting of fragments along the subdivision lines: a wall of 1,000 quads
occludes like one quad. Groups that do not merge into one convex polygon (holes, L-shapes, T-junctions,
overlaps) keep their polygons as individual occluders, which is exact too, only slower.

Pair tests
----------
Occlusion work is done only for (polygon, occluder) pairs where (a) some vertex of the polygon lies
strictly beyond the occluder's plane on the side away from P (precomputed per scene for both sides
— independent of P), and (b) the bounding cones of the two, seen from P, overlap. Everything else (the
clips) only runs for pairs that pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Scene, plane_uncertainty
from .solids import Solids, build_solids, no_solids
from .tolerances import CONVEXITY_EPS, COORD_EPS, PLANARITY_EPS, PLANE_EPS

__all__ = ["Occluders", "build_occluders"]


@dataclass
class Occluders:
    """Convex occluders of a scene.

    Attributes:
        vertices: (n_o, K_o, 3) padded convex polygons (world space).
        counts: (n_o,) vertex counts.
        normals: (n_o, 3) unit plane normals.
        centers, radii: (n_o, 3), (n_o,) bounding spheres.
        members: (n,) occluder index of every convex polygon of the scene.
        beyond_pos, beyond_neg: (n, n_o) bool — polygon i has a vertex strictly on the positive /
            negative side of occluder o's plane. A polygon can only be hidden by o from a point on the
            other side.
        occ_beyond_pos, occ_beyond_neg: (n_o, n_o) bool — the same between occluders.
        front_pos, front_neg: (n, n_o) bool — occluder o has a vertex strictly on the positive / negative
            side of polygon i's plane. o can only hide part of i from a receiver on a side o reaches to.
        tile_of: (n,) tile of every polygon; tiles split the members of large merged occluders into
            spatial groups of about :data:`TILE_SIZE` (sec. 3.4's voxels): tile_corners (T, 8, 3) the
            corners of each tile's bounding box, tile_centers (T, 3), tile_radii (T,), tile_occluder (T,);
            tile_ptr (T+1,), tile_members: CSR lists of every tile's polygons (the hierarchy's leaves).
        coplanar_ptr (n+1,), coplanar_occ: CSR lists of the occluders in whose plane polygon i lies
            without being part of them (overlapping duplicates, reversed copies).
        first_source: (n_o,) lowest input polygon index among each occluder's members (tie-break).
        tilt, noise: (n_o,) uncertainty of each occluder's plane (see :func:`.scene.plane_uncertainty`).
        solids: the convex solids among the occluders (:mod:`.solids`). A solid's volume is occluder
            ``n_o + s``: the tables above have ``n_o + n_s`` columns (``beyond_*`` True for solids,
            ``front_*`` the union over the solid's faces); occ_reach_pos, occ_reach_neg (n_o, n_o + n_s):
            occluder (or solid) o has a vertex strictly on the positive / negative side of occluder k's
            plane (``[k, o]``); vol_centers (n_o + n_s, 3), vol_radii: bounding spheres of all volumes.
    """

    vertices: np.ndarray
    counts: np.ndarray
    normals: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    members: np.ndarray
    beyond_pos: np.ndarray
    beyond_neg: np.ndarray
    occ_beyond_pos: np.ndarray
    occ_beyond_neg: np.ndarray
    front_pos: np.ndarray
    front_neg: np.ndarray
    tile_of: np.ndarray
    tile_corners: np.ndarray
    tile_centers: np.ndarray
    tile_radii: np.ndarray
    tile_occluder: np.ndarray
    tile_ptr: np.ndarray
    tile_members: np.ndarray
    coplanar_ptr: np.ndarray
    coplanar_occ: np.ndarray
    first_source: np.ndarray
    tilt: np.ndarray | None = None
    noise: np.ndarray | None = None
    solids: Solids | None = None
    occ_reach_pos: np.ndarray | None = None
    occ_reach_neg: np.ndarray | None = None
    vol_centers: np.ndarray | None = None
    vol_radii: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.counts)

    @property
    def n_vol(self) -> int:
        """Occluder columns of the tables: the merged faces, then the convex solids."""
        return len(self.vol_radii)


def _merge_group(scene: Scene, group: np.ndarray):
    """Boundary loop (k, 3) of a coplanar, edge-connected group if it is one convex polygon, else None."""
    verts, counts = scene.poly_vertices, scene.poly_counts
    edges: dict[tuple[bytes, bytes], int] = {}
    coords: dict[bytes, np.ndarray] = {}
    area = 0.0
    for i in group:
        k = counts[i]
        pv = verts[i, :k]
        keys = [v.tobytes() for v in pv]
        for j in range(k):
            coords[keys[j]] = pv[j]
            e = (keys[j], keys[(j + 1) % k])
            edges[e] = edges.get(e, 0) + 1
        rel = pv - pv[0]
        area += 0.5 * np.linalg.norm(np.cross(rel, np.roll(rel, -1, axis=0)).sum(axis=0))
    boundary = {}
    for (a, b), c in edges.items():
        if c != 1 or edges.get((b, a), 0) > 1:
            return None  # duplicated edges: overlapping polygons
        if (b, a) not in edges:
            if a in boundary:
                return None  # a vertex with two outgoing boundary edges: not a simple loop
            boundary[a] = b
    if not boundary:
        return None
    start = next(iter(boundary))
    loop = [start]
    while True:
        nxt = boundary[loop[-1]]
        if nxt == start:
            break
        if len(loop) > len(boundary):
            return None
        loop.append(nxt)
    if len(loop) != len(boundary):
        return None  # several loops (holes or disjoint parts)
    pts = np.array([coords[key] for key in loop])
    normal = scene.poly_normals[group[0]]
    # only polygons coplanar to rounding merge: the triangles of a face that was triangulated because it
    # is not planar (Scene, PLANARITY_EPS) must keep their own planes, or the merged cone is off by that
    every = np.array(list(coords.values()))
    hts = (every - every[0]) @ normal
    if 0.5 * (hts.max() - hts.min()) > PLANARITY_EPS * float(np.ptp(every, axis=0).max()):
        return None
    # drop collinear boundary vertices (the subdivision's T-free grid points along the border)
    keep = []
    n_pts = len(pts)
    size = float(np.ptp(pts, axis=0).max())
    for j in range(n_pts):
        e1 = pts[j] - pts[j - 1]
        e2 = pts[(j + 1) % n_pts] - pts[j]
        turn = float(np.dot(np.cross(e1, e2), normal))
        if turn < -CONVEXITY_EPS * np.linalg.norm(e1) * np.linalg.norm(e2):
            return None  # reflex corner: not convex
        if turn > 1e-9 * np.linalg.norm(e1) * np.linalg.norm(e2):
            keep.append(j)
    if len(keep) < 3:
        return None
    pts = pts[keep]
    rel = pts - pts[0]
    loop_area = 0.5 * float(np.dot(np.cross(rel, np.roll(rel, -1, axis=0)).sum(axis=0), normal))
    if abs(loop_area - area) > 1e-9 * max(area, size * size * 1e-12):
        return None  # winding or overlap inconsistency
    return pts


def build_occluders(scene: Scene, *, solids: bool = True) -> Occluders:
    """Merge coplanar edge-connected convex polygons into convex occluders (exact; see module doc).

    With ``solids`` the convex solids among them are found too (:mod:`.solids`); without, every face
    occludes on its own (the same result, slower; for tests and benchmarks).
    """
    n = scene.n_polygons
    members = np.arange(n)
    loops: list[np.ndarray] = []
    if n:
        # group by plane: quantised normal and offset (relative to the scene size)
        size = float(np.ptp(scene.poly_centers, axis=0).max() + scene.poly_radii.max()) or 1.0
        key = np.concatenate([np.round(scene.poly_normals * 1e9), np.round(scene.poly_offsets / size * 1e9)[:, None]],
                             axis=1)
        _, plane_id = np.unique(key, axis=0, return_inverse=True)
        plane_id = plane_id.reshape(-1)
        # identical copies are projected once (Scene._find_duplicates): only representatives occlude
        reps = np.flatnonzero(scene.dup_rep == np.arange(n))
        order = reps[np.argsort(plane_id[reps], kind="stable")]
        bounds = np.flatnonzero(np.diff(plane_id[order])) + 1
        members = np.full(n, -1)
        for grp in np.split(order, bounds):
            merged = None
            if len(grp) > 1:
                comps = _components(scene, grp)
                for comp in comps:
                    merged = _merge_group(scene, comp) if len(comp) > 1 else None
                    if merged is None:
                        for i in comp:
                            members[i] = len(loops)
                            loops.append(scene.poly_vertices[i, : scene.poly_counts[i]])
                    else:
                        members[comp] = len(loops)
                        loops.append(merged)
            else:
                members[grp[0]] = len(loops)
                loops.append(scene.poly_vertices[grp[0], : scene.poly_counts[grp[0]]])
    kmax = max((len(p) for p in loops), default=3)
    counts = np.array([len(p) for p in loops], dtype=np.int64)
    verts = np.zeros((len(loops), kmax, 3))
    for o, p in enumerate(loops):
        verts[o, : len(p)] = p
        verts[o, len(p):] = p[-1]
    rel = verts - verts[:, :1]
    area_vec = 0.5 * np.cross(rel, np.roll(rel, -1, axis=1)).sum(axis=1)
    normals = area_vec / np.linalg.norm(area_vec, axis=1, keepdims=True) if len(loops) else np.zeros((0, 3))
    valid = np.arange(kmax)[None, :] < counts[:, None]
    centers = (verts * valid[..., None]).sum(axis=1) / np.maximum(counts, 1)[:, None]
    radii = np.where(valid, np.linalg.norm(verts - centers[:, None], axis=2), 0.0).max(axis=1) if len(loops) \
        else np.zeros(0)

    occ_tilt, occ_noise = plane_uncertainty(verts)
    # beyond tests, independent of the receiver, for the polygons and for the occluders themselves
    n_o = len(loops)
    none = np.zeros((0, n_o), dtype=bool)
    b_pos, b_neg, bb_pos, bb_neg = (_beyond(scene.poly_vertices, scene.poly_counts, verts, normals, occ_tilt) if n
                                    else (none,) * 4)
    o_pos, o_neg, ob_pos, ob_neg = _beyond(verts, counts, verts, normals, occ_tilt)
    # and the converse: does occluder o reach to either side of polygon i's plane (it can only hide a
    # part of i from a receiver on a side it reaches to)
    f_pos, f_neg, fb_pos, fb_neg = ((t.T.copy() for t in _beyond(verts, counts, scene.poly_vertices,
                                                                 scene.poly_normals, scene.poly_tilt)) if n
                                    else (none,) * 4)
    # Two surfaces are coplanar when each lies in the other's plane within that plane's uncertainty,
    # all of the surface within the tolerance of its farthest vertex (``*_body``); coplanar pairs keep
    # those flags. Other pairs use each vertex's own tolerance: a sliver through P is "beyond" the plane
    # of a 1e-6 triangle by its vertex at P even though its far end is within that plane's uncertainty.
    # A surface within the (poorly known) plane of the other but not vice versa — a huge polygon 1e3
    # from the plane of a 1e-6 one far from the origin — may lie on either side of it: the flags are
    # filters, so both are set and the exact per-vertex tests decide.
    on_b, on_f = ~(bb_pos | bb_neg), ~(fb_pos | fb_neg)
    coplanar = on_b & on_f
    beyond_pos = np.where(coplanar, bb_pos, b_pos) | (on_b & ~on_f)
    beyond_neg = np.where(coplanar, bb_neg, b_neg) | (on_b & ~on_f)
    front_pos = np.where(coplanar, fb_pos, f_pos) | (on_f & ~on_b)
    front_neg = np.where(coplanar, fb_neg, f_neg) | (on_f & ~on_b)
    on_o = ~(ob_pos | ob_neg)
    occ_coplanar = on_o & on_o.T
    occ_pos = np.where(occ_coplanar, ob_pos, o_pos) | (on_o & ~on_o.T)
    occ_neg = np.where(occ_coplanar, ob_neg, o_neg) | (on_o & ~on_o.T)
    if n:
        members = members[scene.dup_rep]
    tiles = _tiles(scene, members, len(loops))
    # coplanar overlapping surfaces (duplicates, reversed copies): polygon i lies in the plane of
    # occluder o but is not part of it; the visibility stage lets one of them win where they overlap
    if n:
        coplanar[np.arange(n), members] = False
    ci, co = np.nonzero(coplanar)
    cop_ptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(cop_ptr, ci + 1, 1)
    first_source = np.full(len(loops), np.iinfo(np.int64).max)
    if n:
        np.minimum.at(first_source, members, scene.poly_source)
    # convex solids: their volumes are extra occluder columns (see :mod:`.solids`)
    sol = build_solids(verts, counts, normals, occ_tilt, occ_noise) if solids else no_solids()
    fs = sol.face_solid

    def per_solid(table):  # (r, n_o) -> (r, n_s): any face of the solid
        out = np.zeros((table.shape[0], sol.n), dtype=bool)
        if sol.n:
            np.logical_or.at(out.T, fs, table.T[sol.face_occ])
        return out

    def with_solids(table, solid_cols):
        return np.concatenate([table, solid_cols], axis=1)

    true_n = np.ones((n, sol.n), dtype=bool)
    true_o = np.ones((n_o, sol.n), dtype=bool)
    beyond_pos, beyond_neg = with_solids(beyond_pos, true_n), with_solids(beyond_neg, true_n)
    front_pos, front_neg = with_solids(front_pos, per_solid(front_pos)), with_solids(front_neg, per_solid(front_neg))
    reach_pos = with_solids(occ_pos.T, per_solid(occ_pos.T))
    reach_neg = with_solids(occ_neg.T, per_solid(occ_neg.T))
    occ_pos, occ_neg = with_solids(occ_pos, true_o), with_solids(occ_neg, true_o)
    return Occluders(verts, counts, normals, centers, radii, members, beyond_pos, beyond_neg, occ_pos, occ_neg,
                     front_pos, front_neg, *tiles, np.cumsum(cop_ptr), co, first_source, occ_tilt, occ_noise,
                     sol, reach_pos, reach_neg, np.concatenate([centers, sol.centers]),
                     np.concatenate([radii, sol.radii]))


#: target number of member polygons per tile of a merged occluder
TILE_SIZE = 16


def _tiles(scene: Scene, members: np.ndarray, n_o: int):
    """Spatial tiles of every occluder's members: a grid over the face's two longest extents."""
    n = scene.n_polygons
    tile_of = np.zeros(n, dtype=np.int64)
    corners, occ_of = [], []
    order = np.argsort(members, kind="stable")
    bounds = np.flatnonzero(np.diff(members[order])) + 1
    for grp in np.split(order, bounds) if n else []:
        c = scene.poly_centers[grp]
        cells = max(1, int(round(np.sqrt(len(grp) / TILE_SIZE))))
        if cells == 1:
            keys = np.zeros(len(grp), dtype=np.int64)
        else:
            ext = np.ptp(c, axis=0)
            a, b = np.argsort(ext)[::-1][:2]
            ia = np.minimum((c[:, a] - c[:, a].min()) / max(ext[a], 1e-300) * cells, cells - 1).astype(np.int64)
            ib = np.minimum((c[:, b] - c[:, b].min()) / max(ext[b], 1e-300) * cells, cells - 1).astype(np.int64)
            keys = ia * cells + ib
        uniq, inv = np.unique(keys, return_inverse=True)
        base = len(occ_of)
        tile_of[grp] = base + inv.reshape(-1)
        for t in range(len(uniq)):
            sel = grp[inv.reshape(-1) == t]
            pv = scene.poly_vertices[sel].reshape(-1, 3)
            lo, hi = pv.min(axis=0), pv.max(axis=0)
            corners.append(np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                     for z in (lo[2], hi[2])]))
            occ_of.append(members[grp[0]])
    corners = np.array(corners).reshape(-1, 8, 3)
    centers = corners.mean(axis=1)
    radii = np.linalg.norm(corners - centers[:, None], axis=2).max(axis=1) if len(corners) else np.zeros(0)
    tile_members = np.argsort(tile_of, kind="stable")
    tile_ptr = np.zeros(len(corners) + 1, dtype=np.int64)
    np.add.at(tile_ptr, tile_of + 1, 1)
    return tile_of, corners, centers, radii, np.array(occ_of, dtype=np.int64), np.cumsum(tile_ptr), tile_members


#: relative rounding of the plane distances in :func:`_beyond` (differences of coordinates and a unit
#: normal, each a few ulp)
_ROUNDING = 64 * np.finfo(np.float64).eps


def _beyond(body_verts, body_counts, occ_verts, occ_normals, occ_tilt):
    """(B, n_o) bool pairs: body b has a vertex strictly on the positive / negative side of occluder o.

    Returns ``(pos, neg, pos_body, neg_body)``: ``pos, neg`` with each vertex's own tolerance (the plane's
    tilt moves a point by tilt × its distance from the plane's reference vertex; a vertex off the plane
    by more than rounding but within that tolerance counts for both sides), and ``pos_body,
    neg_body`` with the body's largest tolerance for all its vertices, which decides coplanarity (a
    surface is in a plane when all of it is within that plane's uncertainty).

    Signed distances are taken relative to a vertex of the occluder: differences of nearby world
    coordinates are exact, so scenes far from the origin keep their precision. "Strictly" allows for
    the occluder plane's own uncertainty ``occ_tilt (n_o,)`` (see :func:`.scene.plane_uncertainty`) and
    for the coordinate noise of both (see :data:`.tolerances.COORD_EPS`).
    """
    b_n, k = body_verts.shape[:2]
    n_o = len(occ_verts)
    pos = np.zeros((b_n, n_o), dtype=bool)
    neg = np.zeros((b_n, n_o), dtype=bool)
    pos_body = np.zeros((b_n, n_o), dtype=bool)
    neg_body = np.zeros((b_n, n_o), dtype=bool)
    valid = np.arange(k)[None, :] < body_counts[:, None]
    step = max(1, int(2e6 // max(1, n_o * k)))
    noise_b = COORD_EPS * np.abs(body_verts).max(axis=(1, 2))                           # (B,)
    noise_o = COORD_EPS * np.abs(occ_verts).max(axis=(1, 2))                            # (n_o,)
    for s in range(0, b_n, step):
        rel = body_verts[s:s + step, :, None, :] - occ_verts[None, None, :, 0, :]     # (b, K, n_o, 3)
        d = (rel * occ_normals[None, None]).sum(axis=3)                               # (b, K, n_o)
        reach = np.abs(rel).max(axis=3)                                                # (b, K, n_o)
        noise = noise_b[s:s + step, None, None] + noise_o[None, None, :]
        eps = (4 * PLANE_EPS + occ_tilt[None, None, :]) * reach + noise
        eps_body = (4 * PLANE_EPS + occ_tilt[None, None, :]) * reach.max(axis=1, keepdims=True) + noise
        d = np.where(valid[s:s + step, :, None], d, 0.0)
        # a vertex off the plane by more than rounding but within the decision tolerance may be on either
        # side: as a filter, it counts for both. Rounding here is that of d itself (a few ulp of |rel|):
        # the relative tolerance 4 PLANE_EPS |rel| is far wider for a vertex far from the plane's
        # reference vertex (a 1e6 quad seen against a 1e-6 triangle's plane: 3e-6 > the quad's true 1e-6
        # reach to the triangle's near side, which decides whether the quad can hide part of it)
        unsure = ((np.abs(d) > _ROUNDING * reach + noise) & (np.abs(d) <= eps)).any(axis=1)
        pos[s:s + step] = (d > eps).any(axis=1) | unsure
        neg[s:s + step] = (d < -eps).any(axis=1) | unsure
        pos_body[s:s + step] = (d > eps_body).any(axis=1)
        neg_body[s:s + step] = (d < -eps_body).any(axis=1)
    return pos, neg, pos_body, neg_body


def _components(scene: Scene, group: np.ndarray) -> list[np.ndarray]:
    """Edge-connected components (shared edges with identical end points) of a coplanar group."""
    parent = {int(i): int(i) for i in group}

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    owner: dict[tuple[bytes, bytes], int] = {}
    for i in group:
        k = scene.poly_counts[i]
        keys = [v.tobytes() for v in scene.poly_vertices[i, :k]]
        for j in range(k):
            a, b = keys[j], keys[(j + 1) % k]
            other = owner.get((b, a))
            if other is not None:
                ra, rb = find(int(i)), find(other)
                if ra != rb:
                    parent[ra] = rb
            owner[(a, b)] = int(i)
    comps: dict[int, list[int]] = {}
    for i in group:
        comps.setdefault(find(int(i)), []).append(int(i))
    return [np.array(c) for c in comps.values()]
