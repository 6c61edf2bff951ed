"""Results out of the core into files and Blender data: OpenEXR, the "Local Pass" image, a PNG
preview, and the ``hlp_radiance`` / ``hlp_irradiance`` colour attributes of vertex mode.

Image arrays here are ``(H, W, ...)`` with row 0 at the *bottom* (Blender's convention); the EXR
writer flips them to the file's top-down order.

EXR channels (all FLOAT, 32-bit; one part, scanlines, ZIP compression):

===================== ============================================================
``R G B``             radiance L = E + rho/pi H (W sr^-1 m^-2, linear RGB)
``A``                 coverage: fraction of the pixel's samples that hit a surface
``irradiance_R/G/B``  irradiance H (W m^-2)
``form_factor_sum``   sum of the visible form factors (1 inside a closed scene)
``Z``                 view depth (camera-space -z) of the pixel centre's hit; 1e10 for a miss
``object_index``      index of the hit object in the job's object list; -1 for a miss
``polygon_index``     polygon index inside that object's evaluated mesh; -1 for a miss
``error_estimate``    adaptive pass: estimated error of H (W m^-2); at its samples their bound, 0 where exact
``exact_sample``      fraction of the pixel's samples evaluated by the core, not interpolated (1: all)
===================== ============================================================

Written with the OpenEXR package (ZIP compression) when it is importable (the built extension bundles
its wheel) and Blender is 4.2 or newer, else with a small built-in writer (uncompressed scanlines;
Blender 3.4 as a legacy add-on, where the wheel clashes with Blender's own OpenEXR library).

A tile (``--tile I/N``) is a file with the full image as its display window and only its rows as
its data window; :func:`merge_exr` assembles the tiles.
"""

from __future__ import annotations

import os
import stat
import tempfile
import zlib

import numpy as np

__all__ = [
    "CHANNELS",
    "MISS_DEPTH",
    "check_writable",
    "merge_exr",
    "read_exr",
    "replace_atomically",
    "store_image",
    "write_exr",
    "write_png",
    "write_vertex_colours",
    "make_active_colour",
    "owns_attribute",
    "prepare_vertex_attribute",
]

#: Depth written where a pixel's centre sample misses every surface (as Blender's Z pass).
MISS_DEPTH = 1e10

#: EXR channel name -> (key in the layers dict, component).
CHANNELS = {
    "R": ("radiance", 0), "G": ("radiance", 1), "B": ("radiance", 2), "A": ("alpha", None),
    "irradiance_R": ("irradiance", 0), "irradiance_G": ("irradiance", 1), "irradiance_B": ("irradiance", 2),
    "form_factor_sum": ("form_factor_sum", None), "Z": ("depth", None),
    "object_index": ("object_index", None), "polygon_index": ("polygon_index", None),
}
#: Channels written when the layers hold them (the adaptive pass, ``core.adaptive_irradiance``): the
#: per-pixel error estimate of H (0 where exact) and the fraction of the pixel's samples evaluated exactly.
OPTIONAL_CHANNELS = {"error_estimate": ("error_estimate", None), "exact_sample": ("exact_sample", None)}
#: Header attribute names of our metadata.
_META = ("hlp_tile", "hlp_window", "hlp_fingerprint", "hlp_software")


def check_writable(path: str) -> str:
    """Fail early (``ValueError`` giving the real reason) when ``path`` cannot be written; return it
    resolved (absolute, ``//`` relative to the .blend file, symbolic links followed)."""
    from .output_paths import check_writable as check

    return check(path)


def _new_file_mode(path: str) -> int:
    """Permission bits for the file written at ``path``: those of the file it replaces, else what
    ``open(path, "w")`` gives (0666 & ~umask). ``mkstemp`` alone would leave 0600."""
    from .output_paths import umask

    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return 0o666 & ~umask()


def replace_atomically(path: str, write) -> str:
    """Call ``write(tmp_path)`` on a temporary file in the directory of ``path``, give it ordinary
    permissions (:func:`_new_file_mode`), then rename it over ``path`` (``os.replace``): readers
    never see a half-written file. A symbolic link is written through: its target is replaced."""
    path = os.path.realpath(os.path.abspath(os.fspath(path)))
    folder, base = os.path.split(path)
    stem, ext = os.path.splitext(base)
    fd, tmp = tempfile.mkstemp(prefix=f".{stem}.", suffix=f".tmp{ext}", dir=folder)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, _new_file_mode(path))
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _openexr():
    """The OpenEXR package, or None: not installed (a legacy add-on has no bundled wheels), or
    Blender older than 4.2, whose own OpenEXR library clashes with the wheel's (Debian's 3.4 links
    the system OpenEXR 3.1 and crashes in ``OpenEXR.File.write``)."""
    try:
        import bpy

        if bpy.app.version < (4, 2, 0):
            return None
    except ImportError:
        pass
    try:
        import OpenEXR
    except ImportError:
        return None
    return OpenEXR


# ------------------------------------------------------------- minimal EXR codec (no dependency)
# Single-part scanline files, FLOAT channels, NO_COMPRESSION: what OpenEXR, Blender and every EXR
# reader accept. Used when the OpenEXR package is missing, and to read such files back.
_MAGIC = b"\x76\x2f\x31\x01"


def _attr(name: str, kind: str, payload: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + np.int32(len(payload)).tobytes() + payload


def _write_plain_exr(path: str, channels: dict, display, data, strings: dict):
    """channels: name -> (h, w) float32, top row first; display/data: inclusive (x0, y0, x1, y1)."""
    names = sorted(channels)
    chlist = b"".join(n.encode() + b"\0" + np.array([2], "<i4").tobytes() + b"\0\0\0\0"
                      + np.array([1, 1], "<i4").tobytes() for n in names) + b"\0"
    header = b"".join([
        _attr("channels", "chlist", chlist),
        _attr("compression", "compression", b"\0"),
        _attr("dataWindow", "box2i", np.array(data, "<i4").tobytes()),
        _attr("displayWindow", "box2i", np.array(display, "<i4").tobytes()),
        _attr("lineOrder", "lineOrder", b"\0"),
        _attr("pixelAspectRatio", "float", np.array([1.0], "<f4").tobytes()),
        _attr("screenWindowCenter", "v2f", np.zeros(2, "<f4").tobytes()),
        _attr("screenWindowWidth", "float", np.array([1.0], "<f4").tobytes()),
    ] + [_attr(k, "string", str(v).encode()) for k, v in sorted(strings.items())]) + b"\0"
    x0, y0, x1, y1 = data
    h = y1 - y0 + 1
    stack = np.stack([np.asarray(channels[n], dtype="<f4") for n in names], axis=1)  # (h, c, w)
    line = stack.reshape(h, -1)  # one scanline: every channel's w values in turn
    start = 8 + len(header) + 8 * h
    chunk = 8 + line.shape[1] * 4
    offsets = start + chunk * np.arange(h, dtype="<u8")
    with open(path, "wb") as fh:
        fh.write(_MAGIC + np.array([2], "<i4").tobytes() + header + offsets.astype("<u8").tobytes())
        heads = np.stack([np.arange(y0, y1 + 1), np.full(h, line.shape[1] * 4)], axis=1).astype("<i4")
        rows = np.concatenate([heads.view("<f4"), line.astype("<f4")], axis=1)  # (h, 2 + c w) 4-byte words
        fh.write(rows.tobytes())


def _read_plain_exr(path: str):
    """Read an uncompressed scanline FLOAT file -> (channels top row first, header dict)."""
    with open(path, "rb") as fh:
        buf = fh.read()
    if buf[:4] != _MAGIC:
        raise ValueError(f"'{path}' is not an OpenEXR file")
    pos, header = 8, {}
    while buf[pos] != 0:
        end = buf.index(b"\0", pos)
        name = buf[pos:end].decode()
        end2 = buf.index(b"\0", end + 1)
        kind = buf[end + 1:end2].decode()
        size = int(np.frombuffer(buf, "<i4", 1, end2 + 1)[0])
        payload = buf[end2 + 5:end2 + 5 + size]
        pos = end2 + 5 + size
        header[name] = (kind, payload)
    pos += 1
    if header["compression"][1] != b"\0":
        raise ValueError(f"'{path}' is compressed: reading it needs the OpenEXR package (pip install openexr)")
    names, p, chl = [], 0, header["channels"][1]
    while chl[p] != 0:
        end = chl.index(b"\0", p)
        names.append(chl[p:end].decode())
        if int(np.frombuffer(chl, "<i4", 1, end + 1)[0]) != 2:
            raise ValueError(f"'{path}': channel {names[-1]} is not FLOAT")
        p = end + 17
    dx0, dy0, dx1, dy1 = np.frombuffer(header["dataWindow"][1], "<i4").tolist()
    h, w = dy1 - dy0 + 1, dx1 - dx0 + 1
    offsets = np.frombuffer(buf, "<u8", h, pos).astype(np.int64)
    out = {n: np.empty((h, w), np.float32) for n in names}
    for off in offsets:
        y = int(np.frombuffer(buf, "<i4", 1, off)[0]) - dy0
        vals = np.frombuffer(buf, "<f4", len(names) * w, off + 8).reshape(len(names), w)
        for c, n in enumerate(names):
            out[n][y] = vals[c]
    meta = {"dataWindow": (np.array([dx0, dy0]), np.array([dx1, dy1])),
            "displayWindow": tuple(np.frombuffer(header["displayWindow"][1], "<i4").reshape(2, 2))}
    for k, (kind, payload) in header.items():
        if kind == "string":
            meta[k] = payload.decode()
    return out, meta


def write_exr(path: str, layers: dict, *, size, window=None, metadata=None) -> str:
    """Write ``layers`` to an OpenEXR file atomically.

    With the OpenEXR package: ZIP-compressed; without it (a legacy add-on in Blender 3.4), the
    built-in uncompressed writer. Both are single-part scanline files with FLOAT channels.

    Args:
        layers: ``radiance`` (h, w, 3), ``irradiance`` (h, w, 3), ``alpha``, ``form_factor_sum``,
            ``depth``, ``object_index``, ``polygon_index`` (h, w) arrays, row 0 at the bottom,
            covering ``window``.
        size: ``(W, H)`` of the full image (the display window).
        window: ``(x0, y0, x1, y1)`` half-open pixel window (y from the bottom) the arrays cover;
            default the full image.
        metadata: extra string header attributes.
    """
    exr = _openexr()
    w_img, h_img = size
    x0, y0, x1, y1 = window if window is not None else (0, 0, w_img, h_img)
    channels = {}
    optional = {n: kc for n, kc in OPTIONAL_CHANNELS.items() if kc[0] in layers}
    for name, (key, comp) in {**CHANNELS, **optional}.items():
        arr = np.asarray(layers[key])
        arr = arr[..., comp] if comp is not None else arr
        if arr.shape != (y1 - y0, x1 - x0):
            raise ValueError(f"layer {key} has shape {arr.shape}, expected {(y1 - y0, x1 - x0)}")
        channels[name] = np.ascontiguousarray(arr[::-1], dtype=np.float32)  # top row first
    # EXR windows are inclusive, y down from the top of the display window
    data = (x0, h_img - y1, x1 - 1, h_img - y0 - 1)
    display = (0, 0, w_img - 1, h_img - 1)
    strings = {"hlp_software": "hemisphere_local_pass", "hlp_window": f"{x0} {y0} {x1} {y1}"}
    strings.update({k: str(v) for k, v in (metadata or {}).items()})
    if exr is None:
        return replace_atomically(path, lambda tmp: _write_plain_exr(tmp, channels, display, data, strings))
    header = {
        "compression": exr.ZIP_COMPRESSION,
        "type": exr.scanlineimage,
        "displayWindow": (np.array(display[:2], dtype=np.int32), np.array(display[2:], dtype=np.int32)),
        "dataWindow": (np.array(data[:2], dtype=np.int32), np.array(data[2:], dtype=np.int32)),
    }
    header.update(strings)
    return replace_atomically(path, lambda tmp: exr.File(header, channels).write(tmp))


def read_exr(path: str):
    """Read one of our EXR files -> ``(layers, size, window, header)`` (arrays row 0 at the bottom)."""
    exr = _openexr()
    if exr is None:
        chans, header = _read_plain_exr(os.fspath(path))
    else:
        f = exr.File(os.fspath(path), separate_channels=True)
        header = f.header()
        chans = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    (dx0, dy0), (dx1, dy1) = header["displayWindow"]
    (ax0, ay0), (ax1, ay1) = header["dataWindow"]
    w_img, h_img = int(dx1 - dx0 + 1), int(dy1 - dy0 + 1)
    window = (int(ax0 - dx0), int(dy1 - ay1), int(ax1 - dx0 + 1), int(dy1 - ay0 + 1))
    chans = {name: c[::-1] for name, c in chans.items()}
    missing = [n for n in CHANNELS if n not in chans]
    if missing:
        raise ValueError(f"'{path}' is not a local-pass EXR (no channel {missing[0]!r})")
    layers = {}
    for key in ("radiance", "irradiance"):
        layers[key] = np.stack([chans[n] for n, (k, _) in CHANNELS.items() if k == key], axis=-1)
    for n, (k, comp) in {**CHANNELS, **OPTIONAL_CHANNELS}.items():
        if comp is None and n in chans:
            layers[k] = chans[n]
    return layers, (w_img, h_img), window, header


def merge_exr(paths, output: str, *, overwrite: bool = False, preview: bool = False, report=None) -> str:
    """Assemble tile files (row bands of one image) into ``output``; every row must be covered once.

    ``output`` (and the preview) follow the overwrite rule of :mod:`.output_paths` (an existing file
    is replaced only when it is ours and ``overwrite``). ``preview``: also write the whole image's
    PNG preview next to it (needs bpy); a refused preview is listed in ``report["refused"]``
    (``report``: a dict with lists ``written`` and ``refused``) instead of stopping the merge."""
    from .output_paths import OutputRefused, check_new_or_ours

    output = check_writable(output)
    if not paths:
        raise ValueError("merge needs at least one tile file")
    size = None
    fingerprint = None
    full = None
    covered = None
    for p in paths:
        if not os.path.isfile(p):
            raise ValueError(f"tile file '{p}' does not exist")
        layers, sz, window, header = read_exr(p)
        fp = header.get("hlp_fingerprint")
        if size is None:
            size, fingerprint = sz, fp
            w, h = size
            full = {k: np.zeros((h, w) + v.shape[2:], dtype=np.float32) for k, v in layers.items()}
            full["depth"][:] = MISS_DEPTH
            full["object_index"][:] = -1
            full["polygon_index"][:] = -1
            covered = np.zeros((h, w), dtype=np.int64)
        elif sz != size:
            raise ValueError(f"tile '{p}' is {sz[0]} x {sz[1]}, the first tile {size[0]} x {size[1]}")
        elif fp != fingerprint:
            raise ValueError(f"tile '{p}' belongs to a different job (scene, camera or settings differ)")
        x0, y0, x1, y1 = window
        for k, v in layers.items():
            full[k][y0:y1, x0:x1] = v
        covered[y0:y1, x0:x1] += 1
    if (covered > 1).any():
        raise ValueError("tiles overlap: the same rows appear in more than one tile file")
    rows = covered.any(axis=1)
    ys = np.flatnonzero(rows)
    xs = np.flatnonzero(covered.any(axis=0))
    window = (int(xs[0]), int(ys[0]), int(xs[-1]) + 1, int(ys[-1]) + 1)
    x0, y0, x1, y1 = window
    if not rows[y0:y1].all():
        gap = int(np.flatnonzero(~rows[y0:y1])[0]) + y0
        raise ValueError(f"tiles leave a gap: row {gap} (from the bottom) is in no tile file")
    crop = {k: v[y0:y1, x0:x1] for k, v in full.items()}
    meta = {"hlp_fingerprint": fingerprint} if fingerprint else None
    output = check_new_or_ours(output, "exr", overwrite=overwrite, what="merge output")
    png = None
    if preview:
        try:
            png = check_new_or_ours(os.path.splitext(output)[0] + ".png", "png", overwrite=overwrite, what="preview")
        except OutputRefused as exc:
            if report is not None:
                report["refused"].append(f"{exc}")
    path = write_exr(output, crop, size=size, window=window, metadata=meta)
    if report is not None:
        report["written"].append(path)
    if png is not None:
        w, h = size
        rgb = np.zeros((h, w, 3))
        rgb[y0:y1, x0:x1] = crop["radiance"]
        written = write_png(png, rgb)
        if report is not None:
            report["written"].append(written)
    return path


def store_image(name: str, rgba: np.ndarray):
    """Put ``rgba (H, W, 4)`` (row 0 at the bottom, linear) into the float image datablock ``name``
    (created or resized as needed) and return it."""
    import bpy

    h, w = rgba.shape[:2]
    img = bpy.data.images.get(name)
    if img is not None and (not img.is_float or img.source != "GENERATED"):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    elif tuple(img.size) != (w, h):
        img.scale(w, h)
    img.pixels.foreach_set(np.ascontiguousarray(rgba, dtype=np.float32).reshape(-1))
    img.update()
    return img


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) of linear values clipped to [0, 1]."""
    x = np.clip(np.nan_to_num(np.asarray(linear, dtype=np.float64)), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def _png_mark_ours(path: str):
    """Insert the ``tEXt`` chunk ``Software = hemisphere_local_pass`` right after IHDR: how a later
    run recognises the preview as ours (see :mod:`.output_paths`)."""
    from .output_paths import SOFTWARE

    with open(path, "rb") as fh:
        buf = fh.read()
    if buf[:8] != b"\x89PNG\r\n\x1a\n" or buf[12:16] != b"IHDR":
        raise ValueError(f"'{path}' is not the PNG Blender was asked to write")
    end = 8 + 12 + int.from_bytes(buf[8:12], "big")  # after IHDR: length, type, data, CRC
    data = b"Software\0" + SOFTWARE.encode("latin-1")
    chunk = (len(data).to_bytes(4, "big") + b"tEXt" + data
             + (zlib.crc32(b"tEXt" + data) & 0xFFFFFFFF).to_bytes(4, "big"))
    with open(path, "wb") as fh:
        fh.write(buf[:end] + chunk + buf[end:])


def write_png(path: str, rgb: np.ndarray, *, exposure: float = 0.0) -> str:
    """Write a preview PNG of linear ``rgb (H, W, 3)`` (row 0 at the bottom): scaled by
    ``2**exposure``, clipped to [0, 1], sRGB-encoded (a plain "Standard" view transform), 8-bit,
    saved through Blender's image writer, atomically."""
    import bpy

    h, w = rgb.shape[:2]
    enc = srgb_encode(np.asarray(rgb, dtype=np.float64) * (2.0 ** exposure))
    rgba = np.concatenate([enc, np.ones((h, w, 1))], axis=-1).astype(np.float32)
    img = bpy.data.images.new(".hlp_preview", w, h, alpha=False, float_buffer=False)
    try:
        img.pixels.foreach_set(rgba.reshape(-1))  # byte image: values are stored as they are (display)

        def save(tmp):
            img.filepath_raw = tmp
            img.file_format = "PNG"
            img.save()
            _png_mark_ours(tmp)

        return replace_atomically(path, save)
    finally:
        bpy.data.images.remove(img)


#: Custom property on a mesh listing the colour attributes this extension created (so a later run
#: may overwrite them, and never an attribute the user made).
OWNED_KEY = "hlp_owned_attributes"


#: Where the user sets each vertices-mode target name (panel field, command-line option).
TARGET_OPTIONS = {
    "radiance": "Radiance Attribute in the panel (Vertices mode), --radiance-attribute NAME on the command line",
    "irradiance": "Irradiance Attribute in the panel (Vertices mode), --irradiance-attribute NAME on the command line",
}


def prepare_vertex_attribute(mesh, name: str, domain: str, *, protected=(), explicit: bool = False, owner=None,
                             role: str = "radiance"):
    """Check that ``name`` may be written on ``mesh`` (an owner's message otherwise).

    Allowed when the attribute does not exist, was created by this extension (listed in the mesh's
    ``hlp_owned_attributes`` property), or the user named it explicitly as the target. Never when it
    is one of ``protected`` (the radiosity input) or a built-in attribute. Messages name the object
    ``owner`` (default: the mesh) as the user sees it in the outliner, and the setting ``role``
    ("radiance" / "irradiance") that chooses another name.
    """
    existing = mesh.attributes.get(name)
    who = f"object '{owner}'" if owner else f"mesh '{mesh.name}'"
    where = TARGET_OPTIONS.get(role, TARGET_OPTIONS["radiance"])
    if name in protected:
        raise ValueError(f"{who}: the output attribute '{name}' is also an input of the job; choose another name: "
                         f"{where}")
    if name.startswith(".") or name in ("position", "sharp_face", "material_index", "UVMap"):
        raise ValueError(f"{who}: '{name}' is a built-in attribute and cannot be an output; choose another name: "
                         f"{where}")
    if existing is None:
        return
    owned = list(mesh.get(OWNED_KEY, []))
    if name not in owned and not explicit:
        mesh_note = f" (on its mesh '{mesh.name}')" if owner and owner != mesh.name else ""
        raise ValueError(f"{who} already has a user attribute '{name}'{mesh_note}; it is not overwritten: "
                         f"choose another name ({where}), or rename yours")


def owns_attribute(mesh, name: str) -> bool:
    """``name`` exists on ``mesh`` and was created by this extension (see :func:`prepare_vertex_attribute`)."""
    return mesh.attributes.get(name) is not None and name in list(mesh.get(OWNED_KEY, []))


def make_active_colour(mesh, name: str):
    """Make the colour attribute ``name`` the active one (what the viewport's Attribute colour and
    vertex paint show); Blender 3.2+ API names differ by version."""
    attr = mesh.attributes.get(name)
    if attr is None:
        return
    for group in (getattr(mesh, "color_attributes", None), mesh.attributes):
        if group is not None and hasattr(group, "active_color"):  # 3.2+ (color_attributes: 3.3+)
            group.active_color = group.get(name) if hasattr(group, "get") else attr
            return


def write_vertex_colours(mesh, name: str, domain: str, values: np.ndarray, mask=None):
    """Write ``values (n, 3)`` (n = vertices for POINT, corners for CORNER) into the FLOAT_COLOR
    attribute ``name`` (alpha 1), creating or re-creating it on ``domain``; where ``mask (n,)`` is
    False an existing value of the same attribute is kept (else 0). Call
    :func:`prepare_vertex_attribute` first."""
    n = len(values)
    rgba = np.zeros((n, 4), dtype=np.float32)
    attr = mesh.attributes.get(name)
    if attr is not None and (attr.domain != domain or attr.data_type != "FLOAT_COLOR"):
        mesh.attributes.remove(attr)
        attr = None
    if attr is not None and mask is not None:
        attr.data.foreach_get("color", rgba.reshape(-1))
    if attr is None:
        attr = mesh.attributes.new(name, "FLOAT_COLOR", domain)
    keep = np.ones(n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    rgba[keep, :3] = values[keep]
    rgba[keep, 3] = 1.0
    attr.data.foreach_set("color", rgba.reshape(-1))
    owned = list(mesh.get(OWNED_KEY, []))
    if name not in owned:
        mesh[OWNED_KEY] = owned + [name]
    return attr
