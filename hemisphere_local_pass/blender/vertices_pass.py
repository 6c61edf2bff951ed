"""Vertices mode of the job: the selected meshes' vertices (or corners) become receivers (one-sided
limit from inside their faces, :mod:`.vertex_receivers`), H there chunk by chunk, and the results
go into the ``hlp_radiance`` / ``hlp_irradiance`` colour attributes (eq. 5).

With a tolerance (relative to the mean irradiance of the receivers, estimated from exact values at
:data:`MEAN_POINTS` of them spread over the job) every chunk runs the core's error-bounded far field
(:mod:`..core.far_field`): what it bounds instead of computing goes into the colour attribute
``<irradiance attribute>_bound`` (W m^-2 per channel, 0 where exact), which is also rewritten with
zeros by an exact run if an earlier one of ours left it.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import os

import numpy as np

from .checkpoint import digest
from .receiver_chunks import compute_chunks
from .vertex_receivers import receiver_materials, receivers, selected_meshes

__all__ = ["MEAN_POINTS", "bound_attribute", "run_vertices"]

#: Receivers evaluated exactly to turn a relative tolerance into an absolute one (W m^-2).
MEAN_POINTS = 64


def bound_attribute(irradiance_attribute: str) -> str:
    """The colour attribute holding the far field's error bound of ``irradiance_attribute``."""
    return irradiance_attribute + "_bound"


def mean_irradiance(exported, points, normals, limit, cancel) -> float:
    """Mean of H over channels at :data:`MEAN_POINTS` receivers spread evenly over the job, exact
    (W m^-2): the scale of a relative tolerance, the same for a resumed run."""
    from ..core import irradiance

    pick = np.unique(np.linspace(0, len(points) - 1, min(MEAN_POINTS, len(points))).round().astype(np.int64))
    h = irradiance(exported.scene, points[pick], normals[pick], limit_directions=limit[pick], cancel=cancel,
                   workers=1)
    return float(h.mean())


def run_vertices(scene, view_layer, exported, report, *, attribute, rho_attr, emit_attr, radiance_attribute,
                  irradiance_attribute, output, resume, progress, cancel, explicit_targets, objects=None,
                  tolerance=0.0):
    import bpy

    from . import outputs
    from .chunk_evaluation import prepare
    from .job_report import stage

    obs = selected_meshes(scene, view_layer, objects)
    edit_objects = [ob for ob in obs if ob.mode == "EDIT"]
    if edit_objects:
        for ob in edit_objects:
            ob.update_from_editmode()
    depsgraph = view_layer.depsgraph
    jobs = []
    for ob in obs:
        mesh = ob.data
        targets = (radiance_attribute, irradiance_attribute) + ((bound_attribute(irradiance_attribute),)
                                                                if tolerance > 0 else ())
        for name in targets:
            outputs.prepare_vertex_attribute(mesh, name, "", protected=(attribute, rho_attr, emit_attr),
                                             explicit=name in explicit_targets, owner=ob.name,
                                             role="radiance" if name == radiance_attribute else "irradiance")
        matrix = np.array(ob.evaluated_get(depsgraph).matrix_world, dtype=np.float64)
        domain, pts, nrm, lim, arrays, cpoly = receivers(ob, mesh, matrix)
        rho, emit = receiver_materials(ob, mesh, arrays, rho_attr, emit_attr)
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
        if mask is not None and not todo.any():
            continue  # Edit Mode, nothing selected on this object: nothing is written on it
        jobs.append((ob, domain, pts, nrm, lim, rho_r, emit_r, mask, todo))
    if not any(j[8].any() for j in jobs):
        if edit_objects:
            names = ", ".join(f"'{ob.name}'" for ob in edit_objects)
            raise ValueError(f"nothing selected: {names} in Edit Mode with no vertex selected; select the vertices "
                             "to evaluate, or leave Edit Mode to evaluate whole meshes")
        names = ", ".join(f"'{ob.name}'" for ob in obs)
        raise ValueError(f"nothing to evaluate: {names} have no faces (loose vertices are no receivers)")
    all_pts = np.concatenate([j[2][j[8]] for j in jobs])
    all_nrm = np.concatenate([j[3][j[8]] for j in jobs])
    all_lim = np.concatenate([j[4][j[8]] for j in jobs])
    core_scene = exported.scene
    absolute = 0.0
    if tolerance > 0:
        prepare(exported, all_pts, all_nrm, all_lim, progress, cancel)
        stage(progress, f"estimating the mean irradiance at {min(MEAN_POINTS, len(all_pts))} points (tolerance "
                        f"{tolerance:g} of it)")
        absolute = tolerance * mean_irradiance(exported, all_pts, all_nrm, all_lim, cancel)
        report.tolerance = absolute
    fingerprint = digest("vertices", core_scene.poly_vertices, core_scene.poly_radiance,
                          core_scene.corner_radiance if core_scene.linear else 0, all_pts, all_nrm, all_lim, absolute)
    ck_path = None if output is None else os.path.abspath(output) + ".checkpoint.npz"
    ck = yield from compute_chunks(exported, all_pts, all_nrm, all_lim, checkpoint_path=ck_path,
                                   fingerprint=fingerprint, resume=resume, progress=progress, cancel=cancel,
                                   report=report, tolerance=absolute)
    report.points = len(all_pts)
    if absolute > 0:
        report.max_form_factor_error = float("nan")  # not computed with a tolerance (see evaluate_chunk)
        report.error_estimate = float(ck.bound.max(initial=0.0))
    else:
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
            bound = np.zeros((len(pts), 3))
            bound[todo] = ck.bound[s:s + n]
            s += n
            radiance = emit_r + rho_r / np.pi * h  # eq. 5
            outputs.write_vertex_colours(ob.data, radiance_attribute, domain, radiance, todo)
            outputs.write_vertex_colours(ob.data, irradiance_attribute, domain, h, todo)
            bound_name = bound_attribute(irradiance_attribute)
            if absolute > 0 or outputs.owns_attribute(ob.data, bound_name):  # no stale bound of ours is left
                outputs.write_vertex_colours(ob.data, bound_name, domain, bound, todo)
                report.outputs.append(f"{ob.name}:{bound_name}")
            outputs.make_active_colour(ob.data, radiance_attribute)  # the viewport shows L, not H
            ob.data.update()
            report.outputs += [f"{ob.name}:{radiance_attribute}", f"{ob.name}:{irradiance_attribute}"]
            results[ob.name] = (domain, radiance, h, todo)
    finally:
        if mode_restore:
            bpy.ops.object.mode_set(mode=mode_restore)
    ck.remove()
    report.result = results
    return results
