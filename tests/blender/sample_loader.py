"""The bundled sample scenes (``sample_scenes/<name>.py``) loaded as modules for the tier-2 tests: each
file is a script meant for ``blender --python``, not a package, so it is loaded from its path."""

import importlib.util
import os

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SAMPLES = os.path.join(ROOT, "sample_scenes")


def sample_module(name: str = "cornell_box"):
    """A fresh module of ``sample_scenes/<name>.py`` (its ``build(...)`` makes the scene in bpy)."""
    spec = importlib.util.spec_from_file_location(f"hlp_sample_{name}", os.path.join(SAMPLES, f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
