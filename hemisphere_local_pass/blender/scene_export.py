"""Blender scene -> core :class:`~hemisphere_local_pass.core.Scene` (the thin extraction layer).

Every render-visible object of the evaluated depsgraph (modifiers applied, instances realised via
``depsgraph.object_instances`` with their ``matrix_world``) becomes polygons in world space. Mesh
data moves with ``foreach_get`` into preallocated arrays of the exact dtype; there is no
per-element Python loop. Conventions (docs/blender-data.md):

* radiosity (the first pass's radiance, linear RGB, W sr^-1 m^-2) comes from a mesh attribute,
  default ``radiosity``: FACE domain -> constant per polygon (the paper's case), POINT or CORNER
  domain -> linear over each triangle; FLOAT_COLOR, BYTE_COLOR (read through ``.color``, which
  Blender decodes from the stored sRGB bytes to scene-linear) or FLOAT_VECTOR.
* reflectivity rho and emission E of the receiving surface: attributes ``reflectivity`` /
  ``emission`` when present (any of the colour/vector types or FLOAT grey; FACE, POINT or CORNER
  domain, averaged over the polygon's corners), else the material (Principled BSDF base colour;
  emission colour x strength; a material without nodes gives its viewport ``diffuse_color``), else
  ``DEFAULT_REFLECTIVITY`` (0.8 grey) and ``DEFAULT_EMISSION`` (0).
* an object without the radiosity attribute is an error naming object and attribute, or with
  ``missing="black"`` a black occluder (radiance 0, still blocks light), listed in the result.
* an object with a negative-determinant transform has its polygons' corner order reversed, so the
  front side stays the side Blender shades as the front.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.scene import Scene

__all__ = [
    "DEFAULT_EMISSION",
    "DEFAULT_REFLECTIVITY",
    "ExportedScene",
    "MeshArrays",
    "export_scene",
    "mesh_arrays",
    "read_attribute",
    "render_visible_objects",
]

#: Reflectivity of a surface with neither a ``reflectivity`` attribute nor a usable material.
DEFAULT_REFLECTIVITY = (0.8, 0.8, 0.8)
#: Emission (W sr^-1 m^-2, added to the reflected radiance) of such a surface.
DEFAULT_EMISSION = (0.0, 0.0, 0.0)

#: Largest |coordinate| (scene units) accepted for a vertex, in object and in world space. Blender stores
#: an infinite coordinate as 3.4e38 (FLT_MAX); its float32 positions are spaced by more than 6e7 units
#: beyond 1e15, so nothing modelled lies there: such a vertex is an error, not a polygon to drop.
MAX_COORDINATE = 1e15

#: Attribute data types accepted for the radiosity, and the RNA property holding their value.
_VALUE_PROP = {"FLOAT_COLOR": ("color", 4), "BYTE_COLOR": ("color", 4), "FLOAT_VECTOR": ("vector", 3)}
_GREY_TYPES = {"FLOAT": ("value", 1)}
#: Object types whose evaluated geometry can be a mesh (to_mesh); lights, cameras, empties ... are ignored.
_GEOMETRY_TYPES = {"MESH", "CURVE", "SURFACE", "FONT", "META", "CURVES", "POINTCLOUD", "VOLUME", "GREASEPENCIL"}


@dataclass
class MeshArrays:
    """One evaluated mesh in Blender's layout (object space).

    Attributes:
        vertices: (V, 3) float64 coordinates.
        loop_vertices: (L,) int64 vertex of every corner.
        loop_start, loop_total: (P,) int64 first corner / corner count per polygon.
        material_index: (P,) int64.
        use_smooth: (P,) bool.
        tri_loops: (T, 3) int64 corners of Blender's own triangulation (``Mesh.loop_triangles``: the
            triangles Cycles and EEVEE render, wound like their polygon); tri_polygon: (T,) int64.
    """

    vertices: np.ndarray
    loop_vertices: np.ndarray
    loop_start: np.ndarray
    loop_total: np.ndarray
    material_index: np.ndarray
    use_smooth: np.ndarray
    tri_loops: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.int64))
    tri_polygon: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def n_polygons(self) -> int:
        return len(self.loop_start)


def _get(collection, prop: str, count: int, width: int, dtype) -> np.ndarray:
    """``collection.foreach_get(prop)`` into a new ``(count, width)`` (or ``(count,)``) array of ``dtype``."""
    out = np.empty(count * width, dtype=dtype)
    if count:
        collection.foreach_get(prop, out)
    return out.reshape(count, width) if width > 1 else out


def mesh_arrays(mesh, *, triangles: bool = False) -> MeshArrays:
    """Pull the geometry of ``mesh`` (a ``bpy.types.Mesh``) into numpy arrays (object space);
    with ``triangles`` its loop triangles too (else ``tri_loops`` / ``tri_polygon`` are empty)."""
    nv, nl, npoly = len(mesh.vertices), len(mesh.loops), len(mesh.polygons)
    verts = _get(mesh.vertices, "co", nv, 3, np.float32).astype(np.float64)
    loops = _get(mesh.loops, "vertex_index", nl, 1, np.int32).astype(np.int64)
    start = _get(mesh.polygons, "loop_start", npoly, 1, np.int32).astype(np.int64)
    total = _get(mesh.polygons, "loop_total", npoly, 1, np.int32).astype(np.int64)
    mat = _get(mesh.polygons, "material_index", npoly, 1, np.int32).astype(np.int64)
    smooth = np.zeros(npoly, dtype=bool)
    if npoly:
        mesh.polygons.foreach_get("use_smooth", smooth)
    if not triangles:
        return MeshArrays(verts, loops, start, total, mat, smooth)
    tris = mesh.loop_triangles
    if npoly and not len(tris) and hasattr(mesh, "calc_loop_triangles"):
        mesh.calc_loop_triangles()  # Blender < 4.0 computes them on request only
        tris = mesh.loop_triangles
    nt = len(tris)
    tri_loops = _get(tris, "loops", nt, 3, np.int32).astype(np.int64).reshape(nt, 3)
    tri_polygon = _get(tris, "polygon_index", nt, 1, np.int32).astype(np.int64)
    return MeshArrays(verts, loops, start, total, mat, smooth, tri_loops, tri_polygon)


def polygon_of_corner(arrays: MeshArrays) -> np.ndarray:
    """(L,) int64 polygon index of every corner."""
    return np.repeat(np.arange(arrays.n_polygons, dtype=np.int64), arrays.loop_total)


def read_attribute(mesh, arrays: MeshArrays, name: str, owner: str, *, allow_grey: bool = False):
    """Read attribute ``name`` of ``mesh`` as linear RGB.

    Returns ``None`` when the mesh has no such attribute, else ``(domain, values)`` with ``domain``
    in ``{"FACE", "POINT", "CORNER"}`` and ``values`` a ``(n_elements, 3)`` float64 array.
    Raises ``ValueError`` naming ``owner`` (the object) for a wrong domain or data type, and the
    polygon for a non-finite value.
    """
    attr = mesh.attributes.get(name)
    if attr is None:
        return None
    types = dict(_VALUE_PROP)
    if allow_grey:
        types.update(_GREY_TYPES)
    if attr.data_type not in types:
        raise ValueError(f"object '{owner}': attribute '{name}' has data type {attr.data_type}; "
                         f"expected one of {', '.join(sorted(types))}")
    if attr.domain not in ("FACE", "POINT", "CORNER"):
        raise ValueError(f"object '{owner}': attribute '{name}' is on the {attr.domain} domain; "
                         "expected FACE (constant per polygon), POINT or CORNER (linear)")
    prop, width = types[attr.data_type]
    n = len(attr.data)
    raw = _get(attr.data, prop, n, width, np.float32).astype(np.float64)
    values = np.repeat(raw[:, None], 3, axis=1) if width == 1 else raw[:, :3]
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if len(bad):
        e = int(bad[0])
        if attr.domain == "FACE":
            poly = e
        elif attr.domain == "CORNER":
            poly = int(polygon_of_corner(arrays)[e])
        else:
            users = np.flatnonzero(arrays.loop_vertices == e)
            poly = int(polygon_of_corner(arrays)[users[0]]) if len(users) else -1
        where = f"polygon {poly}" if poly >= 0 else f"unused vertex {e}"
        raise ValueError(f"object '{owner}': attribute '{name}' has a non-finite value "
                         f"{values[e].tolist()} at {where} ({attr.domain} element {e})")
    return attr.domain, values


def _per_polygon(arrays: MeshArrays, domain: str, values: np.ndarray) -> np.ndarray:
    """Average a FACE/POINT/CORNER attribute over each polygon -> (P, 3)."""
    if domain == "FACE":
        return values
    corner = values if domain == "CORNER" else values[arrays.loop_vertices]
    sums = np.add.reduceat(corner, arrays.loop_start, axis=0) if len(corner) else np.zeros((0, 3))
    return sums / np.maximum(arrays.loop_total, 1)[:, None]


def _per_corner(arrays: MeshArrays, domain: str, values: np.ndarray) -> np.ndarray:
    """A FACE/POINT/CORNER attribute as per-corner values -> (L, 3)."""
    if domain == "CORNER":
        return values
    if domain == "POINT":
        return values[arrays.loop_vertices]
    return values[polygon_of_corner(arrays)]


def _find_principled(tree):
    """The Principled BSDF feeding the active material output, else the first one in the tree."""
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL"]
    active = [n for n in outputs if getattr(n, "is_active_output", False)] or outputs
    for out in active:
        surf = out.inputs.get("Surface")
        if surf is not None and surf.is_linked:
            node = surf.links[0].from_node
            if node.type == "BSDF_PRINCIPLED":
                return node
    return next((n for n in tree.nodes if n.type == "BSDF_PRINCIPLED"), None)


def _uses_nodes_flag() -> bool:
    """Material.use_nodes matters (Blender < 5.0; deprecated since, materials always use nodes)."""
    import bpy

    return bpy.app.version < (5, 0, 0)


def material_colours(material):
    """(rho (3,), E (3,)) of a material: Principled BSDF base colour and emission colour x strength.

    ``None`` material -> the defaults. Materials without nodes give their ``diffuse_color``.
    Linked (textured) inputs fall back to the socket's default value.
    """
    rho = np.array(DEFAULT_REFLECTIVITY, dtype=np.float64)
    emit = np.array(DEFAULT_EMISSION, dtype=np.float64)
    if material is None:
        return rho, emit
    tree = material.node_tree
    if tree is not None and _uses_nodes_flag() and not material.use_nodes:
        tree = None  # before 5.0 a material may carry an unused node tree
    node = _find_principled(tree) if tree is not None else None
    if node is None:
        return np.array(material.diffuse_color[:3], dtype=np.float64), emit
    base = node.inputs.get("Base Color")
    if base is not None:
        rho = np.array(base.default_value[:3], dtype=np.float64)
    colour = node.inputs.get("Emission Color") or node.inputs.get("Emission")  # 4.0+ / 3.x name
    strength = node.inputs.get("Emission Strength")
    if colour is not None:
        emit = np.array(colour.default_value[:3], dtype=np.float64)
        emit = emit * (float(strength.default_value) if strength is not None else 1.0)
    return rho, emit


def _walk_layer_collections(layer_collection, visible: set, hidden_viewport: list):
    """Collect render-visible objects (by name) below ``layer_collection``."""
    col = layer_collection.collection
    if layer_collection.exclude or col.hide_render:
        return
    for ob in col.objects:
        if not ob.hide_render:
            visible.add(ob.name)
    for child in layer_collection.children:
        _walk_layer_collections(child, visible, hidden_viewport)


def render_visible_objects(view_layer) -> set:
    """Names of the objects a render of ``view_layer`` would include (not hidden from render,
    in a collection that is neither excluded nor hidden from render)."""
    visible: set = set()
    _walk_layer_collections(view_layer.layer_collection, visible, [])
    return visible


class _ShowHiddenInViewport:
    """Temporarily make render-visible objects that are hidden in the viewport (eye icon,
    ``hide_viewport``, hidden layer collections) evaluated, so the viewport depsgraph holds
    everything a render would; restores every flag it changed on exit."""

    def __init__(self, view_layer, names: set):
        self.view_layer = view_layer
        self.names = names
        self.undo: list = []

    def __enter__(self):
        import bpy

        def walk(lc):
            if lc.exclude or lc.collection.hide_render:
                return
            if lc.hide_viewport:
                self.undo.append((lc, "hide_viewport", True))
                lc.hide_viewport = False
            if lc.collection.hide_viewport:
                self.undo.append((lc.collection, "hide_viewport", True))
                lc.collection.hide_viewport = False
            for child in lc.children:
                walk(child)

        walk(self.view_layer.layer_collection)
        self._instanced_as_rendered(bpy)
        for name in self.names:
            ob = bpy.data.objects.get(name)
            if ob is None:
                continue
            if ob.hide_viewport:
                self.undo.append((ob, "hide_viewport", True))
                ob.hide_viewport = False
            try:
                hidden = ob.hide_get(view_layer=self.view_layer)
            except (RuntimeError, TypeError):
                hidden = False
            if hidden:
                self.undo.append((ob, "hide_set", True))
                ob.hide_set(False, view_layer=self.view_layer)
        return self

    def _instanced_as_rendered(self, bpy):
        """Collections instanced by objects (nested too): the viewport depsgraph instances what their
        viewport flags show, a render what their render flags show; make the former the latter."""
        stack = [ob.instance_collection for ob in bpy.data.objects if ob.instance_type == "COLLECTION"]
        seen = set()
        while stack:
            col = stack.pop()
            if col is None or col.as_pointer() in seen:
                continue
            seen.add(col.as_pointer())
            for target in (col, *col.objects):
                if target.hide_viewport != target.hide_render:
                    self.undo.append((target, "hide_viewport", target.hide_viewport))
                    target.hide_viewport = target.hide_render
            stack.extend(ob.instance_collection for ob in col.objects if ob.instance_type == "COLLECTION")
            stack.extend(col.children)

    def __exit__(self, *exc):
        for target, what, value in reversed(self.undo):
            if what == "hide_set":
                target.hide_set(value, view_layer=self.view_layer)
            else:
                setattr(target, what, value)
        return False


@dataclass
class ExportedScene:
    """The scene as the core sees it, with what the Blender layer needs to map results back.

    Attributes:
        scene: the core Scene (world space; input polygon i = row i of the arrays below).
        reflectivity: (P, 3) float64 rho of every input polygon.
        emission: (P, 3) float64 E of every input polygon (front side).
        polygon_object: (P,) int64 index into ``objects``.
        polygon_index: (P,) int64 polygon index inside that object's evaluated mesh.
        objects: names of the exported objects (instances as "Object (instance k of Parent)").
        object_pass_index: (n_objects,) int64 ``Object.pass_index`` of each.
        black_occluders: names of objects without the radiosity attribute exported as black occluders.
        linear: radiosity varies linearly over triangles (some object has POINT/CORNER values).
    """

    scene: Scene
    reflectivity: np.ndarray
    emission: np.ndarray
    polygon_object: np.ndarray
    polygon_index: np.ndarray
    objects: list
    object_pass_index: np.ndarray
    black_occluders: list = field(default_factory=list)
    linear: bool = False

    def polygon_name(self, i: int) -> str:
        """``"Object.polygon j"`` for input polygon ``i``."""
        return f"{self.objects[int(self.polygon_object[i])]}.polygon {int(self.polygon_index[i])}"

    def dropped_names(self) -> list:
        """Names of the polygons the core dropped as degenerate, with the reason."""
        return [f"{self.polygon_name(i)}: {why}" for i, why in sorted(self.scene.dropped.items())]


@dataclass
class _Part:
    name: str
    pass_index: int
    arrays: MeshArrays  # world space
    radiance: tuple  # (domain, values) or None (black occluder)
    rho: np.ndarray  # (P, 3)
    emit: np.ndarray  # (P, 3)


def _reverse_corners(arrays: MeshArrays) -> np.ndarray:
    """(L,) permutation reversing each polygon's corner order, keeping its first corner first."""
    poly = polygon_of_corner(arrays)
    j = np.arange(len(arrays.loop_vertices), dtype=np.int64) - arrays.loop_start[poly]
    total = arrays.loop_total[poly]
    return arrays.loop_start[poly] + np.where(j == 0, 0, total - j)


def _check_vertices(name, ob, arrays: MeshArrays, world=None):
    """Raise ``ValueError`` for a non-finite or absurdly large (> :data:`MAX_COORDINATE`) coordinate
    of a vertex some polygon uses, naming the object, the vertex's index in its own (evaluated) mesh
    and all three coordinates. With ``world`` (the same vertices in world space) that is checked instead.
    Returns the (V,) bool mask of the vertices some polygon uses (loose vertices are not rendered)."""
    used = np.zeros(len(arrays.vertices), dtype=bool)
    used[arrays.loop_vertices] = True
    for space, co in [("", arrays.vertices)] if world is None else [(" in world space", world)]:
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(used & ~(np.abs(co) <= MAX_COORDINATE).all(axis=1))
        if not len(bad):
            continue
        v = int(bad[0])
        values = ", ".join(repr(float(c)) for c in co[v])
        finite = bool(np.isfinite(co[v]).all())
        what = f"coordinates beyond {MAX_COORDINATE:g}" if finite else "non-finite coordinates"
        if finite and np.abs(co[v]).max() >= 3.4e38:
            what += " (Blender stores an infinite coordinate as 3.4e38)"
        local = "" if not space else " (object space: (" + ", ".join(repr(float(c)) for c in arrays.vertices[v]) + "))"
        original = getattr(ob, "original", ob)
        derived = original.type != "MESH" or any(m.show_viewport for m in original.modifiers)
        index = f"vertex {v}" + (" of its evaluated mesh (after modifiers)" if derived else "")
        more = f" (and {len(bad) - 1} more vertices)" if len(bad) > 1 else ""
        raise ValueError(f"object '{name}': {index} has {what}: ({values}){space}{local}{more}")
    return used


def _object_part(name, ob, mesh, matrix, *, attribute, rho_attr, emit_attr, missing, pass_index, cache_key, cache):
    """Extract one evaluated mesh (cached per mesh datablock) and place it in world space."""
    local = cache.get(cache_key)
    if local is None:
        arrays = mesh_arrays(mesh, triangles=True)
        _check_vertices(name, ob, arrays)
        radiance = read_attribute(mesh, arrays, attribute, name)
        rho_vals = read_attribute(mesh, arrays, rho_attr, name, allow_grey=True) if rho_attr else None
        emit_vals = read_attribute(mesh, arrays, emit_attr, name, allow_grey=True) if emit_attr else None
        n = arrays.n_polygons
        # material colours per slot, indexed by material_index (clamped as Blender does)
        slots = [s.material for s in ob.material_slots] or [None]
        table = [material_colours(m) for m in slots]
        slot = np.clip(arrays.material_index, 0, len(table) - 1)
        rho_tab = np.array([t[0] for t in table]).reshape(-1, 3)
        emit_tab = np.array([t[1] for t in table]).reshape(-1, 3)
        rho = _per_polygon(arrays, *rho_vals) if rho_vals is not None else rho_tab[slot]
        emit = _per_polygon(arrays, *emit_vals) if emit_vals is not None else emit_tab[slot]
        local = (arrays, radiance, rho.reshape(n, 3), emit.reshape(n, 3))
        cache[cache_key] = local
    arrays, radiance, rho, emit = local
    if radiance is None and missing != "black":
        raise ValueError(f"object '{name}' has no attribute '{attribute}' (the radiosity of its polygons); "
                         "add it, or set Missing Attribute to Black Occluder (command line: --missing black; "
                         "Python: missing=\"black\") to treat the object as a black occluder")
    m = np.asarray(matrix, dtype=np.float64).reshape(4, 4)
    world = arrays.vertices @ m[:3, :3].T + m[:3, 3]
    used = _check_vertices(name, ob, arrays, world)
    if not used.all():
        world[~used] = 0.0  # loose vertices are not rendered; whatever they hold must not reach the core
    loops = arrays.loop_vertices
    tri_loops = arrays.tri_loops
    if np.linalg.det(m[:3, :3]) < 0:  # mirrored: keep Blender's front side
        perm = _reverse_corners(arrays)
        loops = loops[perm]
        if radiance is not None and radiance[0] == "CORNER":
            radiance = ("CORNER", radiance[1][perm])
        inverse = np.argsort(perm)  # new position of every old corner
        tri_loops = inverse[tri_loops[:, ::-1]]  # the same triangles, reversed like their polygons
    placed = MeshArrays(world, loops, arrays.loop_start, arrays.loop_total, arrays.material_index, arrays.use_smooth,
                        tri_loops, arrays.tri_polygon)
    return _Part(name, pass_index, placed, radiance, rho, emit)


def export_scene(
    scene=None,
    *,
    depsgraph=None,
    view_layer=None,
    attribute: str = "radiosity",
    reflectivity_attribute: str = "reflectivity",
    emission_attribute: str = "emission",
    missing: str = "error",
    double_sided: bool = False,
    status=None,
) -> ExportedScene:
    """Build the core Scene from every render-visible object of ``scene`` (default: the context's).

    Args:
        scene: ``bpy.types.Scene``; its view layer ``view_layer`` (default the context's, else the
            first) decides visibility.
        depsgraph: an evaluated depsgraph to use as it is (tests); default: the view layer's,
            evaluated after temporarily un-hiding render-visible objects hidden in the viewport.
        attribute: name of the radiosity attribute.
        reflectivity_attribute, emission_attribute: names of the optional rho / E attributes
            (empty string: use the material only).
        missing: ``"error"`` (default) or ``"black"``: what to do with objects lacking ``attribute``.
        double_sided: polygons emit from both sides.
        status: optional ``status(text)``, told what the export is doing as it goes (the depsgraph
            evaluation, then objects and polygons read so far, then building the core scene).

    Raises:
        ValueError: missing/invalid attribute (naming object and attribute), empty scene.
    """
    import bpy

    if missing not in ("error", "black"):
        raise ValueError(f"missing must be 'error' or 'black', got {missing!r}")
    if scene is None:
        scene = bpy.context.scene
    if view_layer is None:
        ctx_layer = getattr(bpy.context, "view_layer", None)
        view_layer = ctx_layer if ctx_layer is not None and ctx_layer.id_data == scene else scene.view_layers[0]
    visible = render_visible_objects(view_layer)
    say = status if status is not None else (lambda text: None)
    args = (visible, attribute, reflectivity_attribute, emission_attribute, missing, double_sided, say)
    if depsgraph is None:
        with _ShowHiddenInViewport(view_layer, visible):
            say(f"exporting the scene: evaluating {len(visible)} objects (modifiers, instances)")
            depsgraph = view_layer.depsgraph
            depsgraph.update()
            return _export(depsgraph, *args)
    return _export(depsgraph, *args)


def _export(depsgraph, visible, attribute, rho_attr, emit_attr, missing, double_sided, say) -> ExportedScene:
    """One :class:`_Part` per render-visible geometry of ``depsgraph``, in the depsgraph's order.

    ``depsgraph.object_instances`` yields, for an instance, a temporary object that Blender reuses
    for the next instance: its ``type``, ``data``, material slots and matrix are valid during that
    iteration step only (kept references later read the last instance's data, or garbage). So each
    instance's mesh arrays, materials and matrix are copied inside the loop; only original IDs
    (``ob.original``), which persist, are kept past it.
    """
    parts: list = []  # _Part, or (original object, matrix, pass index) for a to_mesh() after the loop
    cache: dict = {}
    counts: dict = {}
    mesh_parents = set()  # non-mesh objects whose evaluated geometry arrives as a MESH instance
    kw = dict(attribute=attribute, rho_attr=rho_attr, emit_attr=emit_attr, missing=missing, cache=cache)
    n_read = 0
    say("exporting the scene: reading meshes")
    for inst in depsgraph.object_instances:
        ob = inst.object
        original = ob.original
        base = original.name
        is_instance = inst.is_instance
        parent_name = None
        if is_instance:
            parent = inst.parent
            parent_name = parent.original.name if parent is not None else base
            if parent_name not in visible or original.hide_render:
                continue
        elif base not in visible:
            continue
        kind = ob.type
        if kind not in _GEOMETRY_TYPES:
            continue  # lights, cameras, empties, ...
        matrix = np.array(inst.matrix_world, dtype=np.float64)
        if kind == "MESH":
            if is_instance:
                if base == parent_name:
                    mesh_parents.add(parent_name)
                k = counts.get((base, parent_name), 0)
                counts[(base, parent_name)] = k + 1
                name = base if base == parent_name and k == 0 else f"{base} (instance {k} of {parent_name})"
            else:
                name = base
            key = (ob.data.as_pointer(), base)
            parts.append(_object_part(name, ob, ob.data, matrix, pass_index=ob.pass_index, cache_key=key, **kw))
            n_read += parts[-1].arrays.n_polygons
            say(f"exporting the scene: {len(parts)} objects, {n_read} polygons read")
        elif not is_instance:
            parts.append((original, matrix, ob.pass_index))  # its evaluated object persists: convert later
    for i, part in enumerate(parts):
        if isinstance(part, _Part):
            continue
        original, matrix, pass_index = part
        parts[i] = None
        if original.name in mesh_parents:
            continue  # its geometry came as the MESH instance above
        ob = original.evaluated_get(depsgraph)
        mesh = ob.to_mesh()  # curves, text, surfaces, metaballs -> mesh if they produce geometry
        try:
            if mesh is not None and len(mesh.polygons):
                parts[i] = _object_part(original.name, ob, mesh, matrix, pass_index=pass_index,
                                        cache_key=("to_mesh", original.name), **kw)
        finally:
            ob.to_mesh_clear()
    parts = [p for p in parts if p is not None and p.arrays.n_polygons]
    if not parts:
        raise ValueError("the scene has no render-visible geometry (no mesh, curve or text object with polygons)")
    say(f"exporting the scene: {len(parts)} objects; building the scene of "
        f"{sum(p.arrays.n_polygons for p in parts)} polygons")
    return _assemble(parts, double_sided)


def _assemble(parts, double_sided) -> ExportedScene:
    """Concatenate the world-space parts into one core Scene."""
    n_v = np.cumsum([0] + [len(p.arrays.vertices) for p in parts])
    n_l = np.cumsum([0] + [len(p.arrays.loop_vertices) for p in parts])
    verts = np.concatenate([p.arrays.vertices for p in parts])
    loops = np.concatenate([p.arrays.loop_vertices + n_v[i] for i, p in enumerate(parts)])
    starts = np.concatenate([p.arrays.loop_start + n_l[i] for i, p in enumerate(parts)])
    totals = np.concatenate([p.arrays.loop_total for p in parts])
    n_p = np.cumsum([0] + [p.arrays.n_polygons for p in parts])
    tri_loops = np.concatenate([p.arrays.tri_loops + n_l[i] for i, p in enumerate(parts)])
    tri_polygon = np.concatenate([p.arrays.tri_polygon + n_p[i] for i, p in enumerate(parts)])
    linear = any(p.radiance is not None and p.radiance[0] != "FACE" for p in parts)
    if linear:
        corner = np.concatenate([
            np.zeros((len(p.arrays.loop_vertices), 3)) if p.radiance is None else _per_corner(p.arrays, *p.radiance)
            for p in parts
        ])
        poly_rad = None
    else:
        corner = None
        poly_rad = np.concatenate([
            np.zeros((p.arrays.n_polygons, 3)) if p.radiance is None else p.radiance[1] for p in parts
        ])
    objects = [p.name for p in parts]
    polygon_object = np.concatenate([np.full(p.arrays.n_polygons, i, dtype=np.int64) for i, p in enumerate(parts)])
    polygon_index = np.concatenate([np.arange(p.arrays.n_polygons, dtype=np.int64) for p in parts])
    names = _PolygonNames(objects, polygon_object, polygon_index)
    # wherever the core would split a polygon (linear radiance; concave or non-planar n-gons) it takes
    # Blender's own triangles: the surface and the interpolated radiance Blender renders
    core_scene = Scene.from_arrays(verts, loops, starts, totals, poly_rad, corner,
                                   double_sided=double_sided, polygon_names=names,
                                   loop_triangles=tri_loops, loop_triangle_polygons=tri_polygon)
    return ExportedScene(
        scene=core_scene,
        reflectivity=np.concatenate([p.rho for p in parts]),
        emission=np.concatenate([p.emit for p in parts]),
        polygon_object=polygon_object,
        polygon_index=polygon_index,
        objects=objects,
        object_pass_index=np.array([p.pass_index for p in parts], dtype=np.int64),
        black_occluders=[p.name for p in parts if p.radiance is None],
        linear=linear,
    )


class _PolygonNames:
    """Callable label ``"Object.polygon j"`` for the core's error messages (picklable, no closures)."""

    def __init__(self, objects, polygon_object, polygon_index):
        self.objects = objects
        self.polygon_object = polygon_object
        self.polygon_index = polygon_index

    def __call__(self, i: int) -> str:
        return f"{self.objects[int(self.polygon_object[i])]}.polygon {int(self.polygon_index[i])}"
