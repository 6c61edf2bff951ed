"""Outputs: OpenEXR layout and atomic writes, tiles and merging, the image datablock, the PNG preview,
vertex-colour attribute rules."""

import importlib
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")


@pytest.fixture
def outputs(extension, scene):
    return importlib.import_module(extension.__name__ + ".blender.outputs")


def layers(h, w, seed=0):
    rng = np.random.default_rng(seed)
    return {
        "radiance": rng.random((h, w, 3)) * 5, "irradiance": rng.random((h, w, 3)), "alpha": rng.random((h, w)),
        "form_factor_sum": rng.random((h, w)), "depth": rng.random((h, w)) + 1,
        "object_index": rng.integers(-1, 5, (h, w)).astype(float),
        "polygon_index": rng.integers(-1, 2**20, (h, w)).astype(float),
    }


def test_exr_round_trip_channels_and_orientation(outputs, tmp_path):
    import OpenEXR

    lay = layers(3, 5)
    path = outputs.write_exr(str(tmp_path / "a.exr"), lay, size=(5, 3), metadata={"hlp_note": "x"})
    got, size, window, header = outputs.read_exr(path)
    assert size == (5, 3) and window == (0, 0, 5, 3) and header["hlp_note"] == "x"
    for k, v in lay.items():
        np.testing.assert_array_equal(got[k], v.astype(np.float32), err_msg=k)
    f = OpenEXR.File(path, separate_channels=True)
    names = set(f.channels())
    assert names == set(outputs.CHANNELS)
    # file row 0 is the top of the image: our row 0 (bottom) is the file's last row
    np.testing.assert_array_equal(np.asarray(f.channels()["R"].pixels)[-1], lay["radiance"][0, :, 0].astype(np.float32))
    # Blender reads it as an ordinary RGBA float image (radiance + coverage)
    img = bpy.data.images.load(path)
    px = np.empty(len(img.pixels), dtype=np.float32)
    img.pixels.foreach_get(px)
    np.testing.assert_allclose(px.reshape(3, 5, 4)[..., :3], lay["radiance"], rtol=1e-6)
    np.testing.assert_allclose(px.reshape(3, 5, 4)[..., 3], lay["alpha"], rtol=1e-6)


def read(path):
    with open(path, "rb") as fh:
        return fh.read()


def test_atomic_replace_and_failures_leave_the_old_file(outputs, tmp_path):
    path = str(tmp_path / "a.exr")
    outputs.write_exr(path, layers(2, 2, 1), size=(2, 2))
    before = read(path)
    bad = layers(2, 2, 2)
    bad["depth"] = np.zeros((3, 3))
    with pytest.raises(ValueError, match="layer depth has shape"):
        outputs.write_exr(path, bad, size=(2, 2))
    assert read(path) == before
    assert os.listdir(tmp_path) == ["a.exr"], "a temporary file was left behind"

    def boom(tmp):
        with open(tmp, "wb") as fh:
            fh.write(b"partial")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        outputs.replace_atomically(path, boom)
    assert read(path) == before and os.listdir(tmp_path) == ["a.exr"]


def test_unwritable_paths(outputs, tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        outputs.check_writable(str(tmp_path / "no" / "x.exr"))
    with pytest.raises(ValueError, match="is a directory"):
        outputs.check_writable(str(tmp_path))
    f = tmp_path / "f"
    f.write_text("")
    with pytest.raises(ValueError, match="cannot write"):
        outputs.check_writable(str(f / "x.exr"))
    assert outputs.check_writable(str(tmp_path / "ok.exr")) == str(tmp_path / "ok.exr")
    assert os.listdir(tmp_path) == ["f"]


def test_merge_tiles(outputs, tmp_path):
    full = layers(6, 4, 3)
    paths = []
    for i, (y0, y1) in enumerate([(4, 6), (2, 4), (0, 2)]):
        p = str(tmp_path / f"t{i}.exr")
        part = {k: v[y0:y1] for k, v in full.items()}
        outputs.write_exr(p, part, size=(4, 6), window=(0, y0, 4, y1), metadata={"hlp_fingerprint": "job1"})
        paths.append(p)
    merged = outputs.merge_exr(paths, str(tmp_path / "m.exr"))
    got, size, window, header = outputs.read_exr(merged)
    assert size == (4, 6) and window == (0, 0, 4, 6) and header["hlp_fingerprint"] == "job1"
    for k, v in full.items():
        np.testing.assert_array_equal(got[k], v.astype(np.float32), err_msg=k)
    other = str(tmp_path / "other.exr")
    outputs.write_exr(other, {k: v[0:2] for k, v in full.items()}, size=(4, 6), window=(0, 0, 4, 2),
                      metadata={"hlp_fingerprint": "job2"})
    with pytest.raises(ValueError, match="different job"):
        outputs.merge_exr([paths[0], other], str(tmp_path / "m2.exr"))
    with pytest.raises(ValueError, match="does not exist"):
        outputs.merge_exr([str(tmp_path / "nope.exr")], str(tmp_path / "m3.exr"))


def test_image_datablock_and_png_preview(outputs, tmp_path):
    rgba = np.zeros((4, 6, 4))
    rgba[..., 0] = np.linspace(0, 1, 6)
    rgba[..., 3] = 1
    img = outputs.store_image("Local Pass", rgba)
    assert img.is_float and tuple(img.size) == (6, 4)
    img2 = outputs.store_image("Local Pass", np.ones((2, 3, 4)))  # resized in place
    assert img2 == img and tuple(img.size) == (3, 2)
    png = outputs.write_png(str(tmp_path / "p.png"), rgba[..., :3])
    loaded = bpy.data.images.load(png)
    assert tuple(loaded.size) == (6, 4) and loaded.file_format == "PNG"
    px = np.empty(len(loaded.pixels), dtype=np.float32)
    loaded.pixels.foreach_get(px)
    want = outputs.srgb_encode(rgba[..., 0])
    np.testing.assert_allclose(px.reshape(4, 6, 4)[..., 0], want, atol=1 / 255 + 1e-6)
    assert ".hlp_preview" not in bpy.data.images
    assert outputs.srgb_encode(np.array([0.0, 0.0031308, 1.0, 7.0])).tolist() == pytest.approx(
        [0.0, 0.04045, 1.0, 1.0], abs=1e-5)


def test_vertex_colour_rules(outputs):
    me = bpy.data.meshes.new("M")
    me.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    user = me.attributes.new("hlp_radiance", "FLOAT_COLOR", "POINT")
    with pytest.raises(ValueError, match="already has a user attribute"):
        outputs.prepare_vertex_attribute(me, "hlp_radiance", "POINT")
    outputs.prepare_vertex_attribute(me, "hlp_radiance", "POINT", explicit=True)
    with pytest.raises(ValueError, match="also an input"):
        outputs.prepare_vertex_attribute(me, "radiosity", "POINT", protected=("radiosity",))
    with pytest.raises(ValueError, match="built-in"):
        outputs.prepare_vertex_attribute(me, "position", "POINT", explicit=True)
    del user
    vals = np.array([(1, 2, 3), (4, 5, 6), (7, 8, 9)], dtype=float)
    outputs.write_vertex_colours(me, "out", "POINT", vals)
    outputs.prepare_vertex_attribute(me, "out", "POINT")  # ours: may be overwritten
    outputs.write_vertex_colours(me, "out", "POINT", vals * 0, mask=np.array([True, False, False]))
    got = np.empty(12, dtype=np.float32)
    me.attributes["out"].data.foreach_get("color", got)
    np.testing.assert_array_equal(got.reshape(3, 4), [(0, 0, 0, 1), (4, 5, 6, 1), (7, 8, 9, 1)])
    outputs.write_vertex_colours(me, "out", "CORNER", np.ones((3, 3)))  # domain change: re-created
    assert me.attributes["out"].domain == "CORNER"
    assert list(me[outputs.OWNED_KEY]) == ["out"]


def test_builtin_writer_without_the_openexr_package(outputs, tmp_path, monkeypatch):
    """Blender 3.4 loads the package as a legacy add-on without its wheels: the built-in writer
    produces files OpenEXR and Blender read, and tiles still merge."""
    import OpenEXR

    full = layers(5, 3, 4)
    monkeypatch.setattr(outputs, "_openexr", lambda: None)
    path = outputs.write_exr(str(tmp_path / "plain.exr"), {k: v[1:4] for k, v in full.items()}, size=(3, 5),
                             window=(0, 1, 3, 4), metadata={"hlp_fingerprint": "j"})
    got, size, window, header = outputs.read_exr(path)  # built-in reader
    assert size == (3, 5) and window == (0, 1, 3, 4) and header["hlp_fingerprint"] == "j"
    for k, v in full.items():
        np.testing.assert_array_equal(got[k], v[1:4].astype(np.float32), err_msg=k)
    f = OpenEXR.File(path, separate_channels=True)  # the reference library agrees
    assert set(f.channels()) == set(outputs.CHANNELS) and f.header()["hlp_fingerprint"] == "j"
    np.testing.assert_array_equal(np.asarray(f.channels()["Z"].pixels)[::-1], full["depth"][1:4].astype(np.float32))
    (ax0, ay0), (ax1, ay1) = f.header()["dataWindow"]
    assert (int(ax0), int(ay0), int(ax1), int(ay1)) == (0, 1, 2, 3)
    img = bpy.data.images.load(path)
    px = np.empty(len(img.pixels), dtype=np.float32)
    img.pixels.foreach_get(px)
    assert tuple(img.size) == (3, 3)  # Blender shows a tile's data window
    np.testing.assert_allclose(px.reshape(3, 3, 4)[..., :3], full["radiance"][1:4], rtol=1e-6)
    rest = [outputs.write_exr(str(tmp_path / f"t{i}.exr"), {k: v[a:b] for k, v in full.items()}, size=(3, 5),
                              window=(0, a, 3, b), metadata={"hlp_fingerprint": "j"})
            for i, (a, b) in enumerate([(0, 1), (4, 5)])]
    merged = outputs.merge_exr([path] + rest, str(tmp_path / "m.exr"))
    got, *_ = outputs.read_exr(merged)
    np.testing.assert_array_equal(got["radiance"], full["radiance"].astype(np.float32))
