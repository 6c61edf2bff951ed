#!/usr/bin/env bash
# Regenerate docs/guide/*.png and docs/guide/images.md: every sample's exact local pass beside Cycles at
# equal time (docs/make_images.py, in the bpy 4.2 venv). Without arguments: all five samples, the Cornell
# box at 96x96, the others at 48x48 (~1 h on the shared 2-core machine). Arguments go to docs/make_images.py:
#   --samples cornell_box,numerical_traps,furnished_room,cornell_box_9500,cornell_box_100k  --resolution N
#   --blend out/cornell_box_100k.blend (one sample: open a prebuilt .blend)  --numeric (Cornell boxes: the local
#   pass by the core on float64 coordinates; the default for cornell_box_100k)
set -euo pipefail
source "$(dirname "$0")/envs.sh"
source "$(dirname "$0")/bpy_envs.sh"
cd "$HLP_ROOT"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
PY="$(bpy_python 4.2)"
"$PY" -c "import OpenEXR" 2>/dev/null || "$PY" -m pip install -q --disable-pip-version-check openexr==3.5.3 >&2
"$PY" docs/make_images.py "$@"
