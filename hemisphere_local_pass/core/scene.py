"""The scene as the core sees it: validated, planar, convex polygons with their radiance.

Input polygons come in Blender's layout (a flat array of vertex indices plus a start and a count
per polygon) or as a sequence of index sequences. Each input polygon becomes one or more *convex
planar* polygons:

* a planar convex polygon is kept as it is (with constant radiance);
* a concave or non-planar polygon is split into triangles by ear clipping in its Newell plane
  (the projection that keeps its area largest); the first ear found walking from vertex 0 is cut
  first, so the rule is deterministic and independent of the vertex coordinates' origin;
* with per-corner (linearly varying) radiance every polygon is split into triangles — a fan from
  its first vertex when it is convex and planar, ear clipping otherwise — because radiance given
  at the corners is linear over each triangle;
* given the mesh's own triangulation (``loop_triangles``, as Blender's ``Mesh.loop_triangles``), every
  polygon that the rules above would split is split into exactly those triangles instead, so the
  surface and the interpolated radiance are the ones the renderer uses;
* polygons with fewer than three distinct vertices or (almost) zero area are dropped, and the
  reason is recorded in :attr:`Scene.dropped` under the input polygon's index.

Non-finite coordinates or radiance, wrong array shapes and out-of-range indices raise
``ValueError`` naming the offending polygon or vertex.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from . import tolerances as tol

__all__ = ["Scene"]


def _describe(names, i: int) -> str:
    if names is None:
        return f"polygon {i}"
    label = names(i) if callable(names) else names[i]
    return f"polygon {i} ({label})"


def _newell(verts: np.ndarray) -> np.ndarray:
    """Area vector (Newell's method) of polygons ``verts (g, k, 3)`` -> ``(g, 3)``; |result| = area.

    Taken relative to the first vertex: far from the origin the raw cross products would be huge and
    cancel (a polygon of size 1 at 1e6 would lose ten digits of its normal).
    """
    rel = verts - verts[:, :1, :]
    nxt = np.roll(rel, -1, axis=1)
    return 0.5 * np.cross(rel, nxt).sum(axis=1)


def plane_uncertainty(verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How well the Newell planes of padded polygons ``verts (g, K, 3)`` are known: ``(tilt, noise)``.

    ``tilt (g,)`` is the angular uncertainty (radians) of the normal: built from vertex differences of
    size s over an area A it is uncertain by about ulp · s² / A (negligible for a fair polygon, large for
    a sliver, whose plane really is only known that well), plus noise · s / A for the vertices' own
    coordinate noise. ``noise (g,)`` is that coordinate noise, ``COORD_EPS · max |x|`` (absolute).
    A plane distance ``n · (v0 - x)`` is thus uncertain by ``tilt · |v0 - x| + noise``.
    """
    rel = verts - verts[:, :1]
    area = 0.5 * np.linalg.norm(np.cross(rel, np.roll(rel, -1, axis=1)).sum(axis=1), axis=1)
    size = np.linalg.norm(rel, axis=2).max(axis=1)
    noise = tol.COORD_EPS * np.abs(verts).max(axis=(1, 2))
    tilt = (8 * np.finfo(np.float64).eps * size + 2 * noise) * size / np.maximum(area, np.finfo(np.float64).tiny)
    return tilt, noise


def _ear_clip(pts2d: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangulate a simple polygon given by ``pts2d (k, 2)`` counter-clockwise; returns index triples.

    Classic ear clipping, O(k^2): the first ear found walking from vertex 0 is cut first. Falls back
    to cutting the first convex corner if no clean ear exists (self-touching input).
    """
    idx = list(range(len(pts2d)))
    tris: list[tuple[int, int, int]] = []
    scale = float(np.ptp(pts2d, axis=0).max()) or 1.0
    eps = tol.CONVEXITY_EPS * scale * scale

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3 and guard < 10 * len(pts2d) ** 2:
        guard += 1
        n = len(idx)
        cut = None
        for j in range(n):
            a, b, c = idx[j - 1], idx[j], idx[(j + 1) % n]
            pa, pb, pc = pts2d[a], pts2d[b], pts2d[c]
            if cross(pa, pb, pc) <= eps:
                continue  # reflex or flat corner: not an ear
            inside = False
            for q in idx:
                if q in (a, b, c):
                    continue
                pq = pts2d[q]
                if cross(pa, pb, pq) >= -eps and cross(pb, pc, pq) >= -eps and cross(pc, pa, pq) >= -eps:
                    inside = True
                    break
            if not inside:
                cut = j
                break
        if cut is None:  # degenerate input: cut the first non-reflex corner
            cut = next((j for j in range(n) if cross(pts2d[idx[j - 1]], pts2d[idx[j]], pts2d[idx[(j + 1) % n]]) > 0), 0)
        tris.append((idx[cut - 1], idx[cut], idx[(cut + 1) % n]))
        del idx[cut]
    if len(idx) == 3:
        tris.append((idx[0], idx[1], idx[2]))
    return tris


class Scene:
    """Convex planar polygons with radiance, ready for the exact hemispherical projection.

    Attributes (read-only by convention):
        poly_vertices: (n, K, 3) float64 vertices, padded past ``poly_counts`` by repeating the last one.
        poly_counts: (n,) int64 vertex count (>= 3) of each convex polygon.
        poly_normals: (n, 3) float64 unit normal of the front (emitting) side, right-handed with
            the vertex order (counter-clockwise seen from the front).
        poly_offsets: (n,) float64 plane offsets, ``poly_normals[i] . x == poly_offsets[i]``.
        poly_centers, poly_radii: (n, 3), (n,) bounding spheres.
        poly_tilt, poly_noise: (n,), (n,) uncertainty of each polygon's plane (see :func:`plane_uncertainty`).
        poly_source: (n,) int64 input polygon each convex polygon came from.
        poly_radiance: (n, 3) float64 radiance (linear RGB, W sr^-1 m^-2); in linear mode the
            mean of the corner values.
        corner_radiance: (n, 3, 3) float64 radiance at the triangle corners, or None (constant mode).
        n_input: number of input polygons.
        dropped: {input polygon index: reason} for degenerate polygons that were dropped.
        double_sided: polygons emit from both sides (they are always opaque from both sides).
    """

    def __init__(
        self,
        poly_vertices: np.ndarray,
        poly_counts: np.ndarray,
        poly_source: np.ndarray,
        poly_radiance: np.ndarray,
        n_input: int,
        *,
        corner_radiance: np.ndarray | None = None,
        double_sided: bool = False,
        dropped: dict[int, str] | None = None,
        polygon_names=None,
    ):
        self.poly_vertices = np.ascontiguousarray(poly_vertices, dtype=np.float64)
        self.poly_counts = np.asarray(poly_counts, dtype=np.int64)
        self.poly_source = np.asarray(poly_source, dtype=np.int64)
        self.poly_radiance = np.asarray(poly_radiance, dtype=np.float64).reshape(-1, 3)
        self.corner_radiance = None if corner_radiance is None else np.asarray(corner_radiance, dtype=np.float64)
        self.n_input = int(n_input)
        self.double_sided = bool(double_sided)
        self.dropped = dict(dropped or {})
        self.polygon_names = polygon_names
        n = len(self.poly_counts)
        # the same with one spare slot (repeating the last vertex), for clipping without re-padding
        self.poly_vertices_spare = np.concatenate([self.poly_vertices, self.poly_vertices[:, -1:]], axis=1)
        if n:
            k = self.poly_vertices.shape[1]
            valid = np.arange(k)[None, :] < self.poly_counts[:, None]  # (n, K)
            area_vec = _newell(self.poly_vertices)  # padding repeats the last vertex: no extra area
            self.poly_normals = area_vec / np.linalg.norm(area_vec, axis=1, keepdims=True)
            w = valid[..., None].astype(np.float64)
            self.poly_centers = (self.poly_vertices * w).sum(axis=1) / self.poly_counts[:, None]
            # offsets are for reporting; the core works with receiver-local planes (n . (v0 - P))
            self.poly_offsets = np.einsum("ij,ij->i", self.poly_normals, self.poly_vertices[:, 0])
            # n . (centre - v0): zero up to rounding; lets n . (v0 - P) come from the centre's offset
            self.poly_center_offsets = np.einsum("ij,ij->i", self.poly_normals,
                                                 self.poly_centers - self.poly_vertices[:, 0])
            d = np.linalg.norm(self.poly_vertices - self.poly_centers[:, None, :], axis=2)
            self.poly_radii = np.where(valid, d, 0.0).max(axis=1)
            self.poly_tilt, self.poly_noise = plane_uncertainty(self.poly_vertices)
            self._find_duplicates(valid)
        else:
            self.dup_rep = self.dup_same = self.dup_opp = np.zeros(0, dtype=np.int64)
            self.poly_normals = np.zeros((0, 3))
            self.poly_centers = np.zeros((0, 3))
            self.poly_offsets = np.zeros(0)
            self.poly_center_offsets = np.zeros(0)
            self.poly_radii = np.zeros(0)
            self.poly_tilt = np.zeros(0)
            self.poly_noise = np.zeros(0)

    def _find_duplicates(self, valid: np.ndarray) -> None:
        """Identical convex polygons (same vertices, either orientation): coplanar overlapping copies.

        Sets ``dup_rep (n,)`` (the first of each group: the only one projected), and for each
        representative ``dup_same`` / ``dup_opp`` (n,): the lowest-index copy with the same / the
        opposite orientation (-1 if none). Seen from a receiver, the copy facing it wins, then the
        lowest index: the surface is seen once, exactly, however ill-defined a sliver's plane is.
        """
        n, k = len(self.poly_counts), self.poly_vertices.shape[1]
        v = np.where(valid[..., None], self.poly_vertices, np.inf)
        order = np.lexsort((v[..., 2], v[..., 1], v[..., 0]), axis=-1)              # (n, K) per row
        key = np.take_along_axis(v, order[..., None], axis=1).reshape(n, 3 * k)
        key = np.concatenate([key, self.poly_counts[:, None].astype(np.float64)], axis=1)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        self.dup_rep = first[inverse]
        self.dup_same = np.arange(n)
        self.dup_opp = np.full(n, -1, dtype=np.int64)
        dups = np.flatnonzero(self.dup_rep != np.arange(n))
        for i in dups[::-1]:  # descending, so the lowest index is written last
            r = self.dup_rep[i]
            if np.dot(self.poly_normals[i], self.poly_normals[r]) > 0:
                self.dup_same[r] = min(self.dup_same[r], i)
            else:
                self.dup_opp[r] = i if self.dup_opp[r] < 0 else min(self.dup_opp[r], i)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_polygons(
        cls,
        vertices,
        polygons: Sequence[Sequence[int]],
        radiance=None,
        *,
        corner_radiance=None,
        double_sided: bool = False,
        polygon_names=None,
    ) -> Scene:
        """Build a scene from ``vertices (V, 3)`` and ``polygons`` (a sequence of index sequences).

        ``radiance`` is ``(n_polygons, 3)`` (or ``(n_polygons,)``, grey) constant per polygon; default
        zero (pure occluders). ``corner_radiance`` is ``(n_corners, 3)``, one row per polygon corner
        in the order the polygons list them: radiance then varies linearly over each triangle.
        """
        polygons = [list(map(int, p)) for p in polygons]
        counts = np.array([len(p) for p in polygons], dtype=np.int64)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if len(counts) else counts
        loops = np.array([i for p in polygons for i in p], dtype=np.int64)
        return cls.from_arrays(
            vertices, loops, starts, counts, radiance, corner_radiance,
            double_sided=double_sided, polygon_names=polygon_names,
        )

    @classmethod
    def from_arrays(
        cls,
        vertices,
        loop_vertices,
        loop_start,
        loop_total,
        polygon_radiance=None,
        corner_radiance=None,
        *,
        double_sided: bool = False,
        polygon_names: Sequence[str] | Callable[[int], str] | None = None,
        loop_triangles=None,
        loop_triangle_polygons=None,
    ) -> Scene:
        """Build a scene from arrays in Blender's mesh layout.

        Args:
            vertices: (V, 3) float coordinates (world space).
            loop_vertices: (L,) int vertex index of every polygon corner.
            loop_start, loop_total: (P,) int first corner and corner count of every polygon.
            polygon_radiance: (P, 3) or (P,) constant radiance per polygon (FACE domain); default 0.
            corner_radiance: (L, 3) or (L,) radiance per corner (CORNER domain; for POINT domain pass
                ``point_values[loop_vertices]``): linear over each triangle.
            double_sided: polygons emit from both sides.
            polygon_names: optional labels (sequence or callable) used in error messages.
            loop_triangles: optional (T, 3) int corner indices (into ``loop_vertices``) of the mesh's
                own triangulation, each triangle wound like its polygon (Blender's ``loop_triangles``
                ``.loops``); loop_triangle_polygons: (T,) int polygon of each. A polygon that would be
                split (any polygon of more than three corners with corner radiance; a concave,
                non-planar or self-touching one otherwise) is split into its triangles instead of a fan
                or ear clipping; triangles of (almost) zero area are left out, and a polygon left with
                none is dropped as "zero area". Polygons without triangles here are split the usual way.
        """
        verts = np.asarray(vertices, dtype=np.float64)
        if verts.ndim != 2 or verts.shape[1] != 3:
            raise ValueError(f"vertices must have shape (V, 3), got {verts.shape}")
        loops = np.asarray(loop_vertices).astype(np.int64, copy=False).reshape(-1)
        starts = np.asarray(loop_start).astype(np.int64, copy=False).reshape(-1)
        totals = np.asarray(loop_total).astype(np.int64, copy=False).reshape(-1)
        n_poly = len(starts)
        if len(totals) != n_poly:
            raise ValueError(f"loop_start and loop_total differ in length ({n_poly} vs {len(totals)})")
        if n_poly and (starts.min() < 0 or (starts + totals).max() > len(loops) or totals.min() < 0):
            bad = int(np.flatnonzero((starts < 0) | (starts + totals > len(loops)) | (totals < 0))[0])
            raise ValueError(f"{_describe(polygon_names, bad)}: corners {starts[bad]}..{starts[bad] + totals[bad]} "
                             f"outside the {len(loops)} corners given")
        bad_idx = np.flatnonzero((loops < 0) | (loops >= len(verts)))
        if len(bad_idx):
            corner = int(bad_idx[0])
            poly = int(np.searchsorted(starts, corner, side="right") - 1) if n_poly else -1
            raise ValueError(f"{_describe(polygon_names, poly)}: vertex index {loops[corner]} out of range "
                             f"(the scene has {len(verts)} vertices)")
        bad_v = np.flatnonzero(~np.isfinite(verts).all(axis=1))
        if len(bad_v):
            users = np.flatnonzero(np.isin(loops, bad_v[:1]))
            who = ""
            if len(users) and n_poly:
                poly = int(np.searchsorted(starts, users[0], side="right") - 1)
                who = f", used by {_describe(polygon_names, poly)}"
            raise ValueError(f"vertex {int(bad_v[0])} has non-finite coordinates {verts[bad_v[0]].tolist()}{who}")

        def as_rgb(values, rows: int, what: str):
            arr = np.asarray(values, dtype=np.float64)
            if arr.ndim == 1 and arr.shape[0] == rows:
                arr = np.repeat(arr[:, None], 3, axis=1)
            if arr.shape != (rows, 3):
                raise ValueError(f"{what} must have shape ({rows}, 3), got {arr.shape}")
            bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
            if len(bad):
                row = int(bad[0])
                poly = row if what == "polygon radiance" else int(np.searchsorted(starts, row, side="right") - 1)
                raise ValueError(f"{_describe(polygon_names, poly)}: {what} is not finite ({arr[row].tolist()})")
            return arr

        linear = corner_radiance is not None
        if linear:
            if polygon_radiance is not None:
                raise ValueError("give either polygon_radiance or corner_radiance, not both")
            corner_rgb = as_rgb(corner_radiance, len(loops), "corner radiance")
        else:
            poly_rgb = (np.zeros((n_poly, 3)) if polygon_radiance is None
                        else as_rgb(polygon_radiance, n_poly, "polygon radiance"))

        tri_ptr = None
        if loop_triangles is not None:
            tris = np.asarray(loop_triangles).astype(np.int64, copy=False).reshape(-1, 3)
            tri_poly = np.asarray(loop_triangle_polygons).astype(np.int64, copy=False).reshape(-1)
            if len(tri_poly) != len(tris):
                raise ValueError(f"loop_triangle_polygons has {len(tri_poly)} entries for {len(tris)} triangles")
            if len(tris) and (tri_poly.min() < 0 or tri_poly.max() >= n_poly):
                raise ValueError(f"loop_triangle_polygons: polygon index outside 0..{n_poly - 1}")
            order = np.argsort(tri_poly, kind="stable")
            tris, tri_poly = tris[order], tri_poly[order]
            if len(tris):
                s_own = starts[tri_poly]
                outside = ((tris < s_own[:, None]) | (tris >= (s_own + totals[tri_poly])[:, None])).any(axis=1)
                if outside.any():
                    t = int(np.flatnonzero(outside)[0])
                    raise ValueError(f"{_describe(polygon_names, int(tri_poly[t]))}: loop triangle {tris[t].tolist()} "
                                     "uses corners of another polygon")
            tri_ptr = np.zeros(n_poly + 1, dtype=np.int64)
            np.add.at(tri_ptr, tri_poly + 1, 1)
            tri_ptr = np.cumsum(tri_ptr)
        has_tris = np.zeros(n_poly, dtype=bool) if tri_ptr is None else np.diff(tri_ptr) > 0
        own_split: list[np.ndarray] = []  # polygons split into their given loop triangles
        poly_size = np.zeros(n_poly)      # longest edge of each polygon

        out_verts: list[np.ndarray] = []   # (g, k, 3) blocks
        out_src: list[np.ndarray] = []
        out_rad: list[np.ndarray] = []     # (g, 3) or (g, 3, 3) in linear mode
        dropped: dict[int, str] = {}
        slow: list[int] = []

        for k in np.unique(totals):
            group = np.flatnonzero(totals == k)
            if k < 3:
                for i in group:
                    dropped[int(i)] = f"fewer than 3 vertices ({int(k)})"
                continue
            corner_idx = starts[group, None] + np.arange(k)[None, :]  # (g, k)
            pv = verts[loops[corner_idx]]                              # (g, k, 3)
            edges = np.roll(pv, -1, axis=1) - pv                       # (g, k, 3)
            elen = np.linalg.norm(edges, axis=2)                       # (g, k)
            size = elen.max(axis=1)                                    # (g,)
            poly_size[group] = size
            area_vec = _newell(pv)
            area = np.linalg.norm(area_vec, axis=1)
            degenerate = ~(area > tol.AREA_EPS * size * size)
            safe_area = np.where(degenerate, 1.0, area)
            nrm = area_vec / safe_area[:, None]
            # distances from the plane through vertex 0 (differences of nearby coordinates are exact, so
            # this is exact to rounding of the local size even far from the origin): a quad off its plane by
            # input rounding (float32 input, a far translation) would be clipped by a depth plane that does
            # not contain its vertices, by 1e-10 / (distance to the receiver) of its form factor
            hts = np.einsum("gkc,gc->gk", pv - pv[:, :1], nrm)
            dev = 0.5 * (hts.max(axis=1) - hts.min(axis=1))
            planar = dev <= tol.PLANARITY_EPS * size
            turn = np.einsum("gkc,gc->gk", np.cross(edges, np.roll(edges, -1, axis=1)), nrm)
            convex = (turn >= -tol.CONVEXITY_EPS * elen * np.roll(elen, -1, axis=1)).all(axis=1)
            distinct = (elen > tol.DUPLICATE_EPS * size[:, None]).all(axis=1)
            fast = ~degenerate & planar & convex & distinct
            for i in group[degenerate]:
                dropped[int(i)] = "zero area"
            # polygons that would be split and come with their own triangulation: split into it
            own = ~degenerate & has_tris[group] & (~fast | (linear and k > 3))
            if own.any():
                own_split.append(group[own])
                fast &= ~own
                degenerate = degenerate | own  # (handled below, not by the core's own splits)
            # convex non-planar quads (typically rounded input) split as ear clipping would split them,
            # (3, 0, 1) and (1, 2, 3), without the per-polygon loop
            split4 = ~degenerate & ~planar & convex & distinct if k == 4 else np.zeros(len(group), dtype=bool)
            if split4.any():
                for tri in ([3, 0, 1], [1, 2, 3]):
                    t = pv[split4][:, tri]
                    t_area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
                    ok = t_area > tol.AREA_EPS * size[split4] ** 2
                    out_verts.append(t[ok])
                    out_src.append(group[split4][ok])
                    if linear:
                        out_rad.append(corner_rgb[corner_idx[split4][:, tri]][ok])
                    else:
                        out_rad.append(poly_rgb[group[split4][ok]])
            slow.extend(int(i) for i in group[~degenerate & ~fast & ~split4])
            if not fast.any():
                continue
            g_idx = group[fast]
            pv = pv[fast]
            if linear:
                cr = corner_rgb[corner_idx[fast]]                      # (g, k, 3)
                for j in range(1, k - 1):  # fan triangulation of a convex planar polygon
                    out_verts.append(pv[:, [0, j, j + 1]])
                    out_rad.append(cr[:, [0, j, j + 1]])
                    out_src.append(g_idx)
            else:
                out_verts.append(pv)
                out_rad.append(poly_rgb[g_idx])
                out_src.append(g_idx)

        if own_split:
            want = np.zeros(n_poly, dtype=bool)
            want[np.concatenate(own_split)] = True
            sel = want[tri_poly]
            t_poly = tri_poly[sel]
            t_corner = tris[sel]                                       # (t, 3)
            tv = verts[loops[t_corner]]                                # (t, 3, 3)
            t_area = 0.5 * np.linalg.norm(np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0]), axis=1)
            ok = t_area > tol.AREA_EPS * poly_size[t_poly] ** 2
            for i in np.setdiff1d(np.flatnonzero(want), t_poly[ok]):
                dropped[int(i)] = "zero area"
            out_verts.append(tv[ok])
            out_src.append(t_poly[ok])
            out_rad.append(corner_rgb[t_corner[ok]] if linear else poly_rgb[t_poly[ok]])

        for i in slow:
            idx = np.arange(starts[i], starts[i] + totals[i])
            pv = verts[loops[idx]]
            size = float(np.linalg.norm(np.roll(pv, -1, axis=0) - pv, axis=1).max())
            keep = [0]  # drop consecutive duplicate vertices
            for j in range(1, len(pv)):
                if np.linalg.norm(pv[j] - pv[keep[-1]]) > tol.DUPLICATE_EPS * size:
                    keep.append(j)
            if len(keep) > 1 and np.linalg.norm(pv[keep[-1]] - pv[keep[0]]) <= tol.DUPLICATE_EPS * size:
                keep.pop()
            if len(keep) < 3:
                dropped[i] = "fewer than 3 distinct vertices"
                continue
            pv, idx = pv[keep], idx[keep]
            nrm = _newell(pv[None])[0]
            nrm = nrm / np.linalg.norm(nrm)
            # 2D frame in the Newell plane, counter-clockwise about nrm
            ax = np.eye(3)[int(np.argmin(np.abs(nrm)))]
            e1 = np.cross(nrm, ax)
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(nrm, e1)
            rel = pv - pv.mean(axis=0)
            pts2d = np.stack([rel @ e1, rel @ e2], axis=1)
            tris = []
            for a, b, c in _ear_clip(pts2d):
                t = pv[[a, b, c]]
                tri_area = 0.5 * np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0]))
                if tri_area > tol.AREA_EPS * size * size:
                    tris.append((a, b, c))
            if not tris:
                dropped[i] = "zero area"
                continue
            tri = np.array(tris)
            out_verts.append(pv[tri])
            out_src.append(np.full(len(tri), i, dtype=np.int64))
            out_rad.append(corner_rgb[idx[tri]] if linear else np.repeat(poly_rgb[i][None], len(tri), axis=0))

        kmax = max((b.shape[1] for b in out_verts), default=3)
        blocks, counts = [], []
        for b in out_verts:
            k = b.shape[1]
            if k < kmax:
                b = np.concatenate([b, np.repeat(b[:, -1:], kmax - k, axis=1)], axis=1)
            blocks.append(b)
            counts.append(np.full(len(b), k, dtype=np.int64))
        poly_vertices = np.concatenate(blocks) if blocks else np.zeros((0, 3, 3))
        poly_counts = np.concatenate(counts) if counts else np.zeros(0, dtype=np.int64)
        poly_source = np.concatenate(out_src) if out_src else np.zeros(0, dtype=np.int64)
        if linear:
            corner = np.concatenate(out_rad) if out_rad else np.zeros((0, 3, 3))
            rad = corner.mean(axis=1)
        else:
            corner = None
            rad = np.concatenate(out_rad) if out_rad else np.zeros((0, 3))
        order = np.argsort(poly_source, kind="stable")  # keep input order: deterministic results
        return cls(
            poly_vertices[order], poly_counts[order], poly_source[order], rad[order], n_poly,
            corner_radiance=None if corner is None else corner[order],
            double_sided=double_sided, dropped=dropped, polygon_names=polygon_names,
        )

    # ------------------------------------------------------------------ helpers
    @property
    def n_polygons(self) -> int:
        """Number of convex polygons (after triangulation and dropping)."""
        return len(self.poly_counts)

    @property
    def linear(self) -> bool:
        """True when radiance varies linearly over each triangle (per-corner input)."""
        return self.corner_radiance is not None

    def describe(self, input_polygon: int) -> str:
        """Human-readable name of an input polygon, for messages."""
        return _describe(self.polygon_names, input_polygon)

    def __repr__(self) -> str:
        mode = "linear" if self.linear else "constant"
        return (f"Scene({self.n_input} input polygons -> {self.n_polygons} convex, {mode} radiance, "
                f"{len(self.dropped)} dropped)")

