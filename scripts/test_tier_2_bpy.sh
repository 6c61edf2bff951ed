#!/usr/bin/env bash
# Tier 2: Blender as a Python module. For each bpy version: create its venv (pinned bpy + numpy +
# pytest + hypothesis), then run tests/blender, which builds the extension with that Blender's own
# blender_ext.py, installs the zip into an isolated user directory and enables it.
# First the release build (dist/, every platform) with the oldest supported Blender's tool.
#
#   HLP_BPY_VERSIONS  versions to test (default: all four: 4.2 4.5 5.0 5.2; 4.2 and 5.2 are the
#                     minimum — see docs/blender.md for the measured cost of each).
# Any failure (venv, build, a test, a missing prerequisite) makes the script exit non-zero.
set -uo pipefail
source "$(dirname "$0")/envs.sh"
source "$(dirname "$0")/bpy_envs.sh"
cd "$HLP_ROOT"

export HLP_REQUIRE_BPY=1   # tests/blender fail instead of skipping when bpy is missing
status=0
versions=(${HLP_BPY_VERSIONS:-4.2 4.5 5.0 5.2})
t_all=$(date +%s)

fail() { echo "tier 2: FAILED: $*" >&2; status=1; }

# Release build: every platform, validated and built by bpy 4.2's tool (the oldest we support).
t0=$(date +%s)
if py42="$(bpy_python 4.2)"; then
    echo "=== tier 2: build (bpy 4.2 tool)" >&2
    "$py42" scripts/build_extension.py --bpy-python "$py42" || fail "extension build"
else
    fail "bpy 4.2 venv"
fi
echo "[time] tier 2 build: $(( $(date +%s) - t0 )) s" >&2

for v in "${versions[@]}"; do
    t0=$(date +%s)
    if ! py="$(bpy_python "$v")"; then
        fail "bpy $v venv"
        continue
    fi
    t1=$(date +%s)
    echo "=== tier 2: bpy $v ($("$py" -c 'import bpy; print(bpy.app.version_string)' 2>/dev/null))" >&2
    "$py" -m pytest -q -p no:cacheprovider tests/blender || fail "tests/blender on bpy $v"
    echo "[time] tier 2 bpy $v: venv $(( t1 - t0 )) s, tests $(( $(date +%s) - t1 )) s" >&2
done
echo "[time] tier 2 total: $(( $(date +%s) - t_all )) s" >&2
exit $status
