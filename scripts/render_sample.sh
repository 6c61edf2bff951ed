#!/usr/bin/env bash
# The README's first command: on a fresh machine, set up what is needed (the bpy 4.2 venv), build the
# sample Cornell box (sample_scenes/cornell_box.py: FACE-domain `radiosity` attribute from the
# radiosity first pass), and render it through the batch path (the same `render` program as
# `blender -b scene.blend -c hemisphere_local_pass render ...`) to out/cornell_box.exr and a PNG
# preview (out/cornell_box.png). Prints the time and max |sum F - 1|.
#   HLP_RESOLUTION (default 64) and HLP_SUBDIVISIONS (default 4: 172 polygons) change the job.
#
#   scripts/render_sample.sh [SAMPLE]   picks another sample of sample_scenes/ (built, solved by the
#   first pass, then rendered to out/SAMPLE.exr): cornell_box (default), cornell_box_9500,
#   furnished_room, numerical_traps, cornell_box_100k. `--list` prints them.
set -euo pipefail
SAMPLES="cornell_box cornell_box_9500 furnished_room numerical_traps cornell_box_100k"
SAMPLE="${1:-${HLP_SAMPLE:-cornell_box}}"
if [ "$SAMPLE" = "--list" ]; then echo "$SAMPLES"; exit 0; fi
case " $SAMPLES " in
    *" $SAMPLE "*) ;;
    *) echo "render_sample: unknown sample '$SAMPLE' (one of: $SAMPLES)" >&2; exit 2 ;;
esac
source "$(dirname "$0")/envs.sh"
source "$(dirname "$0")/bpy_envs.sh"
cd "$HLP_ROOT"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
PY="$(bpy_python 4.2)"
# the built extension bundles the OpenEXR wheel; a checkout needs it in the venv
"$PY" -c "import OpenEXR" 2>/dev/null || "$PY" -m pip install -q --disable-pip-version-check openexr==3.5.3 >&2
mkdir -p out
start=$(date +%s%N)
if [ "$SAMPLE" = cornell_box ]; then
    "$PY" sample_scenes/cornell_box.py out/cornell_box.blend \
        --subdivisions "${HLP_SUBDIVISIONS:-4}" --resolution "${HLP_RESOLUTION:-64}"
else
    "$PY" "sample_scenes/$SAMPLE.py" "out/$SAMPLE.blend" --resolution "${HLP_RESOLUTION:-64}"
fi
"$PY" - "out/$SAMPLE.blend" "out/$SAMPLE.exr" <<'PYEOF'
import sys

import bpy

blend, exr = sys.argv[1], sys.argv[2]
bpy.ops.wm.open_mainfile(filepath=blend)
sys.path.insert(0, ".")
from hemisphere_local_pass.blender import job  # noqa: E402

sys.exit(job.cli_main(["render", "--output", exr, "--overwrite"]))  # out/ belongs to this script
PYEOF
ms=$(( ($(date +%s%N) - start) / 1000000 ))
printf 'render_sample: total %d.%03d s (scene + local pass); outputs in out/\n' $((ms / 1000)) $((ms % 1000))
