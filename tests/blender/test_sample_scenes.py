"""Every sample scene's script builds its scene, solves the first pass and saves a .blend (small settings)."""

import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from sample_loader import sample_module  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SAMPLES = os.path.join(ROOT, "sample_scenes")


def load(name):
    return sample_module(name)


def check_solved(min_meshes):
    meshes = [m for m in bpy.data.meshes if m.users]
    assert len(meshes) >= min_meshes
    for mesh in meshes:
        attr = mesh.attributes.get("radiosity")
        assert attr is not None and attr.domain == "FACE" and attr.data_type == "FLOAT_COLOR", mesh.name
        assert "radiosity" in list(mesh.get("hlp_owned_attributes", [])), mesh.name
        values = np.empty(4 * len(attr.data), dtype=np.float32)
        attr.data.foreach_get("color", values)
        assert np.isfinite(values).all() and (values >= 0).all(), mesh.name
    assert bpy.context.scene.camera is not None


# (script, main() arguments with small settings, meshes at least)
CASES = [
    ("cornell_box", ["--subdivisions", "2", "--resolution", "8"], 9),
    ("cornell_box_9500", ["--subdivisions", "3", "--resolution", "8"], 9),
    ("furnished_room", ["--detail", "1", "--resolution", "8", "--tolerance", "0.05"], 12),
    ("numerical_traps", ["--cells", "2", "--resolution", "8", "--tolerance", "0.05"], 10),
    ("cornell_box_100k", ["--subdivisions", "4", "--clusters", "20", "--resolution", "8"], 9),
    ("cornell_box_100k", ["--subdivisions", "4", "--clusters", "20", "--resolution", "8", "--in-blender"], 9),
]


@pytest.mark.parametrize("name,args,min_meshes", CASES, ids=[c[0] for c in CASES])
def test_sample_script_builds_solves_and_saves(extension, name, args, min_meshes, tmp_path, capsys):
    out = tmp_path / f"{name}.blend"
    assert load(name).main([str(out), *args]) == 0
    from conftest import ensure_enabled

    ensure_enabled()
    err = capsys.readouterr().err
    assert "NOT converged" not in err
    if name == "cornell_box_100k":  # solved on its own polygons, reflected light from clusters
        assert "reflected light shot from" in err and "clusters" in err
    check_solved(min_meshes)
    assert out.is_file() and out.stat().st_size < 5 * 2**20
    bpy.ops.wm.open_mainfile(filepath=str(out))
    check_solved(min_meshes)
