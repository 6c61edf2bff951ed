"""The one job function of the local pass: every entry point (operators, render engine, the
``blender -c`` command, plain Python in the bpy module or under Blender 3.4's ``--python-expr``)
calls :func:`run_local_pass` or advances :func:`local_pass_steps`. It resolves the settings, checks
the input before the (slow) export, exports the scene and runs one of the two modes::

    Blender scene --scene_export--> core Scene, rho, E per polygon
    pixels:   pixels_pass   (camera rays -> receivers -> H -> eq. 5 -> EXR / PNG / "Local Pass" image)
    vertices: vertices_pass (mesh vertices/corners -> H -> eq. 5 -> hlp_radiance / hlp_irradiance)

Both evaluate H chunk by chunk (:mod:`.receiver_chunks`) with a checkpoint (:mod:`.checkpoint`);
the pixels mode's adaptive pass is :mod:`.adaptive_pixels`.

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax; newer bpy APIs behind hasattr.
"""

from __future__ import annotations

import time

import numpy as np

from .interrupts import stops_on_first_sigint
from .job_report import JobReport, Reporter, stage
from .pixels_pass import run_pixels
from .tiles import parse_tile
from .vertex_receivers import selected_meshes
from .vertices_pass import run_vertices

__all__ = ["local_pass_steps", "run_local_pass", "scene_settings"]


def scene_settings(scene):
    """``scene.hlp_settings`` when the extension is registered, else None."""
    return getattr(scene, "hlp_settings", None)


@stops_on_first_sigint
def run_local_pass(*args, **kwargs):
    """Run the exact local pass to the end: :func:`local_pass_steps` (same arguments) drained.

    Returns:
        :class:`JobReport`.
    """
    steps = local_pass_steps(*args, **kwargs)
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


def local_pass_steps(
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
    status=None,
    reflectivity_attribute=None,
    emission_attribute=None,
    double_sided=None,
    radiance_attribute=None,
    irradiance_attribute=None,
    preview=True,
    image=True,
    view_layer=None,
    overwrite=False,
    objects=None,
    workers=None,
    exported=None,
    depsgraph=None,
    tolerance=None,
):
    """The exact local pass on ``scene`` (default: the context's scene) as a generator: it yields a
    :class:`JobStep` after every chunk and returns the :class:`JobReport` (``StopIteration.value``).
    :func:`run_local_pass` drains it; a modal operator advances it one timer tick at a time; closing
    it (``.close()``) between steps stops the job before anything is written.

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
        status: ``status(text)`` when a stage begins or moves on ("exporting the scene: 3 objects,
            1,200 polygons read", "casting 4,096 camera rays", "preparing the scene ...", "computing
            4,096 points"), from the job's first moment on; ``status(None)`` when the job ends.
        radiance_attribute, irradiance_attribute: vertices mode targets (default ``hlp_radiance``,
            ``hlp_irradiance``); an existing attribute of that name is overwritten only if it was
            made by this extension or is named here explicitly.
        image: store the pixels in the image datablock "Local Pass".
        overwrite: replace an existing output (EXR, PNG preview, checkpoint) that this extension
            wrote; files it did not write are never replaced (:mod:`.output_paths`). A refused
            preview is listed in ``report.refused``.
        objects: vertices mode: names of the mesh objects to evaluate (default: the selected ones).
        workers: worker processes (0: every core this process may use; 1: this process only; default
            the scene setting, else 0). Results are the same bits for any number. Workers run the
            bpy-free core in a real Python (see :mod:`hemisphere_local_pass.core.parallel`).
        exported: an :class:`~.scene_export.ExportedScene` of this scene made with the same
            attribute settings, to reuse (the render engine's bands); default: export the scene.
        depsgraph: an evaluated depsgraph to read the objects and the camera from as it is (the
            render engine's); default: the view layer's.
        tolerance: pixels mode: 0 (default) evaluates every pixel exactly; > 0 runs the adaptive pass
            (``core.adaptive_irradiance``) with an error tolerance on H *relative to the image's mean
            irradiance* (estimated from exact values on a 16-pixel grid), e.g. 1e-3, its samples from the
            far field with ``core.adaptive.SAMPLE_SHARE`` of the tolerance (the final ones, which no
            interpolation uses, with ``FINAL_SHARE``); the EXR's ``error_estimate``
            and ``exact_sample`` layers show the estimate (the samples' bounds) and where it interpolated. The adaptive
            pass neither checkpoints nor computes the ``form_factor_sum`` layer (NaN there); it yields
            a step every ``adaptive_pixels.POLL_SECONDS`` while its core calls run in a thread.
            Vertices mode: 0 is exact; > 0 (relative to the receivers' mean irradiance, estimated from
            exact values at ``vertices_pass.MEAN_POINTS`` of them) runs the core's error-bounded far
            field; the bound used goes into ``<irradiance attribute>_bound`` and ``report.error_estimate``
            (sum F is not computed: ``max_form_factor_error`` is NaN).

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
    settings = scene_settings(scene)

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
    workers = pick(workers, "workers", 0)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ValueError(f"workers must be 0 (every core) or a positive number, got {workers!r}")
    tolerance = float(pick(tolerance, "tolerance", 0.0))
    if not (np.isfinite(tolerance) and tolerance >= 0.0):
        raise ValueError(f"tolerance must be a number >= 0 (relative to the mean irradiance), got {tolerance}")
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
    refused = []
    if output is not None:
        from .output_paths import plan_outputs

        output, preview, refused = plan_outputs(output, mode=mode, tile=tile, preview=preview, overwrite=overwrite,
                                                resume=resume)
    elif tile is not None:
        raise ValueError("a tile needs an output file")
    if view_layer is None:
        ctx_layer = getattr(bpy.context, "view_layer", None)
        view_layer = ctx_layer if ctx_layer is not None and ctx_layer.id_data == scene else scene.view_layers[0]
    if objects and mode != "pixels":
        selected_meshes(scene, view_layer, objects)  # unknown names: fail before the (slow) export
    elif objects:
        raise ValueError("--objects applies to vertices mode only")
    if mode == "pixels":
        from .camera import camera_params

        camera_params(scene, depsgraph=depsgraph)  # no camera: fail before the (slow) export

    from .scene_export import export_scene

    progress = Reporter(progress, status)
    if exported is None:
        stage(progress, "exporting the scene")
        try:
            exported = export_scene(scene, depsgraph=depsgraph, view_layer=view_layer, attribute=attribute,
                                    reflectivity_attribute=rho_attr, emission_attribute=emit_attr, missing=missing,
                                    double_sided=double_sided, status=progress.stage)
        except BaseException:
            stage(progress, None)
            raise
        sc = exported.scene
        stage(progress, f"exported {len(exported.objects)} objects, {sc.n_input} polygons ({sc.n_polygons} "
                         f"convex) in {time.perf_counter() - start:.1f} s")
    report = JobReport(mode=mode, black_occluders=list(exported.black_occluders),
                       dropped_polygons=exported.dropped_names(), objects=list(exported.objects), refused=refused)
    if workers == 0:
        from ..core.parallel import default_workers

        workers = default_workers()
    report.workers = workers  # at most; compute_chunks uses one process for small jobs
    try:
        if mode == "pixels":
            yield from run_pixels(scene, exported, report, output=output, region=region, tile=tile, resume=resume,
                                  samples=samples, progress=progress, cancel=cancel, preview=preview, image=image,
                                  depsgraph=depsgraph, tolerance=tolerance)
        else:
            explicit = {n for n in (radiance_attribute, irradiance_attribute) if n}
            yield from run_vertices(scene, view_layer, exported, report, attribute=attribute, rho_attr=rho_attr,
                                    emit_attr=emit_attr,
                                    radiance_attribute=(radiance_attribute or pick(None, "radiance_attribute", "")
                                                        or "hlp_radiance"),
                                    irradiance_attribute=(irradiance_attribute
                                                          or pick(None, "irradiance_attribute", "")
                                                          or "hlp_irradiance"), output=output,
                                    resume=resume, progress=progress, cancel=cancel, explicit_targets=explicit,
                                    objects=objects, tolerance=tolerance)
    finally:
        report.seconds = time.perf_counter() - start
        stage(progress, None)
    return report
