"""The one pipeline of the local pass: every entry point (operator, ``blender -c`` command, plain
Python in the bpy module or under Blender 3.4's ``--python-expr``) calls :func:`run_local_pass`.

Pixels mode::

    Blender scene --scene_export--> core Scene, rho, E per polygon
    scene camera  --camera-->       one ray per pixel centre (k x k samples)
    core.raycast.cast_rays           visible point P, polygon, side
    core.form_factors / irradiance   H(P) on the hit side, sum of F
    L = E + rho / pi * H             (eq. 5) -> OpenEXR, "Local Pass" image, PNG preview

Vertices mode: the selected meshes' vertices (or corners) become receivers (one-sided limit from
inside their faces) and the results go into ``hlp_radiance`` / ``hlp_irradiance`` colour attributes.

Receivers are evaluated in chunks of fixed size (a function of the job only), so a run that was
interrupted and resumed computes exactly the same chunks as an uninterrupted one and writes the same
file. Finished chunks go to a checkpoint ``<output>.checkpoint.npz`` (replaced atomically after each
chunk, removed when the job completes); ``resume=True`` continues from it.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax; newer bpy APIs behind hasattr.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np

__all__ = ["JobReport", "cli_main", "parse_tile", "run_local_pass", "tile_window"]

#: Receivers per chunk are ``clip(ceil(m / CHUNKS_PER_JOB), MIN_CHUNK, MAX_CHUNK)``: few enough
#: checkpoint writes, small enough that an interruption loses little.
CHUNKS_PER_JOB = 100
MIN_CHUNK = 64
MAX_CHUNK = 4096
#: Largest (receivers x input polygons) form-factor block per chunk (32 MB of float64).
MAX_ELEMENTS = 2**22
#: Name of the image datablock that receives the pixels-mode result.
IMAGE_NAME = "Local Pass"
_CHECKPOINT_VERSION = 1


@dataclass
class JobReport:
    """What a local-pass job did.

    Attributes:
        mode: "pixels" or "vertices".
        points: receiver points evaluated (hit samples, or vertices/corners).
        seconds: wall-clock time of the whole job.
        max_form_factor_error: max |sum F - 1| over the receivers (0 in a closed scene up to rounding;
            large where a receiver sees the open sky).
        black_occluders: objects without the radiosity attribute exported as black occluders.
        dropped_polygons: degenerate polygons the core dropped ("Object.polygon i: reason").
        outputs: files written (EXR, PNG) and attributes written ("Object:hlp_radiance").
        image_size, window: pixels mode: (W, H) and the computed (x0, y0, x1, y1).
        resumed_points: receivers taken from a checkpoint instead of being computed.
        cancelled: the job stopped early (finished chunks are in the checkpoint).
        objects: names of the exported objects; the EXR's ``object_index`` indexes this list.
        result: the float64 results: pixels mode the image layers of the window (see
            :mod:`.outputs`; row 0 at the bottom); vertices mode ``{object name: (domain, radiance,
            irradiance, computed mask)}``.
    """

    mode: str
    points: int = 0
    seconds: float = 0.0
    max_form_factor_error: float = 0.0
    black_occluders: list = field(default_factory=list)
    dropped_polygons: list = field(default_factory=list)
    outputs: list = field(default_factory=list)
    image_size: tuple | None = None
    window: tuple | None = None
    resumed_points: int = 0
    cancelled: bool = False
    objects: list = field(default_factory=list, repr=False)
    result: dict = field(default_factory=dict, repr=False)

    @property
    def points_per_second(self) -> float:
        computed = self.points - self.resumed_points
        return computed / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        """One line for the UI and the command line."""
        parts = [f"{self.points} points in {self.seconds:.1f} s ({self.points_per_second:.0f} points/s)",
                 f"max |sum F - 1| = {self.max_form_factor_error:.2e}"]
        if self.black_occluders:
            parts.append(f"{len(self.black_occluders)} black occluder(s)")
        if self.dropped_polygons:
            parts.append(f"{len(self.dropped_polygons)} degenerate polygon(s) dropped")
        return "Local pass: " + ", ".join(parts)


# ---------------------------------------------------------------------------------------- helpers
def parse_tile(tile) -> tuple:
    """``"I/N"`` (1-based, ``1 <= I <= N``) -> ``(I, N)``."""
    if isinstance(tile, (tuple, list)):
        i, n = (int(v) for v in tile)
    else:
        try:
            i_s, n_s = str(tile).split("/")
            i, n = int(i_s), int(n_s)
        except ValueError:
            raise ValueError(f"tile must look like I/N (e.g. 2/8), got {tile!r}") from None
    if not (n >= 1 and 1 <= i <= n):
        raise ValueError(f"tile {i}/{n}: need 1 <= I <= N")
    return i, n


def tile_window(window, tile) -> tuple:
    """Row band ``I`` of ``N`` of the pixel window (bands counted from the top row down, sizes
    differing by at most one row)."""
    i, n = parse_tile(tile)
    x0, y0, x1, y1 = window
    rows = y1 - y0
    if n > rows:
        raise ValueError(f"tile {i}/{n}: the window has only {rows} rows")
    top = y1 - (rows * (i - 1)) // n
    bottom = y1 - (rows * i) // n
    return x0, bottom, x1, top


def _chunk_size(m: int, n_input: int = 0) -> int:
    """Receivers per chunk: a function of the job only (receivers m, input polygons n_input), so a
    resumed run computes the same chunks. The dense (chunk, n_input) form-factor arrays stay below
    ``MAX_ELEMENTS`` entries."""
    size = min(MAX_CHUNK, max(MIN_CHUNK, math.ceil(m / CHUNKS_PER_JOB)))
    return int(max(1, min(size, MAX_ELEMENTS // max(n_input, 1))))


def _settings(scene):
    return getattr(scene, "hlp_settings", None)


def _digest(*arrays) -> str:
    h = hashlib.sha1()
    for a in arrays:
        if isinstance(a, np.ndarray):
            h.update(str(a.dtype).encode() + str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())
        else:
            h.update(repr(a).encode())
    return h.hexdigest()


class _Progress:
    """Maps chunk progress to ``progress(done, total)`` over the whole job."""

    def __init__(self, callback, total, already=0):
        self.callback = callback
        self.total = total
        self.base = already

    def inner(self, size):
        if self.callback is None:
            return None
        base = self.base

        def report(done, total):
            self.callback(base + int(round(size * done / max(total, 1))), self.total)

        return report

    def advance(self, size):
        self.base += size
        if self.callback is not None:
            self.callback(self.base, self.total)


def _evaluate(exported, points, normals, limit, progress, cancel):
    """H (m, 3) and sum F (m,) at the receivers.

    In general two core calls: ``core.irradiance`` (front sides emit, linear radiance integrated
    exactly) and ``core.form_factors``. When the radiance is constant, no receiver has a limit
    direction and every input polygon is one convex polygon, one ``form_factors`` call gives both:
    a plane's front side is visible exactly from the points in front of it, so
    ``H = c * sum_i [P in front of polygon i] F_i L_i`` — eq. 3, with ``c`` the core's own ratio
    ``irradiance / sum F`` measured on a probe (so the result follows the core's convention).
    """
    from ..core import form_factors, irradiance

    scene = exported.scene
    kw = {"limit_directions": limit, "cancel": cancel}
    fast = _constant_planes(exported) if limit is None else None
    if fast is not None:
        normals_in, offsets_in, radiance_in = fast
        ff = form_factors(scene, points, normals, **kw)  # (m, n_input)
        if not scene.double_sided:
            side = points @ normals_in.T - offsets_in  # (m, n_input) signed distances
            ff_lit = np.where(side > 0.0, ff, 0.0)
        else:
            ff_lit = ff
        # einsum's own loops (not BLAS): each row's sum is independent of the chunk's other rows
        h = np.einsum("mn,nc->mc", ff_lit, radiance_in, optimize=False)
        return np.pi * h, ff.sum(axis=1)  # the core's irradiance is eq. 1: H = pi sum L F
    h = irradiance(scene, points, normals, **kw)
    if progress is not None:
        progress(1, 2)
    ff = form_factors(scene, points, normals, **kw)  # (m, n_input)
    return h, ff.sum(axis=1)


def _constant_planes(exported):
    """``(normals (n_in, 3), offsets (n_in,), radiance (n_in, 3))`` per input polygon when the scene
    has constant radiance and no input polygon was split; else None. Cached on the export."""
    cached = getattr(exported, "_hlp_planes", False)
    if cached is not False:
        return cached
    scene = exported.scene
    result = None
    if not scene.linear and np.bincount(scene.poly_source, minlength=scene.n_input).max(initial=0) <= 1:
        n_in = scene.n_input
        normals_in = np.zeros((n_in, 3))
        offsets_in = np.full(n_in, np.inf)  # dropped polygons: never in front (and F = 0)
        radiance_in = np.zeros((n_in, 3))
        normals_in[scene.poly_source] = scene.poly_normals
        offsets_in[scene.poly_source] = scene.poly_offsets
        radiance_in[scene.poly_source] = scene.poly_radiance
        result = (normals_in, offsets_in, radiance_in)
    exported._hlp_planes = result
    return result


class _Checkpoint:
    """Finished chunks of a job: ``<output>.checkpoint.npz``, replaced atomically after each chunk."""

    def __init__(self, path, fingerprint, m, chunk):
        self.path = path
        self.fingerprint = fingerprint
        self.chunk = chunk
        n_chunks = (m + chunk - 1) // chunk
        self.done = np.zeros(n_chunks, dtype=bool)
        self.h = np.zeros((m, 3))
        self.fsum = np.zeros(m)

    def load(self) -> bool:
        """Take over a matching checkpoint file; False when there is none or it belongs to another job."""
        if self.path is None or not os.path.isfile(self.path):
            return False
        try:
            with np.load(self.path, allow_pickle=False) as z:
                if (str(z["fingerprint"]) != self.fingerprint or int(z["chunk"]) != self.chunk
                        or z["h"].shape != self.h.shape or int(z["version"]) != _CHECKPOINT_VERSION):
                    return False
                self.done[:] = z["done"]
                self.h[:] = z["h"]
                self.fsum[:] = z["fsum"]
        except (OSError, KeyError, ValueError):
            return False
        return True

    def save(self):
        if self.path is None:
            return
        from .outputs import replace_atomically

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez(fh, fingerprint=np.array(self.fingerprint), chunk=np.array(self.chunk), done=self.done,
                         h=self.h, fsum=self.fsum, version=np.array(_CHECKPOINT_VERSION))

        replace_atomically(self.path, write)

    def remove(self):
        if self.path is not None and os.path.isfile(self.path):
            os.unlink(self.path)


def _compute(exported, points, normals, limit, *, checkpoint_path, fingerprint, resume, progress, cancel, report):
    """Evaluate all receivers chunk by chunk with checkpointing -> (H (m, 3), sum F (m,))."""
    from ..core import Cancelled

    m = len(points)
    chunk = _chunk_size(m, exported.scene.n_input)
    ck = _Checkpoint(checkpoint_path, fingerprint, m, chunk)
    if resume and ck.load():
        report.resumed_points = int(sum(min(chunk, m - c * chunk) for c in np.flatnonzero(ck.done)))
    prog = _Progress(progress, m, report.resumed_points)
    try:
        for c in range(len(ck.done)):
            if ck.done[c]:
                continue
            if cancel is not None and cancel():
                raise Cancelled("local pass cancelled")
            s, e = c * chunk, min(m, (c + 1) * chunk)
            lim = None if limit is None else limit[s:e]
            h, fs = _evaluate(exported, points[s:e], normals[s:e], lim, prog.inner(e - s), cancel)
            ck.h[s:e], ck.fsum[s:e] = h, fs
            ck.done[c] = True
            ck.save()
            prog.advance(e - s)
    except (KeyboardInterrupt, Cancelled):
        report.cancelled = True
        raise
    return ck


# ---------------------------------------------------------------------------------------- pixels
def _run_pixels(scene, exported, report, *, output, region, tile, resume, samples, progress, cancel, preview, image):
    from ..core.raycast import cast_rays
    from . import camera as hcam
    from . import outputs

    params = hcam.camera_params(scene)
    size = hcam.image_size(params)
    window = hcam.pixel_window(params, region)
    full_window = window
    if tile is not None:
        window = tile_window(window, tile)
    report.image_size, report.window = size, window
    px, py, sx, sy = hcam.pixel_samples(window, samples)
    k2 = sx.shape[1]
    origins, directions, t0, t1 = hcam.camera_rays(params, sx, sy)
    core_scene = exported.scene
    hits = cast_rays(core_scene, origins, directions, t_min=t0, t_max=t1)
    hit = hits.hit
    poly = hits.polygon[hit]
    src = hits.source[hit]
    front = hits.front[hit]
    nrm = core_scene.poly_normals[poly]
    normals = np.where(front[:, None], nrm, -nrm)  # the receiver's hemisphere faces the camera
    # put P exactly on the hit polygon's plane (removes the ray's rounding off the plane)
    pts = hits.point[hit]
    pts = pts - (np.einsum("ij,ij->i", nrm, pts) - core_scene.poly_offsets[poly])[:, None] * nrm

    fingerprint = _digest("pixels", core_scene.poly_vertices, core_scene.poly_radiance,
                          core_scene.corner_radiance if core_scene.linear else 0, pts, normals)
    ck_path = None if output is None else os.path.abspath(output) + ".checkpoint.npz"
    ck = _compute(exported, pts, normals, None, checkpoint_path=ck_path, fingerprint=fingerprint, resume=resume,
                  progress=progress, cancel=cancel, report=report)
    h_hit, fsum_hit = ck.h, ck.fsum
    report.points = len(pts)
    report.max_form_factor_error = float(np.abs(fsum_hit - 1.0).max()) if len(pts) else 0.0

    emits = exported.emission[src] * (front | core_scene.double_sided)[:, None]
    l_hit = emits + exported.reflectivity[src] / np.pi * h_hit  # eq. 5

    n_samples = len(hit)
    radiance = np.zeros((n_samples, 3))
    irr = np.zeros((n_samples, 3))
    fsum = np.zeros(n_samples)
    radiance[hit], irr[hit], fsum[hit] = l_hit, h_hit, fsum_hit
    npix = len(px)
    hit2 = hit.reshape(npix, k2)
    cover = hit2.mean(axis=1)
    lay_rad = radiance.reshape(npix, k2, 3).mean(axis=1)
    lay_irr = irr.reshape(npix, k2, 3).mean(axis=1)
    n_hit = hit2.sum(axis=1)
    lay_f = np.where(n_hit > 0, fsum.reshape(npix, k2).sum(axis=1) / np.maximum(n_hit, 1), 0.0)
    centre = (k2 // 2) if samples % 2 else (samples // 2) * samples + samples // 2  # sample nearest the centre
    cidx = np.arange(npix) * k2 + centre
    chit = hit[cidx]
    depth = np.where(chit, hits.t[cidx], outputs.MISS_DEPTH)
    src_all = hits.source[cidx]
    obj_idx = np.where(chit, exported.polygon_object[np.maximum(src_all, 0)], -1)
    pol_idx = np.where(chit, exported.polygon_index[np.maximum(src_all, 0)], -1)

    x0, y0, x1, y1 = window
    shape = (y1 - y0, x1 - x0)
    layers = {
        "radiance": lay_rad.reshape(shape + (3,)), "irradiance": lay_irr.reshape(shape + (3,)),
        "alpha": cover.reshape(shape), "form_factor_sum": lay_f.reshape(shape), "depth": depth.reshape(shape),
        "object_index": obj_idx.reshape(shape).astype(np.float64),
        "polygon_index": pol_idx.reshape(shape).astype(np.float64),
    }
    report.result = layers
    job_id = _digest(core_scene.poly_vertices, core_scene.poly_radiance, exported.reflectivity, exported.emission,
                     size, params.fingerprint(), samples, full_window)
    meta = {"hlp_fingerprint": job_id}  # the same for every tile of one job
    if tile is not None:
        meta["hlp_tile"] = "{}/{}".format(*parse_tile(tile))
    if output is not None:
        report.outputs.append(outputs.write_exr(output, layers, size=size, window=window, metadata=meta))
        if preview:
            png = os.path.splitext(output)[0] + ".png"
            full = np.zeros((size[1], size[0], 3))
            full[y0:y1, x0:x1] = layers["radiance"]
            report.outputs.append(outputs.write_png(png, full))
        ck.remove()
    if image:
        rgba = np.zeros((size[1], size[0], 4))
        rgba[y0:y1, x0:x1, :3] = layers["radiance"]
        rgba[y0:y1, x0:x1, 3] = layers["alpha"]
        outputs.store_image(IMAGE_NAME, rgba)
    return layers


# -------------------------------------------------------------------------------------- vertices
def _selected_meshes(scene, view_layer):
    obs = [ob for ob in scene.objects if ob.type == "MESH" and ob.select_get(view_layer=view_layer)]
    if not obs:
        raise ValueError("vertices mode needs at least one selected mesh object")
    return obs


def _newell(verts, loops, start, total) -> np.ndarray:
    """(P, 3) unit Newell normals of polygons (vectorised over corners)."""
    v = verts[loops]  # (L, 3)
    poly = np.repeat(np.arange(len(start)), total)
    nxt_idx = np.arange(len(loops)) + 1
    last = start + total - 1
    nxt_idx[last] = start  # wrap around each polygon
    cross = np.cross(v, v[nxt_idx])
    area = np.zeros((len(start), 3))
    np.add.at(area, poly, cross)
    norm = np.linalg.norm(area, axis=1, keepdims=True)
    return area / np.where(norm > 0, norm, 1.0)


def _tangent_towards(target, point, normal) -> np.ndarray:
    """Unit vectors from ``point`` towards ``target`` projected into the plane normal to ``normal``."""
    d = target - point
    d = d - np.einsum("ij,ij->i", d, normal)[:, None] * normal
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.where(n > 0, d / np.where(n > 0, n, 1.0), 0.0)


def _receivers(ob, mesh, matrix):
    """Receiver points of one original mesh in world space.

    Returns ``(domain, points (n, 3), normals (n, 3), limits (n, 3), corner_poly (L,), elem_of_corner)``:
    CORNER domain (some face flat): one receiver per corner, the face normal for flat faces and the
    vertex normal for smooth ones, the limit direction towards the face centroid; POINT domain (all
    faces smooth): one receiver per vertex, its normal, the limit direction the normalised sum of
    the directions to the adjacent faces' centroids.
    """
    from .scene_export import mesh_arrays, polygon_of_corner

    arrays = mesh_arrays(mesh)
    m = np.asarray(matrix, dtype=np.float64).reshape(4, 4)
    lin = m[:3, :3]
    world = arrays.vertices @ lin.T + m[:3, 3]
    det = np.linalg.det(lin)
    face_n = _newell(world, arrays.loop_vertices, arrays.loop_start, arrays.loop_total)
    if det < 0:
        face_n = -face_n  # the exported scene reverses mirrored polygons: same front side
    vn = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    if len(mesh.vertices):
        mesh.vertices.foreach_get("normal", vn)
    vn = vn.reshape(-1, 3).astype(np.float64) @ np.linalg.inv(lin)  # inverse transpose, row vectors
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
    cpoly = polygon_of_corner(arrays)
    centroid = np.add.reduceat(world[arrays.loop_vertices], arrays.loop_start, axis=0) / arrays.loop_total[:, None]
    if arrays.n_polygons and arrays.use_smooth.all():
        n_v = len(world)
        lim = np.zeros((n_v, 3))
        corner_dir = _tangent_towards(centroid[cpoly], world[arrays.loop_vertices], vn[arrays.loop_vertices])
        np.add.at(lim, arrays.loop_vertices, corner_dir)
        first = np.full(n_v, -1, dtype=np.int64)
        first[arrays.loop_vertices[::-1]] = np.arange(len(arrays.loop_vertices))[::-1]
        norm = np.linalg.norm(lim, axis=1)
        weak = (norm < 1e-6) & (first >= 0)
        lim[weak] = corner_dir[first[weak]]  # symmetric neighbourhood: use the first face's direction
        norm = np.linalg.norm(lim, axis=1, keepdims=True)
        lim = np.where(norm > 0, lim / np.where(norm > 0, norm, 1.0), 0.0)
        return "POINT", world, vn, lim, arrays, cpoly
    smooth_c = arrays.use_smooth[cpoly]
    pts = world[arrays.loop_vertices]
    nrm = np.where(smooth_c[:, None], vn[arrays.loop_vertices], face_n[cpoly])
    lim = _tangent_towards(centroid[cpoly], pts, nrm)
    return "CORNER", pts, nrm, lim, arrays, cpoly


def _receiver_materials(ob, mesh, arrays, rho_attr, emit_attr):
    """(P, 3) rho and E of the polygons of an original mesh (attributes, else material, else defaults)."""
    from .scene_export import _per_polygon, material_colours, read_attribute

    rho_vals = read_attribute(mesh, arrays, rho_attr, ob.name, allow_grey=True) if rho_attr else None
    emit_vals = read_attribute(mesh, arrays, emit_attr, ob.name, allow_grey=True) if emit_attr else None
    slots = [s.material for s in ob.material_slots] or [None]
    table = [material_colours(mat) for mat in slots]
    slot = np.clip(arrays.material_index, 0, len(table) - 1)
    rho = _per_polygon(arrays, *rho_vals) if rho_vals is not None else np.array([t[0] for t in table])[slot]
    emit = _per_polygon(arrays, *emit_vals) if emit_vals is not None else np.array([t[1] for t in table])[slot]
    return rho.reshape(-1, 3), emit.reshape(-1, 3)


def _run_vertices(scene, view_layer, exported, report, *, attribute, rho_attr, emit_attr, radiance_attribute,
                  irradiance_attribute, output, resume, progress, cancel, explicit_targets):
    import bpy

    from . import outputs

    obs = _selected_meshes(scene, view_layer)
    edit_objects = [ob for ob in obs if ob.mode == "EDIT"]
    if edit_objects:
        for ob in edit_objects:
            ob.update_from_editmode()
    depsgraph = view_layer.depsgraph
    jobs = []
    for ob in obs:
        mesh = ob.data
        for name in (radiance_attribute, irradiance_attribute):
            outputs.prepare_vertex_attribute(mesh, name, "", protected=(attribute, rho_attr, emit_attr),
                                             explicit=name in explicit_targets)
        matrix = np.array(ob.evaluated_get(depsgraph).matrix_world, dtype=np.float64)
        domain, pts, nrm, lim, arrays, cpoly = _receivers(ob, mesh, matrix)
        rho, emit = _receiver_materials(ob, mesh, arrays, rho_attr, emit_attr)
        if domain == "POINT":
            count = np.bincount(arrays.loop_vertices, minlength=len(pts)).astype(np.float64)[:, None]
            rho_r = np.zeros((len(pts), 3))
            emit_r = np.zeros((len(pts), 3))
            np.add.at(rho_r, arrays.loop_vertices, rho[cpoly])
            np.add.at(emit_r, arrays.loop_vertices, emit[cpoly])
            rho_r /= np.maximum(count, 1)
            emit_r /= np.maximum(count, 1)
        else:
            rho_r, emit_r = rho[cpoly], emit[cpoly]
        mask = None
        if ob.mode == "EDIT" or ob in edit_objects:
            sel = np.zeros(len(mesh.vertices), dtype=bool)
            if len(sel):
                mesh.vertices.foreach_get("select", sel)
            mask = sel if domain == "POINT" else sel[arrays.loop_vertices]
        used = np.ones(len(pts), dtype=bool) if domain == "CORNER" else np.bincount(
            arrays.loop_vertices, minlength=len(pts)) > 0  # loose vertices are no receivers
        todo = used if mask is None else used & mask
        jobs.append((ob, domain, pts, nrm, lim, rho_r, emit_r, mask, todo))
    all_pts = np.concatenate([j[2][j[8]] for j in jobs])
    all_nrm = np.concatenate([j[3][j[8]] for j in jobs])
    all_lim = np.concatenate([j[4][j[8]] for j in jobs])
    core_scene = exported.scene
    fingerprint = _digest("vertices", core_scene.poly_vertices, core_scene.poly_radiance,
                          core_scene.corner_radiance if core_scene.linear else 0, all_pts, all_nrm, all_lim)
    ck_path = None if output is None else os.path.abspath(output) + ".checkpoint.npz"
    ck = _compute(exported, all_pts, all_nrm, all_lim, checkpoint_path=ck_path, fingerprint=fingerprint,
                  resume=resume, progress=progress, cancel=cancel, report=report)
    report.points = len(all_pts)
    report.max_form_factor_error = float(np.abs(ck.fsum - 1.0).max()) if len(all_pts) else 0.0
    results = {}
    mode_restore = None
    if edit_objects and bpy.context.mode.startswith("EDIT"):
        mode_restore = "EDIT"
        bpy.ops.object.mode_set(mode="OBJECT")  # attribute edits must not be overwritten by the edit mesh
    try:
        s = 0
        for ob, domain, pts, _nrm, _lim, rho_r, emit_r, _mask, todo in jobs:
            n = int(todo.sum())
            h = np.zeros((len(pts), 3))
            h[todo] = ck.h[s:s + n]
            s += n
            radiance = emit_r + rho_r / np.pi * h  # eq. 5
            outputs.write_vertex_colours(ob.data, radiance_attribute, domain, radiance, todo)
            outputs.write_vertex_colours(ob.data, irradiance_attribute, domain, h, todo)
            ob.data.update()
            report.outputs += [f"{ob.name}:{radiance_attribute}", f"{ob.name}:{irradiance_attribute}"]
            results[ob.name] = (domain, radiance, h, todo)
    finally:
        if mode_restore:
            bpy.ops.object.mode_set(mode=mode_restore)
    ck.remove()
    report.result = results
    return results


# ------------------------------------------------------------------------------------------- job
def run_local_pass(
    scene=None,
    *,
    output=None,
    mode=None,
    attribute=None,
    region=None,
    tile=None,
    resume=False,
    samples=None,
    missing=None,
    progress=None,
    cancel=None,
    reflectivity_attribute=None,
    emission_attribute=None,
    double_sided=None,
    radiance_attribute=None,
    irradiance_attribute=None,
    preview=True,
    image=True,
    view_layer=None,
):
    """Run the exact local pass on ``scene`` (default: the context's scene).

    Arguments left at ``None`` come from the scene's settings (``scene.hlp_settings`` when the
    extension is registered), else the defaults: ``mode="pixels"``, ``attribute="radiosity"``,
    ``samples=1``, ``missing="error"``, ``reflectivity_attribute="reflectivity"``,
    ``emission_attribute="emission"``, ``double_sided=False``.

    Args:
        output: pixels mode: the OpenEXR file (a PNG preview is written next to it unless
            ``preview=False``); ``None`` keeps the result in the "Local Pass" image only.
            Vertices mode: optional, only names the checkpoint file.
        mode: "pixels" or "vertices".
        attribute: the radiosity attribute.
        region: (x0, y0, x1, y1) pixels (x from the left, y from the bottom, half-open); default the
            render border if enabled, else the whole image.
        tile: "I/N": compute row band I of N (1-based, from the top) of the window and write a
            partial EXR (assemble with :func:`hemisphere_local_pass.blender.outputs.merge_exr`).
        resume: continue from ``<output>.checkpoint.npz`` if it matches this job.
        samples: k for k x k rays per pixel.
        missing: "error" or "black" (objects without the attribute become black occluders).
        progress: ``progress(done, total)`` receivers; cancel: ``cancel() -> bool``.
        radiance_attribute, irradiance_attribute: vertices mode targets (default ``hlp_radiance``,
            ``hlp_irradiance``); an existing attribute of that name is overwritten only if it was
            made by this extension or is named here explicitly.
        image: store the pixels in the image datablock "Local Pass".

    Returns:
        :class:`JobReport`.

    Raises:
        ValueError: bad input (message names the object / attribute / polygon).
        hemisphere_local_pass.core.Cancelled, KeyboardInterrupt: stopped; finished chunks are in
            the checkpoint.
    """
    import bpy

    start = time.perf_counter()
    if scene is None:
        scene = bpy.context.scene
    settings = _settings(scene)

    def pick(value, prop, default, convert=None):
        if value is not None:
            return value
        if settings is not None and hasattr(settings, prop):
            v = getattr(settings, prop)
            return convert(v) if convert else v
        return default

    mode = str(pick(mode, "mode", "pixels", str.lower)).lower()
    attribute = pick(attribute, "attribute", "radiosity")
    samples = int(pick(samples, "samples", 1))
    missing = str(pick(missing, "missing_attribute", "error", str.lower)).lower()
    rho_attr = pick(reflectivity_attribute, "reflectivity_attribute", "reflectivity")
    emit_attr = pick(emission_attribute, "emission_attribute", "emission")
    double_sided = bool(pick(double_sided, "double_sided", False))
    if mode not in ("pixels", "vertices"):
        raise ValueError(f"mode must be 'pixels' or 'vertices', got {mode!r}")
    if not attribute:
        raise ValueError("the radiosity attribute name is empty")
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    if tile is not None:
        parse_tile(tile)
        if mode != "pixels":
            raise ValueError("--tile applies to pixels mode only")
    if output is not None:
        from .outputs import check_writable

        output = check_writable(output)
    elif tile is not None:
        raise ValueError("a tile needs an output file")
    if view_layer is None:
        ctx_layer = getattr(bpy.context, "view_layer", None)
        view_layer = ctx_layer if ctx_layer is not None and ctx_layer.id_data == scene else scene.view_layers[0]
    if mode == "pixels":
        from .camera import camera_params

        camera_params(scene)  # no camera: fail before the (slow) export

    from .scene_export import export_scene

    exported = export_scene(scene, view_layer=view_layer, attribute=attribute, reflectivity_attribute=rho_attr,
                            emission_attribute=emit_attr, missing=missing, double_sided=double_sided)
    report = JobReport(mode=mode, black_occluders=list(exported.black_occluders),
                       dropped_polygons=exported.dropped_names(), objects=list(exported.objects))
    try:
        if mode == "pixels":
            _run_pixels(scene, exported, report, output=output, region=region, tile=tile, resume=resume,
                        samples=samples, progress=progress, cancel=cancel, preview=preview, image=image)
        else:
            explicit = {n for n in (radiance_attribute, irradiance_attribute) if n}
            _run_vertices(scene, view_layer, exported, report, attribute=attribute, rho_attr=rho_attr,
                          emit_attr=emit_attr, radiance_attribute=radiance_attribute or "hlp_radiance",
                          irradiance_attribute=irradiance_attribute or "hlp_irradiance", output=output,
                          resume=resume, progress=progress, cancel=cancel, explicit_targets=explicit)
    finally:
        report.seconds = time.perf_counter() - start
    return report


# ------------------------------------------------------------------------------------------- CLI
class _StderrProgress:
    """Percent, points/s and ETA on stderr, at most every ``interval`` seconds (and at the end)."""

    def __init__(self, stream=None, interval=1.0):
        self.stream = stream if stream is not None else sys.stderr
        self.interval = interval
        self.start = None
        self.first = None
        self.last = 0.0

    def __call__(self, done, total):
        now = time.perf_counter()
        if self.start is None:
            self.start, self.first = now, done
        if now - self.last < self.interval and done < total:
            return
        self.last = now
        rate = (done - self.first) / (now - self.start) if now > self.start else 0.0
        eta = (total - done) / rate if rate > 0 else float("nan")
        pct = 100.0 * done / total if total else 100.0
        eta_s = f"{eta:.0f} s" if math.isfinite(eta) else "?"
        self.stream.write(f"hemisphere_local_pass: {pct:5.1f}% {done}/{total} points, {rate:.0f} points/s, "
                          f"ETA {eta_s}\n")
        self.stream.flush()


def _region(values):
    if values is None:
        return None
    return tuple(int(v) for v in values)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="blender --command hemisphere_local_pass",
        description="Exact local pass of two-pass global illumination for the loaded .blend file.",
    )
    sub = parser.add_subparsers(dest="command", metavar="{render,merge,solve}")
    sub.required = True
    r = sub.add_parser("render", help="compute the local pass (pixels: EXR + PNG; vertices: colour attributes)")
    r.add_argument("--output", "-o", help="pixels: the OpenEXR file (a PNG preview goes next to it); "
                   "vertices: the .blend file to save with the colour attributes")
    r.add_argument("--mode", choices=("pixels", "vertices"), default=None)
    r.add_argument("--attribute", default=None, help="radiosity attribute (default: scene setting or 'radiosity')")
    r.add_argument("--region", nargs=4, type=int, metavar=("X0", "Y0", "X1", "Y1"),
                   help="pixel window, x from the left, y from the bottom, half-open")
    r.add_argument("--tile", metavar="I/N", help="compute row band I of N (1-based, from the top) as a partial EXR")
    r.add_argument("--resume", action="store_true", help="continue from OUTPUT.checkpoint.npz")
    r.add_argument("--samples", type=int, default=None, metavar="K", help="K x K rays per pixel")
    r.add_argument("--missing", choices=("error", "black"), default=None,
                   help="objects without the attribute: error (default) or black occluders")
    r.add_argument("--no-preview", action="store_true", help="do not write the PNG preview")
    r.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    sub.add_parser("solve", add_help=False, help="first pass: solve radiosity and write the FACE-domain attribute "
                   "(options: solve --help; hemisphere_local_pass.blender.first_pass)")
    m = sub.add_parser("merge", help="assemble tile EXRs into one image")
    m.add_argument("tiles", nargs="+", metavar="TILE_FILES")
    m.add_argument("--output", "-o", required=True)
    return parser


def _save_blend(path: str) -> str:
    """Save a copy of the current file (with the new attributes) to ``path``, atomically."""
    import bpy

    from .outputs import replace_atomically

    def save(tmp):
        os.unlink(tmp)  # a new file: Blender then keeps no .blend1 backup of the placeholder
        bpy.ops.wm.save_as_mainfile(filepath=tmp, copy=True)

    return replace_atomically(path, save)


def cli_main(argv) -> int:
    """The ``blender --command hemisphere_local_pass`` program: returns the exit code; errors are
    one line on stderr (exit 1), Ctrl-C exits 130 after the finished chunks are saved."""
    if list(argv)[:1] == ["solve"]:  # the first pass: its own program (blender/first_pass.py)
        from .first_pass import cli_main as solve_main

        return solve_main(list(argv)[1:])
    parser = build_parser()
    args = parser.parse_args(list(argv))
    prefix = "hemisphere_local_pass: "
    try:
        if args.command == "merge":
            from .outputs import merge_exr

            path = merge_exr(args.tiles, os.path.abspath(args.output))
            print(f"{prefix}merged {len(args.tiles)} tile(s) into {path}")
            return 0
        import bpy

        mode = args.mode
        settings = _settings(bpy.context.scene)
        if mode is None:
            mode = str(settings.mode).lower() if settings is not None else "pixels"
        if args.output is None:
            raise ValueError("render needs --output FILE.exr (pixels mode) or --output FILE.blend (vertices mode)")
        output = os.path.abspath(args.output)
        if mode == "vertices" and not output.lower().endswith(".blend"):
            raise ValueError("in vertices mode --output names the .blend file to save the colour attributes to")
        report = run_local_pass(
            output=output, mode=mode, attribute=args.attribute, region=_region(args.region),
            tile=args.tile, resume=args.resume, samples=args.samples, missing=args.missing,
            progress=None if args.quiet else _StderrProgress(), preview=not args.no_preview,
        )
        if mode == "vertices":
            report.outputs.append(_save_blend(output))
    except KeyboardInterrupt:
        print(f"{prefix}interrupted; finished chunks are saved, rerun with --resume to continue", file=sys.stderr)
        return 130
    except Exception as exc:  # one line, non-zero: the command is for scripts and render farms
        from ..core import Cancelled

        if isinstance(exc, Cancelled):
            print(f"{prefix}cancelled; finished chunks are saved, rerun with --resume", file=sys.stderr)
            return 130
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        kind = "" if isinstance(exc, (ValueError, OSError)) else f"{type(exc).__name__}: "
        print(f"{prefix}error: {kind}{msg}", file=sys.stderr)
        return 1
    print(f"{prefix}{report.summary()}")
    for path in report.outputs:
        print(f"{prefix}wrote {path}")
    return 0
