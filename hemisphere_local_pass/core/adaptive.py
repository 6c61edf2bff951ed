"""An error-controlled adaptive local pass for images: exact irradiance at a subset of pixels, the rest
interpolated (issue 11, sec. 2; the paper's sec. 3.4 future work, "evaluate the local illumination
integral not for all pixels and use some kind of interpolation scheme").

Every pixel's camera ray is already cast (its hit point, normal and polygon are known exactly); only the
exact hemispherical projection is expensive. :func:`adaptive_irradiance` evaluates it (with
:func:`.local_pass.irradiance`, so every exact sample is bit for bit the all-exact image's value: a
receiver's result does not depend on the others of its chunk) on a quadtree of image cells:

1. The image is covered by cells of ``coarse`` pixels a side (corners shared; the last row and column
   are corners too), whose four corner pixels are evaluated exactly.
2. A cell is split (its four children's corners then evaluated) — *forced*, before any error estimate —
   when interpolation across it could cross a discontinuity of H:

   * **surface**: a pixel of the cell missed, or two adjacent pixels of the cell lie on different
     planes (different objects or polygon groups, which also covers every depth jump: pixels that are
     adjacent in the image and lie on one plane are adjacent on it), or their normals differ by more
     than :data:`NORMAL_JUMP` radians. H is continuous along a plane across polygon edges (a polygon in
     the receiver's plane contributes nothing), so coplanar polygons of one group are interpolated across.
     Every polygon a camera ray hits inside the cell therefore is the cell's plane; a polygon seen only
     between samples (a small object standing on the floor) is caught here, however small, as long as
     one camera ray hits it.
   * **shadow**: a *light* (an emitter group of high radiance, see :func:`light_groups`) may be partly
     hidden from some point of the cell: some polygon of the scene meets the convex hull of the cell's
     3-D quad and the light's bounding rectangle (a conservative separating-axis test, BVH-accelerated).
     This is the from-region form of the visibility signature: a change of which parts of a light are
     visible, including a hard shadow line narrower than the sample spacing or an occluder seen from no
     sample, cannot happen inside a cell that passes it. Cells in a light's shadow region are refined
     down to single pixels, i.e. evaluated exactly. Only an occluder narrower than the cell (seen from
     the light) forces the split; a polygon of a merged face (coplanar polygons tiling one convex
     polygon, :func:`.culling._merged_faces`: a subdivided wall or block face) counts with the face's
     width, since it occludes exactly as the face does.
3. Otherwise the cell's four edge midpoints and its centre are evaluated exactly (the a-posteriori spot
   check): ``d`` = the largest difference, over those five samples and the three channels, between the
   exact value and the bilinear interpolation of the four corners. The cell's error estimate is
   ``INNER_FACTOR * d`` (``EDGE_FACTOR * d`` for a cell next to a surface break or the image border,
   where H is not smooth: at a concave junction it goes like x log x); if it is at most ``tolerance``
   the cell is accepted and its pixels are interpolated bilinearly from its nine exact samples (over
   its four sub-cells); else it is split and its children go through 2–3 again. Cells of at most
   2 × 2 pixels have exact samples at every pixel.

   **The check extended beyond the cell** (``neighbour_check``, since 2026-12-07): along each of the
   cell's three sample rows the line through the two samples at an end (a corner and the midpoint) is
   extended by their spacing to the pixel just outside; where that pixel is an exact sample on the same
   surface, the miss there (the second difference at the corner) counts, halved, among the cell's
   discrepancies ``d`` (the midpoint's miss is half the second difference at the centre); likewise along
   the three sample columns (:func:`_neighbour_misses`). The cell's own samples see the curvature at its
   centre only: a kink between a corner and the midpoint, or two kinks of opposite sign (a narrow
   valley), leave the centre's second difference small while a corner's is large. On the 512² Cornell
   box of 175 polygons that let errors of 1.33 / 1.11 / 1.47 × the tolerance through at 1e-2 / 1e-3 /
   1e-4 of the mean (a light's penumbra start on the left wall; the right wall where it crosses the
   plane of a block face), up to 5.3 × on crops at 3e-4; with the extension every measured error is
   within 0.51 × the tolerance, for 1–3 more points of the pixels exact (docs/adaptive.md).
4. **Anisotropic splits**: a rejected cell whose interpolation along one axis passes (the estimate from
   the two edge midpoints on that axis's edges is within the tolerance) while the other fails is halved
   along the failing axis only; its two children span the cell along the passing one and check it again
   at the same spacing. H's non-smooth features are lines (kinks where a receiver crosses a bright
   polygon's plane or an edge-edge visibility event, penumbra boundaries, x log x junction layers); a
   line along a column or row is then refined across, not along itself. Cells stay at most
   :data:`MAX_ASPECT` : 1 (longer ones test the passing axis on too few columns: a narrow valley between
   two kinks slipped). docs/adaptive.md: 54 % → 45 % of the pixels exact on the 256² Cornell box at
   1e-2 of the mean, 89 % → 81 % at 1e-3, the measured max errors unchanged.
5. **Far-field samples** (``sample_share`` > 0): the samples are evaluated by :func:`irradiance` with
   ``tolerance = sample_share * tolerance`` (the core's error-bounded far field: distant clusters of
   polygons projected as bounded proxies, sec. 3.4's "approximate projections"), each with its returned
   bound ``b`` (largest channel; only the far field's rounding allowance where it skipped nothing). A
   cell's spot check then sees samples within ``b`` (the largest bound among its nine samples) of their
   exact values: the exact samples' discrepancy is at most ``d + 2 b`` (a check sample's own error plus
   the interpolated corners'), and the interpolant of the samples is within ``b`` of the exact samples'
   interpolant, so the cell's estimate is ``factor * (d + 2 b) + b`` (the anisotropic test likewise),
   and a sample's own error estimate is its bound. ``sample_share = 0`` (the default, with ``final_share``
   None or 0) is steps 1–4 bit for bit. It pays where the exact samples are the cost and the far field
   applies: on the 256² box of 187,588 polygons at 1e-3 of the mean, share 0.2–0.3 halves the time
   (docs/adaptive.md, "Far-field samples").
6. **Final samples** (``final_share``, default ``sample_share``): most samples of a fine image are *final*:
   pixels of cells refined to single pixels (surface breaks, light shadows, rejected cells at the last
   level) that no interpolation ever uses. Only the samples of cells that interpolate (corners and spot
   checks of a cell with a pixel beyond its nine samples) enter an estimate, where a bound ``b`` counts
   ``2 factor + 1`` times; a final sample's bound is its pixel's whole error, counted once. So in each
   round the pixels outside every such cell (later cells lie inside this round's, so they stay outside)
   are evaluated with ``tolerance = final_share * tolerance``, the others with ``sample_share``. The far
   field is cheaper with more tolerance (at 187,588 polygons ~10 ms per receiver at 0.9 of 1e-3 of the
   mean, ~14 ms at 0.05), and a smaller ``sample_share`` lets more cells be accepted.

Order of work: the forced tests (step 2) need geometry only, so a round follows them down at once, to
the cells that need a spot check (at whatever depth) and the cells of single pixels; then one core call
evaluates every corner met and those cells' spot checks, and step 3 (with 4) decides. The rejected
cells' children form the next round and skip the forced tests: a part of a uniform cell is uniform, and a
child's hull with a light lies inside its parent's, and an occluder narrower than the child was narrower
than the parent. The decisions, and so the image, are those of a depth-by-depth order (each cell's tests
see its own geometry and its own exact samples only), with one core call per round instead of two per
depth: on the 256² Cornell box of 9,468 polygons at 1e-3 (2 workers) the pass took 1.29× the time of one
core call over the same pixels, now 1.05× (docs/adaptive.md, "Workers").

Why those factors: for smooth H the bilinear interpolant's error falls with the square of the spacing,
so the accepted interpolant (spacing halved) errs by about ``d / 4``; measured on the 256² Cornell box
the ratio of the true largest error in a cell to ``d`` reached 0.9 inside surfaces and 1.8 next to
junctions, hence the factors 2 and 4 (a margin of about 2). The estimate is a-posteriori, not a bound.
What is *not* guaranteed: the shadows of emitters dimmer than the lights (walls of a radiosity
solution) are left to the spot check — a feature of such an emitter narrower than half a cell can slip
between the nine samples; its size is bounded by the emitter's radiance times the occluder's form
factor, and the tests measure it (tests/core/test_adaptive.py). Forcing the shadow test for every
emitter would force exactness nearly everywhere in a subdivided radiosity scene (every wall cell is
occluded by something somewhere).

``tolerance = 0`` evaluates every hit pixel exactly in one :func:`irradiance` call and so reproduces
the all-exact image bit for bit (whatever ``sample_share``: the samples' tolerance is then 0 too).
"""

from __future__ import annotations

import concurrent.futures as cf
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .culling import _merged_faces
from .local_pass import Cancelled, irradiance
from .parallel import _resolve_workers, job_pool
from .raycast import box_query, build_bvh
from .scene import Scene

__all__ = ["AdaptiveStats", "DEFAULT_COARSE", "FINAL_SHARE", "LIGHT_RATIO", "MAX_ASPECT", "NORMAL_JUMP", "SAMPLE_SHARE",
           "adaptive_irradiance", "light_groups"]

#: Default side (pixels) of the coarsest cells.
DEFAULT_COARSE = 16
#: Adjacent pixels whose normals differ by more than this angle (radians) are not interpolated across.
NORMAL_JUMP = 1e-3
#: An emitter whose radiance (largest channel) is at least ``LIGHT_RATIO`` times the area-weighted mean
#: radiance of all emitters is a *light*: its shadows are found geometrically, not by spot checks.
LIGHT_RATIO = 4.0
#: Error estimate of an accepted cell, per unit of its spot check's discrepancy ``d``: inside a surface
#: and next to a surface break or the image border (module docstring). A cell is accepted when its
#: estimate is at most the tolerance.
INNER_FACTOR = 2.0
EDGE_FACTOR = 4.0
#: Anisotropic splits (module docstring, step 4) make cells at most this many times longer than wide.
MAX_ASPECT = 2
#: The shares of the tolerance the Blender job and the benchmarks give the samples' far field (``sample_share``,
#: module docstring step 5) and the final samples' (``final_share``, step 6): on two 64² crops of the 256²
#: Cornell box of 187,588 polygons, 0.1 / 0.9 took 0.90-0.96x (1e-3 of the mean) and 0.76-0.81x (1e-2) the time
#: of 0.25 for all samples (86.9 % / 41.4 % of the pixels sampled instead of 94.7 % / 58.2 %), 0.98x at 9,468
#: polygons, 1.1x at 175 (one more core call); the measured max error 0.17 / 0.41 of the tolerance
#: (docs/adaptive.md, "Final samples").
SAMPLE_SHARE = 0.1
FINAL_SHARE = 0.9
#: Candidate (cell, light, polygon) triples tested at once by the shadow test (memory bound).
_PAIR_BATCH = 1 << 18


@dataclass
class AdaptiveStats:
    """What :func:`adaptive_irradiance` did.

    Attributes:
        exact_points: core evaluations (pixels evaluated by :func:`irradiance`: exactly, or within their
            far-field bound when ``sample_share`` > 0).
        error_estimate: largest per-pixel error estimate (units of H, per channel); 0 if all exact.
        pixel_error: (h, w) float64 per-pixel error estimate; at samples their far-field bound (0 when
            exact: always with ``sample_share`` 0), 0 at missed pixels.
        exact_mask: (h, w) bool, True where the pixel was a sample (evaluated by the core, not interpolated).
        sample_bound: largest far-field bound of a sample (units of H, per channel); 0 with exact samples.
        final_points: samples evaluated as final ones, with ``final_share`` (0 when it equals ``sample_share``).
        hit_pixels: pixels whose camera ray hit a polygon.
        forced_surface: cells split because they cross a surface discontinuity (miss, plane, normal).
        forced_shadow: cells split because a light may be partly hidden from them.
        rejected: cells split because the spot check exceeded the tolerance.
        accepted: cells interpolated.
        lights: number of light groups given the shadow test.
    """

    exact_points: int
    error_estimate: float
    pixel_error: np.ndarray
    exact_mask: np.ndarray
    hit_pixels: int = 0
    forced_surface: int = 0
    forced_shadow: int = 0
    rejected: int = 0
    accepted: int = 0
    lights: int = 0
    sample_bound: float = 0.0
    final_points: int = 0

    @property
    def exact_fraction(self) -> float:
        """Exact evaluations per hit pixel."""
        return self.exact_points / max(self.hit_pixels, 1)


def _input_planes(scene: Scene):
    """(n_input,) int plane id of every input polygon (coplanar polygons share one), -1 if dropped."""
    first = np.full(scene.n_input, -1, dtype=np.int64)
    src = scene.poly_source
    order = np.arange(len(src))[::-1]
    first[src[order]] = order  # the first convex piece of each input polygon
    ok = first >= 0
    scale = float(np.abs(scene.poly_vertices).max()) if scene.n_polygons else 1.0
    n = scene.poly_normals[first[ok]]
    off = scene.poly_offsets[first[ok]] / (scale if scale > 0 else 1.0)
    # quantised plane: two polygons of one plane agree far below 1e-9; a plane that straddles a
    # quantisation step only splits its group (more refinement), it never merges two planes
    key = np.round(np.column_stack([n, off]) * 1e9).astype(np.int64)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    out = np.full(scene.n_input, -1, dtype=np.int64)
    out[ok] = inv.reshape(-1)
    return out


def light_groups(scene: Scene, *, ratio: float = LIGHT_RATIO):
    """The scene's lights: emitter polygons of high radiance, grouped by plane.

    A polygon is a light when its largest radiance channel is at least ``ratio`` times the
    area-weighted mean (largest channel) of all emitting polygons. Lights of one plane form one group.

    Returns a list of dicts with ``rect (4, 3)`` (the group's bounding rectangle in its plane, a
    superset of the group), ``normal (3,)`` (front side), ``offset`` (plane offset), ``radiance``
    (largest channel) and ``polygons`` (convex-polygon indices).
    """
    if scene.n_polygons == 0:
        return []
    if scene.linear:
        lum = np.abs(scene.corner_radiance).max(axis=(1, 2))
    else:
        lum = np.abs(scene.poly_radiance).max(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(scene.poly_vertices - scene.poly_vertices[:, :1],
                                         np.roll(scene.poly_vertices, -1, axis=1) - scene.poly_vertices[:, :1]),
                                axis=2).sum(axis=1)  # (n,) fan area of each convex polygon
    pv = scene.poly_vertices
    diam = np.linalg.norm(pv[:, :, None, :] - pv[:, None, :, :], axis=3).max(axis=(1, 2))  # (n,)
    diam = np.maximum(diam, 1e-300)
    emit = lum > 0
    if not emit.any():
        return []
    mean = float((lum[emit] * area[emit]).sum() / max(area[emit].sum(), 1e-300))
    light = np.flatnonzero(emit & (lum >= ratio * mean))
    if not len(light):
        return []
    face, member, f_area, f_diam = _merged_face_extents(scene)
    scale = float(np.abs(scene.poly_vertices).max())
    key = np.round(np.column_stack([scene.poly_normals[light], scene.poly_offsets[light] / scale]) * 1e9)
    _, inv = np.unique(key.astype(np.int64), axis=0, return_inverse=True)
    groups = []
    for g in range(inv.max() + 1):
        polys = light[inv.reshape(-1) == g]
        nrm = scene.poly_normals[polys[0]]
        pts = scene.poly_vertices[polys].reshape(-1, 3)
        a = np.cross(nrm, [1.0, 0.0, 0.0] if abs(nrm[0]) < 0.9 else [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(nrm, a)
        u, v = pts @ a, pts @ b
        c = float(pts[0] @ nrm)
        rect = np.array([[u.min(), v.min()], [u.max(), v.min()], [u.max(), v.max()], [u.min(), v.max()]])
        rect3 = rect[:, :1] * a + rect[:, 1:] * b + c * nrm
        # apparent width of every polygon seen from the light: its area projected across the direction
        # from the light, over its largest vertex distance. Its shadow on any receiver behind it is at
        # least this wide (central projection onto a farther, possibly oblique plane only widens it;
        # the light's extent blurs it wider still)
        u = scene.poly_centers - rect3.mean(axis=0)
        u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
        cos = np.abs(np.einsum("nc,nc->n", scene.poly_normals, u))
        width = area * cos / diam
        # a polygon of a merged face (coplanar polygons tiling one convex polygon: a subdivided wall or
        # block face) occludes exactly as that face does (culling module doc): its shadow is the face's,
        # as wide as the face's width (with its smallest cosine over the members: conservative)
        if face is not None:
            f_cos = np.full(len(f_area), np.inf)
            np.minimum.at(f_cos, face[member], cos[member])
            width[member] = np.maximum(width[member], (f_area * f_cos / f_diam)[face[member]])
        groups.append({"rect": rect3, "normal": nrm, "offset": c, "radiance": float(lum[polys].max()),
                       "polygons": polys, "width": width})
    return groups


def _merged_face_extents(scene: Scene):
    """The merged convex faces of :func:`.culling._merged_faces` that have two or more members.

    Returns ``(face, member, area, diam)``: ``member`` the convex polygons in such a face, ``face (n,)``
    their face index (-1 elsewhere), ``area, diam (n_f,)`` each face's area and largest vertex distance;
    ``face`` is None when no polygons merge."""
    members, counts, points = _merged_faces(scene)
    ok = members >= 0
    size = np.bincount(members[ok], minlength=len(counts))
    multi = np.flatnonzero(size > 1)
    if not len(multi):
        return None, None, None, None
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    area = np.zeros(len(multi))
    diam = np.zeros(len(multi))
    for k, o in enumerate(multi):  # few faces of two or more members
        v = points[start[o]:start[o] + counts[o]]
        area[k] = 0.5 * np.linalg.norm(np.cross(v - v[0], np.roll(v, -1, axis=0) - v[0]).sum(axis=0))
        diam[k] = np.linalg.norm(v[:, None] - v[None], axis=2).max()
    face = np.full(len(counts), -1)
    face[multi] = np.arange(len(multi))
    face = np.where(ok, face[np.maximum(members, 0)], -1)
    member = np.flatnonzero(face >= 0)
    return face, member, area, np.maximum(diam, 1e-300)


def _hull_planes(quads, rect, normals, light_normal, eps):
    """Supporting planes of the hulls of cell quads ``quads (c, 4, 3)`` and a light ``rect (4, 3)``.

    The faces of the hull of two convex polygons lie in planes through an edge of one and a vertex of
    the other, or in the polygons' own planes: 34 candidates, kept where every hull point is on one side
    (oriented outward). Returns ``normals (c, 34, 3)`` (unit; zero where not a supporting plane) and
    ``offsets (c, 34)``: the hull is inside ``n·x <= offset``.
    """
    c = len(quads)
    a, b = quads, np.broadcast_to(rect, (c, 4, 3))
    pts = np.concatenate([a, b], axis=1)                                   # (c, 8, 3)
    nrm, base = [normals, np.broadcast_to(light_normal, (c, 3))], [a[:, 0], b[:, 0]]
    for p, q in ((a, b), (b, a)):
        for i in range(4):
            e = p[:, (i + 1) % 4] - p[:, i]
            for j in range(4):
                nrm.append(np.cross(e, q[:, j] - p[:, i]))
                base.append(p[:, i])
    n = np.stack(nrm, axis=1)                                              # (c, 34, 3)
    length = np.linalg.norm(n, axis=2)
    n = np.where(length[..., None] > 0, n / np.where(length > 0, length, 1.0)[..., None], 0.0)
    off = np.einsum("cpk,cpk->cp", n, np.stack(base, axis=1))
    side = np.einsum("cik,cpk->cpi", pts, n) - off[..., None]              # (c, 34, 8)
    out_pos = side.max(axis=2) <= eps                                      # hull on the negative side
    out_neg = side.min(axis=2) >= -eps
    n = np.where(out_pos[..., None], n, np.where(out_neg[..., None], -n, 0.0))
    off = np.where(out_pos, off, np.where(out_neg, -off, 0.0))
    return n, off


def _shadow_cells(scene, bvh, lights, quads, normals, eps):
    """(c,) True where a light may be partly hidden from some point of cell quad ``quads (c, 4, 3)``
    (plane normal ``normals (c, 3)``): some polygon meets the hull of the quad and the light's rectangle.

    Conservative separating-plane test: a polygon is cleared when a supporting plane of the hull, or the
    polygon's own plane, has it (resp. the hull) entirely on one side (touching counts as separated:
    a polygon in the cell's or the light's plane hides nothing of the light from the cell). Unseparated
    pairs that are in fact disjoint only cost refinement."""
    out = np.zeros(len(quads), dtype=bool)
    for g in lights:
        rect = g["rect"]
        # the light must be above the cell's horizon (the cell is planar: one horizon for all its
        # points) and, unless the scene is double-sided, the cell in front of the light
        above = np.einsum("crk,ck->cr", rect[None, :, :] - quads[:, :1, :], normals).max(axis=1) > eps
        front = (quads @ g["normal"] - g["offset"]).max(axis=1) > eps
        cand = np.flatnonzero(above & (front | scene.double_sided) & ~out)
        if not len(cand):
            continue
        hull = np.concatenate([quads[cand], np.broadcast_to(rect, (len(cand), 4, 3))], axis=1)  # (c, 8, 3)
        hn, ho = _hull_planes(quads[cand], rect, normals[cand], g["normal"], eps)
        # the hull's faces by component (c, 34) each, and which are real faces: gathered per pair below
        # as contiguous (pairs, 34) rows (a (pairs, 34, 3) gather and einsum cost ~5x as much)
        hx, hy, hz = (np.ascontiguousarray(hn[..., i]) for i in range(3))
        real_face = np.abs(hn).sum(axis=2) > 0
        diam = np.linalg.norm(quads[cand][:, [0, 1]] - quads[cand][:, [2, 3]], axis=2).max(axis=1)  # (c,)
        qi, poly = box_query(bvh, hull.min(axis=1), hull.max(axis=1))
        own = np.isin(poly, g["polygons"])
        qi, poly = qi[~own], poly[~own]
        hit = np.zeros(len(cand), dtype=bool)
        for s in range(0, len(qi), _PAIR_BATCH):
            qs, ps = qi[s:s + _PAIR_BATCH], poly[s:s + _PAIR_BATCH]
            keep = ~hit[qs]
            qs, ps = qs[keep], ps[keep]
            if not len(qs):
                continue
            # cheapest tests first, each on the pairs still unseparated.
            # An occluder whose shadow is wider than the cell cannot hide a feature between the cell's
            # samples: its shadow's edges cross the cell as ramps or steps, which the spot check sees
            keep = g["width"][ps] < diam[qs]
            qs, ps = qs[keep], ps[keep]
            pv = scene.poly_vertices[ps]                                   # (p, K, 3), padding repeats
            # a polygon on or below the cell's plane hides nothing above the cell's horizon (the light may
            # straddle that plane, so the plane need not bound the hull)
            below = np.einsum("pkc,pc->pk", pv - quads[cand[qs], :1], normals[cand[qs]])
            keep = below.max(axis=1) > eps
            # the polygon's plane with the whole hull on one side
            qs, ps, pv = qs[keep], ps[keep], pv[keep]
            side = np.einsum("pic,pc->pi", hull[qs], scene.poly_normals[ps]) - scene.poly_offsets[ps][:, None]
            keep = (side.max(axis=1) > eps) & (side.min(axis=1) < -eps)
            qs, ps, pv = qs[keep], ps[keep], pv[keep]
            # a hull face with the whole polygon outside it: min over the vertices of n·v, less the offset
            # (the offset's subtraction is monotone, so it may come after the min)
            fx, fy, fz = np.take(hx, qs, axis=0), np.take(hy, qs, axis=0), np.take(hz, qs, axis=0)
            low = None
            for k in range(pv.shape[1]):
                dk = fx * pv[:, k, 0:1]
                dk += fy * pv[:, k, 1:2]
                dk += fz * pv[:, k, 2:3]
                low = dk if low is None else np.minimum(low, dk, out=low)
            low -= np.take(ho, qs, axis=0)                                    # (p, 34)
            sep = (np.take(real_face, qs, axis=0) & (low >= -eps)).any(axis=1)
            np.logical_or.at(hit, qs[~sep], True)
        out[cand[hit]] = True
    return out


def _validate(points, normals, polygons):
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    g = np.asarray(polygons)
    if p.ndim != 3 or p.shape[2] != 3:
        raise ValueError(f"points must have shape (h, w, 3), got {p.shape}")
    if n.shape != p.shape:
        raise ValueError(f"normals must have shape {p.shape}, got {n.shape}")
    if g.shape != p.shape[:2]:
        raise ValueError(f"polygons must have shape {p.shape[:2]}, got {g.shape}")
    if not np.issubdtype(g.dtype, np.integer):
        raise ValueError(f"polygons must be integer input polygon indices (-1 for a miss), got {g.dtype}")
    return p, n, g.astype(np.int64)


def adaptive_irradiance(
    scene: Scene,
    points,
    normals,
    polygons,
    *,
    tolerance: float,
    workers=None,
    executor: cf.Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    coarse: int = DEFAULT_COARSE,
    light_ratio: float = LIGHT_RATIO,
    anisotropic: bool = True,
    neighbour_check: bool = True,
    sample_share: float = 0.0,
    final_share: float | None = None,
    limit_directions=None,
    breaks=None,
):
    """Irradiance image with exact evaluations only where interpolation would err by more than ``tolerance``.

    Args:
        scene: the scene (its radiance is the first pass's).
        points: (h, w, 3) float camera-ray hit points (world space), any value where missed.
        normals: (h, w, 3) float receiver normals (normalised by the core).
        polygons: (h, w) int input polygon index each ray hit (``RayHits.source``), -1 for a miss.
        tolerance: absolute tolerance on H (W m^-2, each RGB channel); 0 evaluates every hit pixel.
        workers: worker processes for the exact evaluations (None: every core; 1: this process only). With
            more than one, the pass runs every core call on one pool (:func:`.parallel.job_pool`: the
            pool of the caller's :class:`.parallel.PoolKeeper` scope, else one started for this pass and
            shut down at its end). The result is bit-identical for any ``workers``.
        executor: run the exact evaluations on this executor instead (see :func:`irradiance`).
        progress: ``progress(exact_done, hit_pixels)`` after each chunk of exact evaluations (the total
            is an upper bound: most pixels are never evaluated).
        cancel: checked by the core between chunks; True raises :class:`Cancelled`.
        coarse: side of the coarsest cells in pixels (a power of two is best).
        light_ratio: see :data:`LIGHT_RATIO`.
        anisotropic: halve a rejected cell along one axis when the other passes its spot check (step 4
            of the module docstring); False: always along both (the earlier method, for comparison).
        neighbour_check: extend each spot check one sample spacing beyond the cell (step 3 of the module
            docstring); False: the cell's own nine samples only (the method before 2026-12-07, which let
            errors up to 5× the tolerance through at 512², for comparison).
        sample_share: in [0, 1): the share of ``tolerance`` the samples themselves may err by: they are
            evaluated by :func:`irradiance` with ``tolerance = sample_share * tolerance`` (the error-bounded
            far field) and their returned bounds enter every estimate (step 5 of the module docstring).
            0 (the default): exact samples. Pays on large scenes (:data:`SAMPLE_SHARE`: the Blender job's).
        final_share: in [0, 1): the share of ``tolerance`` for the *final* samples, those no interpolation
            will ever use (step 6 of the module docstring): their bound is their pixel's whole error.
            None (the default): ``sample_share``, i.e. one tolerance for every sample.
        limit_directions: (h, w, 3) float or None: each sample is the limit from this side (as in
            :func:`irradiance`; the vertex receivers of :mod:`.adaptive_vertices` on a surface's edge).
        breaks: ``(brk_x (h, w-1), brk_y (h-1, w))`` bool or None: further discontinuities between adjacent
            pixels, forced like surface breaks (step 2): other geometry meeting the receivers' plane
            between two vertex receivers (:mod:`.adaptive_vertices`).

    Returns:
        ``(H, stats)``: H (h, w, 3) float64 irradiance (0 where missed), stats :class:`AdaptiveStats`.
    """
    p, n, g = _validate(points, normals, polygons)
    lim = None if limit_directions is None else np.asarray(limit_directions, dtype=np.float64)
    if lim is not None and lim.shape != p.shape:
        raise ValueError(f"limit_directions must have shape {p.shape}, got {lim.shape}")
    if breaks is not None:
        bx, by = (np.asarray(b, dtype=bool) for b in breaks)
        h, w = g.shape
        if bx.shape != (h, max(w - 1, 0)) or by.shape != (max(h - 1, 0), w):
            raise ValueError(f"breaks must have shapes {(h, max(w - 1, 0))} and {(max(h - 1, 0), w)}, "
                             f"got {bx.shape} and {by.shape}")
        breaks = (bx, by)
    tol = float(tolerance)
    if not (tol >= 0.0) or not np.isfinite(tol):
        raise ValueError(f"tolerance must be a finite number >= 0, got {tolerance!r}")
    if int(coarse) < 2:
        raise ValueError(f"coarse must be >= 2 pixels, got {coarse}")
    share = float(sample_share)
    if not 0.0 <= share < 1.0:
        raise ValueError(f"sample_share must be in [0, 1), got {sample_share!r}")
    final = share if final_share is None else float(final_share)
    if not 0.0 <= final < 1.0:
        raise ValueError(f"final_share must be in [0, 1), got {final_share!r}")
    if (g >= scene.n_input).any():
        raise ValueError(f"polygons holds index {int(g.max())}, the scene has {scene.n_input} input polygons")
    # one pool of worker processes for the whole pass (the caller's kept pool in a PoolKeeper scope),
    # started by the first core call: the quadtree makes one core call per round of spot checks, and a pool per call
    # would start its processes and ship the scene to them every time (docs/adaptive.md, "Workers")
    kept = []

    def executor_of_pass():
        if executor is not None:
            return executor
        if not kept:
            kept.append(job_pool(workers) if tol > 0.0 and _resolve_workers(workers) > 1 else (None, False))
        return kept[0][0]

    try:
        return _adaptive_pass(scene, p, n, g, tol, workers, executor_of_pass, progress, cancel, int(coarse),
                              light_ratio, anisotropic, neighbour_check, share, final, lim, breaks)
    finally:
        if kept and kept[0][1]:  # a pool of this pass (a cancel has killed it already: run_chunks does)
            kept[0][0].shutdown(wait=True, cancel_futures=True)


def _adaptive_pass(scene, p, n, g, tol, workers, executor_of_pass, progress, cancel, coarse, light_ratio,
                   anisotropic, neighbour_check, share, final_share, lim=None, extra_breaks=None):
    """The body of :func:`adaptive_irradiance` (arguments checked; ``executor_of_pass()``: the executor of
    the core calls, or None)."""
    h, w = g.shape
    valid = g >= 0
    n_valid = int(valid.sum())
    H = np.zeros((h, w, 3))
    exact = np.zeros((h, w), dtype=bool)
    err = np.zeros((h, w))
    bound = np.zeros((h, w))  # the samples' own error bounds (largest channel): 0 where exact
    stats = AdaptiveStats(0, 0.0, err, exact, hit_pixels=n_valid)

    deferred = np.zeros((h, w), dtype=bool)  # final samples (step 6), evaluated in one call after the rounds

    def evaluate(ys, xs, used=None, sample_tol=share * tol):
        """Evaluate the hit pixels among ``(ys, xs)`` not evaluated yet with ``sample_tol`` (0: exactly, bitwise
        the all-exact values); given ``used (h, w)`` bool (the pixels some interpolation may use), defer the
        others to the call after the rounds: they are final samples (step 6)."""
        flat = np.unique(ys * w + xs)
        flat = flat[valid.reshape(-1)[flat] & ~exact.reshape(-1)[flat]]
        yy, xx = np.divmod(flat, w)
        if used is not None:
            u = used[yy, xx]
            deferred[yy[~u], xx[~u]] = True
            # a used pixel is never a deferred one (later cells lie inside this round's interpolating cells,
            # which no deferred pixel meets); were it one, it is evaluated now, before anything reads it
            deferred[yy[u], xx[u]] = False
            yy, xx = yy[u], xx[u]
        if not len(yy):
            return
        if cancel is not None and cancel():
            raise Cancelled(f"cancelled after {stats.exact_points} exact points")
        before = stats.exact_points
        # progress after every chunk of the call (a round's call can hold most of the image's evaluations)
        chunk_progress = None if progress is None else (lambda done, _total: progress(before + done, n_valid))
        limits = None if lim is None else lim[yy, xx]
        if sample_tol > 0.0:
            H[yy, xx], far = irradiance(scene, p[yy, xx], n[yy, xx], cancel=cancel, workers=workers,
                                        executor=executor_of_pass(), progress=chunk_progress,
                                        tolerance=sample_tol, return_stats=True, limit_directions=limits)
            bound[yy, xx] = far.error_bound.max(axis=1)
        else:
            H[yy, xx] = irradiance(scene, p[yy, xx], n[yy, xx], cancel=cancel, workers=workers,
                                   executor=executor_of_pass(), progress=chunk_progress, limit_directions=limits)
        exact[yy, xx] = True
        stats.exact_points += len(yy)

    if tol == 0.0 or h * w == 0:
        ys, xs = np.nonzero(valid)
        evaluate(ys, xs)
        return H, stats

    # --- surface discontinuities between adjacent pixels, as summed-area tables --------------------
    unit = n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-300)
    brk = _surface_breaks(scene, unit, g)
    if extra_breaks is not None:
        brk = (brk[0] | extra_breaks[0], brk[1] | extra_breaks[1])
    tx, ty = (_summed(b) for b in brk)

    lights = [lg for lg in light_groups(scene, ratio=light_ratio) if np.pi * lg["radiance"] > tol]
    stats.lights = len(lights)
    bvh = build_bvh(scene) if lights else None
    scale = float(np.abs(scene.poly_vertices).max()) if scene.n_polygons else 1.0
    eps = 1e-9 * scale

    # --- the quadtree ------------------------------------------------------------------------------
    # A cell's forced splits (surface, shadow) depend on geometry alone, so they are followed down at once,
    # without any H; the cells that need their spot checks, at whatever depth, then go to the core in one
    # call with every corner still missing. Each round is one core call (two per depth before): fewer,
    # larger calls keep the workers busy (docs/adaptive.md, "Workers"). The decisions are those of the
    # depth-by-depth order: a cell's tests see only its own geometry and its own exact samples.
    def nodes(size):
        v = np.unique(np.concatenate([np.arange(0, size, coarse), [size - 1]]))
        return (v[:-1], v[1:]) if len(v) > 1 else (v, v)

    ax0, ax1 = nodes(w)
    ay0, ay1 = nodes(h)
    X0, Y0 = np.meshgrid(ax0, ay0)
    X1, Y1 = np.meshgrid(ax1, ay1)
    # cells: [x0, x1, y0, y1, depth, clear]; ``clear``: the cell lies in one that passed both forced tests.
    # Both tests are inherited: a part of a uniform cell is uniform, and a child's hull with a light lies in
    # its parent's (an occluder that misses the parent's hull misses the child's) and a child is smaller, so
    # no occluder narrower than the child was wider than the parent. The spot check's children skip them
    pending = [a.reshape(-1) for a in (X0, X1, Y0, Y1)] + [np.zeros(X0.size, dtype=np.int64),
                                                           np.zeros(X0.size, dtype=bool)]
    fills = []
    while len(pending[0]):
        # 1. forced splits, down to cells that need a spot check (ready) or are all corners (small)
        ready, frontier, corners = [], pending, []
        while len(frontier[0]):
            x0, x1, y0, y1, depth, clear = frontier
            corners.append((x0, x1, y0, y1))
            small = (x1 - x0 <= 1) & (y1 - y0 <= 1)          # every pixel is a corner: exact
            ok = ~small & (clear | _uniform(valid, tx, ty, x0, x1, y0, y1))
            forced = ~small & ~ok
            stats.forced_surface += int(forced.sum())
            if lights and (ok & ~clear).any():
                i = np.flatnonzero(ok & ~clear)
                quads = np.stack([p[y0[i], x0[i]], p[y0[i], x1[i]], p[y1[i], x1[i]], p[y1[i], x0[i]]], axis=1)
                sh = _shadow_cells(scene, bvh, lights, quads, unit[y0[i], x0[i]], eps)
                ok[i[sh]] = False
                forced[i[sh]] = True
                stats.forced_shadow += int(sh.sum())
            ready.append([a[ok] for a in frontier])
            s = np.flatnonzero(forced)
            frontier = _children(x0, x1, y0, y1, depth, s, np.ones(len(s), bool), np.ones(len(s), bool), False)
        x0, x1, y0, y1, depth, _ = (np.concatenate(a) for a in zip(*ready, strict=True))
        mx, my = (x0 + x1) // 2, (y0 + y1) // 2
        # 2. one core call: the corners of every cell met (a split cell's corners are its children's) and
        #    the ready cells' spot checks: the four edge midpoints and the centre
        cx = np.stack([mx, mx, x0, x1, mx], axis=1)                    # (c, 5) spot-check pixels
        cy = np.stack([y0, y1, my, my, my], axis=1)
        ca, cb, cc, cd = (np.concatenate(a) for a in zip(*corners, strict=True))
        # step 6: a pixel outside every ready cell that interpolates (one with a pixel beyond its nine samples)
        # is never used by an interpolation, in this round or later (later cells lie inside this round's
        # ready cells): its sample is final, deferred to one call with final_share after the rounds. The
        # ready cells that do not interpolate need no spot check then (every pixel of theirs is a sample)
        used = None
        if final_share != share:
            big = (x1 - x0 > 2) | (y1 - y0 > 2)
            used = _covered(h, w, x0[big], x1[big], y0[big], y1[big])
        evaluate(np.concatenate([cc, cc, cd, cd, cy.reshape(-1)]), np.concatenate([ca, cb, ca, cb, cx.reshape(-1)]),
                 used)
        if used is not None:
            x0, x1, y0, y1, depth, mx, my, cx, cy = (a[big] for a in (x0, x1, y0, y1, depth, mx, my, cx, cy))
        if not len(x0):
            break
        # 3. the spot checks
        u = ((cx - x0[:, None]) / np.maximum(x1 - x0, 1)[:, None])[..., None]
        v = ((cy - y0[:, None]) / np.maximum(y1 - y0, 1)[:, None])[..., None]
        c00, c10 = H[y0, x0][:, None], H[y0, x1][:, None]
        c01, c11 = H[y1, x0][:, None], H[y1, x1][:, None]
        interp = (1 - v) * ((1 - u) * c00 + u * c10) + v * ((1 - u) * c01 + u * c11)
        miss = np.abs(H[cy, cx] - interp).max(axis=2)                  # (c, 5)
        # far-field samples (step 5): with every sample within b of its exact value, the exact samples'
        # miss is at most miss + 2b (a check sample's error plus the interpolated corners'), and the
        # interpolant of the samples is within b of the exact samples' one: estimate factor (miss + 2b) + b
        b = np.maximum(bound[cy, cx].max(axis=1), bound[[y0, y0, y1, y1], [x0, x1, x0, x1]].max(axis=0))  # (c,)
        miss = miss + 2.0 * b[:, None]
        if neighbour_check:
            nb_x, nb_y = _neighbour_misses(H, exact, bound, tx, ty, x0, mx, x1, y0, my, y1)
            miss = np.concatenate([miss, nb_x[:, None], nb_y[:, None]], axis=1)   # (c, 7)
        d = miss.max(axis=1)
        # next to a surface break (or the image border, behind which one may lie) H is not smooth:
        # at a concave junction it goes like x log x (x the distance to the junction), the spot
        # check's ratio to the interpolant's error is no longer 4 and its largest error is not at
        # the checked pixels (measured up to 1.8 d at a wall's edge): stricter test, larger estimate
        edge = _touches_break(tx, ty, x0, x1, y0, y1, w, h)
        factor = np.where(edge, EDGE_FACTOR, INNER_FACTOR)
        d = d * factor + b                                             # the estimate
        good = d <= tol
        stats.accepted += int(good.sum())
        stats.rejected += int((~good).sum())
        want_x = np.ones(len(x0), dtype=bool)
        want_y = np.ones(len(x0), dtype=bool)
        if anisotropic:
            # interpolation along y (the left and right edge midpoints) within the tolerance while
            # the rest misses: halve x alone (the children check y again at the same spacing); and
            # the converse. A kink or a break's neighbourhood along a column or row is then not
            # sampled densely along its own direction
            bad = ~good
            along_x = miss[:, 0:2].max(axis=1)
            along_y = miss[:, 2:4].max(axis=1)
            if neighbour_check:
                along_x = np.maximum(along_x, miss[:, 5])
                along_y = np.maximum(along_y, miss[:, 6])
            fine_y = factor * along_y + b <= tol
            fine_x = factor * along_x + b <= tol
            # at most MAX_ASPECT : 1 (a cell long along the passing axis tests it on few columns or
            # rows; measured: unbounded aspect let a 3-pixel valley between two kinks slip, 1.55 x
            # the tolerance on the 128² Cornell box at 1e-2)
            sx, sy = x1 - x0, y1 - y0
            want_y[bad & fine_y & ~fine_x & (sy <= MAX_ASPECT * sx // 2)] = False
            want_x[bad & fine_x & ~fine_y & (sx <= MAX_ASPECT * sy // 2)] = False
        if good.any():
            fills.append((x0[good], mx[good], x1[good], y0[good], my[good], y1[good], d[good], depth[good]))
        s = np.flatnonzero(~good)
        pending = _children(x0, x1, y0, y1, depth, s, want_x[s], want_y[s], True)

    if deferred.any():  # the final samples (step 6), in one call
        ys, xs = np.nonzero(deferred)
        stats.final_points = len(ys)
        evaluate(ys, xs, sample_tol=final_share * tol)
    # --- interpolate the accepted cells over their four sub-cells ----------------------------------
    # shallower cells first: where a cell's edge borders finer cells, the finer interpolation is the one kept
    if fills:
        x0, mx, x1, y0, my, y1, est, depth = (np.concatenate(a) for a in zip(*fills, strict=True))
        order = np.argsort(depth, kind="stable")
        for dep in np.unique(depth):
            k = order[depth[order] == dep]
            for xa, xb, ya, yb in ((x0, mx, y0, my), (mx, x1, y0, my), (x0, mx, my, y1), (mx, x1, my, y1)):
                _fill_bilinear(H, err, exact, xa[k], xb[k], ya[k], yb[k], est[k])
    err[exact] = bound[exact]
    err[~valid] = 0.0
    H[~valid] = 0.0
    stats.error_estimate = float(err.max()) if err.size else 0.0
    stats.sample_bound = float(bound.max()) if bound.size else 0.0
    return H, stats


def _surface_breaks(scene: Scene, unit, g):
    """Surface breaks between adjacent pixels (step 2): ``(brk_x (h, w-1), brk_y (h-1, w))`` bool, True where
    a pixel and its right / lower neighbour are not both hit, lie on different planes, or have unit normals
    ``unit (h, w, 3)`` more than :data:`NORMAL_JUMP` apart; ``g (h, w)`` the hit polygons' input indices."""
    valid = g >= 0
    plane = np.where(valid, _input_planes(scene)[np.maximum(g, 0)], -1)
    cos_jump = np.cos(NORMAL_JUMP)
    brk_x = ~(valid[:, :-1] & valid[:, 1:] & (plane[:, :-1] == plane[:, 1:])
              & (np.einsum("hwc,hwc->hw", unit[:, :-1], unit[:, 1:]) >= cos_jump))
    brk_y = ~(valid[:-1] & valid[1:] & (plane[:-1] == plane[1:])
              & (np.einsum("hwc,hwc->hw", unit[:-1], unit[1:]) >= cos_jump))
    return brk_x, brk_y


def _summed(a):
    """Summed-area table ``(h+1, w+1)`` int64 of ``a (h, w)``: ``t[y, x]`` = the sum of ``a[:y, :x]``."""
    t = np.zeros((a.shape[0] + 1, a.shape[1] + 1), dtype=np.int64)
    t[1:, 1:] = a.cumsum(axis=0).cumsum(axis=1)
    return t


def _children(x0, x1, y0, y1, depth, s, want_x, want_y, clear):
    """The children of cells ``s`` (indices into the cell arrays), halved along each wanted axis that still
    has an interior pixel (if none, along every one that has); along an axis not cut a child spans the whole
    cell. Returns ``[x0, x1, y0, y1, depth, clear]`` of the children (``clear`` the bool given for all)."""
    mx, my = (x0[s] + x1[s]) // 2, (y0[s] + y1[s]) // 2
    wide, tall = x1[s] - x0[s] >= 2, y1[s] - y0[s] >= 2
    cut_x, cut_y = want_x & wide, want_y & tall
    none = ~cut_x & ~cut_y
    cut_x |= none & wide
    cut_y |= none & tall
    kids = [[], [], [], [], []]
    for xa, xb, ya, yb, need_x, need_y in ((x0[s], mx, y0[s], my, False, False), (mx, x1[s], y0[s], my, True, False),
                                           (x0[s], mx, my, y1[s], False, True), (mx, x1[s], my, y1[s], True, True)):
        m = (cut_x if need_x else True) & (cut_y if need_y else True) & np.ones(len(s), dtype=bool)
        kids[0].append(np.where(cut_x[m], xa[m], x0[s][m]))
        kids[1].append(np.where(cut_x[m], xb[m], x1[s][m]))
        kids[2].append(np.where(cut_y[m], ya[m], y0[s][m]))
        kids[3].append(np.where(cut_y[m], yb[m], y1[s][m]))
        kids[4].append(depth[s][m] + 1)
    out = [np.concatenate(k) for k in kids]
    return out + [np.full(len(out[0]), clear, dtype=bool)]


def _neighbour_misses(H, exact, bound, tx, ty, x0, mx, x1, y0, my, y1):
    """The cells' interpolant extended one sample spacing beyond each side, against the exact samples there.

    For each of the three sample rows (``y0, my, y1``) the line through a cell's two end samples of that side
    (``x0, mx`` or ``mx, x1``) is extended by their spacing to the pixel just outside; where that pixel is an
    exact sample on the same surface (no break between), the miss ``|f(out) - (2 f(end) - f(mid))|`` is the
    second difference at the cell's corner, as the midpoint check's miss is half the one at its centre. A kink
    between a corner and the midpoint leaves the midpoint's second difference small while the corner's is
    not; halved, it is on the scale of the spot checks' misses. Likewise along the three sample columns (the
    same on the transposed image: ``ty.T`` is the summed-area table of the transposed breaks).
    Returns ``(along_x, along_y)`` (c,) each: half the largest such second difference (largest channel), with
    the samples' far-field bounds (4 b: weights 1, 2, 1), 0 where no check applies.
    """
    along_x = _row_extension_misses(H, exact, bound, tx, (x0, mx, x1), (y0, my, y1))
    along_y = _row_extension_misses(H.swapaxes(0, 1), exact.T, bound.T, ty.T, (y0, my, y1), (x0, mx, x1))
    return along_x, along_y


def _row_extension_misses(H, exact, bound, tx, cols, rows):
    """:func:`_neighbour_misses` along x: ``cols = (x0, mx, x1)``, ``rows`` the cells' three sample rows."""
    w = exact.shape[1]
    lo, mid, hi = cols
    out = np.zeros(len(lo))
    for end in (lo, hi):
        s = end - mid                                        # toward the outside: -(spacing) or +(spacing)
        o = end + s
        ok = (s != 0) & (o >= 0) & (o < w)
        o = np.clip(o, 0, w - 1)
        a, z = np.minimum(o, end), np.maximum(o, end)        # the links between the outside pixel and the end
        for y in rows:
            sel = ok & exact[y, o] & (_box_sum(tx, y, y, a, z - 1) == 0)
            d2 = np.abs(H[y, o] - 2.0 * H[y, end] + H[y, mid]).max(axis=1)
            b = np.maximum(np.maximum(bound[y, o], bound[y, end]), bound[y, mid])
            np.maximum(out, np.where(sel, 0.5 * d2 + 2.0 * b, 0.0), out=out)
    return out


def _uniform(valid, tx, ty, x0, x1, y0, y1):
    """(c,) True where cells ``[x0, x1] × [y0, y1]`` hold no surface break (step 2, *surface*): their first
    pixel hit (``valid (h, w)``) and no break between two of their pixels (``tx, ty``: :func:`_summed` tables
    of :func:`_surface_breaks`)."""
    ok = valid[y0, x0].copy()
    wide = x1 > x0
    ok[wide] &= _box_sum(tx, y0[wide], y1[wide], x0[wide], x1[wide] - 1) == 0
    tall = y1 > y0
    ok[tall] &= _box_sum(ty, y0[tall], y1[tall] - 1, x0[tall], x1[tall]) == 0
    return ok


def _box_sum(t, y0, y1, x0, x1):
    """Sum over the inclusive pixel ranges ``[y0, y1] × [x0, x1]`` of the table ``t`` made by :func:`_summed`
    (empty ranges sum to 0)."""
    return t[y1 + 1, x1 + 1] - t[y0, x1 + 1] - t[y1 + 1, x0] + t[y0, x0]


def _covered(h, w, x0, x1, y0, y1):
    """(h, w) bool: True on every pixel of the rectangles ``[x0, x1] × [y0, y1]`` (inclusive), by a 2-D
    difference table (O(h w + rectangles))."""
    d = np.zeros((h + 1, w + 1), dtype=np.int64)
    np.add.at(d, (y0, x0), 1)
    np.add.at(d, (y0, x1 + 1), -1)
    np.add.at(d, (y1 + 1, x0), -1)
    np.add.at(d, (y1 + 1, x1 + 1), 1)
    return d.cumsum(axis=0).cumsum(axis=1)[:h, :w] > 0


def _touches_break(tx, ty, x0, x1, y0, y1, w, h):
    """(c,) True where cell ``[x0, x1] × [y0, y1]`` touches the image border or has a surface break
    between one of its pixels and a pixel just outside (``tx, ty`` summed-area tables of the breaks)."""
    border = (x0 == 0) | (y0 == 0) | (x1 == w - 1) | (y1 == h - 1)
    a0, a1 = np.maximum(x0 - 1, 0), np.minimum(x1, w - 2)       # horizontal links of the grown cell
    b0, b1 = np.maximum(y0 - 1, 0), np.minimum(y1, h - 2)
    return border | (_box_sum(tx, y0, y1, a0, a1) > 0) | (_box_sum(ty, b0, b1, x0, x1) > 0)


def _fill_bilinear(H, err, exact, x0, x1, y0, y1, est):
    """Bilinear interpolation inside rectangles ``[x0, x1] × [y0, y1]`` (inclusive, exact corners) of every
    pixel that is not exact; ``err`` takes the largest ``est`` of the rectangles covering a pixel."""
    nx, ny = x1 - x0 + 1, y1 - y0 + 1
    count = nx * ny
    if not count.sum():
        return
    cell = np.repeat(np.arange(len(x0)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    ly, lx = np.divmod(local, nx[cell])
    xs, ys = x0[cell] + lx, y0[cell] + ly
    keep = ~exact[ys, xs]
    cell, xs, ys, lx, ly = cell[keep], xs[keep], ys[keep], lx[keep], ly[keep]
    u = (lx / np.maximum(x1 - x0, 1)[cell])[:, None]
    v = (ly / np.maximum(y1 - y0, 1)[cell])[:, None]
    c00, c10 = H[y0[cell], x0[cell]], H[y0[cell], x1[cell]]
    c01, c11 = H[y1[cell], x0[cell]], H[y1[cell], x1[cell]]
    H[ys, xs] = (1 - v) * ((1 - u) * c00 + u * c10) + v * ((1 - u) * c01 + u * c11)
    np.maximum.at(err, (ys, xs), est[cell])
