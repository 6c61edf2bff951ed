"""Pixels mode of the job: the scene camera's rays, the receivers they hit, H there (exactly, chunk
by chunk, or by the adaptive pass), L = E + rho / pi * H (eq. 5) -> image layers, EXR, PNG preview
and the "Local Pass" image::

    scene camera  --camera-->       one ray per pixel centre (k x k samples)
    core.raycast.cast_rays           visible point P, polygon, side
    core.form_factors / irradiance   H(P) on the hit side, sum of F  (receiver_chunks, or adaptive_pixels)
    L = E + rho / pi * H             (eq. 5) -> OpenEXR, "Local Pass" image, PNG preview

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import os

import numpy as np

from .adaptive_pixels import adaptive_pixels
from .checkpoint import digest
from .job_report import stage
from .receiver_chunks import compute_chunks
from .tiles import parse_tile, tile_window

__all__ = ["IMAGE_NAME", "run_pixels"]

#: Name of the image datablock that receives the pixels-mode result.
IMAGE_NAME = "Local Pass"


def run_pixels(scene, exported, report, *, output, region, tile, resume, samples, progress, cancel, preview, image,
                depsgraph=None, tolerance=0.0):
    from ..core.raycast import cast_rays
    from . import camera as hcam
    from . import outputs

    params = hcam.camera_params(scene, depsgraph=depsgraph)
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
    stage(progress, f"casting {len(origins)} camera rays ({core_scene.n_polygons} convex polygons)")
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

    npix = len(px)
    shape = (window[3] - window[1], window[2] - window[0])
    ck = None
    if tolerance > 0:
        h_hit, exact_hit, err_hit = yield from adaptive_pixels(core_scene, pts, normals, src, hit, shape, k2,
                                                               tolerance, progress, cancel, report)
        fsum_hit = np.full(len(pts), np.nan)  # not computed: the adaptive pass evaluates H only
        report.max_form_factor_error = float("nan")
    else:
        fingerprint = digest("pixels", core_scene.poly_vertices, core_scene.poly_radiance,
                              core_scene.corner_radiance if core_scene.linear else 0, pts, normals)
        ck_path = None if output is None else os.path.abspath(output) + ".checkpoint.npz"
        ck = yield from compute_chunks(exported, pts, normals, None, checkpoint_path=ck_path, fingerprint=fingerprint,
                                       resume=resume, progress=progress, cancel=cancel, report=report)
        h_hit, fsum_hit = ck.h, ck.fsum
        exact_hit, err_hit = np.ones(len(pts)), np.zeros(len(pts))
        report.max_form_factor_error = float(np.abs(fsum_hit - 1.0).max()) if len(pts) else 0.0
    report.points = len(pts)

    emits = exported.emission[src] * (front | core_scene.double_sided)[:, None]
    l_hit = emits + exported.reflectivity[src] / np.pi * h_hit  # eq. 5

    n_samples = len(hit)
    radiance = np.zeros((n_samples, 3))
    irr = np.zeros((n_samples, 3))
    fsum = np.zeros(n_samples)
    radiance[hit], irr[hit], fsum[hit] = l_hit, h_hit, fsum_hit
    exact_s, err_s = np.zeros(n_samples), np.zeros(n_samples)
    exact_s[hit], err_s[hit] = exact_hit, err_hit
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
    layers = {
        # the adaptive pass (tolerance > 0): error estimate of H (mean over the pixel's samples; 0 where
        # exact) and the fraction of the pixel's samples evaluated exactly (1 everywhere at tolerance 0)
        "error_estimate": err_s.reshape(npix, k2).mean(axis=1).reshape(shape),
        "exact_sample": exact_s.reshape(npix, k2).mean(axis=1).reshape(shape),
        "radiance": lay_rad.reshape(shape + (3,)), "irradiance": lay_irr.reshape(shape + (3,)),
        "alpha": cover.reshape(shape), "form_factor_sum": lay_f.reshape(shape), "depth": depth.reshape(shape),
        "object_index": obj_idx.reshape(shape).astype(np.float64),
        "polygon_index": pol_idx.reshape(shape).astype(np.float64),
    }
    report.result = layers
    job_id = digest(core_scene.poly_vertices, core_scene.poly_radiance, exported.reflectivity, exported.emission,
                     size, params.fingerprint(), samples, full_window)
    meta = {"hlp_fingerprint": job_id}  # the same for every tile of one job
    if tile is not None:
        meta["hlp_tile"] = "{}/{}".format(*parse_tile(tile))
    if output is not None:
        report.outputs.append(outputs.write_exr(output, layers, size=size, window=window, metadata=meta))
        if preview:  # the preview's path, checked by output_paths.plan_outputs (None: not written)
            png = preview
            full = np.zeros((size[1], size[0], 3))
            full[y0:y1, x0:x1] = layers["radiance"]
            report.outputs.append(outputs.write_png(png, full))
        if ck is not None:
            ck.remove()
    if image:
        rgba = np.zeros((size[1], size[0], 4))
        rgba[y0:y1, x0:x1, :3] = layers["radiance"]
        rgba[y0:y1, x0:x1, 3] = layers["alpha"]
        outputs.store_image(IMAGE_NAME, rgba)
    return layers
