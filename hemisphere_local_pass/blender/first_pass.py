"""The first pass inside Blender: solve radiosity on the scene and write the FACE-domain attribute.

One job in three phases, shared by every entry point (operator, ``-c hemisphere_local_pass solve``,
:func:`solve_first_pass`):

1. :func:`prepare` exports the scene the way the local pass sees it (``scene_export.export_scene``:
   render-visible objects, modifiers, instances; reflectivity and emission by the local pass's own rule —
   attributes, then materials, then defaults) and builds the numeric solver
   (:class:`hemisphere_local_pass.first_pass.ProgressiveSolver`). To map evaluated polygons back to the
   mesh faces they came from (through Subdivision, Array, Mirror ... modifiers and instancing), every
   editable mesh carries a temporary FACE attribute ``hlp_first_pass_origin`` = (face index, mesh number)
   during the export only; it is removed before ``prepare`` returns, whatever happens.
2. ``job.solver.step()`` until done (the modal operator: one step per timer tick; the others: a loop),
   progress with ETA in the status bar / on stderr. Esc, Ctrl-C or ``cancel()`` end here with the
   scene unchanged: nothing has been written.
3. :meth:`FirstPassJob.finish` writes the radiance (linear RGB, W sr^-1 m^-2) as the FLOAT_COLOR FACE
   attribute (default ``radiosity``) on every exported mesh: the area-weighted mean over the evaluated
   polygons of each face (several when a modifier splits it, or when a mesh is used by several objects
   or instances — then it holds their mean, and the report names the mesh). An existing attribute of
   that name is replaced only when this extension made it (listed in the mesh's
   ``hlp_owned_attributes`` custom property); a user's attribute stops the job before anything is
   written, with a message naming mesh and attribute.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..first_pass import DEFAULT_TOLERANCE, FirstPassResult, make_solver
from .stderr_lines import PREFIX

__all__ = ["ORIGIN_ATTRIBUTE", "FirstPassJob", "FirstPassReport", "cli_main", "prepare", "solve_first_pass"]

#: temporary FACE attribute (face index, mesh number + 1, 0) present on the meshes during the export only
ORIGIN_ATTRIBUTE = "hlp_first_pass_origin"
#: custom property listing the attributes this extension made (shared with the vertex mode's outputs)
OWNED_KEY = "hlp_owned_attributes"


@dataclass
class FirstPassReport:
    """What the job did: the solver's report plus what was written where."""

    result: FirstPassResult
    attribute: str
    meshes: list = field(default_factory=list)             # names of the meshes written
    shared_meshes: dict = field(default_factory=dict)      # mesh -> number of placements averaged
    unwritten_objects: list = field(default_factory=list)  # exported objects that are not editable meshes
    dropped_polygons: list = field(default_factory=list)
    replaced: list = field(default_factory=list)           # meshes whose attribute (ours) was replaced
    outputs: list = field(default_factory=list)
    seconds: float = 0.0

    def summary(self) -> str:
        parts = [self.result.summary(), f"wrote '{self.attribute}' on {len(self.meshes)} mesh(es)"]
        if self.replaced:
            parts.append(f"replaced this extension's earlier '{self.attribute}' on {len(self.replaced)}")
        if self.shared_meshes:
            parts.append("mean over placements: " + ", ".join(f"'{m}' ({k})" for m, k in self.shared_meshes.items()))
        if self.unwritten_objects:
            parts.append("solved but not written (not an editable mesh): " + ", ".join(self.unwritten_objects))
        if self.dropped_polygons:
            parts.append(f"{len(self.dropped_polygons)} degenerate polygon(s) dropped")
        return "; ".join(parts)


def _settings(scene):
    return getattr(scene, "hlp_settings", None), getattr(scene, "hlp_first_pass", None)


def _editable_meshes(bpy_data):
    """Meshes whose faces we can tag and write: local (not linked from a library), with polygons."""
    return [m for m in bpy_data.meshes if m.library is None and len(m.polygons)]


class _OriginTags:
    """Context manager: the temporary origin attribute on ``meshes`` (removed on exit, always)."""

    def __init__(self, meshes):
        self.meshes = meshes

    def __enter__(self):
        for k, mesh in enumerate(self.meshes):
            old = mesh.attributes.get(ORIGIN_ATTRIBUTE)
            if old is not None:  # left over from an interrupted run: ours by name
                mesh.attributes.remove(old)
            n = len(mesh.polygons)
            attr = mesh.attributes.new(ORIGIN_ATTRIBUTE, "FLOAT_VECTOR", "FACE")
            vec = np.zeros((n, 3), dtype=np.float32)
            vec[:, 0] = np.arange(n)      # exact in float32 up to 2**24 faces
            vec[:, 1] = k + 1             # 0: not a tagged mesh (black occluder, curve, text ...)
            attr.data.foreach_set("vector", vec.reshape(-1))
            mesh.update()
        return self

    def __exit__(self, *exc):
        for mesh in self.meshes:
            try:
                attr = mesh.attributes.get(ORIGIN_ATTRIBUTE)
                if attr is not None:
                    mesh.attributes.remove(attr)
                    mesh.update()
            except ReferenceError:  # removed meanwhile
                pass
        return False


class FirstPassJob:
    """An exported scene and its solver (phase 1), to step (phase 2) and write back (phase 3)."""

    def __init__(self, exported, solver, meshes, attribute, start):
        self.exported = exported
        self.solver = solver
        self.mesh_names = [m.name for m in meshes]
        self.mesh_faces = [len(m.polygons) for m in meshes]
        self.attribute = attribute
        self.start = start
        # (n_input, 2) face, mesh + 1 of every input polygon, from its convex pieces (dropped ones: 0, 0)
        sc = exported.scene
        origin = np.zeros((sc.n_input, 2), dtype=np.int64)
        origin[sc.poly_source] = np.rint(sc.poly_radiance[:, :2]).astype(np.int64)
        self.face = origin[:, 0]
        self.mesh = origin[:, 1] - 1                                                # -1: not a tagged mesh
        self.dropped = np.zeros(sc.n_input, dtype=bool)
        self.dropped[list(sc.dropped)] = True

    def run(self, progress=None, cancel=None) -> FirstPassResult:
        return self.solver.run(progress=progress, cancel=cancel)

    def _check_targets(self, bpy_data, used):
        meshes = []
        for k in used:
            mesh = bpy_data.meshes.get(self.mesh_names[k])
            if mesh is None or len(mesh.polygons) != self.mesh_faces[k]:
                raise ValueError(f"mesh '{self.mesh_names[k]}' changed while the first pass ran; nothing was "
                                 "written (solve again)")
            existing = mesh.attributes.get(self.attribute)
            if existing is not None and self.attribute not in list(mesh.get(OWNED_KEY, [])):
                raise ValueError(f"mesh '{mesh.name}' already has an attribute '{self.attribute}' that this "
                                 "extension did not make; it is never overwritten: rename it, or choose another "
                                 "radiosity attribute name. Nothing was written")
            if self.attribute.startswith(".") or self.attribute in ("position", "sharp_face", "material_index"):
                raise ValueError(f"'{self.attribute}' is a built-in attribute and cannot hold the radiosity")
            meshes.append(mesh)
        return meshes

    def finish(self, result: FirstPassResult | None = None) -> FirstPassReport:
        """Write the solution (``result``: default the solver's current state) and return the report."""
        import bpy

        if result is None:
            result = self.solver.result()
        if not result.converged:
            raise ValueError(f"the first pass stopped after {result.shots} shots with {result.unshot_fraction:.2e} "
                             f"of the emitted power unshot (tolerance {result.tolerance:.0e}); is a reflectivity 1 "
                             "in a closed scene? Nothing was written")
        report = FirstPassReport(result=result, attribute=self.attribute,
                                 dropped_polygons=self.exported.dropped_names())
        tagged = self.mesh >= 0
        used = sorted(set(self.mesh[tagged].tolist()))
        meshes = self._check_targets(bpy.data, used)
        objects = np.asarray(self.exported.polygon_object)
        report.unwritten_objects = sorted({self.exported.objects[i]
                                           for i in np.unique(objects[~tagged & ~self.dropped])})
        w = result.areas                                                          # (n,) area weights
        for k, mesh in zip(used, meshes):
            sel = np.flatnonzero(self.mesh == k)
            n = self.mesh_faces[k]
            face = self.face[sel]
            wsum = np.bincount(face, weights=w[sel], minlength=n)
            cnt = np.bincount(face, minlength=n).astype(np.float64)
            values = np.zeros((n, 3))
            for c in range(3):
                lw = np.bincount(face, weights=w[sel] * result.radiance[sel, c], minlength=n)
                lm = np.bincount(face, weights=result.radiance[sel, c], minlength=n)
                values[:, c] = np.where(wsum > 0, lw / np.where(wsum > 0, wsum, 1), lm / np.maximum(cnt, 1))
            placements = len(np.unique(objects[sel]))
            if placements > 1:
                report.shared_meshes[mesh.name] = placements
            if mesh.attributes.get(self.attribute) is not None:
                report.replaced.append(mesh.name)
            _write_face_colours(mesh, self.attribute, values)
            report.meshes.append(mesh.name)
        report.seconds = time.perf_counter() - self.start
        return report


def _write_face_colours(mesh, name: str, values: np.ndarray):
    """``values (n_faces, 3)`` into the FLOAT_COLOR FACE attribute ``name`` (alpha 1), marked as ours."""
    attr = mesh.attributes.get(name)
    if attr is not None and (attr.domain != "FACE" or attr.data_type != "FLOAT_COLOR"):
        mesh.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = mesh.attributes.new(name, "FLOAT_COLOR", "FACE")
    rgba = np.ones((len(values), 4), dtype=np.float32)
    rgba[:, :3] = values
    attr.data.foreach_set("color", rgba.reshape(-1))
    owned = list(mesh.get(OWNED_KEY, []))
    if name not in owned:
        mesh[OWNED_KEY] = owned + [name]
    mesh.update()


def prepare(scene=None, *, attribute=None, reflectivity_attribute=None, emission_attribute=None, double_sided=None,
            tolerance=None, order=None, view_layer=None, max_shots=None, clusters=None) -> FirstPassJob:
    """Phase 1: export ``scene`` (default: the context's) and build the solver; the scene is left as it was.

    Arguments left at ``None`` come from ``scene.hlp_settings`` (attribute names, double-sided) and
    ``scene.hlp_first_pass`` (tolerance, quadrature order, clusters) when the extension is registered, else
    the defaults (``radiosity``, ``reflectivity``, ``emission``, single-sided, ``DEFAULT_TOLERANCE``, order 2,
    no clusters). ``clusters`` > 0 shoots reflected light from about that many clusters of polygons
    (:class:`hemisphere_local_pass.first_pass.ClusteredSolver`; docs/first-pass.md, "Large scenes").
    """
    import bpy

    from .scene_export import export_scene

    start = time.perf_counter()
    if scene is None:
        scene = bpy.context.scene
    settings, fp = _settings(scene)

    def pick(value, group, prop, default):
        if value is not None:
            return value
        return getattr(group, prop) if group is not None and hasattr(group, prop) else default

    attribute = pick(attribute, settings, "attribute", "radiosity")
    rho_attr = pick(reflectivity_attribute, settings, "reflectivity_attribute", "reflectivity")
    emit_attr = pick(emission_attribute, settings, "emission_attribute", "emission")
    double_sided = bool(pick(double_sided, settings, "double_sided", False))
    tolerance = float(pick(tolerance, fp, "tolerance", DEFAULT_TOLERANCE))
    order = int(pick(order, fp, "order", 2))
    clusters = int(pick(clusters, fp, "clusters", 0))
    if clusters < 0:
        raise ValueError(f"clusters must be 0 (every polygon shoots) or positive, got {clusters}")
    if not attribute:
        raise ValueError("the radiosity attribute name is empty")
    if attribute == ORIGIN_ATTRIBUTE:
        raise ValueError(f"'{ORIGIN_ATTRIBUTE}' is reserved for the first pass's own bookkeeping")
    editing = [m.name for m in bpy.data.meshes if getattr(m, "is_editmode", False)]
    if editing:
        raise ValueError(f"mesh '{editing[0]}' is in Edit Mode; switch to Object Mode to solve the first pass")
    meshes = _editable_meshes(bpy.data)
    if view_layer is None:
        ctx_layer = getattr(bpy.context, "view_layer", None)
        view_layer = ctx_layer if ctx_layer is not None and ctx_layer.id_data == scene else scene.view_layers[0]
    with _OriginTags(meshes):
        exported = export_scene(scene, view_layer=view_layer, attribute=ORIGIN_ATTRIBUTE,
                                reflectivity_attribute=rho_attr, emission_attribute=emit_attr, missing="black",
                                double_sided=double_sided)
    # the tags are gone: re-evaluate so that the depsgraph matches the file again
    view_layer.update()
    solver = make_solver(exported.scene, exported.reflectivity, exported.emission, tolerance=tolerance,
                         order=order, double_sided=double_sided, max_shots=max_shots, clusters=clusters or None)
    return FirstPassJob(exported, solver, meshes, attribute, start)


def solve_first_pass(scene=None, *, progress=None, cancel=None, **kwargs) -> FirstPassReport:
    """Solve the first pass on ``scene`` and write the attribute (the plain-Python entry point).

    ``progress(SolveProgress)`` after every step, ``cancel() -> bool`` before every step (raises
    :class:`hemisphere_local_pass.core.Cancelled`; nothing is written). Other arguments: :func:`prepare`.
    Raises ``ValueError`` with a message naming object / mesh / attribute / polygon for bad input.
    """
    job = prepare(scene, **kwargs)
    return job.finish(job.run(progress=progress, cancel=cancel))


# ------------------------------------------------------------------------------------------- CLI
class SolverProgressLines:
    """The solver's progress line (percent, shots, unshot fraction, ETA) on stderr at most every ``interval``
    s, with the job's prefix (the local pass's lines are :class:`.stderr_lines.StderrProgress`)."""

    def __init__(self, stream=None, interval=1.0):
        self.stream = stream if stream is not None else sys.stderr
        self.interval = interval
        self.last = -math.inf

    def __call__(self, p):
        now = time.perf_counter()
        if now - self.last < self.interval and p.unshot_fraction > p.tolerance:
            return
        self.last = now
        self.stream.write(f"{PREFIX}{p.message()}\n")
        self.stream.flush()


def build_parser():
    import argparse

    p = argparse.ArgumentParser(
        prog="blender --command hemisphere_local_pass solve",
        description="First pass: solve diffuse radiosity on the loaded scene and write the FACE-domain "
                    "radiosity attribute on every exported mesh, then save the result as --output.")
    p.add_argument("--output", "-o", required=True, help="the .blend file to save (never the file that was opened)")
    p.add_argument("--attribute", default=None, help="attribute to write (default: scene setting or 'radiosity')")
    p.add_argument("--tolerance", type=float, default=None,
                   help=f"stop when the unshot power is below this fraction of the emitted power "
                        f"(default: scene setting or {DEFAULT_TOLERANCE:g})")
    p.add_argument("--order", type=int, choices=(1, 2), default=None,
                   help="quadrature on the shooting patches: 2 (default; 3-4 points) or 1 (centroid)")
    p.add_argument("--clusters", type=int, default=None,
                   help="shoot reflected light from about this many clusters of coplanar polygons (large scenes, "
                        "docs/first-pass.md); 0: every polygon (default: scene setting or 0)")
    p.add_argument("--double-sided", action="store_true", default=None, help="patches emit and reflect on both sides")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    return p


def cli_main(argv) -> int:
    """``solve`` sub-command: returns the exit code (0 done, 1 error, 130 interrupted; nothing saved then)."""
    import bpy

    from .stderr_lines import run_command

    args = build_parser().parse_args(list(argv))

    def job():
        output = os.path.abspath(args.output)
        if not output.lower().endswith(".blend"):
            raise ValueError(f"--output must name a .blend file, got '{args.output}'")
        if bpy.data.filepath and os.path.realpath(output) == os.path.realpath(bpy.data.filepath):
            raise ValueError(f"--output '{args.output}' is the file that was opened; it is not overwritten "
                             "(give another name)")
        report = solve_first_pass(attribute=args.attribute, tolerance=args.tolerance, order=args.order,
                                  double_sided=args.double_sided, clusters=args.clusters,
                                  progress=None if args.quiet else SolverProgressLines())
        from .blend_output import save_blend

        report.outputs.append(save_blend(output))
        return report

    return run_command(job, interrupted=lambda: "interrupted; nothing was written",
                       cancelled="cancelled; nothing was written")
