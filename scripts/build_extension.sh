#!/usr/bin/env bash
# Build the extension zips into dist/ (one per platform), using the bpy 4.2 venv's Python and the
# blender_ext.py inside its bpy wheel (the venv is created on first use). Arguments go to
# scripts/build_extension.py (e.g. --platform linux-x64, --offline).
set -euo pipefail
source "$(dirname "$0")/envs.sh"
source "$(dirname "$0")/bpy_envs.sh"
cd "$HLP_ROOT"
py="$(bpy_python "${HLP_BUILD_BPY:-4.2}")"
exec "$py" scripts/build_extension.py --bpy-python "$py" "$@"
