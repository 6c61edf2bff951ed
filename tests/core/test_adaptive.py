"""The adaptive local pass (core.adaptive_irradiance, issue 11 sec. 2): error against the all-exact image.

Every test renders a small image (48 × 48) twice — every hit pixel exact with ``core.irradiance``, and
adaptively — and checks the *measured* largest error over pixels and channels against the tolerance,
on the Cornell box and on scenes built to break interpolation: hard shadow lines of thin occluders
narrower than a pixel (let alone the coarse spacing), cast by a small bright light from occluders no
camera ray sees; contact shadows at block feet; a chequerboard radiosity solution; grazing light.
"""

from __future__ import annotations

import numpy as np
import pytest

from hemisphere_local_pass.core import Scene, adaptive_irradiance, irradiance
from hemisphere_local_pass.core.raycast import cast_rays
from hemisphere_local_pass.scenes import PAPER_SETTINGS, camera_rays, cornell_box, radiosity
from hemisphere_local_pass.scenes.radiosity import centroid_form_factors

SIZE = 48


def pinhole(eye, target, up, fov, size=SIZE):
    """Rays ``(size², 3)`` through the pixel centres of a square pinhole camera, top row first."""
    eye, target, up = (np.asarray(a, dtype=float) for a in (eye, target, up))
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    upv = np.cross(right, fwd)
    s = (np.arange(size) + 0.5) / size * 2 - 1
    gx, gy = np.meshgrid(s, -s)
    d = fwd + np.tan(fov / 2) * (gx[..., None] * right + gy[..., None] * upv)
    d = d.reshape(-1, 3)
    return np.broadcast_to(eye, d.shape).copy(), d / np.linalg.norm(d, axis=1, keepdims=True)


def image_inputs(scene, o, d, size=SIZE):
    """Camera-ray hits as the adaptive pass wants them: points, normals (h, w, 3), polygons (h, w)."""
    h = cast_rays(scene, o, d)
    hit = h.hit
    p = np.where(hit[:, None], h.point, 0.0).reshape(size, size, 3)
    n = np.where(hit[:, None], scene.poly_normals[np.maximum(h.polygon, 0)], 0.0)
    # the receiver faces the camera: a ray that hits a back side sees the other hemisphere
    n = np.where((~h.front & hit)[:, None], -n, n).reshape(size, size, 3)
    return p, n, h.source.reshape(size, size)


def exact_image(scene, p, n, g):
    out = np.zeros(p.shape)
    hit = g >= 0
    out[hit] = irradiance(scene, p[hit], n[hit])
    return out


def quad(x0, x1, y0, y1, z):
    return [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]


def grid(b, corners, nu, nv, radiance):
    """Add quad ``corners (4, 3)`` (counter-clockwise seen from its front) cut into nu × nv cells."""
    c = np.asarray(corners, dtype=float)
    for i in range(nu):
        for j in range(nv):
            def at(s, t):
                return (1 - t) * ((1 - s) * c[0] + s * c[1]) + t * ((1 - s) * c[3] + s * c[2])
            cell = [at(i / nu, j / nv), at((i + 1) / nu, j / nv), at((i + 1) / nu, (j + 1) / nv),
                    at(i / nu, (j + 1) / nv)]
            b.append((cell, radiance(i, j) if callable(radiance) else radiance))


def build(parts):
    verts, polys, rad = [], [], []
    for pts, r in parts:
        polys.append(list(range(len(verts), len(verts) + len(pts))))
        verts.extend(pts)
        rad.append(np.broadcast_to(np.asarray(r, dtype=float), (3,)))
    return Scene.from_polygons(np.array(verts, dtype=float), polys, np.array(rad))


def down(pts):
    """The same quad facing -z (reversed order)."""
    return list(pts)[::-1]


# ---------------------------------------------------------------------------------------------------
# scenes


def cornell(size=SIZE):
    box = cornell_box(**PAPER_SETTINGS["small"])
    f = centroid_form_factors(box.scene(), box.centroids(), box.normals())
    lum = radiosity(box.vertices, box.polygons, box.reflectivity, box.emission, form_factor_matrix=f)
    scene = box.scene(radiance=lum)
    o, d = camera_rays(box, size)
    return scene, o, d


def thin_occluders(offset=0.0, size=SIZE):
    """A floor lit by a small bright light through thin bars outside the camera's view.

    The light (0.02 wide, radiance 200) stands 1 above the floor, off to the side; bars 0.003 wide at
    height 0.5 cast penumbra lines ~0.02 wide: about one pixel of the 48² view of the unit floor, a
    sixteenth of the coarse spacing. A dim sky (radiance 0.3) lights everything a little.
    """
    parts = []
    grid(parts, quad(-1, 2, -1, 2, 0.0), 3, 3, 0.0)                     # floor, facing +z
    parts.append((down(quad(-0.6, -0.58, 0.49, 0.51, 1.0)), 200.0))     # light, facing -z
    parts.append((down(quad(-3, 4, -3, 4, 3.0)), 0.3))                  # sky
    for k in range(5):                                                  # bars along y, at x ~ -0.1
        x = -0.25 + 0.031 * k + offset
        parts.append((quad(x, x + 0.003, -1, 2, 0.5), 0.0))
        parts.append((down(quad(x, x + 0.003, -1, 2, 0.5)), 0.0))
    scene = build(parts)
    # the camera sees the floor [0, 1]²; the bars (x < 0) are outside its view
    o, d = pinhole((0.5, 0.5, 2.0), (0.5, 0.5, 0.0), (0, 1, 0), 2 * np.arctan(0.25), size=size)
    return scene, o, d


def contact_shadows(size=SIZE):
    """A block standing on a floor under a sky and a light: contact shadows at its feet."""
    parts = []
    grid(parts, quad(-1, 2, -1, 2, 0.0), 6, 6, 0.0)
    parts.append((down(quad(0.2, 0.3, 0.2, 0.3, 1.5)), 40.0))
    parts.append((down(quad(-3, 4, -3, 4, 3.0)), 0.5))
    a, b, hgt = 0.35, 0.65, 0.3
    parts.append((quad(a, b, a, b, hgt), 0.0))                                              # top
    parts.append(([(a, a, 0), (b, a, 0), (b, a, hgt), (a, a, hgt)], 0.0))                   # -y side
    parts.append(([(b, b, 0), (a, b, 0), (a, b, hgt), (b, b, hgt)], 0.0))                   # +y
    parts.append(([(a, b, 0), (a, a, 0), (a, a, hgt), (a, b, hgt)], 0.0))                   # -x
    parts.append(([(b, a, 0), (b, b, 0), (b, b, hgt), (b, a, hgt)], 0.0))                   # +x
    scene = build(parts)
    o, d = pinhole((0.5, -0.6, 0.9), (0.5, 0.5, 0.05), (0, 0, 1), np.radians(40), size=size)
    return scene, o, d


def chequerboard(size=SIZE):
    """A back wall whose radiosity solution is a chequerboard (1.0 / 0.05), a floor and a side wall."""
    parts = []
    grid(parts, quad(0, 1, 0, 1, 0.0), 4, 4, 0.0)
    grid(parts, [(0, 1, 0), (1, 1, 0), (1, 1, 1), (0, 1, 1)][::-1], 8, 8,
         lambda i, j: 1.0 if (i + j) % 2 else 0.05)                                         # faces -y
    grid(parts, [(0, 0, 0), (0, 1, 0), (0, 1, 1), (0, 0, 1)], 4, 4, 0.2)                    # faces +x
    scene = build(parts)
    o, d = pinhole((0.6, -0.5, 0.8), (0.5, 0.8, 0.2), (0, 0, 1), np.radians(55), size=size)
    return scene, o, d


def grazing(size=SIZE):
    """A light panel standing 0.01 above the floor, tilted 2° from vertical: the floor sees it grazing."""
    parts = []
    grid(parts, quad(0, 1, 0, 1, 0.0), 4, 4, 0.0)
    t = np.radians(2.0)
    base, top = 0.01, 0.31
    light = [(0.1, 1.0, base), (0.9, 1.0, base), (0.9, 1.0 + np.sin(t) * (top - base), top),
             (0.1, 1.0 + np.sin(t) * (top - base), top)]
    parts.append((light, 30.0))  # counter-clockwise from -y: faces the floor (-y)
    parts.append((down(quad(-3, 4, -3, 4, 3.0)), 0.2))
    scene = build(parts)
    o, d = pinhole((0.5, -0.3, 0.6), (0.5, 0.6, 0.0), (0, 0, 1), np.radians(60), size=size)
    return scene, o, d


SCENES = {"cornell": cornell, "thin occluders": thin_occluders, "contact shadows": contact_shadows,
          "chequerboard": chequerboard, "grazing light": grazing}
_CACHE: dict = {}


def prepared(name, size=SIZE):
    if (name, size) not in _CACHE:
        scene, o, d = SCENES[name](size=size)
        p, n, g = image_inputs(scene, o, d, size)
        _CACHE[name, size] = (scene, p, n, g, exact_image(scene, p, n, g))
    return _CACHE[name, size]


# ---------------------------------------------------------------------------------------------------
# tests


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("rel", [1e-2, 1e-3])
def test_measured_error_within_tolerance(name, rel):
    scene, p, n, g, ref = prepared(name)
    hit = g >= 0
    assert hit.mean() > 0.5, "the test scene's camera must see it"
    tol = rel * ref[hit].mean()
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=tol)
    err = np.abs(img - ref).max(axis=2)
    assert err.max() <= tol, (name, rel, err.max() / tol, st)
    # the estimate is reported, bounded by the tolerance, and 0 exactly where the pixel is exact
    assert st.error_estimate <= tol
    assert (st.pixel_error[st.exact_mask] == 0).all() and (st.pixel_error >= 0).all()
    assert st.exact_points == int(st.exact_mask.sum()) <= int(hit.sum())
    # exact samples are bit for bit the all-exact image's pixels; misses are 0
    assert np.array_equal(img[st.exact_mask], ref[st.exact_mask])
    assert not img[~hit].any() and not st.exact_mask[~hit].any()


@pytest.mark.parametrize("name", ["cornell", "thin occluders"])
def test_tolerance_zero_is_bitwise_exact(name):
    scene, p, n, g, ref = prepared(name)
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=0.0)
    assert np.array_equal(img, ref)  # bit for bit, misses included
    assert st.exact_points == int((g >= 0).sum()) and st.error_estimate == 0.0
    assert np.array_equal(st.exact_mask, g >= 0)


@pytest.mark.parametrize("name, size, most", [("thin occluders", 48, 0.6), ("chequerboard", 96, 0.6)])
def test_interpolation_does_skip_work(name, size, most):
    """At 1e-2 of the mean a good part of the pixels is interpolated (the error checked too)."""
    scene, p, n, g, ref = prepared(name, size)
    tol = 1e-2 * ref[g >= 0].mean()
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=tol)
    assert np.abs(img - ref).max() <= tol
    assert st.exact_fraction < most, st


def test_thin_shadow_lines_slip_without_the_shadow_test():
    """The thin occluders' penumbra lines fall between samples (the scene really is adversarial): with
    the geometric shadow test switched off (no emitter counts as a light) the error exceeds the
    tolerance; with it, the same lines force refinement and the error stays within it. (Bars offset by
    0.02: at offset 0 the anisotropic splits happen to land samples on the lines at 1e-2; 7-8 of 12
    random offsets slip without the shadow test, benchmarks/bench_adaptive_slip.py.)"""
    scene, o, d = thin_occluders(offset=0.02)
    p, n, g = image_inputs(scene, o, d)
    ref = exact_image(scene, p, n, g)
    tol = 1e-2 * ref[g >= 0].mean()
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=tol, light_ratio=np.inf)
    assert st.lights == 0
    assert np.abs(img - ref).max() > tol
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=tol)
    assert st.lights == 1 and st.forced_shadow > 0
    assert np.abs(img - ref).max() <= tol


@pytest.mark.parametrize("y0, x0, rel, where", [
    (368, 448, 1e-3, "right wall where it crosses the plane of a block face"),
    (256, 80, 1e-2, "left wall where the light's penumbra starts"),
])
def test_kinks_between_a_cells_samples_slip_without_the_extended_check(y0, x0, rel, where):
    """A 32² crop of the 512² Cornell box: a cell's own nine samples see the curvature at its centre only,
    so a kink between a corner and the midpoint (or a narrow valley between two kinks) slips: measured
    1.54× / 1.10× the tolerance without ``neighbour_check`` (5.1× on the first crop at 3e-4; up to 1.5× on the
    full 512² image at 1e-2 to 1e-4 of the mean, 3.0× at 1024²: docs/adaptive.md). Extending each spot check
    one spacing beyond the cell (the second difference at its corners) sees it: 0.07× the tolerance."""
    scene, o, d = cornell(size=512)
    idx = (np.arange(y0, y0 + 32)[:, None] * 512 + np.arange(x0, x0 + 32)[None]).reshape(-1)
    p, n, g = image_inputs(scene, o[idx], d[idx], size=32)
    ref = exact_image(scene, p, n, g)
    tol = rel * ref[g >= 0].mean()
    img, st_old = adaptive_irradiance(scene, p, n, g, tolerance=tol, neighbour_check=False)
    assert np.abs(img - ref).max() > tol, where
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=tol)
    assert np.abs(img - ref).max() <= tol, (where, np.abs(img - ref).max() / tol)
    assert st.exact_points < int((g >= 0).sum()), "the crop is not all exact: the test sees interpolation"


def test_anisotropic_splits_follow_one_dimensional_variation():
    """A floor under a long light bar along y: H varies along x only, so rejected cells are halved along
    x alone (their interpolation along y passes, up to 2:1 cells), with fewer exact pixels (measured 721
    against 1,209 at 1e-2) and the error still within the tolerance."""
    parts = []
    grid(parts, quad(-1, 2, -3, 4, 0.0), 3, 3, 0.0)
    parts.append((down(quad(-0.3, -0.1, -3, 4, 0.6)), 5.0))
    scene = build(parts)
    o, d = pinhole((0.5, 0.5, 2.0), (0.5, 0.5, 0.0), (0, 1, 0), 2 * np.arctan(0.25))
    p, n, g = image_inputs(scene, o, d)
    ref = exact_image(scene, p, n, g)
    tol = 1e-2 * ref[g >= 0].mean()
    img_a, st_a = adaptive_irradiance(scene, p, n, g, tolerance=tol)
    img_i, st_i = adaptive_irradiance(scene, p, n, g, tolerance=tol, anisotropic=False)
    assert np.abs(img_a - ref).max() <= tol and np.abs(img_i - ref).max() <= tol
    assert st_a.exact_points < 0.75 * st_i.exact_points, (st_a, st_i)


def test_progress_and_cancel():
    from hemisphere_local_pass.core import Cancelled

    scene, p, n, g, ref = prepared("chequerboard")
    seen = []
    _, st = adaptive_irradiance(scene, p, n, g, tolerance=1e-3, progress=lambda done, total: seen.append((done, total)))
    assert seen and all(t == int((g >= 0).sum()) for _, t in seen)
    assert [d for d, _ in seen] == sorted(d for d, _ in seen) and seen[-1][0] == st.exact_points
    # after every chunk of a core call, not once a round (a round's call holds many chunks)
    assert len(seen) > 4
    with pytest.raises(Cancelled):
        adaptive_irradiance(scene, p, n, g, tolerance=1e-3, cancel=lambda: True)


def test_bad_input():
    scene, p, n, g, ref = prepared("chequerboard")
    with pytest.raises(ValueError, match="tolerance"):
        adaptive_irradiance(scene, p, n, g, tolerance=-1.0)
    with pytest.raises(ValueError, match="polygons must have shape"):
        adaptive_irradiance(scene, p, n, g[:-1], tolerance=0.1)
    with pytest.raises(ValueError, match="points must have shape"):
        adaptive_irradiance(scene, p.reshape(-1, 3), n, g, tolerance=0.1)
    with pytest.raises(ValueError, match="input polygons"):
        adaptive_irradiance(scene, p, n, np.full_like(g, scene.n_input), tolerance=0.1)


def test_all_missed():
    scene, p, n, g, ref = prepared("chequerboard")
    img, st = adaptive_irradiance(scene, p, n, np.full_like(g, -1), tolerance=0.1)
    assert not img.any() and st.exact_points == 0


def test_workers_share_one_pool_and_give_the_same_bits(monkeypatch):
    """With 2 workers every core call of the pass runs on one pool (the kept pool of a PoolKeeper scope
    here: started once, whatever the number of quadtree rounds), and the image is bit for bit that of
    one worker."""
    import hemisphere_local_pass.core.adaptive as ad
    from hemisphere_local_pass.core.parallel import PoolKeeper

    scene, p, n, g, ref = prepared("cornell")
    tol = 1e-2 * ref[g >= 0].mean()
    one, st1 = adaptive_irradiance(scene, p, n, g, tolerance=tol, workers=1)
    executors = []
    core = ad.irradiance

    def spy(*args, **kw):
        executors.append(kw.get("executor"))
        return core(*args, **kw)

    monkeypatch.setattr(ad, "irradiance", spy)
    keeper = PoolKeeper()
    try:
        with keeper.scope():
            two, st2 = adaptive_irradiance(scene, p, n, g, tolerance=tol, workers=2)
        assert keeper.started == 1 and keeper.pool.n_workers == 2
        # one core call per round of spot checks (the forced splits need none)
        assert len(executors) >= 2 and all(e is keeper.pool for e in executors)
    finally:
        keeper.close()
    assert np.array_equal(one, two) and st1.exact_points == st2.exact_points
    # without a scope the pass starts its own pool and shuts it down at its end
    executors.clear()
    adaptive_irradiance(scene, p, n, g, tolerance=tol, workers=2)
    pools = {id(e) for e in executors}
    assert len(pools) == 1 and executors[0] is not None and executors[0]._closed


# ---------------------------------------------------------------------------------------------------
# far-field samples (sample_share > 0, module docstring step 5)


def smooth_box_image(sub=20, size=SIZE):
    """test_far_field's smooth-radiance box (3,064 polygons at 20: the far field's linear proxies apply)
    through its camera."""
    from test_far_field import smooth_box

    box, scene = smooth_box(sub)
    o, d = camera_rays(box, size)
    p, n, g = image_inputs(scene, o, d, size)
    return scene, p, n, g, exact_image(scene, p, n, g)


def test_far_field_samples_stay_within_the_tolerance_and_their_bounds():
    """With ``sample_share`` 0.25 the samples come from the error-bounded far field: each sample's error
    against the exact value is within its reported bound (its ``pixel_error``), the bounds within a quarter
    of the tolerance (plus the far field's rounding allowance), the image within the tolerance, and the far
    field really was used (measured: 1,919 of 2,195 samples with a bound above 1e-6 of the tolerance)."""
    from hemisphere_local_pass.core.far_field import ROUNDING

    scene, p, n, g, ref = smooth_box_image()
    hit = g >= 0
    tol = 1e-2 * ref[hit].mean()
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=tol, sample_share=0.25)
    err = np.abs(img - ref).max(axis=2)
    assert err.max() <= tol and st.error_estimate <= tol, (err.max() / tol, st.error_estimate / tol)
    m = st.exact_mask
    assert (err[m] <= st.pixel_error[m]).all(), (err - st.pixel_error)[m].max()
    assert st.sample_bound == st.pixel_error[m].max()
    assert st.sample_bound <= 0.25 * tol * (1 + 1e-9) + 4 * ROUNDING * ref.max()
    assert (st.pixel_error[m] > 1e-6 * tol).sum() > 0.5 * m.sum(), st
    assert st.exact_points == int(m.sum()) and not m[~hit].any() and not img[~hit].any()
    # the exact samples' pass (share 0) is the default, and bit for bit what it was
    exact_samples, st0 = adaptive_irradiance(scene, p, n, g, tolerance=tol)
    again, st00 = adaptive_irradiance(scene, p, n, g, tolerance=tol, sample_share=0.0)
    assert np.array_equal(exact_samples, again) and np.array_equal(st0.exact_mask, st00.exact_mask)
    assert st0.sample_bound == 0.0 and (st0.pixel_error[st0.exact_mask] == 0).all()
    assert np.array_equal(exact_samples[st0.exact_mask], ref[st0.exact_mask])


@pytest.mark.parametrize("shares", [(0.25, None), (0.05, 0.9)], ids=["share", "final"])
@pytest.mark.parametrize("name", list(SCENES))
def test_far_field_samples_on_every_test_scene(name, shares):
    """The Cornell box and the scenes built to break interpolation, with far-field samples (and final samples
    with 0.9 of the tolerance, step 6): the image within the tolerance, each sample within its bound."""
    scene, p, n, g, ref = prepared(name)
    share, final = shares
    for rel in (1e-2, 1e-3):
        tol = rel * ref[g >= 0].mean()
        img, st = adaptive_irradiance(scene, p, n, g, tolerance=tol, sample_share=share, final_share=final)
        err = np.abs(img - ref).max(axis=2)
        assert err.max() <= tol and st.error_estimate <= tol, (name, rel, err.max() / tol)
        assert (err[st.exact_mask] <= st.pixel_error[st.exact_mask]).all()
        assert (st.final_points > 0) == (final is not None), st.final_points


def test_final_samples_take_their_share():
    """Step 6 on the smooth box: the final samples (pixels no interpolation uses) get 0.9 of the tolerance,
    the others 0.05. The image within the tolerance, each sample within its bound, some bound above the
    smaller share (the final share was used) and pixels still interpolated; ``final_share`` None or equal to
    ``sample_share`` is one tolerance for all."""
    from hemisphere_local_pass.core.far_field import ROUNDING

    scene, p, n, g, ref = smooth_box_image()
    hit = g >= 0
    tol = 1e-2 * ref[hit].mean()
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=tol, sample_share=0.05, final_share=0.9)
    err = np.abs(img - ref).max(axis=2)
    m = st.exact_mask
    assert err.max() <= tol and st.error_estimate <= tol, (err.max() / tol, st.error_estimate / tol)
    assert (err[m] <= st.pixel_error[m]).all(), (err - st.pixel_error)[m].max()
    allowance = 4 * ROUNDING * ref.max()
    assert st.sample_bound <= 0.9 * tol * (1 + 1e-9) + allowance
    assert st.sample_bound > 0.05 * tol * (1 + 1e-9) + allowance and 0 < st.final_points < st.exact_points, st
    assert (hit & ~m).any()
    same, st_same = adaptive_irradiance(scene, p, n, g, tolerance=tol, sample_share=0.25, final_share=0.25)
    default, st_default = adaptive_irradiance(scene, p, n, g, tolerance=tol, sample_share=0.25)
    assert np.array_equal(same, default) and np.array_equal(st_same.pixel_error, st_default.pixel_error)
    assert st_same.final_points == 0 == st_default.final_points


def test_far_field_samples_tolerance_zero_and_bad_share():
    scene, p, n, g, ref = prepared("thin occluders")
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=0.0, sample_share=0.5)
    assert np.array_equal(img, ref) and st.error_estimate == 0.0 and st.sample_bound == 0.0
    img, st = adaptive_irradiance(scene, p, n, g, tolerance=0.0, sample_share=0.1, final_share=0.9)
    assert np.array_equal(img, ref) and st.error_estimate == 0.0 and st.sample_bound == 0.0
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="sample_share"):
            adaptive_irradiance(scene, p, n, g, tolerance=0.1, sample_share=bad)
        with pytest.raises(ValueError, match="final_share"):
            adaptive_irradiance(scene, p, n, g, tolerance=0.1, sample_share=0.1, final_share=bad)


def test_neighbour_misses_are_the_corners_second_differences():
    """``_neighbour_misses`` on a synthetic image: half the second difference at each end of a cell, along the
    axis it varies on, from exact samples on the same surface only (a break or a missing sample drops it)."""
    from hemisphere_local_pass.core.adaptive import _neighbour_misses, _summed

    h, w = 5, 12
    x = np.arange(w, dtype=float)
    f = np.abs(x - 8.6) + 0.01 * x**2                          # a kink between x = 8 and 10
    H = np.repeat(np.broadcast_to(f, (h, w))[..., None], 3, axis=2).copy()
    exact = np.ones((h, w), dtype=bool)
    bound = np.zeros((h, w))
    no_x, no_y = np.zeros((h, w - 1), dtype=bool), np.zeros((h - 1, w), dtype=bool)
    cell = [np.array([v]) for v in (4, 6, 8, 0, 2, 4)]          # x0, mx, x1, y0, my, y1
    left, right = abs(f[2] - 2 * f[4] + f[6]) / 2, abs(f[10] - 2 * f[8] + f[6]) / 2
    ax, ay = _neighbour_misses(H, exact, bound, _summed(no_x), _summed(no_y), *cell)
    assert ax[0] == max(left, right) and right > left and ay[0] == 0.0
    brk = no_x.copy()
    brk[:, 9] = True                                          # a surface break between x = 9 and 10
    ax, _ = _neighbour_misses(H, exact, bound, _summed(brk), _summed(no_y), *cell)
    assert ax[0] == left
    missing = exact.copy()
    missing[:, 2] = False                                     # the left outside pixel is no sample
    ax, _ = _neighbour_misses(H, missing, bound, _summed(brk), _summed(no_y), *cell)
    assert ax[0] == 0.0
    bound[0, 10] = 0.5                                        # a far-field sample's bound counts 4 b, halved
    ax, _ = _neighbour_misses(H, exact, bound, _summed(no_x), _summed(no_y), *cell)
    assert ax[0] == max(left, right + 1.0)
