"""The inspector's Blender side without a GPU (bpy module, background): snapping a view ray to the
surface, the list against the core at that point, registration leaving no handler behind. (The
overlay's pixels: tests/blender_exe/test_ui.py under Xvfb.)"""

import importlib
import importlib.util
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import MODULE  # noqa: E402
from sample_loader import sample_module  # noqa: E402


@pytest.fixture
def inspector(extension, scene):
    return importlib.import_module(f"{extension.__name__}.blender.inspector")


def build_box():
    sample_module().build(2, resolution=8, reset=False)
    return bpy.context.scene


def test_snap_and_list_agree_with_the_core(inspector):
    from hemisphere_local_pass.core import irradiance, project_point

    scene = build_box()
    exported = inspector.export_for_inspection(bpy.context)
    cam = np.array(scene.camera.matrix_world.translation)
    target = np.array([0.31, 0.42, 0.0])  # a floor point of the unit box
    d = (target - cam) / np.linalg.norm(target - cam)
    t_min = scene.camera.data.clip_start / d[1]  # the camera looks along +y through the front wall
    ins = inspector.inspect_ray(bpy.context, cam, d, t_min)
    assert ins is not None
    assert abs(ins.point[2]) < 1e-12 and np.allclose(ins.normal, [0, 0, 1])  # on the floor, facing up
    np.testing.assert_allclose(ins.point, target, atol=1e-9)
    proj = project_point(exported.scene, ins.point, ins.normal)
    h = irradiance(exported.scene, ins.point[None], ins.normal[None])[0]
    assert ins.form_factor_sum == float(np.sum(proj.form_factor))
    assert np.array_equal(ins.irradiance, h)
    # the overlay's line says what its H is: the mean of the RGB channels, with the unit
    assert inspector.label_text(ins).endswith(f"H (mean of R, G, B) = {h.mean():.4g} W/m²")
    for row in ins.rows:
        assert row.form_factor == proj.polygon_form_factors[row.polygon]
        assert row.label == exported.polygon_name(row.polygon)
    assert inspector.inspect_ray(bpy.context, cam, -d) is None  # away from the box: nothing
    inspector.State.clear()
    assert inspector.State.inspection is None and not inspector.State.handles


def test_unregister_removes_handlers(extension):
    module = extension
    insp = sys.modules[MODULE + ".blender.inspector"]
    try:
        for _ in range(2):
            module.unregister()
            assert insp._on_load_pre not in bpy.app.handlers.load_pre
            assert not hasattr(bpy.types.WindowManager, "hlp_inspector_radius")
            assert not insp.HLP_OT_inspect_form_factors.is_registered
            module.register()
            assert insp._on_load_pre in bpy.app.handlers.load_pre
    finally:
        if not hasattr(bpy.types.Scene, "hlp_settings"):
            module.register()
