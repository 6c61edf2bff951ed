"""Camera rays against Blender's own camera model (view_frame, world_to_camera_view)."""

import importlib.util
import os
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
if importlib.util.find_spec("hemisphere_local_pass") is None:  # before the extension is installed
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Euler, Vector  # noqa: E402

from hemisphere_local_pass.blender import camera as hcam  # noqa: E402

pytestmark = pytest.mark.bpy

CASES = [
    # type, fit, shift, resolution, percentage, pixel aspect
    ("PERSP", "AUTO", (0.0, 0.0), (64, 48), 100, (1.0, 1.0)),
    ("PERSP", "AUTO", (0.1, -0.2), (48, 64), 50, (1.0, 1.0)),
    ("PERSP", "HORIZONTAL", (0.0, 0.3), (40, 70), 100, (2.0, 1.0)),
    ("PERSP", "VERTICAL", (-0.25, 0.1), (80, 40), 75, (1.0, 1.5)),  # view_frame uses unrounded sizes
    ("ORTHO", "AUTO", (0.2, 0.1), (64, 48), 100, (1.0, 1.0)),
    ("ORTHO", "VERTICAL", (0.0, -0.1), (30, 50), 100, (1.0, 2.0)),
]


def _setup(kind, fit, shift, res, pct, aspect):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    cam = bpy.data.cameras.new("Cam")
    ob = bpy.data.objects.new("Cam", cam)
    sc.collection.objects.link(ob)
    sc.camera = ob
    cam.type = kind
    cam.sensor_fit = fit
    cam.lens = 35.0
    cam.sensor_width = 36.0
    cam.sensor_height = 24.0
    cam.ortho_scale = 5.0
    cam.shift_x, cam.shift_y = shift
    ob.location = (1.0, -2.0, 3.0)
    ob.rotation_euler = Euler((1.1, 0.2, -0.7))
    ob.scale = (1.3, 1.3, 1.3)  # ignored by Blender's camera
    r = sc.render
    r.resolution_x, r.resolution_y = res
    r.resolution_percentage = pct
    r.pixel_aspect_x, r.pixel_aspect_y = aspect
    bpy.context.view_layer.update()
    return sc, ob


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-{c[1]}-{i}" for i, c in enumerate(CASES)])
def test_frame_corners_match_view_frame(case):
    sc, ob = _setup(*case)
    p = hcam.camera_params(sc)
    w, h = hcam.image_size(p)
    frame = [np.array(v) for v in ob.data.view_frame(scene=sc)]  # camera space
    ours = hcam.camera_space(p, np.array([w, w, 0, 0], float), np.array([h, 0, 0, h], float))
    for v, c in zip(frame, ours, strict=True):
        if p.type == "PERSP":  # same direction
            np.testing.assert_allclose(v[:2] / -v[2], c[:2], rtol=1e-5, atol=1e-6, err_msg=str(case))
        else:
            np.testing.assert_allclose(v[:2], c[:2], rtol=1e-5, atol=1e-6, err_msg=str(case))


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-{c[1]}-{i}" for i, c in enumerate(CASES)])
def test_rays_project_to_their_pixel(case):
    rng = np.random.default_rng(7)
    sc, ob = _setup(*case)
    p = hcam.camera_params(sc)
    w, h = hcam.image_size(p)
    sx = rng.uniform(0, w, 20)
    sy = rng.uniform(0, h, 20)
    o, d, t0, t1 = hcam.camera_rays(p, sx, sy)
    assert t0 == pytest.approx(ob.data.clip_start) and t1 == pytest.approx(ob.data.clip_end)
    for i in range(20):
        t = 2.0 + i * 0.3
        x = o[i] + t * d[i]
        u, v, depth = world_to_camera_view(sc, ob, Vector(x))
        assert u == pytest.approx(sx[i] / w, abs=1e-5), (case, i)
        assert v == pytest.approx(sy[i] / h, abs=1e-5), (case, i)
        assert depth == pytest.approx(t, rel=1e-5), (case, i)


def test_pixel_window_border_region_and_samples():
    sc, ob = _setup("PERSP", "AUTO", (0, 0), (100, 50), 50, (1, 1))
    p = hcam.camera_params(sc)
    assert hcam.image_size(p) == (50, 25)
    assert hcam.pixel_window(p) == (0, 0, 50, 25)
    sc.render.use_border = True
    sc.render.border_min_x, sc.render.border_max_x = 0.2, 0.6
    sc.render.border_min_y, sc.render.border_max_y = 0.0, 0.5
    p = hcam.camera_params(sc)
    assert hcam.pixel_window(p) == (10, 0, 30, 13)
    assert hcam.pixel_window(p, region=(5, 5, 8, 100)) == (5, 5, 8, 25)
    with pytest.raises(ValueError, match="does not overlap"):
        hcam.pixel_window(p, region=(60, 0, 70, 5))
    px, py, sx, sy = hcam.pixel_samples((5, 5, 8, 7), samples=2)
    assert px.tolist() == [5, 6, 7, 5, 6, 7] and py.tolist() == [5, 5, 5, 6, 6, 6]
    np.testing.assert_allclose(sx[0], [5.25, 5.75, 5.25, 5.75])
    np.testing.assert_allclose(sy[0], [5.25, 5.25, 5.75, 5.75])


def test_no_camera_is_a_clear_error():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with pytest.raises(ValueError, match="has no camera"):
        hcam.camera_params(bpy.context.scene)
