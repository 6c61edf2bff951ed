"""Camera rays through pixel centres, following Blender's camera model (pure numpy + one bpy reader).

:func:`camera_params` pulls the numbers out of a scene's camera; everything else is numpy, so the
model can be tested against ``Camera.view_frame`` and ``bpy_extras.object_utils.world_to_camera_view``.

Blender's model (``BKE_camera_params_compute_viewplane``): the image is ``W x H`` pixels with
``W = resolution_x * resolution_percentage // 100`` (same for H); with pixel aspect ``ax, ay`` the
view plane spans ``[-W/2, W/2] x [-H/2 * ay/ax, H/2 * ay/ax]`` pixel units, shifted by
``shift * viewfac`` where ``viewfac = W`` for a horizontal sensor fit and ``H * ay/ax`` for a vertical
one (AUTO picks horizontal when ``W ax >= H ay``); one pixel unit is ``sensor / lens / viewfac`` at
distance 1 (perspective; ``sensor`` is the sensor width, or its height for a VERTICAL fit) or
``ortho_scale / viewfac`` (orthographic). The camera looks along its local -Z axis, +Y up.

Pixel coordinates: ``x`` from the left, ``y`` from the *bottom* (Blender's image convention), pixel
``(i, j)`` covers ``[i, i+1) x [j, j+1)`` and its centre is ``(i + 1/2, j + 1/2)``. A region
``(x0, y0, x1, y1)`` is half-open in the same coordinates. The render border (``use_border``) maps
to the pixel window ``round(min * W) .. round(max * W)``.

Ray parameter ``t`` is the depth along the view axis (the camera-space ``-z``): directions are
scaled so that their camera-space z component is -1, so ``t`` is Blender's Z pass depth, and the
clip planes are ``clip_start <= t <= clip_end``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CameraParams", "camera_params", "camera_rays", "image_size", "pixel_samples", "pixel_window"]


@dataclass(frozen=True)
class CameraParams:
    """Everything the ray generator needs (plain numbers; ``matrix_world`` is (4, 4) float64)."""

    type: str  # "PERSP" or "ORTHO"
    lens: float  # mm
    sensor_width: float  # mm
    sensor_height: float  # mm
    sensor_fit: str  # "AUTO", "HORIZONTAL", "VERTICAL"
    ortho_scale: float
    shift_x: float
    shift_y: float
    clip_start: float
    clip_end: float
    matrix_world: tuple  # 16 floats, row-major
    resolution_x: int
    resolution_y: int
    resolution_percentage: int = 100
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0
    border: tuple | None = None  # (min_x, min_y, max_x, max_y) in [0, 1] when use_border
    name: str = "Camera"

    @property
    def matrix(self) -> np.ndarray:
        return np.array(self.matrix_world, dtype=np.float64).reshape(4, 4)

    def fingerprint(self) -> tuple:
        """A hashable summary (for checkpoints)."""
        return tuple(getattr(self, f) for f in self.__dataclass_fields__)


def camera_params(scene, camera_object=None, depsgraph=None) -> CameraParams:
    """Read the camera of ``scene`` (default ``scene.camera``), evaluated (animation, constraints)
    in ``depsgraph`` (default: the context's evaluated depsgraph; a render engine passes its own).

    Raises ``ValueError`` when the scene has no camera or the camera is panoramic.
    """
    ob = camera_object if camera_object is not None else scene.camera
    if ob is None:
        raise ValueError(f"scene '{scene.name}' has no camera: add a camera and make it the scene's active camera")
    if ob.type != "CAMERA":
        raise ValueError(f"scene '{scene.name}': the active camera '{ob.name}' is a {ob.type} object, not a camera")
    cam = ob.data
    if cam.type not in ("PERSP", "ORTHO"):
        raise ValueError(f"camera '{ob.name}' is {cam.type}; only perspective and orthographic cameras are supported")
    try:
        import bpy

        ob_eval = ob.evaluated_get(depsgraph if depsgraph is not None else bpy.context.evaluated_depsgraph_get())
        matrix = ob_eval.matrix_world
    except (AttributeError, RuntimeError):  # no context (should not happen), use the stored matrix
        matrix = ob.matrix_world
    r = scene.render
    border = None
    if r.use_border:
        border = (float(r.border_min_x), float(r.border_min_y), float(r.border_max_x), float(r.border_max_y))
    m = np.array(matrix, dtype=np.float64).reshape(16)
    return CameraParams(
        type=cam.type, lens=float(cam.lens), sensor_width=float(cam.sensor_width),
        sensor_height=float(cam.sensor_height), sensor_fit=cam.sensor_fit, ortho_scale=float(cam.ortho_scale),
        shift_x=float(cam.shift_x), shift_y=float(cam.shift_y), clip_start=float(cam.clip_start),
        clip_end=float(cam.clip_end), matrix_world=tuple(float(v) for v in m),
        resolution_x=int(r.resolution_x), resolution_y=int(r.resolution_y),
        resolution_percentage=int(r.resolution_percentage), pixel_aspect_x=float(r.pixel_aspect_x),
        pixel_aspect_y=float(r.pixel_aspect_y), border=border, name=ob.name,
    )


def image_size(p: CameraParams) -> tuple:
    """``(W, H)`` of the rendered image in pixels (resolution x percentage, as Blender truncates)."""
    return (p.resolution_x * p.resolution_percentage) // 100, (p.resolution_y * p.resolution_percentage) // 100


def pixel_window(p: CameraParams, region=None) -> tuple:
    """The pixels to compute, ``(x0, y0, x1, y1)`` half-open, y from the bottom.

    ``region`` (x0, y0, x1, y1) wins over the render border; it is clipped to the image and must
    not be empty.
    """
    w, h = image_size(p)
    if region is not None:
        x0, y0, x1, y1 = (int(v) for v in region)
        x0, x1 = max(0, x0), min(w, x1)
        y0, y1 = max(0, y0), min(h, y1)
        if x1 <= x0 or y1 <= y0:
            raise ValueError(f"region {tuple(region)} does not overlap the {w} x {h} image")
        return x0, y0, x1, y1
    if p.border is not None:
        bx0, by0, bx1, by1 = p.border
        x0, x1 = int(np.floor(bx0 * w + 0.5)), int(np.floor(bx1 * w + 0.5))
        y0, y1 = int(np.floor(by0 * h + 0.5)), int(np.floor(by1 * h + 0.5))
        x0, x1, y0, y1 = max(0, x0), min(w, x1), max(0, y0), min(h, y1)
        if x1 <= x0 or y1 <= y0:
            raise ValueError(f"the render border {p.border} covers no pixel of the {w} x {h} image")
        return x0, y0, x1, y1
    return 0, 0, w, h


def pixel_samples(window, samples: int = 1):
    """Sample positions of the pixels of ``window`` with ``samples x samples`` supersampling.

    Returns ``(px, py, sx, sy)``: ``px, py`` (n,) int64 pixel coordinates, row by row from the
    window's bottom row (y ascending, then x); ``sx, sy`` (n, k*k) float64 sample positions in pixel
    units at the centres of a regular k x k grid inside each pixel (k = 1: the pixel centre).
    """
    k = int(samples)
    if k < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    x0, y0, x1, y1 = window
    py, px = np.meshgrid(np.arange(y0, y1, dtype=np.int64), np.arange(x0, x1, dtype=np.int64), indexing="ij")
    px, py = px.reshape(-1), py.reshape(-1)
    sub = (np.arange(k) + 0.5) / k
    oy, ox = np.meshgrid(sub, sub, indexing="ij")
    sx = px[:, None] + ox.reshape(1, -1)
    sy = py[:, None] + oy.reshape(1, -1)
    return px, py, sx, sy


def _plane(p: CameraParams):
    """(pixel size at distance 1 or ortho, xmin, ymin, ycor) of Blender's view plane, pixel units."""
    w, h = image_size(p)
    if w <= 0 or h <= 0:
        raise ValueError(f"camera '{p.name}': empty image ({w} x {h} pixels)")
    ycor = p.pixel_aspect_y / p.pixel_aspect_x
    fit = p.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if w * p.pixel_aspect_x >= h * p.pixel_aspect_y else "VERTICAL"
    if p.type == "ORTHO":
        size = p.ortho_scale
    else:
        sensor = p.sensor_height if p.sensor_fit == "VERTICAL" else p.sensor_width
        size = sensor / p.lens
    viewfac = w if fit == "HORIZONTAL" else ycor * h
    pix = size / viewfac
    xmin = -0.5 * w + p.shift_x * viewfac
    ymin = -0.5 * ycor * h + p.shift_y * viewfac
    return pix, xmin, ymin, ycor


def camera_space(p: CameraParams, sx, sy) -> np.ndarray:
    """Camera-space position ``(..., 3)`` of image positions ``sx, sy`` (pixel units) on the plane
    at distance 1 (perspective; z = -1) or on the camera plane (orthographic; z = 0)."""
    pix, xmin, ymin, ycor = _plane(p)
    sx = np.asarray(sx, dtype=np.float64)
    sy = np.asarray(sy, dtype=np.float64)
    x = pix * (xmin + sx)
    y = pix * (ymin + ycor * sy)
    z = np.full_like(x, 0.0 if p.type == "ORTHO" else -1.0)
    return np.stack([x, y, z], axis=-1)


def camera_rays(p: CameraParams, sx, sy):
    """World-space rays through image positions ``sx, sy`` (any equal shapes, pixel units).

    Returns ``origins (n, 3)``, ``directions (n, 3)`` (camera-space z component -1, so the ray
    parameter is the view depth), ``t_min``, ``t_max`` (the clip planes; scalars).
    """
    m = p.matrix
    rot, loc = m[:3, :3], m[:3, 3]
    rot = rot / np.linalg.norm(rot, axis=0, keepdims=True)  # Blender ignores the camera object's scale
    c = camera_space(p, sx, sy).reshape(-1, 3)  # (n, 3)
    if p.type == "ORTHO":
        origins = c @ rot.T + loc
        directions = np.broadcast_to(-rot[:, 2], origins.shape).copy()
    else:
        directions = c @ rot.T
        origins = np.broadcast_to(loc, directions.shape).copy()
    return origins, directions, float(p.clip_start), float(p.clip_end)
