"""The form-factor inspector's pure geometry builder (hemisphere_local_pass/blender/inspector_geometry.py,
no bpy, no GPU): its list agrees with the core at the point, the Nusselt analog's areas / pi are the
form factors, and the drawn arrays have the shapes the GPU batches need."""

import numpy as np
import pytest

from hemisphere_local_pass.blender.inspector_geometry import (
    arc_points,
    false_colour,
    inspect_point,
    nusselt_area,
    tangent_basis,
)
from hemisphere_local_pass.core import form_factors, irradiance, project_point
from hemisphere_local_pass.scenes.cornell_box import cornell_box


@pytest.fixture(scope="module")
def box_scene():
    box = cornell_box(2)
    rng = np.random.default_rng(5)
    radiance = box.emission + 0.05 + 0.3 * rng.random((box.n_polygons, 3))
    return box, box.scene(radiance)


def floor_point(box):
    """A point on the floor (y = 0 plane of the box) and its inward normal."""
    centroids = box.centroids()
    normals = box.normals()
    i = int(np.argmax(normals[:, 1]))  # a floor cell
    return centroids[i] + np.array([0.013, 0.0, -0.021]) * box.size, normals[i]


def test_list_agrees_with_the_core(box_scene):
    box, scene = box_scene
    p, n = floor_point(box)
    ins = inspect_point(scene, p, n, radius=0.1, reflectivity=(0.5, 0.6, 0.7), emission=(0.01, 0.0, 0.0))
    proj = project_point(scene, p, n)
    ff = form_factors(scene, p[None], n[None])[0]
    h = irradiance(scene, p[None], n[None])[0]
    assert ins.form_factor_sum == pytest.approx(1.0, abs=1e-12)  # closed box
    assert ins.form_factor_sum == float(np.sum(proj.form_factor))
    assert np.array_equal(ins.irradiance, h)
    np.testing.assert_allclose(ins.radiance, np.array([0.01, 0, 0]) + np.array([0.5, 0.6, 0.7]) / np.pi * h,
                               rtol=1e-15)
    rows = {r.polygon: r for r in ins.rows}
    assert set(rows) == set(np.flatnonzero(proj.polygon_form_factors > 0))
    for i, row in rows.items():
        assert row.form_factor == proj.polygon_form_factors[i]
        assert row.form_factor == pytest.approx(ff[i], rel=1e-12, abs=1e-15)
    keys = [(r.share, r.form_factor) for r in ins.rows]
    assert keys == sorted(keys, reverse=True)  # the largest contributions to H first
    assert box.names[ins.rows[0].polygon] == "light"  # the emitter dominates H
    # eq. 3: H = pi sum L_i F_i over the lit polygons, the list's shares sum to 1
    lf = np.sum([r.radiance_ff for r in ins.rows], axis=0)
    np.testing.assert_allclose(np.pi * lf, h, rtol=1e-12)
    assert sum(r.share for r in ins.rows) == pytest.approx(1.0, abs=1e-12)


def test_nusselt_areas_are_the_form_factors(box_scene):
    box, scene = box_scene
    p, n = floor_point(box)
    ins = inspect_point(scene, p, n, radius=0.1)
    proj = project_point(scene, p, n)
    assert ins.fragments == len(proj.fragments) > 5
    # the projected boundary samples arcs with 16 points per edge: area converges as 1/segments^2
    np.testing.assert_allclose(ins.nusselt_areas, proj.form_factor, rtol=2e-2, atol=1e-4)
    fine = np.array([nusselt_area(arc_points(d, 256), n) / np.pi for d in proj.fragments])
    np.testing.assert_allclose(fine, proj.form_factor, rtol=1e-4, atol=1e-7)


def test_drawn_arrays(box_scene):
    box, scene = box_scene
    p, n = floor_point(box)
    r = 0.05
    for mode in ("RADIANCE", "FORM_FACTOR"):
        ins = inspect_point(scene, p, n, radius=r, colour_by=mode, top=3)
        assert ins.hemisphere_tris.shape[0] % 3 == 0 and ins.hemisphere_tris.shape[1] == 3
        assert ins.hemisphere_colours.shape == (len(ins.hemisphere_tris), 4)
        for arr in (ins.hemisphere_tris, ins.hemisphere_colours, ins.hemisphere_lines, ins.disc_tris,
                    ins.disc_colours, ins.disc_lines, ins.frame_lines, ins.top_lines):
            assert arr.dtype == np.float32 and arr.flags["C_CONTIGUOUS"]  # what a GPU vertex buffer reads
        assert ((ins.hemisphere_colours >= 0) & (ins.hemisphere_colours <= 1)).all()
        assert ins.hemisphere_lines.shape[0] % 2 == 0
        d = np.linalg.norm(ins.hemisphere_lines - (p + 1e-3 * r * n), axis=1)  # outlines on the sphere
        np.testing.assert_allclose(d, r, rtol=1e-5)
        height = (ins.hemisphere_lines - p) @ n
        assert (height >= -1e-6).all(), "fragments lie on the upper hemisphere"
        disc_h = (ins.disc_tris - p) @ n
        np.testing.assert_allclose(disc_h, 1e-3 * r, atol=1e-6)  # the disc lies in the tangent plane
        assert (np.linalg.norm(ins.disc_tris - p, axis=1) <= r * (1 + 1e-5)).all()
        assert ins.top_lines.shape[0] % 2 == 0 and len(ins.top_lines) > 0
    top = {int(s) for s in np.flatnonzero(np.isin(scene.poly_source, [row.polygon for row in ins.rows[:3]]))}
    assert len(ins.top_lines) == 2 * sum(int(scene.poly_counts[i]) for i in top)


def test_helpers():
    rng = np.random.default_rng(1)
    for _ in range(5):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        t, b = tangent_basis(n)
        np.testing.assert_allclose(np.cross(t, b), n, atol=1e-15)
        assert abs(t @ n) < 1e-15 and abs(b @ n) < 1e-15
    quarter = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0]])  # an octant: F of the upper hemisphere's 1/4
    assert nusselt_area(arc_points(quarter[::-1], 512), [0, 0, 1]) / np.pi == pytest.approx(0.25, rel=1e-5)
    pts = arc_points(quarter, 8)
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 1.0, atol=1e-15)
    c = false_colour(np.array([0.0, 0.5, 1.0]))
    assert c.shape == (3, 3) and (c >= 0).all() and (c <= 1).all()
