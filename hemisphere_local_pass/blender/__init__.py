"""The thin Blender layer: scene extraction, camera, outputs, the job, the CLI command and the UI.

Nothing here is imported by ``hemisphere_local_pass`` at import time; ``registration`` is imported
inside ``register()``.
"""
