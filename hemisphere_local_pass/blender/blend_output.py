"""The ``.blend`` file a command saves its result to (vertices mode's ``render --output FILE.blend``,
``solve --output``): checked before the job, saved atomically after it, the old file kept as
``.blend1``; never the open file itself, never a file that is not a .blend."""

from __future__ import annotations

import os
import shutil

__all__ = ["check_blend_output", "save_blend"]


def check_blend_output(path: str, overwrite: bool) -> str:
    """Vertices mode's ``--output FILE.blend``: resolved and writable; never the open file itself,
    never an existing file that is not a .blend; an existing .blend only with ``--overwrite``."""
    import bpy

    from . import output_paths as op

    path = op.check_writable(path)
    if not path.lower().endswith(".blend"):
        raise ValueError("in vertices mode --output names the .blend file to save the colour attributes to")
    if not os.path.lexists(path):
        return path
    if bpy.data.filepath and os.path.exists(bpy.data.filepath) and os.path.samefile(path, bpy.data.filepath):
        raise op.OutputRefused(f"--output '{path}' is the open .blend file: the job never overwrites its input; "
                               "give another file name")
    found = op.describe(path)
    if not os.path.isfile(path) or op.file_kind(path) != "blend":
        raise op.OutputRefused(f"--output '{path}' exists and is {found}, not a .blend file: it is never replaced")
    if not overwrite:
        raise op.OutputRefused(f"--output '{path}' exists: pass --overwrite to replace it (the old file is kept "
                               "as .blend1)")
    return path


def save_blend(path: str) -> str:
    """Save a copy of the current file (with the new attributes) to ``path``, atomically; an existing
    file there is kept as ``path + "1"`` (Blender's own backup name)."""
    import bpy

    from .outputs import replace_atomically

    def save(tmp):
        os.unlink(tmp)  # a new file: Blender then keeps no .blend1 backup of the placeholder
        bpy.ops.wm.save_as_mainfile(filepath=tmp, copy=True)
        if os.path.isfile(path):  # only with --overwrite (check_blend_output): keep the old file
            backup = path + "1"
            if os.path.lexists(backup):
                os.unlink(backup)
            shutil.copy2(path, backup)

    return replace_atomically(path, save)
