"""The render engine "Hemisphere Local Pass": F12, *Render Animation* and ``blender -b file.blend -E
HEMISPHERE_LOCAL_PASS -f 1`` render the exact local pass of the scene camera into the Render Result.

The engine is one more entry point into :func:`.job.run_local_pass` (pixels mode, no files written,
no image datablock: ``output=None, image=False``); Blender's own output settings then write the
passes (PNG, multilayer EXR, ...) and the compositor can use them.

Passes (``update_render_passes`` / ``register_pass``, as Cycles' ``engine.py``):

=================== ======= ==========================================================================
``Combined``        RGBA    outgoing radiance L = E + rho/pi H (eq. 5); alpha = coverage with a
                            transparent film, else 1
``Depth``           Z       view depth of the pixel centre's hit (Blender's Z pass)
``Irradiance``      RGB     H (eq. 3), W m^-2
``Form Factor Sum`` X       sum of the visible form factors (1 inside a closed scene)
``Error Estimate``  X       error estimate of H of the adaptive (tolerance) job (its samples' bounds); 0 if exact
``Exact Samples``   X       fraction of the pixel's samples computed, not interpolated (1 for the exact job)
``IndexOB``         X       ``Object.pass_index`` of the hit object (Blender's Object Index pass)
=================== ======= ==========================================================================

The window is cut into row bands (``BAND_PIXELS`` pixels each), rendered top to bottom: each band is
one ``run_local_pass(region=band)`` on one export of the render depsgraph, written with
``begin_result``/``end_result`` so it appears in the Image Editor while the rest renders.
``test_break()`` (latched: True from its first True on) is the job's ``cancel`` callback, polled by
the job between chunks, by the core before each of its chunks and by the waiting threads of the worker
pool every ``core.parallel.POLL_SECONDS``: the render ends within ~0.05 s of test_break's first True
and keeps the finished bands (``tests/blender/test_engine.py``).

One worker pool serves every band of a render and every frame of an animation (``_KEEPER``, a
:class:`core.parallel.PoolKeeper`); it is shut down when the render job ends (``render_complete`` /
``render_cancel`` handlers) and when the add-on is unregistered, so no worker process outlives the job.

Esc in a window: Blender sets its break flag only when its main thread next reads window events, which
it does between redraws; with software OpenGL (llvmpipe) a redraw is CPU work of the window's threads
and takes 0.3-2 s on a loaded machine. So the engine asks for as few redraws as it can
(``update_stats``/``update_progress``/``update_result`` at most every ``UPDATE_SECONDS``; each one makes
Blender redraw the status bar and timeline) and, with a window, runs its workers ``WORKER_NICE`` below
Blender so that they do not take the CPU the window needs (docs/blender-ui.md has the measurements).
"""

from __future__ import annotations

import math
import time

import bpy
import numpy as np

__all__ = ["ENGINE_ID", "PASSES", "HLP_PT_engine_bake", "HLP_PT_engine_settings", "HLP_RenderEngine", "band_windows",
           "pass_arrays"]

ENGINE_ID = "HEMISPHERE_LOCAL_PASS"

#: (name, channel ids, type) of every pass besides Combined, in the order of ``update_render_passes``.
PASSES = (
    ("Depth", "Z", 'VALUE'),
    ("Irradiance", "RGB", 'COLOR'),
    ("Form Factor Sum", "X", 'VALUE'),
    ("Error Estimate", "X", 'VALUE'),
    ("Exact Samples", "X", 'VALUE'),
    ("IndexOB", "X", 'VALUE'),
)

#: Pixels per band (a band is whole rows): small enough that partial results come every second or so.
BAND_PIXELS = 4096

#: Least seconds between two progress/statistics updates and between two partial results: each makes
#: Blender's window redraw (status bar, timeline, Image Editor), during which it does not see Esc.
UPDATE_SECONDS = 1.0

#: Nice value added to the worker processes of a render with a window (0 in background mode: a farm's
#: ``blender -b`` keeps its normal priority).
WORKER_NICE = 10

#: The running / last render, for scripts and tests: ``done``, ``total`` points, ``cancelled``,
#: ``seconds``, ``bands`` finished of ``n_bands``, ``break_at`` (``time.perf_counter()`` when
#: test_break() first returned True), ``cancelled_at`` (when the job had stopped for it), ``ended_at``
#: (when the result was ended) (updated as the render goes).
status: dict = {}

#: Keys of the job's layers (``JobReport.result``) that fill Error Estimate / Exact Samples (the adaptive
#: job's); absent keys mean an exact job (error 0, every sample exact).
_ERROR_KEYS = ("error_estimate", "error")
_EXACT_KEYS = ("exact_sample", "exact_samples", "exact")


def _keeper():
    from ..core.parallel import PoolKeeper

    global _KEEPER
    if _KEEPER is None:
        _KEEPER = PoolKeeper()
    return _KEEPER


#: The worker pool of the running render job (bands and frames); None until the first render.
_KEEPER = None


def close_pool() -> None:
    """Shut the render's worker pool down (its processes exit and are reaped): the end of a render job,
    unregistering."""
    if _KEEPER is not None:
        _KEEPER.close()


@bpy.app.handlers.persistent
def _end_of_job(*_args):
    """``render_complete`` / ``render_cancel``: the render job (one frame, or every frame of an
    animation) has ended; its worker pool goes."""
    close_pool()


def band_windows(window, band_pixels: int | None = None) -> list:
    """Row bands ``(x0, y0, x1, y1)`` of ``window`` from the top row down, each about
    ``band_pixels`` (default ``BAND_PIXELS``) pixels (at least one row), covering the window exactly once."""
    if band_pixels is None:
        band_pixels = BAND_PIXELS  # read at call time: scripts and tests may change it
    x0, y0, x1, y1 = window
    rows = max(1, band_pixels // max(1, x1 - x0))
    bands = []
    top = y1
    while top > y0:
        bottom = max(y0, top - rows)
        bands.append((x0, bottom, x1, top))
        top = bottom
    return bands


def _layer(layers, keys, shape, default):
    for key in keys:
        if key in layers:
            return np.asarray(layers[key], dtype=np.float64).reshape(shape)
    return np.full(shape, default, dtype=np.float64)


def pass_arrays(layers: dict, pass_index, film_transparent: bool) -> dict:
    """The job's image layers of one band (:mod:`.outputs`; ``(h, w, ...)``, row 0 at the bottom)
    -> ``{pass name: (h * w, channels) float32}`` in the order of the render result's rects.

    ``pass_index``: (n_objects,) ``Object.pass_index`` of the job's objects (IndexOB)."""
    rad = np.asarray(layers["radiance"], dtype=np.float64)
    h, w = rad.shape[:2]
    n = h * w
    alpha = np.asarray(layers["alpha"], dtype=np.float64).reshape(n, 1)
    combined = np.concatenate([rad.reshape(n, 3), alpha if film_transparent else np.ones((n, 1))], axis=1)
    obj = np.asarray(layers["object_index"]).reshape(n).astype(np.int64)
    pass_index = np.asarray(pass_index, dtype=np.float64)
    index_ob = np.where(obj >= 0, pass_index[np.maximum(obj, 0)] if len(pass_index) else 0.0, 0.0)
    covered = alpha[:, 0] > 0
    out = {
        "Combined": combined,
        "Depth": np.asarray(layers["depth"]).reshape(n, 1),
        "Irradiance": np.asarray(layers["irradiance"]).reshape(n, 3),
        "Form Factor Sum": np.asarray(layers["form_factor_sum"]).reshape(n, 1),
        "Error Estimate": _layer(layers, _ERROR_KEYS, (n, 1), 0.0),
        "Exact Samples": np.where(covered[:, None], _layer(layers, _EXACT_KEYS, (n, 1), 1.0), 0.0),
        "IndexOB": index_ob.reshape(n, 1),
    }
    return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in out.items()}


def _image_window(scene, result_size, depsgraph=None):
    """The render result's pixels ``(x0, y0, x1, y1)`` in image coordinates: the render border's
    rectangle (``camera.pixel_window``), sized as Blender made the result (``result_size``)."""
    from . import camera as hcam

    x0, y0, _x1, _y1 = hcam.pixel_window(hcam.camera_params(scene, depsgraph=depsgraph))
    return x0, y0, x0 + int(result_size[0]), y0 + int(result_size[1])


def _break_requested(engine) -> bool:
    """``engine.test_break()`` (Esc, or the render being cancelled); one place, so tests can inject a stop."""
    return bool(engine.test_break())


class _Stats:
    """update_stats / update_progress: "12,288 / 65,536 points, 3,100 points/s, ETA 17 s"."""

    def __init__(self, engine, total):
        self.engine = engine
        self.total = max(int(total), 1)
        self.base = 0
        self.start = time.perf_counter()
        self.last = 0.0

    def band(self, size):
        base = self.base

        def progress(done, total):
            self.show(base + int(size * done / max(total, 1)))

        return progress

    def finish_band(self, size):
        self.base += size
        self.show(self.base)

    def show(self, done):
        """``status`` now; Blender's statistics and progress at most every ``UPDATE_SECONDS`` (each
        update redraws the window's status bar and timeline)."""
        status.update(done=int(done), total=self.total)
        now = time.perf_counter()
        if now - self.last < UPDATE_SECONDS:
            return
        self.last = now
        elapsed = now - self.start
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - done) / rate if rate > 0 else math.nan
        eta_s = f"{eta:,.0f} s" if math.isfinite(eta) else "?"
        self.engine.update_stats("Hemisphere Local Pass",
                                 f"{done:,} / {self.total:,} points, {rate:,.0f} points/s, ETA {eta_s}")
        self.engine.update_progress(min(1.0, done / self.total))


class HLP_RenderEngine(bpy.types.RenderEngine):
    """Exact local pass of two-pass global illumination from the scene's radiosity attribute"""

    bl_idname = ENGINE_ID
    bl_label = "Hemisphere Local Pass"
    bl_use_preview = False
    bl_use_postprocess = True
    bl_use_eevee_viewport = True  # Material Preview / Rendered viewport shading through EEVEE

    def _fail(self, message):
        """Bad input: the render stops with the message (Image Editor header, stdout in ``-b``)."""
        if hasattr(self, "error_set"):
            self.error_set(message)
        self.report({'ERROR'}, message)

    def update_render_passes(self, scene=None, renderlayer=None):
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", 'COLOR')
        for name, chans, kind in PASSES:
            self.register_pass(scene, renderlayer, name, len(chans), chans, kind)

    def render(self, depsgraph):
        from ..core import Cancelled
        from .job import run_local_pass
        from .scene_export import export_scene

        scene = depsgraph.scene
        view_layer = depsgraph.view_layer
        settings = getattr(scene, "hlp_settings", None)
        kwargs = {}
        if settings is not None:
            kwargs = {"attribute": settings.attribute, "reflectivity_attribute": settings.reflectivity_attribute,
                      "emission_attribute": settings.emission_attribute,
                      "missing": settings.missing_attribute.lower(), "double_sided": settings.double_sided}
        k = int(settings.samples) if settings is not None else 1
        # the result is the border's size when a render border is set (resolution_x/y: the whole image)
        result = self.begin_result(0, 0, int(self.resolution_x), int(self.resolution_y), layer=view_layer.name)
        try:
            size = (int(result.resolution_x), int(result.resolution_y))
            window = _image_window(scene, size, depsgraph)
            self.update_stats("Hemisphere Local Pass", "Exporting the scene")
            exported = export_scene(scene, depsgraph=depsgraph, view_layer=view_layer, **kwargs)
        except ValueError as ex:
            self.end_result(result)
            self._fail(str(ex))
            return
        n = size[0] * size[1]
        rects = {"Combined": np.zeros((n, 4), np.float32)}
        rects.update({name: np.zeros((n, len(chans)), np.float32) for name, chans, _kind in PASSES})
        layer = result.layers[0]
        targets = {name: layer.passes.get(name) for name in rects}  # None: not a pass of this result
        bands = band_windows(window)
        stats = _Stats(self, n * k * k)
        transparent = bool(scene.render.film_transparent)
        points = 0
        worst = 0.0
        start = time.perf_counter()
        status.clear()
        status.update(done=0, total=n * k * k, cancelled=False, bands=0, n_bands=len(bands), seconds=0.0,
                      break_at=None, worker_pids=[], result_updates=0)
        pending = set()  # passes with finished bands not yet written into the result
        shown = start  # when the last partial result was sent

        def write_pending():
            for name in sorted(pending):
                if targets.get(name) is not None:
                    targets[name].rect = rects[name]
            pending.clear()

        def stop():
            """test_break(), latched: once Esc is seen every later poll (core chunks, workers' waits)
            answers True without asking Blender again, and ``status["break_at"]`` says when."""
            if status["break_at"] is None and _break_requested(self):
                status["break_at"] = time.perf_counter()
            return status["break_at"] is not None

        keeper = _keeper()
        try:
            # one pool for every band (and, until the job ends, every frame); below Blender with a window
            with keeper.scope(nice=0 if bpy.app.background else WORKER_NICE):
                for band in bands:
                    if stop():
                        status.update(cancelled=True, cancelled_at=time.perf_counter())
                        break
                    size_b = (band[2] - band[0]) * (band[3] - band[1]) * k * k
                    try:
                        report = run_local_pass(scene, mode="pixels", region=band, output=None, image=False,
                                                preview=False, samples=k, exported=exported, depsgraph=depsgraph,
                                                view_layer=view_layer, progress=stats.band(size_b),
                                                cancel=stop, **kwargs)
                    except Cancelled:  # Esc: keep the finished bands
                        status.update(cancelled=True, cancelled_at=time.perf_counter())
                        break
                    except ValueError as ex:
                        self._fail(str(ex))
                        break
                    finally:
                        if keeper.pool is not None and keeper.pool.pids not in status["worker_pids"]:
                            status["worker_pids"].append(keeper.pool.pids)
                    points += report.points
                    worst = max(worst, report.max_form_factor_error)
                    arrays = pass_arrays(report.result, exported.object_pass_index, transparent)
                    rows = np.arange(band[1], band[3]) - window[1]
                    cols = np.arange(band[0], band[2]) - window[0]
                    flat = (rows[:, None] * size[0] + cols[None, :]).reshape(-1)  # result rect rows, bottom first
                    for name, values in arrays.items():
                        rects[name][flat] = values
                        pending.add(name)
                    status["bands"] += 1
                    now = time.perf_counter()
                    if now - shown >= UPDATE_SECONDS and status["bands"] < len(bands):
                        write_pending()
                        self.update_result(result)  # the finished bands appear in the Image Editor
                        status["result_updates"] += 1
                        shown = now
                    stats.finish_band(size_b)
        finally:
            write_pending()  # every finished band, also after Esc
            self.end_result(result)
            status["ended_at"] = time.perf_counter()
            status["seconds"] = status["ended_at"] - start
        seconds = time.perf_counter() - start
        self.update_stats("Hemisphere Local Pass",
                          f"{points:,} points in {seconds:.1f} s, max |sum F - 1| = {worst:.2e}")


class HLP_EngineButtonsPanel:
    """Render-context panels of this engine (as ``RenderButtonsPanel`` + ``COMPAT_ENGINES``)."""

    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE_ID}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES and hasattr(context.scene, "hlp_settings")


#: Settings that other parts of the extension add to ``HLP_PG_settings`` (drawn when present).
_OPTIONAL = (("tolerance", "Tolerance"), ("workers", "Workers"))


class HLP_PT_engine_settings(HLP_EngineButtonsPanel, bpy.types.Panel):
    """Radiosity input and sampling of the exact local pass"""

    bl_label = "Local Pass"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.hlp_settings
        col = layout.column()
        col.prop(settings, "attribute", text="Radiosity")
        col.prop(settings, "missing_attribute", text="Missing")
        col.prop(settings, "double_sided", text="Two-Sided")
        col = layout.column(heading="Receiver")  # short labels: they fit the default editor width
        col.prop(settings, "reflectivity_attribute", text="Albedo")
        col.prop(settings, "emission_attribute", text="Emission")
        col = layout.column()
        col.prop(settings, "samples", text="Samples")
        for prop, label in _OPTIONAL:
            if hasattr(settings, prop):
                col.prop(settings, prop, text=label)


class HLP_PT_engine_bake(HLP_EngineButtonsPanel, bpy.types.Panel):
    """Bake the local pass into vertex colours, or render it to the Local Pass image without F12"""

    bl_label = "Bake"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.operator("hlp.bake_vertex_colours", icon='VPAINT_HLT')
        layout.prop(context.scene.hlp_settings, "output_path")
        layout.operator("hlp.render_local_pass", text="Render to Image", icon='RENDER_STILL')


def draw_render_context(self, context):
    """One line under Properties > Render > Render Engine with any engine: the local pass's buttons,
    found without scrolling (the full panel is at the end of the tab)."""
    if context.engine == ENGINE_ID or not hasattr(context.scene, "hlp_settings"):
        return
    split = self.layout.split(factor=0.6, align=True)
    split.operator("hlp.render_local_pass", text="Local Pass", icon='RENDER_STILL')
    split.operator("hlp.bake_vertex_colours", text="Bake", icon='VPAINT_HLT')


classes = (HLP_RenderEngine, HLP_PT_engine_settings, HLP_PT_engine_bake)


def compatible_panels():
    """Blender's own render panels that list their engines (``COMPAT_ENGINES``) and apply here."""
    names = ("RENDER_PT_color_management", "RENDER_PT_color_management_curves",
             "RENDER_PT_color_management_display_settings")
    return [getattr(bpy.types, n) for n in names if hasattr(bpy.types, n)]


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    for panel in compatible_panels():
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if isinstance(engines, set):
            engines.add(ENGINE_ID)
    if hasattr(bpy.types, "RENDER_PT_context"):
        bpy.types.RENDER_PT_context.append(draw_render_context)
    for handlers in (bpy.app.handlers.render_complete, bpy.app.handlers.render_cancel):
        if _end_of_job not in handlers:
            handlers.append(_end_of_job)


def unregister():
    for handlers in (bpy.app.handlers.render_complete, bpy.app.handlers.render_cancel):
        while _end_of_job in handlers:
            handlers.remove(_end_of_job)
    close_pool()
    if hasattr(bpy.types, "RENDER_PT_context"):
        bpy.types.RENDER_PT_context.remove(draw_render_context)
    for panel in compatible_panels():
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if isinstance(engines, set):
            engines.discard(ENGINE_ID)
    for cls in reversed(classes):
        if getattr(cls, "is_registered", True):
            bpy.utils.unregister_class(cls)
